//! Procedural test volumes.

use crate::volume::{DType, Volume, VolumeData, VolumeDesc};

/// A smooth ball: value 1 at the centre falling to 0 at `radius` (fraction of the
/// half-extent), as u8.
pub fn sphere(n: u32) -> Volume {
    let c = (n as f32 - 1.0) * 0.5;
    let r = n as f32 * 0.4;
    u8_field(n, |[x, y, z]| {
        let d = ((x as f32 - c).powi(2) + (y as f32 - c).powi(2) + (z as f32 - c).powi(2)).sqrt();
        let v = (1.0 - d / r).clamp(0.0, 1.0);
        // The 8-bit level as computed in f32 (exact through u8_field).
        (v * 255.0).round() as f64 / 255.0
    })
}

/// An `n^3` u8 volume (value range 0..255, unit spacing) of `f` at each voxel's
/// integer coordinates `[x, y, z]`, clamped to 0..1 and rounded to 8 bits.
pub fn u8_field(n: u32, f: impl Fn([u32; 3]) -> f64) -> Volume {
    let mut data = Vec::with_capacity((n as usize).pow(3));
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                data.push((f([x, y, z]).clamp(0.0, 1.0) * 255.0).round() as u8);
            }
        }
    }
    let desc = VolumeDesc {
        dims: [n; 3],
        dtype: DType::U8,
        spacing: [1.0; 3],
        value_range: [0.0, 255.0],
        kind: Default::default(),
    };
    Volume::new(desc, VolumeData::U8(data)).expect("valid by construction")
}

/// The Marschner-Lobb test signal (fM = 6, alpha = 0.25) sampled on an `n^3`
/// grid over `[-1, 1]^3`, as f32 in 0..1.
pub fn marschner_lobb(n: u32) -> Volume {
    let (fm, alpha) = (6.0f64, 0.25f64);
    let pi = std::f64::consts::PI;
    let mut data = Vec::with_capacity((n * n * n) as usize);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|i| -1.0 + 2.0 * (i as f64 + 0.5) / n as f64);
                let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
                let rho = (2.0 * pi * fm * (pi * r / 2.0).cos()).cos();
                let v =
                    (1.0 - (pi * p[2] / 2.0).sin() + alpha * (1.0 + rho)) / (2.0 * (1.0 + alpha));
                data.push(v as f32);
            }
        }
    }
    let desc = VolumeDesc {
        dims: [n; 3],
        dtype: DType::F32,
        spacing: [1.0; 3],
        value_range: [0.0, 1.0],
        kind: Default::default(),
    };
    Volume::new(desc, VolumeData::F32(data)).expect("valid by construction")
}

/// A cheap 3D value-noise field in 0..1 (hash-based, deterministic), octaves summed.
/// Useful for procedural "large" volumes; `p` in voxel units.
pub fn fractal_noise(p: [f64; 3], base_period: f64, octaves: u32) -> f64 {
    let mut sum = 0.0;
    let mut amp = 0.5;
    let mut norm = 0.0;
    let mut period = base_period;
    for o in 0..octaves {
        sum += amp * value_noise([p[0] / period, p[1] / period, p[2] / period], o);
        norm += amp;
        amp *= 0.5;
        period *= 0.5;
        if period < 1.0 {
            break;
        }
    }
    sum / norm
}

fn hash(x: i64, y: i64, z: i64, seed: u32) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ (seed as u64).wrapping_mul(0x27D4_EB2F_1656_67C5);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn value_noise(p: [f64; 3], seed: u32) -> f64 {
    let f = p.map(|c| c.floor());
    let t = [p[0] - f[0], p[1] - f[1], p[2] - f[2]].map(|t| t * t * (3.0 - 2.0 * t));
    let i = f.map(|c| c as i64);
    let mut acc = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let w = (if dx == 0 { 1.0 - t[0] } else { t[0] })
                    * (if dy == 0 { 1.0 - t[1] } else { t[1] })
                    * (if dz == 0 { 1.0 - t[2] } else { t[2] });
                acc += w * hash(i[0] + dx, i[1] + dy, i[2] + dz, seed);
            }
        }
    }
    acc
}
