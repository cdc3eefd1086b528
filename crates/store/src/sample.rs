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
                        let s: i32 = v.iter().map(|&x| x as i32).sum();
                        // Round half up: floor(s / 8 + 1/2).
                        (s + 4).div_euclid(8) as $t
                    }
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
        _ => true,
    }
}
