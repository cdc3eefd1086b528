//! Volume input files that must be refused: FIFOs and other non-regular files
//! (fast, never blocking), data files outside the header's folder, non-finite
//! declared ranges and spacings.

mod common;

use brickray_core::{DType, Volume, VolumeError};
use brickray_io::{self as io, IoError, NrrdReader, RawReader, VolumeReader};
use common::*;
use std::path::Path;
use tempfile::TempDir;

// ---------------------------------------------------------------------------
// Safety: FIFOs and other non-regular files, data files outside the header's
// folder, non-finite declared ranges.

fn mkfifo(path: &Path) {
    let st = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .unwrap();
    assert!(st.success(), "mkfifo failed");
}

/// Runs `f` on a thread; fails if it has not returned within 20 s, after
/// unblocking a reader stuck opening `fifo` (by opening its other end), so a
/// regression fails instead of hanging the suite.
fn within<T: Send + 'static>(fifo: &Path, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(std::time::Duration::from_secs(20)) {
        Ok(v) => v,
        Err(_) => {
            let other_end = fifo.to_owned();
            std::thread::spawn(move || {
                let _ = std::fs::OpenOptions::new().write(true).open(&other_end);
            });
            panic!("blocked on the FIFO {}", fifo.display());
        }
    }
}

fn is_not_regular(e: &Result<Volume, IoError>, path: &Path, kind: io::FileKind) -> bool {
    matches!(e, Err(IoError::NotRegularFile { path: p, kind: k }) if p == path && *k == kind)
}

#[test]
fn fifos_and_directories_are_refused_fast() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let t = std::time::Instant::now();
    let (le, _) = samples(DType::U8, DIMS, 3);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    // The sidecar, the NRRD header: FIFOs.
    for name in ["f.json", "f.nrrd", "f.nhdr"] {
        let fifo = d.join(name);
        mkfifo(&fifo);
        let p = fifo.clone();
        let r = within(&fifo, move || io::read_volume(&p));
        assert!(
            is_not_regular(&r, &fifo, io::FileKind::Fifo),
            "{name}: {r:?}"
        );
    }
    // `.raw` opens its sidecar: a FIFO named `g.json` beside `g.raw`.
    write(&d.join("g.raw"), &le);
    mkfifo(&d.join("g.json"));
    let p = d.join("g.raw");
    let r = within(&d.join("g.json"), move || io::read_volume(&p));
    assert!(
        is_not_regular(&r, &d.join("g.json"), io::FileKind::Fifo),
        "{r:?}"
    );
    // The raw data file named by a sidecar, with and without a declared range.
    for (i, range) in [None, Some([0.0, 255.0])].into_iter().enumerate() {
        let data = d.join(format!("fifo{i}.raw"));
        mkfifo(&data);
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["file"] = serde_json::json!(format!("fifo{i}.raw"));
        if let Some(r) = range {
            j["value_range"] = serde_json::json!(r);
        }
        let json = write(&d.join(format!("r{i}.json")), j.to_string().as_bytes());
        let r = within(&data, move || io::read_volume(&json));
        assert!(is_not_regular(&r, &data, io::FileKind::Fifo), "{r:?}");
    }
    // A detached NRRD's data file, raw and gzip.
    for enc in ["raw", "gzip"] {
        let data = d.join(format!("{enc}.data"));
        mkfifo(&data);
        let f = ok.replace("encoding: raw", &format!("encoding: {enc}"));
        let h = write(
            &d.join(format!("{enc}.nhdr")),
            format!("NRRD0004\n{f}data file: {enc}.data\n").as_bytes(),
        );
        let r = within(&data, move || io::read_volume(&h));
        assert!(
            is_not_regular(&r, &data, io::FileKind::Fifo),
            "{enc}: {r:?}"
        );
    }
    // Directories.
    std::fs::create_dir(d.join("dir.json")).unwrap();
    let r = io::read_volume(d.join("dir.json"));
    assert!(
        is_not_regular(&r, &d.join("dir.json"), io::FileKind::Directory),
        "{r:?}"
    );
    std::fs::create_dir(d.join("dir.data")).unwrap();
    let h = write(
        &d.join("dd.nhdr"),
        format!("NRRD0004\n{ok}data file: dir.data\n").as_bytes(),
    );
    let r = io::read_volume(&h);
    assert!(
        is_not_regular(&r, &d.join("dir.data"), io::FileKind::Directory),
        "{r:?}"
    );
    // The low-level constructor too.
    let data = d.join("fifo0.raw");
    let desc = brickray_core::VolumeDesc {
        dims: DIMS,
        dtype: DType::U8,
        spacing: [1.0; 3],
        value_range: [0.0, 1.0],
        kind: Default::default(),
    };
    let p = data.clone();
    let r = within(&data, move || RawReader::new(p, 0, desc).map(|_| ()));
    assert!(
        matches!(&r, Err(IoError::NotRegularFile { path, kind: io::FileKind::Fifo }) if path == &data),
        "{r:?}"
    );
    assert!(t.elapsed().as_secs_f64() < 10.0, "took {:?}", t.elapsed());
}

#[test]
fn data_files_outside_the_headers_folder_are_refused() {
    let top = TempDir::new().unwrap();
    let d = top.path().join("vol");
    std::fs::create_dir(&d).unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    let (le, _) = samples(DType::U8, DIMS, 4);
    // The "secret" outside the folder, of exactly the announced size.
    let secret = write(&top.path().join("secret.raw"), &le);
    std::os::unix::fs::symlink(&secret, d.join("escape.raw")).unwrap();
    write(&d.join("sub").join("in.raw"), &le);
    let outside = |name: &str| -> Vec<String> {
        vec![
            "../secret.raw".to_owned(),
            secret.display().to_string(),
            "sub/../../secret.raw".to_owned(),
            "escape.raw".to_owned(),
            format!("../vol/{name}"),
        ]
    };
    let refused = |e: &IoError, header: &Path| matches!(e, IoError::OutsideDir { path, .. } if path == header);
    // Sidecars.
    for (i, f) in outside("in.raw").iter().enumerate() {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["file"] = serde_json::json!(f);
        let json = write(&d.join(format!("o{i}.json")), j.to_string().as_bytes());
        if f.starts_with("../vol/") {
            // Leaves the folder by name but comes back into it: resolves inside.
            write(&d.join("in.raw"), &le);
            assert_eq!(io::read_volume(&json).unwrap().data().as_bytes(), le);
            continue;
        }
        let e = err_of(&json);
        assert!(refused(&e, &json), "{f}: {e}");
        assert!(
            e.to_string().contains(f.trim_start_matches("sub/"))
                || e.to_string().contains("secret"),
            "{e}"
        );
        // Allowed explicitly.
        let opts = io::ReadOptions::default().allow_outside_dir(true);
        let v = RawReader::open_sidecar_with(&json, &opts)
            .unwrap()
            .read_volume()
            .unwrap();
        assert_eq!(v.data().as_bytes(), le);
        let v = io::open_with(&json, &opts).unwrap().read_volume().unwrap();
        assert_eq!(v.data().as_bytes(), le);
    }
    // A subfolder is inside.
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["file"] = serde_json::json!("sub/in.raw");
    let json = write(&d.join("sub.json"), j.to_string().as_bytes());
    assert_eq!(io::read_volume(&json).unwrap().data().as_bytes(), le);
    // NRRD detached data files.
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    for (i, f) in outside("in.raw").iter().enumerate() {
        let h = write(
            &d.join(format!("o{i}.nhdr")),
            format!("NRRD0004\n{ok}data file: {f}\n").as_bytes(),
        );
        if f.starts_with("../vol/") {
            assert_eq!(io::read_volume(&h).unwrap().data().as_bytes(), le);
            continue;
        }
        let e = err_of(&h);
        assert!(refused(&e, &h), "{f}: {e}");
        let opts = io::ReadOptions::default().allow_outside_dir(true);
        let v = NrrdReader::open_with(&h, &opts)
            .unwrap()
            .read_volume()
            .unwrap();
        assert_eq!(v.data().as_bytes(), le);
    }
    let h = write(
        &d.join("sub.nhdr"),
        format!("NRRD0004\n{ok}data file: sub/in.raw\n").as_bytes(),
    );
    assert_eq!(io::read_volume(&h).unwrap().data().as_bytes(), le);
}

#[test]
fn non_finite_declared_ranges_and_spacings_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 5);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    for (min, max) in [
        ("nan", "1"),
        ("0", "nan"),
        ("-inf", "1"),
        ("0", "inf"),
        ("0", "1e39"),
    ] {
        let e = nrrd_err(d, &format!("{ok}min: {min}\nmax: {max}\n"), &le);
        let bad = if min == "0" { "max" } else { "min" };
        assert!(
            matches!(e, IoError::NonFiniteValue { field, value, .. } if field == bad && !value.is_finite()),
            "{min} {max}: {e}"
        );
        let e = nrrd_err(d, &format!("{ok}old min: {min}\nold max: {max}\n"), &le);
        assert!(
            matches!(e, IoError::NonFiniteValue { field, .. } if field == format!("old {bad}")),
            "old {min} {max}: {e}"
        );
    }
    for (min, max) in [("zero", "1"), ("0", "")] {
        let e = nrrd_err(d, &format!("{ok}min: {min}\nmax: {max}\n"), &le);
        assert!(
            matches!(e, IoError::BadHeader { .. }),
            "{min:?} {max:?}: {e}"
        );
    }
    // A flat declared range (min == max, a constant volume) falls back to the data.
    let v = io::read_volume(write_attached(
        d,
        "flat",
        &format!("{ok}min: 3\nmax: 3\n"),
        &le,
    ))
    .unwrap();
    assert!(v.desc().value_range[0] < v.desc().value_range[1]);
    // Spacings that overflow f32 are infinite: typed.
    for sp in [
        "spacings: 1e39 1 1",
        "space directions: (1e39,0,0) (0,1,0) (0,0,1)",
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
    // Sidecars: JSON has no NaN literal, but 1e39 overflows f32 to infinity.
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["spacing"] = serde_json::json!([1.0, 1e39, 1.0]);
    let e = err_of(&write_sidecar(d, "sp", j, &le));
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadSpacing(_),
                ..
            }
        ),
        "{e}"
    );
    for vr in [
        serde_json::json!([0.0, 1e39]),
        serde_json::json!([-1e39, 0.0]),
    ] {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["value_range"] = vr.clone();
        let e = err_of(&write_sidecar(d, "vr", j, &le));
        assert!(
            matches!(e, IoError::NonFiniteValue { field: "value_range", value, .. } if value.is_infinite()),
            "{vr}: {e}"
        );
    }
}
