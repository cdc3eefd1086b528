//! Volume input that must fail: typed errors for every kind of bad input
//! (sizes, headers, truncation, non-finite values, forged sizes), never a
//! panic. The mutation fuzz is in `io_fuzz.rs`; non-regular and outside files
//! are in `io_files.rs`.

mod common;

use brickray_core::{DType, VolumeError};
use brickray_io::{self as io, IoError};
use common::*;
use tempfile::TempDir;

// ---------------------------------------------------------------------------
// Bad input: typed errors, never a panic.

#[test]
fn raw_size_must_match_dims_and_dtype() {
    let dir = TempDir::new().unwrap();
    for dtype in DTYPES {
        let (le, _) = samples(dtype, DIMS, 2);
        let need = le.len() as u64;
        let j = sidecar_json(dtype.name(), DIMS.map(u64::from), SPACING);
        let short = write_sidecar(dir.path(), "short", j.clone(), &le[..le.len() - 1]);
        assert!(
            matches!(err_of(&short), IoError::SizeMismatch { expected, actual, .. } if expected == need && actual == need - 1)
        );
        let mut long = le.clone();
        long.extend_from_slice(&[0; 4]);
        let long = write_sidecar(dir.path(), "long", j.clone(), &long);
        assert!(
            matches!(err_of(&long), IoError::SizeMismatch { expected, actual, .. } if expected == need && actual == need + 4)
        );
        let empty = write_sidecar(dir.path(), "empty", j, &[]);
        assert!(matches!(
            err_of(&empty),
            IoError::SizeMismatch { actual: 0, .. }
        ));
    }
}

#[test]
fn sidecar_errors_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 2);
    let case = |name: &str, json: serde_json::Value| err_of(&write_sidecar(d, name, json, &le));
    // (u32 is a sample type since label maps; u64 is not.)
    for ty in ["f64", "double", "int32", "u64", "uint64", "", "u 8"] {
        let e = case("ty", sidecar_json(ty, [7, 5, 3], SPACING));
        assert!(
            matches!(&e, IoError::UnknownDType { name, .. } if name == ty),
            "{ty}: {e}"
        );
    }
    // names are trimmed and case-insensitive
    assert!(
        io::read_volume(write_sidecar(
            d,
            "ok",
            sidecar_json(" U8 ", [7, 5, 3], SPACING),
            &le
        ))
        .is_ok()
    );
    for dims in [
        [0, 5, 3],
        [7, 0, 3],
        [7, 5, 0],
        [1 << 30, 1, 1],
        [1, 1 << 30, 1],
        [1 << 24, 1 << 24, 1 << 24],
    ] {
        let e = case("dims", sidecar_json("u8", dims, SPACING));
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadDims { .. },
                    ..
                }
            ),
            "{dims:?}: {e}"
        );
    }
    // u64 overflow of the product, and dims beyond u32
    let e = case(
        "dims",
        serde_json::json!({ "dims": [u64::MAX, u64::MAX, 2], "dtype": "u8" }),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    let e = case(
        "dims",
        serde_json::json!({ "dims": [1u64 << 33, 1, 1], "dtype": "u8" }),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    for dims in [
        serde_json::json!([7, 5]),
        serde_json::json!([7, 5, 3, 1]),
        serde_json::json!([]),
    ] {
        let e = case("ndims", serde_json::json!({ "dims": dims, "dtype": "u8" }));
        assert!(matches!(e, IoError::BadHeader { .. }), "{dims}: {e}");
    }
    for dims in [
        serde_json::json!([7, -5, 3]),
        serde_json::json!([7.5, 5, 3]),
        serde_json::json!("7x5x3"),
    ] {
        let e = case(
            "baddims",
            serde_json::json!({ "dims": dims, "dtype": "u8" }),
        );
        assert!(matches!(e, IoError::BadHeader { .. }), "{dims}: {e}");
    }
    for sp in [[1.0, -1.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, -0.0]] {
        let e = case("sp", sidecar_json("u8", [7, 5, 3], sp));
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadSpacing(_),
                    ..
                }
            ),
            "{sp:?}: {e}"
        );
    }
    let e = case(
        "sp2",
        serde_json::json!({ "dims": [7, 5, 3], "dtype": "u8", "spacing": [1.0, 1.0] }),
    );
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    for vr in [
        serde_json::json!([1.0, 1.0]),
        serde_json::json!([2.0, 1.0]),
        serde_json::json!([1.0]),
    ] {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["value_range"] = vr;
        assert!(matches!(case("vr", j), IoError::BadHeader { .. }));
    }
    let mut j = sidecar_json("u16", [7, 5, 3], SPACING);
    j["byte_order"] = serde_json::json!("big");
    assert!(matches!(case("bo", j), IoError::Unsupported { .. }));
    // malformed JSON: syntax, NaN literal, missing fields, wrong top-level type
    for text in [
        "{ \"dims\": [7, 5, 3], \"dtype\": \"u8\"",
        "{ \"dims\": [7, 5, 3], \"dtype\": \"u8\", \"spacing\": [NaN, 1, 1] }",
        "{ \"dtype\": \"u8\" }",
        "{ \"dims\": [7, 5, 3] }",
        "[7, 5, 3]",
        "",
        "\u{feff}{}",
    ] {
        let p = write(&d.join("m.json"), text.as_bytes());
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{text:?}");
    }
    let p = write(&d.join("bin.json"), &[0xff, 0xfe, b'{', b'}']);
    assert!(matches!(
        err_of(&p),
        IoError::Io { .. } | IoError::BadHeader { .. }
    ));
    // missing files
    assert!(matches!(err_of(&d.join("absent.json")), IoError::Io { .. }));
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["file"] = serde_json::json!("absent.raw");
    let p = write(&d.join("nofile.json"), j.to_string().as_bytes());
    assert!(matches!(err_of(&p), IoError::Io { path, .. } if path.ends_with("absent.raw")));
}

#[test]
fn nrrd_header_errors_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 2);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    assert!(io::read_volume(write_attached(d, "ok", ok, &le)).is_ok());
    let without = |key: &str| {
        ok.lines()
            .filter(|l| !l.starts_with(key))
            .map(|l| format!("{l}\n"))
            .collect::<String>()
    };
    for key in ["type", "sizes", "encoding", "dimension"] {
        let e = nrrd_err(d, &without(key), &le);
        assert!(matches!(e, IoError::BadHeader { .. }), "{key}: {e}");
    }
    // no magic; empty file; magic only
    for bytes in [
        &b"NRRX0004\ntype: uchar\n\n"[..],
        b"",
        b"NRRD0004",
        b"\xff\xfeNRRD0004\n",
    ] {
        let p = write(&d.join("m.nrrd"), bytes);
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{bytes:?}");
    }
    let p = write(&d.join("m.nrrd"), b"NRRD0004\n");
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    for ty in [
        "double",
        "int32",
        "int",
        "uint",
        "long long",
        "block",
        "char",
    ] {
        let f = ok.replace("uchar", ty);
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::UnknownDType { name, .. } if name == ty),
            "{ty}"
        );
    }
    for enc in ["ascii", "text", "bzip2", "hex", "zstd"] {
        let f = ok.replace("encoding: raw", &format!("encoding: {enc}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::Unsupported { .. }),
            "{enc}"
        );
    }
    // 2D, 5D and 4D with a non-trivial leading axis
    for (dim, sizes) in [(2, "7 15"), (5, "1 1 7 5 3"), (4, "3 7 5 1"), (1, "105")] {
        let f = ok
            .replace("dimension: 3", &format!("dimension: {dim}"))
            .replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::Unsupported { .. }),
            "{dim}D"
        );
    }
    // sizes not matching dimension, not numbers
    for sizes in ["7 5", "7 5 3 1", "7 -5 3", "7 five 3", "7 5 3.0", ""] {
        let f = ok.replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::BadHeader { .. }),
            "{sizes:?}"
        );
    }
    for dim in ["three", "-3", ""] {
        let f = ok.replace("dimension: 3", &format!("dimension: {dim}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::BadHeader { .. }),
            "{dim:?}"
        );
    }
    // zero and absurd dims
    for sizes in [
        "0 5 3",
        "7 5 0",
        "1073741824 1 1",
        "16777216 16777216 16777216",
        "18446744073709551615 2 2",
    ] {
        let f = ok.replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        let e = nrrd_err(d, &f, &le);
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadDims { .. },
                    ..
                }
            ),
            "{sizes}: {e}"
        );
    }
    let e = nrrd_err(
        d,
        &ok.replace("sizes: 7 5 3", "sizes: 99999999999999999999999 1 1"),
        &le,
    );
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // bad spacing: negative, zero, NaN, Inf, wrong count, zero direction, garbage
    for sp in [
        "spacings: 1 -1 1",
        "spacings: 0 1 1",
        "spacings: 1 nan 1",
        "spacings: inf 1 1",
        "space directions: (1,0,0) (0,0,0) (0,0,1)",
    ] {
        let e = nrrd_err(d, &format!("{ok}{sp}\n"), &le);
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadSpacing(_),
                    ..
                }
            ),
            "{sp}: {e}"
        );
    }
    for sp in [
        "spacings: 1 1",
        "spacings: 1 1 1 1",
        "spacings: a b c",
        "space directions: (1,0,0) (0,1,0)",
        "space directions: (1,0) (0,1,0) (0,0,1)",
        "space directions: (1,x,0) (0,1,0) (0,0,1)",
        "space directions: none (0,1,0) (0,0,1)",
    ] {
        let e = nrrd_err(d, &format!("{ok}{sp}\n"), &le);
        assert!(matches!(e, IoError::BadHeader { .. }), "{sp}: {e}");
    }
    // unparsable line, byte skip, line skip, multi-file data
    assert!(matches!(
        nrrd_err(d, &format!("{ok}what is this\n"), &le),
        IoError::BadHeader { .. }
    ));
    for skip in ["byte skip: 4", "byte skip: -1", "line skip: 2"] {
        assert!(
            matches!(
                nrrd_err(d, &format!("{ok}{skip}\n"), &le),
                IoError::Unsupported { .. }
            ),
            "{skip}"
        );
    }
    assert_eq!(
        io::read_volume(write_attached(
            d,
            "bs0",
            &format!("{ok}byte skip: 0\n"),
            &le
        ))
        .unwrap()
        .data()
        .as_bytes(),
        le
    );
    let p = write(
        &d.join("list.nhdr"),
        format!("NRRD0004\n{ok}data file: LIST\na.raw\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Unsupported { .. }));
    let p = write(
        &d.join("fmt.nhdr"),
        format!("NRRD0004\n{ok}data file: s%03d.raw 0 2 1\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Unsupported { .. }));
    // detached header naming a file that does not exist
    let p = write(
        &d.join("nodata.nhdr"),
        format!("NRRD0004\n{ok}data file: absent.raw\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Io { path, .. } if path.ends_with("absent.raw")));
    let p = write(&d.join("nodata.nhdr"), format!("NRRD0004\n{ok}").as_bytes());
    assert!(matches!(err_of(&p), IoError::Truncated { actual: 0, .. }));
}

#[test]
fn nrrd_header_limit_and_non_text() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    // many comment lines past 1 MiB
    let comments =
        "# padding padding padding padding padding padding\n".repeat((1 << 20) / 50 + 10);
    let e = nrrd_err(d, &format!("{ok}{comments}"), &[0; 105]);
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // one endless line without a newline, after the magic and in the magic
    let mut b = b"NRRD0004\ntype: ".to_vec();
    b.extend(std::iter::repeat_n(b'a', 3 << 20));
    let p = write(&d.join("long.nrrd"), &b);
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    let mut b = b"NRRD0004".to_vec();
    b.extend(std::iter::repeat_n(b'4', 3 << 20));
    let p = write(&d.join("long.nrrd"), &b);
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    // non-UTF-8 bytes in a field and in a comment
    for bad in [&b"type: \xff\xfe\n"[..], b"# caf\xe9\n", b"\x80\n"] {
        let mut b = b"NRRD0004\n".to_vec();
        b.extend_from_slice(bad);
        b.extend_from_slice(ok.as_bytes());
        b.extend_from_slice(b"\n");
        b.extend_from_slice(&[0; 105]);
        let p = write(&d.join("bin.nrrd"), &b);
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{bad:?}");
    }
    // CRLF line ends are accepted
    let (le, _) = samples(DType::U8, DIMS, 4);
    let mut b = b"NRRD0004\r\n".to_vec();
    b.extend_from_slice(ok.replace('\n', "\r\n").as_bytes());
    b.extend_from_slice(b"\r\n");
    b.extend_from_slice(&le);
    let p = write(&d.join("crlf.nrrd"), &b);
    assert_eq!(io::read_volume(&p).unwrap().data().as_bytes(), le);
}

#[test]
fn nrrd_truncated_data_is_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    for dtype in DTYPES {
        let (le, _) = samples(dtype, DIMS, 5);
        let need = le.len() as u64;
        for detached in [false, true] {
            let fields = nrrd_fields(dtype, DIMS, "raw", false);
            for cut in [0, 1, le.len() / 2, le.len() - 1] {
                let p = if detached {
                    write_detached(d, "t", &fields, &le[..cut])
                } else {
                    write_attached(d, "t", &fields, &le[..cut])
                };
                let e = err_of(&p);
                assert!(
                    matches!(e, IoError::Truncated { expected, actual, .. } if expected == need && actual == cut as u64),
                    "{e}"
                );
            }
            // trailing bytes after the data are tolerated (NRRD readers skip them)
            let mut more = le.clone();
            more.extend_from_slice(b"trailer");
            let p = if detached {
                write_detached(d, "t", &fields, &more)
            } else {
                write_attached(d, "t", &fields, &more)
            };
            assert_eq!(io::read_volume(&p).unwrap().data().as_bytes(), le);
        }
    }
}

#[test]
fn nrrd_truncated_and_corrupt_gzip_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let dims = [16, 16, 8];
    for dtype in [DType::U8, DType::F32] {
        let (le, _) = samples(dtype, dims, 6);
        let gz = gzip(&le);
        let fields = nrrd_fields(dtype, dims, "gzip", false);
        let with_range = format!("{fields}min: -1e9\nmax: 1e9\n");
        for f in [&fields, &with_range] {
            // cut inside the gzip header, the deflate data and the CRC/length trailer
            for cut in [
                0,
                5,
                10,
                11,
                gz.len() / 3,
                gz.len() / 2,
                gz.len() - 9,
                gz.len() - 8,
                gz.len() - 4,
                gz.len() - 1,
            ] {
                let p = write_detached(d, "g", f, &gz[..cut]);
                let e = err_of(&p);
                assert!(
                    matches!(e, IoError::Truncated { .. }),
                    "cut {cut}/{}: {e}",
                    gz.len()
                );
                let p = write_attached(d, "g", f, &gz[..cut]);
                assert!(matches!(err_of(&p), IoError::Truncated { .. }), "cut {cut}");
            }
            // a stream that decodes to fewer bytes than announced
            let p = write_attached(d, "short", f, &gzip(&le[..le.len() - 4]));
            let e = err_of(&p);
            assert!(
                matches!(e, IoError::Truncated { expected, actual, .. } if expected == le.len() as u64 && actual == le.len() as u64 - 4),
                "{e}"
            );
            // not gzip at all, bad magic, bad CRC, bad length
            let p = write_attached(d, "raw_as_gz", f, &le);
            assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
            let mut bad = gz.clone();
            bad[0] ^= 0xff;
            assert!(matches!(
                err_of(&write_attached(d, "c", f, &bad)),
                IoError::BadHeader { .. }
            ));
            let n = bad.len();
            for i in [n - 8, n - 5, n - 4, n - 1] {
                let mut bad = gz.clone();
                bad[i] ^= 0x55;
                let e = err_of(&write_attached(d, "c", f, &bad));
                assert!(
                    matches!(e, IoError::BadHeader { .. }),
                    "trailer byte {i}: {e}"
                );
            }
            // corrupt deflate bytes: an error (corrupt or short), never wrong data
            for i in (12..n - 8).step_by((n / 7).max(1)) {
                let mut bad = gz.clone();
                bad[i] ^= 0xa5;
                let e = err_of(&write_attached(d, "c", f, &bad));
                assert!(
                    matches!(e, IoError::BadHeader { .. } | IoError::Truncated { .. }),
                    "byte {i}: {e}"
                );
            }
        }
    }
}

#[test]
fn non_finite_f32_is_typed_in_both_readers() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (_, mut values) = samples(DType::F32, DIMS, 8);
    // first bad voxel at (3, 2, 1) = index 3 + 7 * (2 + 5 * 1) = 52
    values[52] = f32::NAN;
    values[60] = f32::INFINITY;
    values[104] = f32::NEG_INFINITY;
    let le = f32_bytes(&values);
    let is_nonfinite = |e: &IoError| {
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::NonFinite {
                    count: 3,
                    first: [3, 2, 1]
                },
                ..
            }
        )
    };
    for declared in [false, true] {
        let mut j = sidecar_json("f32", DIMS.map(u64::from), SPACING);
        if declared {
            j["value_range"] = serde_json::json!([0.0, 1.0]);
        }
        let e = err_of(&write_sidecar(d, "nan", j, &le));
        assert!(is_nonfinite(&e), "sidecar declared={declared}: {e}");
        let range = if declared { "min: 0\nmax: 1\n" } else { "" };
        for encoding in ["raw", "gzip"] {
            for big in [false, true] {
                let mut payload = if big {
                    to_big_endian(DType::F32, &le)
                } else {
                    le.clone()
                };
                if encoding == "gzip" {
                    payload = gzip(&payload);
                }
                let f = format!("{}{range}", nrrd_fields(DType::F32, DIMS, encoding, big));
                let e = err_of(&write_attached(d, "nan", &f, &payload));
                assert!(
                    is_nonfinite(&e),
                    "nrrd {encoding} big={big} declared={declared}: {e}"
                );
            }
        }
    }
    // a single NaN in the very last voxel
    let (_, mut values) = samples(DType::F32, DIMS, 8);
    *values.last_mut().unwrap() = f32::NAN;
    let le = f32_bytes(&values);
    let e = err_of(&write_sidecar(
        d,
        "last",
        sidecar_json("f32", DIMS.map(u64::from), SPACING),
        &le,
    ));
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::NonFinite {
                    count: 1,
                    first: [6, 4, 2]
                },
                ..
            }
        ),
        "{e}"
    );
    // integer types never hold non-finite values: 0xFFFF is a valid u16/i16 sample
    let e = io::read_volume(write_sidecar(
        d,
        "ff",
        sidecar_json("u16", DIMS.map(u64::from), SPACING),
        &vec![0xff; 210],
    ));
    assert_eq!(e.unwrap().desc().value_range, [65535.0, 65536.0]);
}

#[test]
fn non_finite_count_spans_the_whole_volume() {
    // Larger than one scan chunk (1 MiB): the count is over all of it.
    let dir = TempDir::new().unwrap();
    let dims = [128u32, 128, 40];
    let n = dims.iter().product::<u32>() as usize;
    let mut values = vec![0.5f32; n];
    let bad = [n / 2 + 3, n / 2 + 4, n - 1, 300_000, 600_000];
    for &i in &bad {
        values[i] = f32::NAN;
    }
    let le = f32_bytes(&values);
    let first = 300_000u32;
    let first = [first % 128, (first / 128) % 128, first / (128 * 128)];
    let ok = |e: &IoError| matches!(e, IoError::Volume { source: VolumeError::NonFinite { count: 5, first: f }, .. } if *f == first);
    let e = err_of(&write_sidecar(
        dir.path(),
        "big",
        sidecar_json("f32", dims.map(u64::from), [1.0; 3]),
        &le,
    ));
    assert!(ok(&e), "{e}");
    let f = nrrd_fields(DType::F32, dims, "gzip", false);
    let e = err_of(&write_attached(dir.path(), "big", &f, &gzip(&le)));
    assert!(ok(&e), "{e}");
}

#[test]
fn forged_sizes_fail_fast_without_allocating() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let t = std::time::Instant::now();
    // beyond the voxel-count limit: rejected from the header alone
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 100000\nencoding: gzip\n",
        &gzip(&[0; 64]),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n",
        &[0; 64],
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    // within the limit but 40 GB (a 40 GB slice!) announced over a few bytes: the
    // size check (raw) and the bounded-memory scan (gzip) find the data missing
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: raw\n",
        &[0; 64],
    );
    assert!(
        matches!(
            e,
            IoError::Truncated {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: gzip\n",
        &gzip(&[0; 64]),
    );
    assert!(
        matches!(
            e,
            IoError::Truncated {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: gzip\nmin: 0\nmax: 1\n",
        &gzip(&[0; 64]),
    );
    assert!(matches!(e, IoError::Truncated { .. }), "{e}");
    let e = err_of(&write_sidecar(
        d,
        "forged",
        sidecar_json("f32", [100_000, 100_000, 1], [1.0; 3]),
        &[0; 64],
    ));
    assert!(
        matches!(
            e,
            IoError::SizeMismatch {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    assert!(t.elapsed().as_secs_f64() < 2.0, "took {:?}", t.elapsed());
}
