//! The spread model on the shared volumes, in the CPU reference: whole coarse
//! levels of the head CT with every third slice (4.5 mm, anisotropic) and of
//! the T1 MRI, 64 x 64, unshaded and shaded, against the finest level
//! (`docs/accuracy.md`, *Coarse levels*, has the 96 px figures of every
//! level). Ignored, with the reason, when `../shared/data` is absent; with
//! `CI=true` it runs and fails without it.

#[path = "../examples/spread_common/mod.rs"]
mod spread_common;

use spread_common::{bone_ramp, every_third_slice, level_psnrs, mri_tf, read_shared, shared_dir};

/// Each of the first two coarse levels scores at least 1 dB closer to the
/// finest level with its spread than as the TF of its mean (measured at 64 px:
/// printed with `--nocapture`).
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data (absent)")]
fn spread_brings_coarse_levels_of_the_shared_volumes_closer() {
    let dir = shared_dir();
    let ct = read_shared(&dir, "invesalius_cranium_ct").expect("the shared head CT");
    let ct5 = every_third_slice(&ct);
    let mri = read_shared(&dir, "pycortex_s1_t1_mri").expect("the shared T1 MRI");
    let (bone, mri_tf) = (bone_ramp(), mri_tf());
    for (name, vol, tf) in [("ct5", &ct5, &bone), ("mri", &mri, &mri_tf)] {
        for shaded in [false, true] {
            for (l, f) in level_psnrs(vol, tf, shaded, 64, 2).iter().enumerate() {
                println!(
                    "{name} shaded={shaded} level {}: TF of the mean {:.1} dB, spread {:.1} dB",
                    l + 1,
                    f.today,
                    f.spread
                );
                assert!(
                    f.spread >= f.today + 1.0,
                    "{name} shaded={shaded} level {}: {f:?}",
                    l + 1
                );
            }
        }
    }
}
