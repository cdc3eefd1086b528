//! Coarse levels drawn as the TF of their mean against the spread model
//! (`docs/rendering-model.md`, *Coarse levels*), in the CPU reference alone:
//! each level of the shared head CT, the same CT with every third slice
//! (4.5 mm, an anisotropic pyramid) and the shared T1 MRI, rendered at 96 x 96
//! as the out-of-core renderer draws a level (opacity per finest voxel, the
//! step 0.5 finest voxels times 2^e, e the fewest halvings of any axis),
//! against the finest level at step 0.5 (PSNR, dB). Needs `../shared/data` next to the repository.
//!
//! `cargo run --release -p brickray-reference --example spread_levels`

use brickray_core::{
    Camera, DType, MomentGrid, RenderSettings, Shading, TransferFunction, Volume, VolumeData,
    VolumeDesc, VolumeFrame, anisotropic_split_masks,
};
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use glam::{Mat4, Vec3};
use std::path::{Path, PathBuf};

/// The numbers of `key`'s array (or value) in a flat JSON sidecar.
fn numbers(json: &str, key: &str) -> Vec<f64> {
    let Some(i) = json.find(&format!("\"{key}\"")) else {
        return Vec::new();
    };
    let rest = &json[i + key.len() + 2..];
    let rest = rest.trim_start_matches([':', ' ', '\n', '[']);
    let end = rest.find([']', '}', '"']).unwrap_or(rest.len());
    rest[..end]
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

fn read_shared(dir: &Path, name: &str) -> Result<Volume, String> {
    let json = std::fs::read_to_string(dir.join(name).join(format!("{name}.json")))
        .map_err(|e| format!("{name}: {e}"))?;
    let dims = numbers(&json, "dims");
    let spacing = numbers(&json, "spacing");
    let range = numbers(&json, "value_range");
    let dtype = json
        .split("\"dtype\"")
        .nth(1)
        .and_then(|s| s.split('"').nth(1))
        .and_then(DType::parse)
        .ok_or("no dtype")?;
    if dims.len() != 3 || spacing.len() != 3 || range.len() != 2 {
        return Err(format!("{name}: unreadable sidecar"));
    }
    let bytes = std::fs::read(dir.join(name).join(format!("{name}.raw")))
        .map_err(|e| format!("{name}: {e}"))?;
    Volume::new(
        VolumeDesc {
            dims: [0, 1, 2].map(|i| dims[i] as u32),
            spacing: [0, 1, 2].map(|i| spacing[i] as f32),
            dtype,
            value_range: [range[0] as f32, range[1] as f32],
        },
        VolumeData::from_le_bytes(dtype, &bytes),
    )
    .map_err(|e| e.to_string())
}

/// Every third slice of `vol` (z), three times as thick.
fn every_third_slice(vol: &Volume) -> Volume {
    let d = vol.desc().clone();
    let slice = (d.dims[0] * d.dims[1]) as usize;
    let nz = d.dims[2].div_ceil(3);
    let VolumeData::I16(all) = vol.data() else {
        panic!("the head CT is i16")
    };
    let thick: Vec<i16> = (0..nz as usize)
        .flat_map(|z| all[3 * z * slice..(3 * z + 1) * slice].iter().copied())
        .collect();
    Volume::new(
        VolumeDesc {
            dims: [d.dims[0], d.dims[1], nz],
            spacing: [d.spacing[0], d.spacing[1], d.spacing[2] * 3.0],
            ..d
        },
        VolumeData::I16(thick),
    )
    .expect("a valid volume")
}

fn hu(v: f32) -> f32 {
    (v + 1024.0) / 4010.0
}

fn main() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if !dir.is_dir() {
        eprintln!("needs the shared data at {}", dir.display());
        std::process::exit(2);
    }
    // The bone ramp: opacity 0.02 to 0.5 between 150 and 300 HU.
    let bone = TransferFunction::from_points(
        &[
            (hu(100.0), [0.8, 0.5, 0.4, 0.0]),
            (hu(150.0), [0.9, 0.8, 0.7, 0.02]),
            (hu(300.0), [1.0, 0.95, 0.85, 0.5]),
        ],
        512,
    );
    let mri_tf = TransferFunction::from_points(
        &[
            (0.12, [0.3, 0.12, 0.06, 0.0]),
            (0.35, [0.9, 0.5, 0.3, 0.08]),
            (0.7, [1.0, 0.9, 0.8, 0.4]),
        ],
        512,
    );
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
    let size = 96;
    for (name, vol, tf) in [
        ("ct", &ct, &bone),
        ("ct5", &ct5, &bone),
        ("mri", &mri, &mri_tf),
    ] {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let fine_extent = Vec3::from_array(d.spacing) * glam::UVec3::from_array(d.dims).as_vec3();
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        // Halvings going up from the finest level (32-voxel bricks).
        let mut masks = anisotropic_split_masks(d.dims, d.spacing, 32);
        masks.reverse();
        for shaded in [false, true] {
            let settings = RenderSettings {
                shading: Shading {
                    enabled: shaded,
                    ..Default::default()
                },
                ..Default::default()
            };
            let opts = ReferenceOptions::new(size, size).with_step_factor(0.5);
            let finest =
                render_reference(vol, &frame, tf, &camera, &settings, &opts).to_rgba8([0.0; 3]);
            let mut level = MomentGrid::from_volume(vol);
            let mut halvings = [0u32; 3];
            for (l, mask) in masks.iter().take(3).enumerate() {
                level = level.downsample(*mask);
                for (a, h) in halvings.iter_mut().enumerate() {
                    *h += u32::from(mask & (1 << a) != 0);
                }
                // As out of core: opacity stays per finest voxel, and the
                // level's step is the finest step times 2^e, e the fewest
                // halvings of any axis.
                let e = halvings.iter().min().copied().unwrap_or(0);
                let lopts = opts.with_step_factor(0.5 * (1u32 << e) as f32);
                let coarse = level.mean_volume().expect("a valid level");
                let sigma = level.sigmas();
                // The level's box starts where the finest does and covers
                // its (possibly padded) voxels.
                let extent = Vec3::from_array(level.spacing())
                    * glam::UVec3::from_array(level.dims()).as_vec3();
                let model = frame.model * Mat4::from_scale(extent / fine_extent);
                let mut cframe = VolumeFrame::new(model, level.dims());
                cframe.voxel_world = frame.voxel_world;
                let today = render_reference(&coarse, &cframe, tf, &camera, &settings, &lopts)
                    .to_rgba8([0.0; 3]);
                let spread = render_reference(
                    &coarse,
                    &cframe,
                    tf,
                    &camera,
                    &settings,
                    &lopts.with_spread(&sigma),
                )
                .to_rgba8([0.0; 3]);
                println!(
                    "{name} shaded={shaded} level {} {:?}: TF of the mean {:.1} dB, spread {:.1} dB",
                    l + 1,
                    level.dims(),
                    psnr(&finest, &today),
                    psnr(&finest, &spread)
                );
            }
        }
    }
}
