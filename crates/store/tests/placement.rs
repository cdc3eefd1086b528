//! The placement record (format version 6): a store keeps the voxel-to-world
//! affine and space of the file it was built from, bit for bit; stores
//! without one (older versions included) open with none; a damaged record is
//! a typed error; `brickray-store info` prints it.
#![allow(missing_docs)]

mod common;

use brickray_core::{DType, RangeReader, VolumeDesc};
use brickray_io::{IoError, Placement, VolumeReader};
use brickray_store::format::PLACEMENT_LEN;
use brickray_store::{BuildOptions, Store, StoreError, build, open};
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Header byte of the flags, and the placement flag (bit 5).
const FLAGS: usize = 30;
const FLAG_PLACEMENT: u8 = 32;

/// A rotated and mirrored LPS placement: voxel x runs along world -y, voxel
/// y along world -x (together a mirror: the determinant is negative), voxel
/// z along +z with a slight shear into x; spacings and offsets with many
/// significant bits and a negative zero, so that a bit-for-bit comparison
/// means something.
fn lps_placement() -> Placement {
    Placement {
        affine: [
            [0.0, -0.703_125, 0.012_5, 120.337_890_625],
            [-0.703_125, 0.0, 0.0, 98.1],
            [0.0, 0.0, 2.499_968_75, -0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
        space: "LPS",
    }
}

/// A reader with a placement.
struct Placed(MemReader, Option<Placement>);

impl VolumeReader for Placed {
    fn desc(&self) -> &VolumeDesc {
        self.0.desc()
    }
    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        self.0.read_slices(z0, z1, out)
    }
    fn path(&self) -> &Path {
        self.0.path()
    }
    fn placement(&self) -> Option<Placement> {
        self.1
    }
}

fn reader(placement: Option<Placement>) -> Placed {
    let dims = [12, 10, 7];
    Placed(
        MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 11)),
        placement,
    )
}

fn options() -> BuildOptions {
    BuildOptions {
        brick: 4,
        apron: 1,
        ..BuildOptions::default()
    }
}

/// Builds a store from `reader(placement)` at `dir/name`; its path and bytes.
fn store(dir: &Path, name: &str, placement: Option<Placement>) -> (PathBuf, Vec<u8>) {
    let out = dir.join(name);
    let report = build(&mut reader(placement), &out, &options()).unwrap();
    assert_eq!(report.placement, placement);
    let b = std::fs::read(&out).unwrap();
    assert_eq!(report.file_bytes, b.len() as u64);
    (out, b)
}

fn bits(p: &Placement) -> [[u64; 4]; 4] {
    p.affine.map(|r| r.map(f64::to_bits))
}

fn reseal_header(b: &mut [u8]) {
    let crc = crc32fast::hash(&b[..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
}

fn open_bytes(dir: &Path, name: &str, b: &[u8]) -> Result<Store, StoreError> {
    let p = dir.join(name);
    std::fs::write(&p, b).unwrap();
    open(&p)
}

/// Every node's metadata and brick of `a` equals `b`'s.
fn same_nodes(a: &Store, b: &Store) {
    let bb = a.layout().brick_bytes();
    let (mut x, mut y) = (vec![0u8; bb], vec![0u8; bb]);
    assert_eq!(a.nodes().count(), b.nodes().count());
    for rec in a.nodes() {
        assert_eq!(b.info(rec.key).unwrap(), rec.info);
        a.read(rec.key, &mut x).unwrap();
        b.read(rec.key, &mut y).unwrap();
        assert_eq!(x, y, "{:?}", rec.key);
    }
}

#[test]
fn a_store_keeps_its_inputs_placement_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let want = lps_placement();
    let (path, b) = store(dir.path(), "placed.brs", Some(want));
    let (plain_path, plain) = store(dir.path(), "plain.brs", None);
    assert_eq!(u32::from_le_bytes(b[8..12].try_into().unwrap()), 7);
    assert_eq!(b[FLAGS] & FLAG_PLACEMENT, FLAG_PLACEMENT);
    assert_eq!(plain[FLAGS] & FLAG_PLACEMENT, 0);
    // The record ends the file; everything before it is the store without
    // a placement (but the header's flag and checksum).
    assert_eq!(b.len(), plain.len() + PLACEMENT_LEN);
    assert_eq!(b[128..plain.len()], plain[128..]);
    let rec = &b[plain.len()..];
    assert_eq!(rec[96], 2, "LPS is space code 2");
    assert_eq!(rec[97..100], [0; 3]);
    assert_eq!(
        u32::from_le_bytes(rec[100..104].try_into().unwrap()),
        crc32fast::hash(&rec[..100])
    );
    let s = open(&path).unwrap();
    assert_eq!(s.version(), 7);
    let got = s.placement().expect("a placement");
    assert_eq!(got.space, "LPS");
    assert_eq!(bits(&got), bits(&want));
    // The negative zero survives.
    assert_eq!(got.affine[2][3].to_bits(), (-0.0f64).to_bits());
    let plain_store = open(&plain_path).unwrap();
    assert_eq!(plain_store.placement(), None);
    assert_eq!(plain_store.version(), 7);
    same_nodes(&s, &plain_store);
    // Each space, and a deterministic file.
    for space in ["RAS", "image"] {
        let p = Placement {
            space,
            ..lps_placement()
        };
        let (path, _) = store(dir.path(), &format!("{space}.brs"), Some(p));
        let got = open(&path).unwrap().placement().unwrap();
        assert_eq!((got.space, bits(&got)), (space, bits(&p)));
    }
    let (_, again) = store(dir.path(), "again.brs", Some(want));
    assert_eq!(again, b);
}

/// A reader that counts its reads and says it is remote: a store over the
/// network reads its placement with the rest of the metadata.
#[derive(Debug)]
struct Counting(brickray_store::MemRangeReader, Arc<AtomicUsize>);

impl RangeReader for Counting {
    fn len(&self) -> std::io::Result<u64> {
        self.0.len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
        self.1.fetch_add(1, Ordering::SeqCst);
        self.0.read_exact_at(buf, offset)
    }
    fn is_remote(&self) -> bool {
        true
    }
}

#[test]
fn a_store_read_through_a_range_reader_has_its_placement_without_another_read() {
    let dir = tempfile::tempdir().unwrap();
    let want = lps_placement();
    for placement in [Some(want), None] {
        let (_, b) = store(dir.path(), "r.brs", placement);
        let reads = Arc::new(AtomicUsize::new(0));
        let s = Store::open_with(
            Counting(brickray_store::MemRangeReader::new(b), reads.clone()),
            "https://example.invalid/r.brs",
        )
        .unwrap();
        assert_eq!(reads.load(Ordering::SeqCst), 2, "the header, then the tail");
        assert_eq!(s.placement().map(|p| bits(&p)), placement.map(|p| bits(&p)));
        assert_eq!(s.placement().map(|p| p.space), placement.map(|p| p.space));
    }
}

#[test]
fn version_5_stores_open_without_a_placement() {
    let dir = tempfile::tempdir().unwrap();
    let (path, b) = store(dir.path(), "placed.brs", Some(lps_placement()));
    let s6 = open(&path).unwrap();
    // As version 5 wrote it: no record, no flag, the version field 5.
    let mut v5 = b[..b.len() - PLACEMENT_LEN].to_vec();
    v5[8..12].copy_from_slice(&5u32.to_le_bytes());
    v5[FLAGS] &= !FLAG_PLACEMENT;
    reseal_header(&mut v5);
    let s5 = open_bytes(dir.path(), "v5.brs", &v5).unwrap();
    assert_eq!(s5.version(), 5);
    assert_eq!(s5.placement(), None);
    assert!(s5.has_errors());
    same_nodes(&s5, &s6);
    // Version 5 does not know the flag: with it (and the record) the header
    // is refused, never read as a placement.
    let mut bad = b.clone();
    bad[8..12].copy_from_slice(&5u32.to_le_bytes());
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad5.brs", &bad),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
    // Nor does a version-7 reader accept version 8.
    let mut v8 = b.clone();
    v8[8..12].copy_from_slice(&8u32.to_le_bytes());
    reseal_header(&mut v8);
    assert!(matches!(
        open_bytes(dir.path(), "v8.brs", &v8),
        Err(StoreError::UnsupportedVersion { version: 8, .. })
    ));
}

#[test]
fn a_damaged_placement_record_is_a_typed_error() {
    let dir = tempfile::tempdir().unwrap();
    let (_, good) = store(dir.path(), "placed.brs", Some(lps_placement()));
    let at = good.len() - PLACEMENT_LEN;
    let path = dir.path().join("m.brs");
    // Every single-bit flip of the record (its CRC included) is caught.
    for i in at..good.len() {
        for bit in 0..8 {
            let mut b = good.clone();
            b[i] ^= 1 << bit;
            std::fs::write(&path, &b).unwrap();
            match open(&path) {
                Err(StoreError::PlacementChecksum { .. }) => {}
                Err(e) => panic!("byte {} bit {bit}: unexpected {e}", i - at),
                Ok(_) => panic!("byte {} bit {bit}: opened", i - at),
            }
        }
    }
    // Forged records with their CRC recomputed: non-finite, singular, an
    // unknown space, reserved bytes.
    let reseal = |b: &mut [u8]| {
        let crc = crc32fast::hash(&b[at..at + 100]);
        b[at + 100..].copy_from_slice(&crc.to_le_bytes());
    };
    let f64s = |vals: &[(usize, f64)]| {
        let mut b = good.clone();
        for &(i, v) in vals {
            b[at + 8 * i..at + 8 * i + 8].copy_from_slice(&v.to_le_bytes());
        }
        b
    };
    let byte = |i: usize, v: u8| {
        let mut b = good.clone();
        b[at + i] = v;
        b
    };
    let zero: Vec<(usize, f64)> = (0..12).map(|i| (i, 0.0)).collect();
    let cases = [
        ("NaN", f64s(&[(3, f64::NAN)]), "affine", "non-finite"),
        (
            "infinity",
            f64s(&[(10, f64::INFINITY)]),
            "affine",
            "non-finite",
        ),
        // Row 2 made a multiple of row 0 (affine elements 8..12).
        (
            "singular",
            f64s(&[(8, 0.0), (9, -1.40625), (10, 0.025), (11, 3.0)]),
            "affine",
            "do not span space",
        ),
        ("all zero", f64s(&zero), "affine", "zero column"),
        ("space 0", byte(96, 0), "space", "unknown code 0"),
        ("space 4", byte(96, 4), "space", "unknown code 4"),
        ("reserved", byte(99, 1), "reserved", "non-zero"),
    ];
    for (what, mut b, field, reason) in cases {
        reseal(&mut b);
        match open_bytes(dir.path(), "forged.brs", &b) {
            Err(StoreError::BadPlacement {
                field: f,
                reason: r,
                ..
            }) if f == field && r.contains(reason) => {}
            Err(e) => panic!("{what}: unexpected {e}"),
            Ok(_) => panic!("{what}: opened"),
        }
    }
    // Cut short, or announced and missing: truncated.
    for cut in [1, PLACEMENT_LEN] {
        match open_bytes(dir.path(), "cut.brs", &good[..good.len() - cut]) {
            Err(StoreError::Truncated {
                section: "placement record",
                ..
            }) => {}
            Err(e) => panic!("cut {cut}: unexpected {e}"),
            Ok(_) => panic!("cut {cut}: opened"),
        }
    }
    // The record without its flag: bytes after the store.
    let mut b = good.clone();
    b[FLAGS] &= !FLAG_PLACEMENT;
    reseal_header(&mut b);
    assert!(matches!(
        open_bytes(dir.path(), "noflag.brs", &b),
        Err(StoreError::BadHeader {
            field: "table_offset",
            ..
        })
    ));
}

#[test]
fn a_placement_the_record_cannot_hold_fails_the_build_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let mut singular = lps_placement();
    singular.affine[2] = [0.0, -1.40625, 0.025, 0.0];
    let mut nan = lps_placement();
    nan.affine[0][3] = f64::NAN;
    let mut last_row = lps_placement();
    last_row.affine[3] = [0.0, 0.0, 0.5, 1.0];
    let odd_space = Placement {
        space: "RAS+",
        ..lps_placement()
    };
    for (what, p, field, reason) in [
        ("singular", singular, "affine", "do not span space"),
        ("NaN", nan, "affine", "non-finite"),
        ("last row", last_row, "affine", "last row"),
        ("space", odd_space, "space", "RAS+"),
    ] {
        let out = dir.path().join("bad.brs");
        match build(&mut reader(Some(p)), &out, &options()) {
            Err(StoreError::BadPlacement {
                field: f,
                reason: r,
                ..
            }) if f == field && r.contains(reason) => {}
            Err(e) => panic!("{what}: unexpected {e}"),
            Ok(_) => panic!("{what}: built"),
        }
        assert!(!out.exists(), "{what}");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "{what}: a temporary was left"
        );
    }
}

/// The lines `info` prints for a placement: the heading and three rows.
fn placement_lines(stdout: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(stdout);
    let lines: Vec<&str> = text.lines().collect();
    match lines.iter().position(|l| l.starts_with("placement ")) {
        Some(i) => lines[i..(i + 4).min(lines.len())]
            .iter()
            .map(|l| l.to_string())
            .collect(),
        None => Vec::new(),
    }
}

fn info(target: &Path) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_brickray-store"))
        .args(["info", "--bins", "2"])
        .arg(target)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn info_prints_a_stores_placement() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = store(dir.path(), "placed.brs", Some(lps_placement()));
    let lines = placement_lines(&info(&path).stdout);
    assert_eq!(
        lines,
        [
            "placement   voxel to world (LPS):",
            "              [    0.0000    -0.7031     0.0125   120.3379]",
            "              [   -0.7031     0.0000     0.0000    98.1000]",
            "              [    0.0000     0.0000     2.5000    -0.0000]",
        ]
    );
    let (plain, _) = store(dir.path(), "plain.brs", None);
    let out = info(&plain);
    assert_eq!(placement_lines(&out.stdout), Vec::<String>::new());
    assert!(String::from_utf8_lossy(&out.stdout).contains("levels"));
}

/// A store built from the shared NIfTI (RAS, a FreeSurfer LIA orientation)
/// and DICOM series (LPS) keeps the file's placement, and `info` prints the
/// same placement for the store as for the file.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn stores_built_from_nifti_and_dicom_keep_their_placement() {
    let Some(data) = shared_data() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for (input, space) in [
        ("formats/nifti/pycortex_s1_t1.nii.gz", "RAS"),
        ("formats/dicom/cranium_ct", "LPS"),
    ] {
        let input = data.join(input);
        let want = brickray_io::open(&input)
            .unwrap()
            .placement()
            .expect("the file places its volume");
        assert_eq!(want.space, space);
        let out = dir.path().join("s.brs");
        let report = brickray_store::build_file(&input, &out, &BuildOptions::default()).unwrap();
        assert_eq!(report.placement, Some(want));
        let got = open(&out).unwrap().placement().expect("a placement");
        assert_eq!(got.space, space, "{}", input.display());
        assert_eq!(bits(&got), bits(&want), "{}", input.display());
        let from_file = placement_lines(&info(&input).stdout);
        assert_eq!(from_file.len(), 4, "{}", input.display());
        assert_eq!(placement_lines(&info(&out).stdout), from_file);
    }
}
