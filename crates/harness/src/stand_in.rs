//! Procedural stand-ins for the shared volumes, so that benchmarks run in a
//! clone without `../shared/data`: a head-CT-like i16 volume in Hounsfield
//! units (the value range of the shared head CT, so [`crate::ct`]'s transfer
//! functions apply) and a T1-MRI-like u8 volume. They resemble the real
//! volumes in what the benchmarks exercise (air around a head, a bone shell,
//! soft tissue with texture), not in anatomy; figures measured on them are
//! labelled with the volume's name.

use brickray_core::synthetic::fractal_noise;
use brickray_core::{DType, Volume, VolumeData, VolumeDesc};

/// Where a suite's volume came from.
pub const SHARED_HEAD_CT: &str = "invesalius_cranium_ct";
/// The shared T1 MRI's name.
pub const SHARED_MRI: &str = "pycortex_s1_t1_mri";

/// The position of voxel `[x, y, z]` of `dims` in the head's frame: each axis
/// in -1..1 of an ellipsoid slightly longer front to back.
fn head_coords(dims: [u32; 3], [x, y, z]: [u32; 3]) -> [f64; 3] {
    let c = |v: u32, n: u32| (v as f64 + 0.5) / n as f64 * 2.0 - 1.0;
    [
        c(x, dims[0]) / 0.82,
        c(y, dims[1]) / 0.9,
        c(z, dims[2]) / 0.95,
    ]
}

/// A head-like i16 CT of `n x n x (0.42 n)` voxels (the shared head CT's
/// shape) in Hounsfield units: air (-1000) around a head of skin and soft
/// tissue (20-60), a skull shell of bone (700-1500, thinner and denser in
/// places) and brain (25-45), all with fractal texture. Deterministic.
pub fn head_ct_phantom(n: u32) -> Volume {
    let dims = [n, n, (n * 108).div_ceil(256).max(1)];
    let mut data = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = head_coords(dims, [x, y, z]);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let q = [x as f64, y as f64, z as f64];
                let texture = fractal_noise(q, 24.0, 3) - 0.5;
                let hu = if r > 1.0 {
                    -1000.0 + 30.0 * texture
                } else if r > 0.96 {
                    40.0 + 40.0 * texture
                } else if r > 0.86 {
                    // The skull: denser where the texture is high.
                    1100.0 + 800.0 * texture
                } else {
                    35.0 + 20.0 * texture
                };
                data.push(hu.round().clamp(-1024.0, 2986.0) as i16);
            }
        }
    }
    let desc = VolumeDesc {
        dims,
        dtype: DType::I16,
        spacing: [1.0, 1.0, 2.4],
        value_range: [-1024.0, 2986.0],
        kind: Default::default(),
    };
    Volume::new(desc, VolumeData::I16(data)).expect("valid by construction")
}

/// A T1-MRI-like u8 volume of `n^3` voxels: dark air (about 0.02), a bright
/// scalp (about 0.8), darker cerebrospinal fluid (about 0.15) and brain
/// (0.35-0.65) with fractal texture. Deterministic.
pub fn mri_phantom(n: u32) -> Volume {
    let dims = [n; 3];
    brickray_core::synthetic::u8_field(n, |v| {
        let p = head_coords(dims, v);
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let q = [v[0] as f64, v[1] as f64, v[2] as f64];
        let texture = fractal_noise(q, 16.0, 3) - 0.5;
        if r > 1.0 {
            0.02 + 0.02 * texture
        } else if r > 0.93 {
            0.8 + 0.1 * texture
        } else if r > 0.88 {
            0.15 + 0.05 * texture
        } else {
            0.5 + 0.3 * texture
        }
    })
}

/// Set to `1`, the `*_or_phantom` functions return the stand-ins even where
/// the shared data is present (the benchmarks' smoke tests check the
/// fallback that way).
pub const FORCE_ENV: &str = "BRICKRAY_STAND_IN";

/// The shared volume `name` where `../shared/data` has it (and [`FORCE_ENV`]
/// is not `1`), else `stand_in`; with the name of what was returned.
fn shared_or(
    name: &'static str,
    stand_in: impl FnOnce() -> Volume,
    stand_in_name: &'static str,
) -> Result<(Volume, &'static str), String> {
    if std::env::var(FORCE_ENV).is_ok_and(|v| v == "1") {
        return Ok((stand_in(), stand_in_name));
    }
    match crate::shared_volume(name).filter(|p| p.is_file()) {
        Some(path) => brickray_io::read_volume(&path)
            .map(|v| (v, name))
            .map_err(|e| format!("{}: {e}", path.display())),
        None => Ok((stand_in(), stand_in_name)),
    }
}

/// The shared head CT, or without `../shared/data` [`head_ct_phantom`] at
/// 256 voxels a side (`"head_ct_phantom"`).
pub fn head_ct_or_phantom() -> Result<(Volume, &'static str), String> {
    shared_or(SHARED_HEAD_CT, || head_ct_phantom(256), "head_ct_phantom")
}

/// The shared T1 MRI, or without `../shared/data` [`mri_phantom`] at 256
/// voxels a side (`"mri_phantom"`).
pub fn mri_or_phantom() -> Result<(Volume, &'static str), String> {
    shared_or(SHARED_MRI, || mri_phantom(256), "mri_phantom")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hu_at(v: &Volume, [x, y, z]: [u32; 3]) -> i16 {
        let d = v.desc().dims;
        let VolumeData::I16(data) = v.data() else {
            panic!("not i16")
        };
        data[(z as usize * d[1] as usize + y as usize) * d[0] as usize + x as usize]
    }

    #[test]
    fn the_ct_phantom_has_air_bone_and_tissue_where_a_head_has_them() {
        let v = head_ct_phantom(64);
        assert_eq!(v.desc().dims, [64, 64, 27]);
        assert_eq!(v.desc().value_range, [-1024.0, 2986.0]);
        // Air in a corner, tissue at the centre.
        assert!(hu_at(&v, [0, 0, 0]) < -900);
        let c = hu_at(&v, [32, 32, 13]);
        assert!((0..100).contains(&c), "{c}");
        // Along the x axis through the centre: bone (above the bone TF's
        // 250 HU) between the brain and the skin.
        let bone = (32..64).filter(|&x| hu_at(&v, [x, 32, 13]) > 250).count();
        assert!((2..12).contains(&bone), "{bone} voxels of bone");
        // Deterministic.
        assert_eq!(v.data(), head_ct_phantom(64).data());
    }

    #[test]
    fn the_mri_phantom_is_dark_outside_and_bright_at_the_scalp() {
        let v = mri_phantom(64);
        let VolumeData::U8(data) = v.data() else {
            panic!("not u8")
        };
        let at = |x: usize, y: usize, z: usize| data[(z * 64 + y) * 64 + x];
        assert!(at(0, 0, 0) < 20);
        let max_on_axis = (32..64).map(|x| at(x, 32, 32)).max().unwrap_or(0);
        assert!(max_on_axis > 180, "{max_on_axis}");
        assert!((60..200).contains(&at(32, 32, 32)));
    }
}
