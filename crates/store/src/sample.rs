//! Typed operations on little-endian sample bytes, one implementation per dtype.

use crate::Filter;
use brickray_core::DType;

/// A sample type of the store (u8, u16, i16, f32).
pub(crate) trait Sample: Copy + Send + Sync + PartialEq + 'static {
    /// Bytes per sample.
    const SIZE: usize;
    /// Reads one sample from `SIZE` little-endian bytes.
    fn read(b: &[u8]) -> Self;
    /// Writes one sample as little-endian bytes.
    fn write(self, out: &mut [u8]);
    /// The value as f32 (exact for every integer type).
    fn to_f32(self) -> f32;
    /// The 2x2x2 filter of eight samples (order: x fastest, then y, then z).
    fn filter(v: [Self; 8], filter: Filter) -> Self;
    /// The sample nearest to `v` (saturating; used for fill values).
    fn from_f32(v: f32) -> Self;
}

macro_rules! int_sample {
    ($t:ty, $n:expr) => {
        impl Sample for $t {
            const SIZE: usize = $n;
            #[inline(always)]
            fn read(b: &[u8]) -> Self {
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                <$t>::from_le_bytes(a)
            }
            #[inline(always)]
            fn write(self, out: &mut [u8]) {
                out[..$n].copy_from_slice(&self.to_le_bytes());
            }
            #[inline(always)]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline(always)]
            fn filter(v: [Self; 8], filter: Filter) -> Self {
                match filter {
                    Filter::Max => v.into_iter().fold(v[0], |a, b| a.max(b)),
                    Filter::Average => {
                        let s: i64 = v.iter().map(|&x| x as i64).sum();
                        // Round half up: floor(s / 8 + 1/2).
                        (s + 4).div_euclid(8) as $t
                    }
                    Filter::Mode => brickray_core::labels::mode_of(&mut { v }),
                }
            }
            #[inline(always)]
            fn from_f32(v: f32) -> Self {
                v.round() as $t
            }
        }
    };
}

int_sample!(u8, 1);
int_sample!(u16, 2);
int_sample!(i16, 2);
int_sample!(u32, 4);

impl Sample for f32 {
    const SIZE: usize = 4;
    #[inline(always)]
    fn read(b: &[u8]) -> Self {
        f32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }
    #[inline(always)]
    fn write(self, out: &mut [u8]) {
        out[..4].copy_from_slice(&self.to_le_bytes());
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn filter(v: [Self; 8], filter: Filter) -> Self {
        match filter {
            Filter::Max => v.into_iter().fold(v[0], f32::max),
            Filter::Average => (v.iter().map(|&x| x as f64).sum::<f64>() / 8.0) as f32,
            // (Refused for f32 by the builder; the total order keeps it defined.)
            Filter::Mode => {
                let mut k = v.map(f32::to_bits);
                f32::from_bits(brickray_core::labels::mode_of(&mut k))
            }
        }
    }
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
}

/// Calls `$body` with the type alias `$T` bound to the sample type of `$dtype`.
macro_rules! with_sample {
    ($dtype:expr, $T:ident => $body:expr) => {
        match $dtype {
            brickray_core::DType::U8 => {
                type $T = u8;
                $body
            }
            brickray_core::DType::U16 => {
                type $T = u16;
                $body
            }
            brickray_core::DType::I16 => {
                type $T = i16;
                $body
            }
            brickray_core::DType::U32 => {
                type $T = u32;
                $body
            }
            _ => {
                type $T = f32;
                $body
            }
        }
    };
}
pub(crate) use with_sample;

/// Min and max of little-endian samples, and whether they are all equal.
pub(crate) fn range_of<T: Sample>(bytes: &[u8]) -> (f32, f32) {
    let mut it = bytes.chunks_exact(T::SIZE).map(T::read);
    let Some(first) = it.next() else {
        return (0.0, 0.0);
    };
    let f = first.to_f32();
    let (mut lo, mut hi) = (f, f);
    for v in it {
        let v = v.to_f32();
        lo = lo.min(v);
        hi = hi.max(v);
    }
    (lo, hi)
}

/// Min and max of u8 samples, vectorisable.
pub(crate) fn range_u8(bytes: &[u8]) -> (f32, f32) {
    let (mut lo, mut hi) = (u8::MAX, u8::MIN);
    for c in bytes.chunks(4096) {
        let (a, b) = c
            .iter()
            .fold((u8::MAX, u8::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        lo = lo.min(a);
        hi = hi.max(b);
    }
    (lo as f32, hi as f32)
}

/// Min and max of little-endian samples of `dtype`.
pub(crate) fn range_dyn(dtype: DType, bytes: &[u8]) -> (f32, f32) {
    if dtype == DType::U8 {
        return range_u8(bytes);
    }
    with_sample!(dtype, T => range_of::<T>(bytes))
}

/// Fills `out` with `value` converted to `dtype`.
pub(crate) fn fill(dtype: DType, value: f32, out: &mut [u8]) {
    with_sample!(dtype, T => {
        let mut b = [0u8; 4];
        T::from_f32(value).write(&mut b);
        for c in out.chunks_exact_mut(T::SIZE) {
            c.copy_from_slice(&b[..T::SIZE]);
        }
    })
}

/// True when `v` is exactly representable in `dtype`.
pub(crate) fn representable(dtype: DType, v: f32) -> bool {
    if !v.is_finite() {
        return false;
    }
    match dtype {
        DType::U8 => v.fract() == 0.0 && (0.0..=255.0).contains(&v),
        DType::U16 => v.fract() == 0.0 && (0.0..=65535.0).contains(&v),
        DType::I16 => v.fract() == 0.0 && (-32768.0..=32767.0).contains(&v),
        DType::U32 => v.fract() == 0.0 && (0.0..=u32::MAX as f32).contains(&v),
        _ => true,
    }
}

/// Independent accumulators of the f32 pass, so that it vectorises.
const LANES: usize = 16;

/// Smallest and largest sample of little-endian samples of `dtype` (as f32),
/// and whether any is NaN, in one pass without allocating. `(+inf, -inf,
/// false)` for no samples.
pub(crate) fn stats_dyn(dtype: DType, bytes: &[u8]) -> (f32, f32, bool) {
    // A plain fold over fixed-size chunks vectorises for the integer types
    // (min/max reductions); f32 needs independent lanes (below).
    macro_rules! int_stats {
        ($t:ty, $n:expr) => {{
            let (chunks, _) = bytes.as_chunks::<$n>();
            if chunks.is_empty() {
                (f32::INFINITY, f32::NEG_INFINITY, false)
            } else {
                let (mut lo, mut hi) = (<$t>::MAX, <$t>::MIN);
                for c in chunks {
                    let x = <$t>::from_le_bytes(*c);
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
                (lo as f32, hi as f32, false)
            }
        }};
    }
    match dtype {
        DType::U8 => int_stats!(u8, 1),
        DType::U16 => {
            // Biased to i16 (an order-preserving map): x86-64's baseline SIMD
            // has a signed 16-bit min/max but no unsigned one.
            let (chunks, _) = bytes.as_chunks::<2>();
            if chunks.is_empty() {
                (f32::INFINITY, f32::NEG_INFINITY, false)
            } else {
                let (mut lo, mut hi) = (i16::MAX, i16::MIN);
                for c in chunks {
                    let x = (u16::from_le_bytes(*c) ^ 0x8000) as i16;
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
                let unbias = |v: i16| ((v as u16) ^ 0x8000) as f32;
                (unbias(lo), unbias(hi), false)
            }
        }
        DType::I16 => int_stats!(i16, 2),
        DType::U32 => int_stats!(u32, 4),
        _ => {
            // Compare-and-select (NaN never selected) plus an unordered test,
            // which map to vector min, max and compare instructions.
            let mut lo = [f32::INFINITY; LANES];
            let mut hi = [f32::NEG_INFINITY; LANES];
            let mut nan = [false; LANES];
            let mut chunks = bytes.chunks_exact(4 * LANES);
            for c in &mut chunks {
                for i in 0..LANES {
                    let x =
                        f32::from_le_bytes([c[4 * i], c[4 * i + 1], c[4 * i + 2], c[4 * i + 3]]);
                    lo[i] = if x < lo[i] { x } else { lo[i] };
                    hi[i] = if x > hi[i] { x } else { hi[i] };
                    nan[i] |= x.is_nan();
                }
            }
            for c in chunks.remainder().chunks_exact(4) {
                let x = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                lo[0] = if x < lo[0] { x } else { lo[0] };
                hi[0] = if x > hi[0] { x } else { hi[0] };
                nan[0] |= x.is_nan();
            }
            let lo = lo.into_iter().fold(f32::INFINITY, f32::min);
            let hi = hi.into_iter().fold(f32::NEG_INFINITY, f32::max);
            (lo, hi, nan.contains(&true))
        }
    }
}

/// Index of the first NaN sample (f32 only).
pub(crate) fn first_nan(dtype: DType, bytes: &[u8]) -> Option<usize> {
    if dtype != DType::F32 {
        return None;
    }
    bytes
        .chunks_exact(4)
        .position(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_nan())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_match_a_naive_scan() {
        let mut h = 0x1234_5678_u64;
        for dtype in [DType::U8, DType::U16, DType::I16, DType::F32] {
            for n in [0usize, 1, 2, 3, 1000, 5000, 9001] {
                let bytes: Vec<u8> = (0..n * dtype.size())
                    .map(|_| {
                        h ^= h << 13;
                        h ^= h >> 7;
                        h ^= h << 17;
                        (h >> 24) as u8 & 0x7f
                    })
                    .collect();
                let v = dtype.decode_le(&bytes);
                let lo = v.iter().copied().fold(f32::INFINITY, f32::min);
                let hi = v.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                assert_eq!(stats_dyn(dtype, &bytes), (lo, hi, false), "{dtype:?} {n}");
            }
        }
        let mut b: Vec<u8> = [1.0f32, -2.0, 3.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(stats_dyn(DType::F32, &b), (-2.0, 3.0, false));
        b[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(stats_dyn(DType::F32, &b), (1.0, 3.0, true));
        assert_eq!(first_nan(DType::F32, &b), Some(1));
        assert_eq!(
            stats_dyn(DType::I16, &(-5i16).to_le_bytes()),
            (-5.0, -5.0, false)
        );
        // The whole range of each integer type, ends included.
        let le = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        for (v, lo, hi) in [
            (vec![0x8000u16, 0x7FFF, 0x8001], 32767.0, 32769.0),
            (vec![0xFFFF, 1, 0x8000], 1.0, 65535.0),
            (vec![0, 0xFFFF], 0.0, 65535.0),
            (vec![0xFFFF; 3], 65535.0, 65535.0),
        ] {
            assert_eq!(stats_dyn(DType::U16, &le(&v)), (lo, hi, false), "{v:?}");
        }
        let b: Vec<u8> = [i16::MIN, 0, i16::MAX]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        assert_eq!(stats_dyn(DType::I16, &b), (-32768.0, 32767.0, false));
        assert_eq!(stats_dyn(DType::U8, &[255, 0, 128]), (0.0, 255.0, false));
        assert_eq!(
            stats_dyn(DType::U16, &[7]),
            (f32::INFINITY, f32::NEG_INFINITY, false)
        );
    }
}
