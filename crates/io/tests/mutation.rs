//! The mutation suite: every reader fed mutated files, down to the codecs.
//!
//! Seeds are small valid files the tests generate (`fixtures/`): NIfTI
//! (plain and gzip), TIFF stacks (uncompressed, Deflate, LZW, PackBits, with
//! ImageJ metadata), DICOM series (explicit and implicit VR, RLE Lossless,
//! JPEG baseline), OME-Zarr images with each chunk codec (raw, zstd, gzip,
//! blosc, zstd + crc32c, sharding with its index, zarr v2 blosc and zstd);
//! and, when `../shared/data` is present, files of the shared fixtures
//! (the NIfTI atlas, the TIFF stack, RLE and JPEG 2000 DICOM slices, a
//! chunk or shard of each OME-Zarr store). Each case applies a few byte
//! mutations (bit flips, boundary values of sizes and offsets, truncation,
//! insertion, deletion, copies; biased to the headers, and for shards to the
//! index at the end), opens and reads the result, and for OME-Zarr also
//! serves bricks from it.
//!
//! Every outcome must be a volume that keeps the readers' promises or a
//! typed error; a panic, a hang (60 s for one case) or an abort fails the
//! test. The seeds of the random generator are fixed, so a failure
//! reproduces; `BRICKRAY_FUZZ_CASES=<n>` multiplies the case counts for a
//! longer local run (`cargo test -p brickray-io --test mutation`). Each
//! crash found became a named test in `hostile.rs`, `zarr_bounds.rs` or
//! `dicom.rs`.
#![cfg(all(
    feature = "nifti",
    feature = "tiff",
    feature = "dicom",
    feature = "zarr"
))]

mod fixtures;

use brickray_io::{self as io, IoError, ReadOptions};
use fixtures::ZarrCodec;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};
use std::path::{Path, PathBuf};
use tempfile::TempDir;

// ---------------------------------------------------------------------------
// Mutations.

/// Where a mutation lands: in the first bytes (headers), the last bytes (a
/// shard index, a gzip trailer, IFDs) or anywhere.
#[derive(Debug, Clone, Copy)]
enum Pos {
    Head(usize),
    Tail(usize),
    Any(usize),
}

impl Pos {
    fn at(self, len: usize) -> usize {
        let len = len.max(1);
        match self {
            Pos::Head(i) => i % len.min(600),
            Pos::Tail(i) => len - 1 - i % len.min(300),
            Pos::Any(i) => i % len,
        }
    }
}

#[derive(Debug, Clone)]
enum Mutation {
    Flip(Pos, u8),
    Set(Pos, u8),
    /// A boundary value of a size or an offset, little-endian, 2, 4 or 8 bytes.
    Word(Pos, u64, u8),
    Truncate(Pos),
    Insert(Pos, Vec<u8>),
    Remove(Pos, usize),
    Copy(Pos, Pos, usize),
}

fn pos() -> impl Strategy<Value = Pos> {
    prop_oneof![
        4 => any::<usize>().prop_map(Pos::Head),
        2 => any::<usize>().prop_map(Pos::Tail),
        3 => any::<usize>().prop_map(Pos::Any),
    ]
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let words = prop::sample::select(vec![
        0u64,
        1,
        2,
        0x7f,
        0x80,
        0xff,
        0x100,
        0x7fff,
        0x8000,
        0xffff,
        0x1_0000,
        0x7fff_ffff,
        0x8000_0000,
        0xffff_fffe,
        0xffff_ffff,
        1 << 40,
        u64::MAX / 2,
        u64::MAX - 8,
        u64::MAX,
    ]);
    prop_oneof![
        3 => (pos(), 0u8..8).prop_map(|(p, b)| Mutation::Flip(p, b)),
        3 => (pos(), any::<u8>()).prop_map(|(p, b)| Mutation::Set(p, b)),
        3 => (pos(), words, prop::sample::select(vec![2u8, 4, 8]))
            .prop_map(|(p, v, w)| Mutation::Word(p, v, w)),
        1 => pos().prop_map(Mutation::Truncate),
        1 => (pos(), prop::collection::vec(any::<u8>(), 1..12)).prop_map(|(p, b)| Mutation::Insert(p, b)),
        1 => (pos(), 1usize..64).prop_map(|(p, n)| Mutation::Remove(p, n)),
        1 => (pos(), pos(), 1usize..64).prop_map(|(a, b, n)| Mutation::Copy(a, b, n)),
    ]
}

fn mutations() -> impl Strategy<Value = Vec<Mutation>> {
    prop::collection::vec(mutation(), 1..5)
}

fn apply(mut b: Vec<u8>, muts: &[Mutation]) -> Vec<u8> {
    for m in muts {
        if b.is_empty() {
            break;
        }
        let n = b.len();
        match m {
            Mutation::Flip(p, bit) => b[p.at(n)] ^= 1 << bit,
            Mutation::Set(p, v) => b[p.at(n)] = *v,
            Mutation::Word(p, v, w) => {
                let at = p.at(n);
                let end = (at + *w as usize).min(n);
                b[at..end].copy_from_slice(&v.to_le_bytes()[..end - at]);
            }
            Mutation::Truncate(p) => b.truncate(p.at(n)),
            Mutation::Insert(p, bytes) => {
                let at = p.at(n);
                b.splice(at..at, bytes.iter().copied());
            }
            Mutation::Remove(p, len) => {
                let at = p.at(n);
                b.drain(at..(at + len).min(n));
            }
            Mutation::Copy(from, to, len) => {
                let (f, t) = (from.at(n), to.at(n));
                let len = (*len).min(n - f).min(n - t);
                let src = b[f..f + len].to_vec();
                b[t..t + len].copy_from_slice(&src);
            }
        }
    }
    b
}

// ---------------------------------------------------------------------------
// Running one case: no panic, no hang; a volume keeps the promises.

/// Case counts are multiplied by `BRICKRAY_FUZZ_CASES` (default 1).
fn cases(n: u32) -> u32 {
    let k = std::env::var("BRICKRAY_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse::<u32>().ok())
        .unwrap_or(1)
        .max(1);
    n.saturating_mul(k)
}

fn config(n: u32, seed: u64) -> Config {
    Config {
        cases: cases(n),
        rng_seed: RngSeed::Fixed(seed),
        failure_persistence: None,
        // the shrinker replays the failing case: a few hundred replays at most
        max_shrink_iters: 256,
        ..Config::default()
    }
}

/// What a case did.
#[derive(Debug)]
enum Outcome {
    Read,
    Refused,
}

/// Runs `f` on its own thread: a panic there (with its message) or no answer
/// within 60 s fails the case.
fn guarded(what: &str, f: impl FnOnce() -> Result<(), IoError> + Send + 'static) -> Outcome {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
        let _ = tx.send(r.map_err(|p| {
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        }));
    });
    match rx.recv_timeout(std::time::Duration::from_secs(60)) {
        Ok(Ok(Ok(()))) => Outcome::Read,
        Ok(Ok(Err(e))) => {
            // typed by construction; its message must render
            let _ = e.to_string();
            Outcome::Refused
        }
        Ok(Err(msg)) => panic!("{what}: panicked: {msg}"),
        Err(_) => panic!("{what}: no answer within 60 s (a hang)"),
    }
}

/// Opens `path` with `opts`, reads it whole, asks for a slab past its end,
/// and checks what a volume promises.
fn exercise(path: &Path, opts: ReadOptions) -> Outcome {
    let p = path.to_owned();
    guarded(&path.display().to_string(), move || {
        let mut r = io::open_with(&p, &opts)?;
        let v = r.read_volume()?;
        let d = v.desc();
        assert!(d.byte_len() <= 1 << 28, "{d:?}");
        assert!(d.spacing.iter().all(|s| s.is_finite() && *s > 0.0), "{d:?}");
        assert!(
            d.value_range.iter().all(|x| x.is_finite()) && d.value_range[0] < d.value_range[1],
            "{d:?}"
        );
        if let Some(pl) = r.placement() {
            assert!(pl.affine.iter().flatten().all(|x| x.is_finite()), "{pl:?}");
        }
        let _ = r.warnings();
        let _ = r.notes();
        let z = d.dims[2];
        assert!(r.read_slices(z, z + 1, &mut []).is_err());
        Ok(())
    })
}

/// The OME-Zarr image served as bricks: every node of the two finest
/// levels answered (or refused).
fn exercise_bricks(root: &Path) -> Outcome {
    use brickray_core::{BrickSource, NodeKey};
    let p = root.to_owned();
    guarded(&format!("{} (bricks)", root.display()), move || {
        let src = io::zarr::ZarrBrickSource::open(&p, &ReadOptions::default(), 4, 1, None)?;
        let lay = src.layout().clone();
        let mut buf = vec![0u8; lay.brick_bytes()];
        for l in lay.levels.saturating_sub(2)..lay.levels {
            let n = 1u32 << l;
            for k in 0..n * n * n {
                let key = NodeKey::new(l, k % n, (k / n) % n, k / (n * n));
                let _ = src.node(key);
                let _ = src.read_brick(key, &mut buf);
            }
        }
        Ok(())
    })
}

fn seed_must_read(path: &Path, opts: ReadOptions) {
    assert!(
        matches!(exercise(path, opts), Outcome::Read),
        "{}: the unmutated seed does not read",
        path.display()
    );
}

fn shared_formats() -> Option<PathBuf> {
    brickray_harness::shared_data_dir().map(|d| d.join("formats"))
}

// ---------------------------------------------------------------------------
// NIfTI

proptest! {
    #![proptest_config(config(384, 0x4e49_6654_0001))]

    /// A NIfTI file's bytes mutated; for `.nii.gz` either the decoded bytes
    /// (then compressed: the header fuzzed behind gzip) or the gzip stream
    /// itself (deflate blocks, trailer).
    #[test]
    fn nifti(muts in mutations(), form in 0u8..3) {
        let d = TempDir::new().unwrap();
        let base = fixtures::nifti();
        let (name, bytes) = match form {
            0 => ("m.nii", apply(base, &muts)),
            1 => ("m.nii.gz", fixtures::gzip(&apply(base, &muts), 1)),
            _ => ("m.nii.gz", apply(fixtures::gzip(&base, 6), &muts)),
        };
        let p = fixtures::write(&d.path().join(name), &bytes);
        exercise(&p, ReadOptions::default());
    }
}

#[test]
fn nifti_seeds_read() {
    let d = TempDir::new().unwrap();
    let base = fixtures::nifti();
    seed_must_read(
        &fixtures::write(&d.path().join("a.nii"), &base),
        ReadOptions::default(),
    );
    seed_must_read(
        &fixtures::write(&d.path().join("b.nii.gz"), &fixtures::gzip(&base, 6)),
        ReadOptions::default(),
    );
}

proptest! {
    #![proptest_config(config(24, 0x4e49_6654_0002))]

    /// The shared atlas (`mricron_brodmann.nii.gz`): its decoded header
    /// mutated, or its gzip stream.
    #[test]
    #[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
    fn nifti_shared(muts in mutations(), behind_gzip in any::<bool>()) {
        let Some(f) = shared_formats() else { return Ok(()) };
        let gz = std::fs::read(f.join("nifti/mricron_brodmann.nii.gz")).unwrap();
        let d = TempDir::new().unwrap();
        let bytes = if behind_gzip {
            let mut plain = Vec::new();
            std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&gz[..]), &mut plain).unwrap();
            fixtures::gzip(&apply(plain, &muts), 1)
        } else {
            apply(gz, &muts)
        };
        let p = fixtures::write(&d.path().join("s.nii.gz"), &bytes);
        exercise(&p, ReadOptions::default());
    }
}

// ---------------------------------------------------------------------------
// TIFF

fn tiff_seed(kind: u8) -> Vec<u8> {
    let ij = "ImageJ=1.53\nimages=4\nslices=4\nspacing=2\nunit=micron\n";
    match kind {
        0 => fixtures::tiff(None, None),
        1 => fixtures::tiff(Some((ij, 2.0, 4.0)), Some("deflate")),
        2 => fixtures::tiff(Some((ij, 2.0, 4.0)), Some("lzw")),
        _ => fixtures::tiff(None, Some("packbits")),
    }
}

proptest! {
    #![proptest_config(config(384, 0x5449_4646_0001))]

    /// A TIFF stack mutated anywhere (its IFDs follow the data).
    #[test]
    fn tiff(muts in mutations(), kind in 0u8..4) {
        let d = TempDir::new().unwrap();
        let p = fixtures::write(&d.path().join("m.tif"), &apply(tiff_seed(kind), &muts));
        exercise(&p, ReadOptions::default());
    }
}

#[test]
fn tiff_seeds_read() {
    let d = TempDir::new().unwrap();
    for k in 0..4 {
        let p = fixtures::write(&d.path().join(format!("{k}.tif")), &tiff_seed(k));
        seed_must_read(&p, ReadOptions::default());
    }
}

proptest! {
    #![proptest_config(config(16, 0x5449_4646_0002))]

    /// The shared TIFF stack (`cells3d_nuclei.tif`).
    #[test]
    #[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
    fn tiff_shared(muts in mutations()) {
        let Some(f) = shared_formats() else { return Ok(()) };
        let base = std::fs::read(f.join("tiff/cells3d_nuclei.tif")).unwrap();
        let d = TempDir::new().unwrap();
        let p = fixtures::write(&d.path().join("s.tif"), &apply(base, &muts));
        exercise(&p, ReadOptions::default());
    }
}

// ---------------------------------------------------------------------------
// DICOM

/// A 4-slice series in `dir` of the given kind (0 explicit, 1 implicit,
/// 2 RLE, 3 JPEG baseline); returns slice 1's file.
fn dicom_seed(dir: &Path, kind: u8) -> PathBuf {
    use fixtures::Syntax;
    let files: Vec<PathBuf> = match kind {
        0 => fixtures::dicom_series(dir, Syntax::Explicit),
        1 => fixtures::dicom_series(dir, Syntax::Implicit),
        2 => fixtures::dicom_series(dir, Syntax::Rle),
        _ => (0..fixtures::DIMS[2])
            .map(|z| fixtures::dicom_jpeg_slice(&dir.join(format!("j{z}.dcm")), z))
            .collect(),
    };
    files[1].clone()
}

proptest! {
    #![proptest_config(config(256, 0x4449_434f_0001))]

    /// One slice of a series mutated: its header, its pixel data (native,
    /// RLE segments, a JPEG stream), the encapsulation items.
    #[test]
    fn dicom(muts in mutations(), kind in 0u8..4) {
        let d = TempDir::new().unwrap();
        let f = dicom_seed(d.path(), kind);
        let b = std::fs::read(&f).unwrap();
        std::fs::write(&f, apply(b, &muts)).unwrap();
        exercise(d.path(), ReadOptions::default());
    }
}

#[test]
fn dicom_seeds_read() {
    for k in 0..4 {
        let d = TempDir::new().unwrap();
        dicom_seed(d.path(), k);
        seed_must_read(d.path(), ReadOptions::default());
    }
}

proptest! {
    #![proptest_config(config(24, 0x4449_434f_0002))]

    /// One slice of the shared RLE or JPEG 2000 series, alone in a folder,
    /// mutated (the JPEG 2000 codestream's SIZ and tiles included).
    #[test]
    #[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
    fn dicom_shared(muts in mutations(), j2k in any::<bool>()) {
        let Some(f) = shared_formats() else { return Ok(()) };
        let folder = if j2k { "dicom/cranium_ct_j2k" } else { "dicom/cranium_ct_rle" };
        let base = std::fs::read(f.join(folder).join("IM00050.dcm")).unwrap();
        let d = TempDir::new().unwrap();
        fixtures::write(&d.path().join("one.dcm"), &apply(base, &muts));
        exercise(d.path(), ReadOptions::default());
    }
}

// ---------------------------------------------------------------------------
// OME-Zarr: metadata, and chunks through each codec.

proptest! {
    #![proptest_config(config(320, 0x5a41_5252_0001))]

    /// A chunk (or shard) file mutated, for each codec: zstd frames, gzip
    /// streams, blosc headers and blocks, crc32c, shard indexes and the
    /// inner chunks they point at.
    #[test]
    fn zarr_chunks(muts in mutations(), codec in 0usize..8, which in any::<usize>()) {
        let codec = fixtures::ZARR_CODECS[codec];
        let d = TempDir::new().unwrap();
        let root = d.path().join("m.ome.zarr");
        let files = fixtures::zarr(&root, codec);
        let f = &files[which % files.len()];
        let b = std::fs::read(f).unwrap();
        std::fs::write(f, apply(b, &muts)).unwrap();
        exercise(&root, ReadOptions::default());
        exercise_bricks(&root);
    }

    /// The array's or the group's metadata mutated.
    #[test]
    fn zarr_metadata(muts in mutations(), codec in 0usize..8, group in any::<bool>()) {
        let codec = fixtures::ZARR_CODECS[codec];
        let d = TempDir::new().unwrap();
        let root = d.path().join("m.ome.zarr");
        fixtures::zarr(&root, codec);
        let f = if !group {
            fixtures::zarr_array_meta(&root)
        } else if matches!(codec, ZarrCodec::V2Blosc | ZarrCodec::V2Zstd) {
            root.join(".zattrs")
        } else {
            root.join("zarr.json")
        };
        let b = std::fs::read(&f).unwrap();
        std::fs::write(&f, apply(b, &muts)).unwrap();
        exercise(&root, ReadOptions::default());
        exercise_bricks(&root);
    }
}

#[test]
fn zarr_seeds_read() {
    for codec in fixtures::ZARR_CODECS {
        let d = TempDir::new().unwrap();
        let root = d.path().join("m.ome.zarr");
        fixtures::zarr(&root, codec);
        seed_must_read(&root, ReadOptions::default());
        assert!(matches!(exercise_bricks(&root), Outcome::Read), "{codec:?}");
    }
}

/// Copies a folder (the shared stores are read-only).
fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        let q = dst.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

proptest! {
    #![proptest_config(config(24, 0x5a41_5252_0002))]

    /// A chunk or shard of the coarsest level of each shared store (v0.4
    /// blosc, v0.5 zstd, v0.5 sharded), read at that level.
    #[test]
    #[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
    fn zarr_shared(muts in mutations(), store in 0usize..3, which in any::<usize>()) {
        let Some(f) = shared_formats() else { return Ok(()) };
        let (name, level) = [
            ("cryoet_tomo_v04.ome.zarr", 4),
            ("pycortex_s1_t1_v05.ome.zarr", 4),
            ("cells3d_nuclei_sharded_v05.ome.zarr", 1),
        ][store];
        let d = TempDir::new().unwrap();
        let root = d.path().join(name);
        copy_dir(&f.join("ome-zarr").join(name), &root);
        let mut chunks = Vec::new();
        collect(&root.join(format!("s{level}")), &mut chunks);
        chunks.sort();
        let c = &chunks[which % chunks.len()];
        let b = std::fs::read(c).unwrap();
        std::fs::write(c, apply(b, &muts)).unwrap();
        exercise(&root, ReadOptions::default().level(Some(level)));
    }
}

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        let n = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_dir() {
            collect(&p, out);
        } else if !n.starts_with('.') && n != "zarr.json" {
            out.push(p);
        }
    }
}
