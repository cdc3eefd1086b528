//! OME-Zarr chunks whose compressed streams declare (or decode to) more than
//! the chunk's geometry holds: each is a typed error, and no single
//! allocation made while reading them exceeds a bound far below what they
//! declare (a counting allocator watches). Before, a 16-byte zstd frame made
//! zarrs allocate 1 TiB and abort the process.
#![cfg(feature = "zarr")]
// The counting allocator wraps the system allocator: an `unsafe impl` of
// `GlobalAlloc` that forwards every call unchanged.
#![allow(unsafe_code)]

mod fixtures;

use brickray_io::{self as io, IoError};
use fixtures::ZarrCodec;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use tempfile::TempDir;

struct Counting;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every method forwards to `System` with the caller's arguments.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        LARGEST.fetch_max(l.size(), Ordering::Relaxed);
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        LARGEST.fetch_max(new, Ordering::Relaxed);
        unsafe { System.realloc(p, l, new) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// The tests measure one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// Far more than any chunk of the generated images needs (they hold 48
/// bytes), far less than what the forged chunks declare.
const BOUND: usize = 16 << 20;

/// Opens and reads `root`; the error, and the largest single allocation
/// made meanwhile.
fn open_measured(root: &Path) -> (Result<(), IoError>, usize) {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    LARGEST.store(0, Ordering::Relaxed);
    let r = io::open(root).and_then(|mut r| r.read_volume().map(|_| ()));
    let streamed = io::zarr::ZarrBrickSource::open(root, &Default::default(), 4, 1, None);
    let largest = LARGEST.load(Ordering::Relaxed);
    assert!(
        streamed.is_err() == r.is_err(),
        "streamed and read disagree: {r:?}"
    );
    (r, largest)
}

fn assert_refused(root: &Path, what: &str) {
    let (r, largest) = open_measured(root);
    match r {
        Ok(()) => panic!("{what}: read"),
        Err(e) => assert!(matches!(&e, IoError::Decode { .. }), "{what}: {e:?}"),
    }
    assert!(largest <= BOUND, "{what}: an allocation of {largest} bytes");
}

/// Replaces every chunk (or shard) file of a generated image.
fn replace_chunks(codec: ZarrCodec, with: &dyn Fn(&Path) -> Vec<u8>) -> TempDir {
    let d = TempDir::new().unwrap();
    let root = d.path().join("b.ome.zarr");
    for f in fixtures::zarr(&root, codec) {
        let b = with(&f);
        std::fs::write(&f, b).unwrap();
    }
    d
}

fn root(d: &TempDir) -> std::path::PathBuf {
    d.path().join("b.ome.zarr")
}

#[test]
fn zstd_frame_declaring_a_tebibyte_is_refused() {
    for codec in [ZarrCodec::Zstd, ZarrCodec::V2Zstd] {
        let d = replace_chunks(codec, &|_| fixtures::ZSTD_TIB.to_vec());
        assert_refused(&root(&d), &format!("{codec:?}"));
    }
    // behind a valid crc32c
    let d = replace_chunks(ZarrCodec::ZstdCrc, &|_| {
        let mut b = fixtures::ZSTD_TIB.to_vec();
        let crc = fixtures::crc32c(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        b
    });
    assert_refused(&root(&d), "ZstdCrc");
    // as the inner chunks of a shard
    let d = replace_chunks(ZarrCodec::Sharded, &|_| {
        fixtures::shard(&vec![fixtures::ZSTD_TIB.to_vec(); 8], &|_| None)
    });
    assert_refused(&root(&d), "Sharded");
}

#[test]
fn gzip_bomb_is_refused_within_the_chunk_size() {
    // 64 MiB of zeros in about 64 KiB, in place of a 48-byte chunk
    let bomb = fixtures::gzip(&vec![0u8; 64 << 20], 9);
    let d = replace_chunks(ZarrCodec::Gzip, &|_| bomb.clone());
    assert_refused(&root(&d), "gzip");
}

#[test]
fn blosc_header_declaring_more_than_the_chunk_is_refused() {
    for codec in [ZarrCodec::Blosc, ZarrCodec::V2Blosc] {
        let d = replace_chunks(codec, &|f| {
            let mut b = std::fs::read(f).unwrap();
            // nbytes (bytes 4..8): 1 GiB
            b[4..8].copy_from_slice(&(1u32 << 30).to_le_bytes());
            b
        });
        assert_refused(&root(&d), &format!("{codec:?}"));
    }
}

#[test]
fn shard_index_pointing_past_the_file_is_refused() {
    for (what, entry) in [
        ("1 TiB long", (0u64, 1u64 << 40)),
        ("past the end", (1u64 << 40, 16)),
        ("overflowing", (u64::MAX - 8, 16)),
    ] {
        let d = replace_chunks(ZarrCodec::Sharded, &|f| {
            // the real inner chunks, the first entry forged
            let b = std::fs::read(f).unwrap();
            let n = b.len();
            let index = &b[n - 4 - 8 * 16..n - 4];
            let chunks: Vec<Vec<u8>> = (0..8)
                .map(|i| {
                    let e = &index[16 * i..16 * i + 16];
                    let off = u64::from_le_bytes(e[..8].try_into().unwrap()) as usize;
                    let len = u64::from_le_bytes(e[8..].try_into().unwrap()) as usize;
                    b[off..off + len].to_vec()
                })
                .collect();
            fixtures::shard(&chunks, &|i| (i == 0).then_some(entry))
        });
        assert_refused(&root(&d), what);
    }
}
