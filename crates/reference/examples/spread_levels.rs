//! Coarse levels drawn as the TF of their mean against the spread model
//! (`docs/rendering-model.md`, *Coarse levels*), in the CPU reference alone:
//! each level of the shared head CT, the same CT with every third slice
//! (4.5 mm, an anisotropic pyramid) and the shared T1 MRI, rendered at 96 x 96
//! as the out-of-core renderer draws a level (opacity per finest voxel, the
//! step 0.5 finest voxels times 2^e, e the fewest halvings of any axis),
//! against the finest level at step 0.5 (PSNR, dB). Needs `../shared/data` next to the repository.
//!
//! `cargo run --release -p brickray-reference --example spread_levels`

mod spread_common;

use spread_common::{bone_ramp, every_third_slice, level_psnrs, mri_tf, read_shared, shared_dir};

fn main() {
    let dir = shared_dir();
    if !dir.is_dir() {
        eprintln!("needs the shared data at {}", dir.display());
        std::process::exit(2);
    }
    let (bone, mri_tf) = (bone_ramp(), mri_tf());
    for (name, tf) in [("bone ramp", &bone), ("mri", &mri_tf)] {
        let t = std::time::Instant::now();
        let table = tf.spread_table(brickray_core::tf::SPREAD_ROWS, 8192);
        println!(
            "spread table of the {name} TF: {} x {} texels in {:.1} ms",
            table.width,
            table.rows,
            t.elapsed().as_secs_f64() * 1e3
        );
    }
    let ct = read_shared(&dir, "invesalius_cranium_ct").unwrap_or_else(|e| panic!("{e}"));
    let ct5 = every_third_slice(&ct);
    let mri = read_shared(&dir, "pycortex_s1_t1_mri").unwrap_or_else(|e| panic!("{e}"));
    for (name, vol, tf) in [
        ("ct", &ct, &bone),
        ("ct5", &ct5, &bone),
        ("mri", &mri, &mri_tf),
    ] {
        for shaded in [false, true] {
            for (l, f) in level_psnrs(vol, tf, shaded, 96, 3).iter().enumerate() {
                println!(
                    "{name} shaded={shaded} level {} {:?}: TF of the mean {:.1} dB, spread {:.1} dB",
                    l + 1,
                    f.dims,
                    f.today,
                    f.spread
                );
            }
        }
    }
}
