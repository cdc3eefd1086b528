//! No input destroyed, nothing left behind: the builder refuses outputs that are
//! its inputs or not regular files, the reader refuses FIFOs, and interrupted
//! builds leave no temporaries.
#![allow(missing_docs)]

mod common;

use brickray_core::DType;
use brickray_store::{BuildOptions, build_file};
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn small_opts() -> BuildOptions {
    BuildOptions {
        brick: 4,
        apron: 1,
        ..BuildOptions::default()
    }
}

/// Writes `v.raw` and `v.json` (u16, 12x10x7) into `dir`.
fn raw_input(dir: &Path) -> (PathBuf, PathBuf) {
    let dims = [12u32, 10, 7];
    let raw = dir.join("v.raw");
    std::fs::write(&raw, test_volume(dims, DType::U16, 3)).unwrap();
    let json = dir.join("v.json");
    std::fs::write(
        &json,
        r#"{"dims": [12, 10, 7], "dtype": "u16", "file": "v.raw", "value_range": [0, 65535]}"#,
    )
    .unwrap();
    (json, raw)
}

/// Snapshot of every regular file in `dir` (name, bytes), sorted.
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.symlink_metadata().unwrap().is_file())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn output_that_is_an_input_is_refused_and_the_input_is_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (json, raw) = raw_input(d);
    // NRRD: detached header + data file, and an attached file.
    let payload = test_volume([12, 10, 7], DType::U8, 5);
    let fields = "type: uchar\ndimension: 3\nsizes: 12 10 7\nencoding: raw\n";
    std::fs::write(d.join("h.data"), &payload).unwrap();
    let nhdr = d.join("h.nhdr");
    std::fs::write(&nhdr, format!("NRRD0004\n{fields}data file: h.data\n")).unwrap();
    let nrrd = d.join("a.nrrd");
    let mut attached = format!("NRRD0004\n{fields}\n").into_bytes();
    attached.extend_from_slice(&payload);
    std::fs::write(&nrrd, attached).unwrap();
    // Other spellings of the same files.
    std::os::unix::fs::symlink(&raw, d.join("link.raw")).unwrap();
    std::os::unix::fs::symlink("v.json", d.join("link.json")).unwrap();
    std::fs::hard_link(&raw, d.join("hard.raw")).unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    let before = snapshot(d);
    let cases: Vec<(PathBuf, PathBuf)> = vec![
        (json.clone(), json.clone()),
        (json.clone(), raw.clone()),
        (json.clone(), d.join(".").join("v.json")),
        (json.clone(), d.join("sub").join("..").join("v.raw")),
        (json.clone(), d.join("link.raw")),
        (json.clone(), d.join("link.json")),
        (json.clone(), d.join("hard.raw")),
        (raw.clone(), raw.clone()),
        (raw.clone(), json.clone()),
        (nhdr.clone(), nhdr.clone()),
        (nhdr.clone(), d.join("h.data")),
        (nrrd.clone(), nrrd.clone()),
    ];
    for (input, output) in &cases {
        let r = build_file(input, output, &small_opts());
        match r {
            Err(brickray_store::StoreError::OutputIsInput {
                output: o,
                input: i,
            }) => {
                assert_eq!(&o, output);
                assert!(i.exists(), "{}", i.display());
            }
            other => panic!(
                "build {} -> {}: expected OutputIsInput, got {other:?}",
                input.display(),
                output.display()
            ),
        }
        assert_eq!(snapshot(d), before, "{} changed", output.display());
        assert!(d.join("link.raw").symlink_metadata().unwrap().is_symlink());
    }
    // The CLI says so and fails.
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let st = Command::new(exe)
        .args(["build", "--quiet"])
        .arg(&json)
        .arg(&json)
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("is an input"), "{err}");
    assert_eq!(snapshot(d), before);
    // Only the inputs and the links are there: no temporaries.
    assert_eq!(
        names(d),
        [
            "a.nrrd",
            "h.data",
            "h.nhdr",
            "hard.raw",
            "link.json",
            "link.raw",
            "sub",
            "v.json",
            "v.raw"
        ]
    );
}

fn mkfifo(path: &Path) {
    let st = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(st.success(), "mkfifo failed");
}

/// Runs `f` on a thread; fails if it has not returned within 20 s (after
/// unblocking a reader stuck opening `fifo`, by opening its other end).
fn within<T: Send + 'static>(fifo: &Path, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(Duration::from_secs(20)) {
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

#[test]
fn non_regular_outputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (json, _) = raw_input(d);
    // A FIFO: not replaced by a regular file, and never opened (which would block).
    let fifo = d.join("out.fifo");
    mkfifo(&fifo);
    let (j, f) = (json.clone(), fifo.clone());
    let r = within(&fifo, move || build_file(&j, &f, &small_opts()));
    assert!(
        matches!(r, Err(brickray_store::StoreError::OutputNotRegularFile { ref path, .. }) if path == &fifo),
        "{r:?}"
    );
    assert!(std::os::unix::fs::FileTypeExt::is_fifo(
        &fifo.symlink_metadata().unwrap().file_type()
    ));
    // A directory.
    let sub = d.join("sub");
    std::fs::create_dir(&sub).unwrap();
    let r = build_file(&json, &sub, &small_opts());
    assert!(
        matches!(r, Err(brickray_store::StoreError::OutputNotRegularFile { ref path, .. }) if path == &sub),
        "{r:?}"
    );
    assert!(sub.is_dir());
    // A character device (a copy of /dev/null made in the temporary folder, so
    // a regression cannot replace the real one); needs root, else skipped.
    let null = d.join("null");
    let made = Command::new("mknod")
        .arg(&null)
        .args(["c", "1", "3"])
        .status()
        .is_ok_and(|s| s.success());
    if made {
        let r = build_file(&json, &null, &small_opts());
        assert!(
            matches!(r, Err(brickray_store::StoreError::OutputNotRegularFile { ref path, .. }) if path == &null),
            "{r:?}"
        );
        assert!(std::os::unix::fs::FileTypeExt::is_char_device(
            &null.symlink_metadata().unwrap().file_type()
        ));
    } else {
        eprintln!("skipping the device-node case: mknod needs root");
    }
    // Nothing left behind.
    let mut n = names(d);
    n.retain(|x| x != "null");
    assert_eq!(n, ["out.fifo", "sub", "v.json", "v.raw"]);
}

#[test]
fn opening_a_fifo_as_a_store_is_refused_fast() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("s.brs");
    mkfifo(&fifo);
    let f = fifo.clone();
    let t = Instant::now();
    let r = within(&fifo, move || brickray_store::open(&f).map(|_| ()));
    assert!(
        matches!(r, Err(brickray_store::StoreError::NotRegularFile { ref path, .. }) if path == &fifo),
        "{r:?}"
    );
    assert!(t.elapsed() < Duration::from_secs(5));
    // The CLI too.
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let mut child = Command::new(exe)
        .arg("info")
        .arg(&fifo)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let status = wait_timeout(&mut child, Duration::from_secs(20));
    let status = match status {
        Some(s) => s,
        None => {
            let _ = std::fs::OpenOptions::new().write(true).open(&fifo);
            let _ = child.kill();
            panic!("brickray-store info blocked on a FIFO");
        }
    };
    assert!(!status.success());
}

fn wait_timeout(
    child: &mut std::process::Child,
    limit: Duration,
) -> Option<std::process::ExitStatus> {
    let t = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return Some(s);
        }
        if t.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A sparse u8 input of zeros, `n`^3 voxels (1024: 1 GiB, slow enough to
/// build that a signal sent as soon as the temporary appears arrives
/// mid-build).
fn big_sparse_input(dir: &Path, n: u64) -> PathBuf {
    let raw = dir.join("big.raw");
    let f = std::fs::File::create(&raw).unwrap();
    f.set_len(n * n * n).unwrap();
    let json = dir.join("big.json");
    std::fs::write(
        &json,
        format!(r#"{{"dims": [{n}, {n}, {n}], "dtype": "u8", "value_range": [0, 255]}}"#),
    )
    .unwrap();
    json
}

#[test]
fn signals_during_a_build_leave_no_temporaries() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let json = big_sparse_input(d, 1024);
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    for sig in ["INT", "TERM", "HUP", "USR1"] {
        let num = match sig {
            "INT" => 2,
            "TERM" => 15,
            "USR1" => 10,
            _ => 1,
        };
        // A signal this process ignores (the suite run under `nohup`) is
        // ignored by the child too, which is the build's documented behaviour
        // (`a_build_started_under_nohup_survives_sighup`), not this test's.
        if brickray_store::ignored_signals() & (1u64 << (num - 1)) != 0 {
            eprintln!("SIG{sig} is ignored in this process: the child would ignore it too");
            continue;
        }
        let out = d.join("big.brs");
        let mut child = Command::new(exe)
            .args(["build", "--quiet"])
            .arg(&json)
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // Wait for the temporary to appear, then signal.
        let t = Instant::now();
        let inputs = ["big.json", "big.raw"];
        loop {
            let extra = names(d).into_iter().any(|n| !inputs.contains(&n.as_str()));
            if extra {
                break;
            }
            assert!(
                child.try_wait().unwrap().is_none(),
                "SIG{sig}: the build ended before writing anything"
            );
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "no temporary appeared"
            );
            std::thread::sleep(Duration::from_millis(2));
        }
        // Let the build get going (temporaries of later stages too).
        std::thread::sleep(Duration::from_millis(100));
        let st = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(child.id().to_string())
            .status()
            .unwrap();
        assert!(st.success());
        let status = wait_timeout(&mut child, Duration::from_secs(30)).unwrap_or_else(|| {
            let _ = child.kill();
            panic!("SIG{sig}: the build did not stop");
        });
        assert!(
            !status.success(),
            "SIG{sig}: the build finished before the signal; make the input larger"
        );
        // It died of the signal, as without a handler.
        assert_eq!(
            std::os::unix::process::ExitStatusExt::signal(&status),
            Some(num),
            "SIG{sig}: {status:?}"
        );
        assert_eq!(names(d), inputs, "SIG{sig} left files behind");
    }
}

/// Over the file size limit (`ulimit -f`) a build used to die of SIGXFSZ
/// with its temporary left behind: now it fails (the write refused, or the
/// signal handled) and leaves nothing.
#[test]
fn a_build_over_the_file_size_limit_leaves_no_temporaries() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 64^3 u8 of noise: about 300 KiB of store, past the 64-block limit.
    let mut x = 12345u32;
    let noise: Vec<u8> = (0..64 * 64 * 64)
        .map(|_| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            (x >> 24) as u8
        })
        .collect();
    std::fs::write(d.join("n.raw"), noise).unwrap();
    std::fs::write(
        d.join("n.json"),
        r#"{"dims": [64, 64, 64], "dtype": "u8", "file": "n.raw", "value_range": [0, 255]}"#,
    )
    .unwrap();
    if brickray_store::ignored_signals() & (1u64 << (25 - 1)) != 0 {
        eprintln!("SIGXFSZ is ignored in this process: the write fails either way");
    }
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = Command::new("sh")
        .arg("-c")
        .arg(r#"ulimit -c 0; ulimit -f 64; exec "$0" build --quiet --brick 16 "$1" "$2""#)
        .arg(exe)
        .arg(d.join("n.json"))
        .arg(d.join("n.brs"))
        .output()
        .unwrap();
    assert!(!out.status.success(), "{out:?}");
    eprintln!(
        "{:?}: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr).trim()
    );
    assert_eq!(names(d), ["n.json", "n.raw"], "files left behind");
}

#[test]
fn stale_temporaries_are_removed_by_the_next_build() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (json, _) = raw_input(d);
    // pid 999999999 cannot exist (pid_max is at most 2^22); pid 1 always does.
    let dead = [
        ".v.brs.brickray-partial.999999999-0",
        ".v.brs.brickray-partial.999999999-7",
        ".w.brs.brickray-partial.999999998-1",
    ];
    let alive = ".v.brs.brickray-partial.1-0";
    let unrelated = ["v.brs.brickray-partial.notapid", ".x.partial", "notes.txt"];
    for n in dead.iter().chain([&alive]).chain(unrelated.iter()) {
        std::fs::write(d.join(n), b"junk").unwrap();
    }
    build_file(&json, &d.join("v.brs"), &small_opts()).unwrap();
    let n = names(d);
    for x in dead {
        assert!(!n.contains(&x.to_string()), "{x} was not removed: {n:?}");
    }
    assert!(n.contains(&alive.to_string()), "{n:?}");
    for x in unrelated {
        assert!(n.contains(&x.to_string()), "{x} was removed");
    }
    assert!(n.contains(&"v.brs".to_string()));
}

#[test]
fn absurd_memory_bound_is_refused_by_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (json, _) = raw_input(d);
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    // 2^44 MiB = 2^64 bytes: used to wrap to a bound of 0 bytes.
    for mib in ["17592186044416", "18446744073709551615", "0"] {
        let st = Command::new(exe)
            .args(["build", "--quiet", "--memory-mib", mib])
            .arg(&json)
            .arg(d.join("o.brs"))
            .output()
            .unwrap();
        assert!(!st.status.success(), "{mib}");
        let err = String::from_utf8_lossy(&st.stderr);
        assert!(err.contains("memory-mib"), "{mib}: {err}");
        assert!(!d.join("o.brs").exists());
    }
}

#[test]
fn degenerate_build_options_are_typed_errors() {
    use brickray_store::{StoreError, build};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.brs");
    let dims = [9u32, 7, 5];
    let mut r = MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 1));
    let bad = |o: BuildOptions, r: &mut MemReader| match build(r, &out, &o) {
        Err(StoreError::BadOption { option, .. }) => option,
        other => panic!("{o:?}: {other:?}"),
    };
    let o = BuildOptions::default;
    assert_eq!(bad(BuildOptions { brick: 0, ..o() }, &mut r), "brick");
    assert_eq!(bad(BuildOptions { brick: 513, ..o() }, &mut r), "brick");
    assert_eq!(
        bad(
            BuildOptions {
                brick: u32::MAX,
                ..o()
            },
            &mut r
        ),
        "brick"
    );
    assert_eq!(bad(BuildOptions { apron: 17, ..o() }, &mut r), "apron");
    assert_eq!(
        bad(
            BuildOptions {
                apron: u32::MAX,
                ..o()
            },
            &mut r
        ),
        "apron"
    );
    assert_eq!(
        bad(
            BuildOptions {
                memory_bound: 0,
                ..o()
            },
            &mut r
        ),
        "memory_bound"
    );
    for t in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        assert_eq!(
            bad(
                BuildOptions {
                    empty_below: Some(t),
                    ..o()
                },
                &mut r
            ),
            "empty_below"
        );
    }
    // A description with NaN spacing (a reader that did not validate it).
    let mut nan = r.clone();
    nan.desc.spacing = [1.0, f32::NAN, 1.0];
    assert_eq!(bad(o(), &mut nan), "input");
    assert!(!out.exists());
    // Not degenerate: the largest bound, a one-voxel brick with an apron
    // wider than the brick, a bound just too small (a typed MemoryBound).
    build(
        &mut r,
        &out,
        &BuildOptions {
            memory_bound: u64::MAX,
            ..o()
        },
    )
    .unwrap();
    let s = brickray_store::open(&out).unwrap();
    assert_eq!(s.layout().brick, 32);
    build(
        &mut r,
        &out,
        &BuildOptions {
            brick: 1,
            apron: 16,
            ..o()
        },
    )
    .unwrap();
    let s = brickray_store::open(&out).unwrap();
    let levels = reference_levels(s.layout(), decode(DType::U8, &r.bytes), Default::default());
    check_source(&s, &levels, None);
    assert!(matches!(
        build(
            &mut r,
            &out,
            &BuildOptions {
                memory_bound: 1,
                ..o()
            }
        ),
        Err(StoreError::MemoryBound { bound: 1, .. })
    ));
    assert_eq!(names(dir.path()), ["o.brs"]);
}

#[test]
fn cli_reads_outside_the_sidecars_folder_only_when_asked() {
    let top = tempfile::tempdir().unwrap();
    let d = top.path().join("in");
    std::fs::create_dir(&d).unwrap();
    std::fs::write(
        top.path().join("data.raw"),
        test_volume([12, 10, 7], DType::U8, 2),
    )
    .unwrap();
    let json = d.join("v.json");
    std::fs::write(
        &json,
        r#"{"dims": [12, 10, 7], "dtype": "u8", "file": "../data.raw"}"#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = top.path().join("v.brs");
    let st = Command::new(exe)
        .args(["build", "--quiet"])
        .arg(&json)
        .arg(&out)
        .output()
        .unwrap();
    assert!(!st.status.success());
    let err = String::from_utf8_lossy(&st.stderr);
    assert!(err.contains("outside the header's folder"), "{err}");
    assert!(err.contains("--allow-outside-dir"), "{err}");
    assert!(!out.exists());
    let st = Command::new(exe)
        .args(["build", "--quiet", "--allow-outside-dir"])
        .arg(&json)
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert_eq!(brickray_store::open(&out).unwrap().desc().dims, [12, 10, 7]);
    // The library's build_file is strict.
    assert!(matches!(
        build_file(&json, &top.path().join("w.brs"), &small_opts()),
        Err(brickray_store::StoreError::Input(
            brickray_io::IoError::OutsideDir { .. }
        ))
    ));
}

#[test]
fn a_build_started_under_nohup_survives_sighup() {
    // SIGHUP ignored at start (as `nohup` does) stays ignored: the build
    // completes; SIGTERM still cleans up (tested above).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let json = big_sparse_input(d, 384);
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = d.join("big.brs");
    let mut child = Command::new("nohup")
        .arg(exe)
        .args(["build", "--quiet", "--brick", "64"])
        .arg(&json)
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while names(d).len() < 3 {
        assert!(child.try_wait().unwrap().is_none(), "the build ended early");
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "no temporary appeared"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    let st = Command::new("kill")
        .arg("-HUP")
        .arg(child.id().to_string())
        .status()
        .unwrap();
    assert!(st.success());
    let status = wait_timeout(&mut child, Duration::from_secs(300)).unwrap_or_else(|| {
        let _ = child.kill();
        panic!("the build did not finish");
    });
    assert!(status.success(), "{status:?}");
    assert!(brickray_store::open(&out).is_ok());
    assert_eq!(names(d), ["big.brs", "big.json", "big.raw"]);
}
