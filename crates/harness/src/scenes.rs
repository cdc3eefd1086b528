//! Small scenes shared by the tests and the bench suites (stability, pareto,
//! preint, skipping).

use brickray_core::{
    Camera, DType, DepthConvention, Projection, Volume, VolumeData, VolumeDesc, VolumeError,
};
use glam::Vec3;

/// The pareto suite's TF of Marschner-Lobb: a spike of opacity 0.6 at 0.5
/// over 0.45..0.55, blue below and orange above.
pub fn marschner_lobb_tf() -> brickray_core::TransferFunction {
    brickray_core::TransferFunction::from_points(
        &[
            (0.45, [0.2, 0.4, 0.9, 0.0]),
            (0.5, [0.9, 0.9, 0.9, 0.6]),
            (0.55, [0.9, 0.5, 0.2, 0.0]),
        ],
        512,
    )
}

/// The pareto suite's fractal noise: four octaves of value noise on an
/// `n^3` u8 grid, base period 32 voxels.
pub fn pareto_noise(n: u32) -> Volume {
    brickray_core::synthetic::u8_field(n, |p| {
        brickray_core::synthetic::fractal_noise(p.map(f64::from), 32.0, 4)
    })
}

/// A bright box 12 voxels thick (0.8, below the top of the range, which
/// would end MIP rays at once) around fractal noise at a fifth of its level,
/// on an `n^3` u8 grid: a volume where MIP's empty-space skipping pays.
pub fn bright_shell(n: u32) -> Volume {
    brickray_core::synthetic::u8_field(n, |p| {
        let edge = p.iter().map(|&c| c.min(n - 1 - c)).min().unwrap_or(0);
        if edge < 12 {
            0.8
        } else {
            0.2 * brickray_core::synthetic::fractal_noise(p.map(f64::from), 16.0, 3)
        }
    })
}

/// The pareto suite's TF of the fractal noise: from 0.55, opaque toward 0.8.
pub fn noise_tf() -> brickray_core::TransferFunction {
    brickray_core::TransferFunction::from_points(
        &[
            (0.55, [0.8, 0.4, 0.1, 0.0]),
            (0.65, [1.0, 0.8, 0.4, 0.3]),
            (0.8, [1.0, 1.0, 1.0, 0.9]),
        ],
        512,
    )
}

/// A narrow opacity spike (0.47..0.53, peak 0.8 at 0.5) in an otherwise
/// clear TF: what a coarse step samples through (pre-integration's tests and
/// the `preint` suite).
pub fn spike_tf() -> brickray_core::TransferFunction {
    brickray_core::TransferFunction::from_points(
        &[
            (0.47, [1.0, 0.6, 0.2, 0.0]),
            (0.5, [1.0, 0.9, 0.5, 0.8]),
            (0.53, [0.3, 0.6, 1.0, 0.0]),
        ],
        1024,
    )
}

/// The pareto suite's TF of the shared T1 MRI: tissue from 0.12, brighter
/// and more opaque to 0.7.
pub fn mri_tf() -> brickray_core::TransferFunction {
    brickray_core::TransferFunction::from_points(
        &[
            (0.12, [0.3, 0.12, 0.06, 0.0]),
            (0.35, [0.9, 0.5, 0.3, 0.08]),
            (0.7, [1.0, 0.9, 0.8, 0.4]),
        ],
        512,
    )
}

/// A u8 volume of `dims` voxels from `data` (x fastest), value range 0..255.
pub fn u8_volume(dims: [u32; 3], data: Vec<u8>) -> Result<Volume, VolumeError> {
    Volume::new(
        VolumeDesc {
            dims,
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
            kind: Default::default(),
        },
        VolumeData::U8(data),
    )
}

/// An `n^3` volume of air (0) holding a one-voxel sheet (200), two one-voxel
/// lines (220) and 27 single bright voxels (255): thin structures that
/// coarser levels average away.
pub fn thin_volume(n: u32) -> Result<Volume, VolumeError> {
    let nn = n as usize;
    let mut data = vec![0u8; nn * nn * nn];
    let idx = |x: usize, y: usize, z: usize| (z * nn + y) * nn + x;
    let f = |k: f32| ((n as f32 * k) as usize).min(nn - 1);
    for a in f(0.125)..f(0.875) {
        for b in f(0.125)..f(0.875) {
            data[idx(f(0.3125), a, b)] = 200;
        }
        data[idx(f(0.75), a, f(0.5))] = 220;
        data[idx(f(0.5), f(0.25), a)] = 220;
    }
    for x in [0.44, 0.53, 0.63] {
        for y in [0.31, 0.5, 0.69] {
            for z in [0.19, 0.34, 0.81] {
                data[idx(f(x), f(y), f(z))] = 255;
            }
        }
    }
    u8_volume([n; 3], data)
}

/// An orthographic camera looking at `c` from the direction `dir`, the view
/// `height` world units tall.
pub fn ortho(c: Vec3, dir: Vec3, height: f32) -> Camera {
    Camera {
        eye: c + dir.normalize() * 2.0,
        target: c,
        up: Vec3::Y,
        projection: Projection::Orthographic { height },
        near: 0.01,
        far: 10.0,
        depth: DepthConvention::Standard,
    }
}

/// An `n^3` 8-bit fractal-noise volume (detail at every level, so level
/// changes show), from [`brickray_core::synthetic::fractal_noise`] at voxel
/// centres.
pub fn noise_volume(n: u32) -> Volume {
    brickray_core::synthetic::u8_field(n, |p| {
        brickray_core::synthetic::fractal_noise(p.map(|i| i as f64 + 0.5), n as f64 / 4.0, 4)
    })
}
