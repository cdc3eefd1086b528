//! Shared by the `spread_levels` example and the `spread_shared` test: the
//! shared volumes, the scenes, and whole coarse levels rendered by the CPU
//! reference as the TF of their mean and with their spread.

#![allow(dead_code)] // each user calls a part

use brickray_core::{
    Camera, DType, MomentGrid, RenderSettings, Shading, TransferFunction, Volume, VolumeData,
    VolumeDesc, VolumeFrame, anisotropic_split_masks,
};
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use glam::{Mat4, Vec3};
use std::path::{Path, PathBuf};

/// `<workspace>/../shared/data`.
pub(crate) fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
}

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

pub(crate) fn read_shared(dir: &Path, name: &str) -> Result<Volume, String> {
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
            kind: Default::default(),
        },
        VolumeData::from_le_bytes(dtype, &bytes),
    )
    .map_err(|e| e.to_string())
}

/// Every third slice of `vol` (z), three times as thick.
pub(crate) fn every_third_slice(vol: &Volume) -> Volume {
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

pub(crate) fn hu(v: f32) -> f32 {
    (v + 1024.0) / 4010.0
}

/// The bone ramp on the head CT: opacity 0 at 100 HU, 0.02 at 150,
/// 0.5 at 300.
pub(crate) fn bone_ramp() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (hu(100.0), [0.8, 0.5, 0.4, 0.0]),
            (hu(150.0), [0.9, 0.8, 0.7, 0.02]),
            (hu(300.0), [1.0, 0.95, 0.85, 0.5]),
        ],
        512,
    )
}

/// The pareto suite's MRI TF.
pub(crate) fn mri_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.12, [0.3, 0.12, 0.06, 0.0]),
            (0.35, [0.9, 0.5, 0.3, 0.08]),
            (0.7, [1.0, 0.9, 0.8, 0.4]),
        ],
        512,
    )
}

/// One coarse level's figures: its dims and the PSNR (dB) against the finest
/// level of the TF of its mean and of the spread model.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LevelFigures {
    pub(crate) dims: [u32; 3],
    pub(crate) today: f64,
    pub(crate) spread: f64,
}

/// The first `levels` coarse levels of `vol` (anisotropic split masks of
/// 32-voxel bricks), `size x size`, orbit camera at distance 2 (azimuth 0.5,
/// elevation 0.3), each drawn as out of core draws it: opacity per finest
/// voxel, the step 0.5 finest voxels times `2^e`, `e` the fewest halvings of
/// any axis; against the finest level at step 0.5.
pub(crate) fn level_psnrs(
    vol: &Volume,
    tf: &TransferFunction,
    shaded: bool,
    size: u32,
    levels: usize,
) -> Vec<LevelFigures> {
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let fine_extent = Vec3::from_array(d.spacing) * glam::UVec3::from_array(d.dims).as_vec3();
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let mut masks = anisotropic_split_masks(d.dims, d.spacing, 32);
    masks.reverse();
    let settings = RenderSettings {
        shading: Shading {
            enabled: shaded,
            ..Default::default()
        },
        ..Default::default()
    };
    let opts = ReferenceOptions::new(size, size).with_step_factor(0.5);
    let finest = render_reference(vol, &frame, tf, &camera, &settings, &opts).to_rgba8([0.0; 3]);
    let mut level = MomentGrid::from_volume(vol);
    let mut halvings = [0u32; 3];
    let mut out = Vec::new();
    for mask in masks.iter().take(levels) {
        level = level.downsample(*mask);
        for (a, h) in halvings.iter_mut().enumerate() {
            *h += u32::from(mask & (1 << a) != 0);
        }
        let e = halvings.iter().min().copied().unwrap_or(0);
        let lopts = opts.with_step_factor(0.5 * (1u32 << e) as f32);
        let coarse = level.mean_volume().expect("a valid level");
        let sigma = level.sigmas();
        // The level's box starts where the finest does and covers its
        // (possibly padded) voxels.
        let extent =
            Vec3::from_array(level.spacing()) * glam::UVec3::from_array(level.dims()).as_vec3();
        let mut cframe = VolumeFrame::new(
            frame.model * Mat4::from_scale(extent / fine_extent),
            level.dims(),
        );
        cframe.voxel_world = frame.voxel_world;
        let today =
            render_reference(&coarse, &cframe, tf, &camera, &settings, &lopts).to_rgba8([0.0; 3]);
        let spread = render_reference(
            &coarse,
            &cframe,
            tf,
            &camera,
            &settings,
            &lopts.with_spread(&sigma),
        )
        .to_rgba8([0.0; 3]);
        out.push(LevelFigures {
            dims: level.dims(),
            today: psnr(&finest, &today),
            spread: psnr(&finest, &spread),
        });
    }
    out
}
