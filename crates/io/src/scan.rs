//! Ranges and slabs: checking a slab request, scanning samples for their
//! range and for non-finite values, bounded in memory whatever a header
//! claims.

use crate::{IoError, slab};
use brickray_core::volume::{DType, VolumeDesc, VolumeError};
use std::io::Read;
use std::path::Path;

/// Checks that a slab request fits the volume and the buffer.
pub(crate) fn check_slab(desc: &VolumeDesc, z0: u32, z1: u32, out: &[u8]) -> Result<u64, IoError> {
    if z0 > z1 || z1 > desc.dims[2] {
        return Err(IoError::BadSlab {
            z0,
            z1,
            depth: desc.dims[2],
        });
    }
    let slice = desc.dims[0] as u64 * desc.dims[1] as u64 * desc.dtype.size() as u64;
    let need = (z1 - z0) as u64 * slice;
    if out.len() as u64 != need {
        return Err(IoError::SlabBuffer {
            expected: need,
            actual: out.len() as u64,
        });
    }
    Ok(slice)
}

/// Min and max of little-endian samples, and the index of the first non-finite one.
pub fn scan_range(dtype: DType, bytes: &[u8]) -> (f32, f32, Option<usize>) {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    let mut bad = None;
    let mut push = |i: usize, x: f32| {
        if x.is_finite() {
            lo = lo.min(x);
            hi = hi.max(x);
        } else if bad.is_none() {
            bad = Some(i);
        }
    };
    match dtype {
        DType::U8 => bytes
            .iter()
            .enumerate()
            .for_each(|(i, &b)| push(i, b as f32)),
        DType::U16 => bytes
            .chunks_exact(2)
            .enumerate()
            .for_each(|(i, c)| push(i, u16::from_le_bytes([c[0], c[1]]) as f32)),
        DType::I16 => bytes
            .chunks_exact(2)
            .enumerate()
            .for_each(|(i, c)| push(i, i16::from_le_bytes([c[0], c[1]]) as f32)),
        DType::F32 => bytes
            .chunks_exact(4)
            .enumerate()
            .for_each(|(i, c)| push(i, f32::from_le_bytes([c[0], c[1], c[2], c[3]]))),
        // A sample type added to brickray-core after this reader: no range.
        _ => {}
    }
    (lo, hi, bad)
}

/// Bytes decoded per step by [`scan_stream`]: memory stays bounded whatever the
/// dims claim (a multiple of every sample size).
const SCAN_CHUNK: usize = 1 << 20;

/// Streams the `desc.byte_len()` sample bytes of `src` (in file byte order) once,
/// returning the data's min..max (widened to `lo..lo+1` when flat). Errors on
/// NaN/Inf with the total count and the first voxel, and with
/// [`IoError::Truncated`] when the stream ends early. `io_err` maps a read error
/// at a decoded byte position. Memory use is bounded by [`SCAN_CHUNK`], so a
/// forged header cannot make the scan allocate what the data does not hold.
pub(crate) fn scan_stream(
    path: &Path,
    desc: &VolumeDesc,
    big_endian: bool,
    src: &mut dyn Read,
    io_err: &dyn Fn(std::io::Error, u64) -> IoError,
) -> Result<[f32; 2], IoError> {
    let size = desc.dtype.size();
    let total = desc.byte_len();
    let mut buf = vec![0u8; (SCAN_CHUNK as u64).min(total) as usize];
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut count = 0u64;
    let mut first: Option<u64> = None;
    let mut pos = 0u64;
    while pos < total {
        let want = (total - pos).min(buf.len() as u64) as usize;
        let chunk = &mut buf[..want];
        let mut filled = 0;
        while filled < want {
            match src.read(&mut chunk[filled..]) {
                Ok(0) => {
                    return Err(IoError::Truncated {
                        path: path.to_owned(),
                        expected: total,
                        actual: pos + filled as u64,
                    });
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io_err(e, pos + filled as u64)),
            }
        }
        if big_endian && size > 1 {
            chunk.chunks_exact_mut(size).for_each(|c| c.reverse());
        }
        let (a, b, bad) = scan_range(desc.dtype, chunk);
        if let Some(i) = bad {
            count += bytes_non_finite(desc.dtype, chunk);
            first.get_or_insert(pos / size as u64 + i as u64);
        }
        lo = lo.min(a);
        hi = hi.max(b);
        pos += want as u64;
    }
    if let Some(i) = first {
        let [nx, ny, _] = desc.dims.map(u64::from);
        let first = [
            (i % nx) as u32,
            ((i / nx) % ny) as u32,
            (i / (nx * ny)) as u32,
        ];
        return Err(IoError::volume(
            path,
            VolumeError::NonFinite { count, first },
        ));
    }
    // Both finite here (NaN/Inf returned above, and there is at least one voxel).
    Ok(slab::widen_flat(lo, hi))
}

fn bytes_non_finite(dtype: DType, bytes: &[u8]) -> u64 {
    if dtype != DType::F32 {
        return 0;
    }
    bytes
        .chunks_exact(4)
        .filter(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
        .count() as u64
}
