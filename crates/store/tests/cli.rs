//! The `brickray-store` command line: build and info.
#![allow(missing_docs)]

mod common;

use brickray_core::DType;
use common::*;
use std::process::Command;

#[test]
fn build_then_info() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [30u32, 20, 10];
    std::fs::write(dir.path().join("v.raw"), test_volume(dims, DType::U16, 4)).unwrap();
    std::fs::write(
        dir.path().join("v.json"),
        r#"{"dims": [30, 20, 10], "dtype": "u16", "spacing": [1, 1, 2], "byte_order": "little"}"#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = dir.path().join("v.brs");
    let st = Command::new(exe)
        .args([
            "build",
            "--brick",
            "8",
            "--apron=2",
            "--filter",
            "max",
            "--empty-below",
            "3",
            "--quiet",
        ])
        .arg(dir.path().join("v.json"))
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let store = brickray_store::open(&out).unwrap();
    assert_eq!(store.layout().brick, 8);
    // The store gets the mode of any file this process writes (0666 less the
    // umask), not a temporary file's 0600.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let plain = dir.path().join("plain");
        std::fs::write(&plain, b"x").unwrap();
        let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&out), mode(&plain), "store mode {:o}", mode(&out));
    }
    assert_eq!(store.filter(), brickray_store::Filter::Max);
    assert_eq!(store.empty_below(), Some(3.0));
    let info = Command::new(exe)
        .args(["info", "--bins", "4"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        info.status.success(),
        "{}",
        String::from_utf8_lossy(&info.stderr)
    );
    let text = String::from_utf8_lossy(&info.stdout);
    for want in [
        "levels",
        "uniform",
        "compression",
        "histogram   6000 voxels, 4 bins",
    ] {
        assert!(text.contains(want), "info lacks {want:?}:\n{text}");
    }
    // A negative threshold is a value, not an option (`--empty-below -500`).
    let neg = dir.path().join("neg.brs");
    let st = Command::new(exe)
        .args(["build", "--quiet", "--empty-below", "-500"])
        .arg(dir.path().join("v.json"))
        .arg(&neg)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    assert_eq!(
        brickray_store::open(&neg).unwrap().empty_below(),
        Some(-500.0)
    );
    // An input volume (here the raw file) is described as an input.
    let input = Command::new(exe)
        .args(["info"])
        .arg(dir.path().join("v.raw"))
        .output()
        .unwrap();
    assert!(input.status.success());
    assert!(String::from_utf8_lossy(&input.stdout).contains("input "));
    // Errors: a message and a failure status, never a panic.
    std::fs::write(dir.path().join("junk.bin"), [b'x'; 200]).unwrap();
    let bad = Command::new(exe)
        .args(["info"])
        .arg(dir.path().join("junk.bin"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a brickray store"));
    let bad = Command::new(exe)
        .args(["build", "--brick", "x", "a.json", "b"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
}

/// `build --spread` records the spreads (format version 7) and `info` says
/// whether a store has them; `--spread` with `--labels` is refused.
#[test]
fn build_with_spreads_then_info() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("v.raw"),
        test_volume([30, 20, 10], DType::U16, 4),
    )
    .unwrap();
    std::fs::write(
        dir.path().join("v.json"),
        r#"{"dims": [30, 20, 10], "dtype": "u16", "spacing": [1, 1, 2], "byte_order": "little"}"#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let run = |args: &[&str]| Command::new(exe).args(args).output().unwrap();
    let input = dir.path().join("v.json");
    let input = input.to_str().unwrap();
    for (name, spread) in [("s.brs", true), ("p.brs", false)] {
        let out = dir.path().join(name);
        let out = out.to_str().unwrap();
        let mut args = vec!["build", "--brick", "8", "--quiet", input, out];
        if spread {
            args.push("--spread");
        }
        let st = run(&args);
        assert!(
            st.status.success(),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
        let built = String::from_utf8_lossy(&st.stdout);
        assert_eq!(built.contains("spreads     recorded"), spread, "{built}");
        assert_eq!(brickray_store::open(out).unwrap().has_spread(), spread);
        let info = run(&["info", out]);
        assert!(info.status.success());
        let text = String::from_utf8_lossy(&info.stdout);
        let want = if spread {
            "spreads     recorded (format version 7)"
        } else {
            "spreads     not recorded"
        };
        assert!(text.contains(want), "info lacks {want:?}:\n{text}");
    }
    let out = dir.path().join("l.brs");
    let st = run(&[
        "build",
        "--quiet",
        "--labels",
        "--spread",
        input,
        out.to_str().unwrap(),
    ]);
    assert!(!st.status.success());
    assert!(String::from_utf8_lossy(&st.stderr).contains("`spread`"));
}

/// `convert` writes raw + JSON for inputs in other formats (the shared
/// fixtures), voxel for voxel, and `info` lists an input's parts.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn convert_and_info_read_every_format() {
    let Some(root) = shared_formats_dir() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_brickray-store");
    for (input, raw, name) in [
        ("nifti/pycortex_s1_t1.nii.gz", "pycortex_s1_t1_mri", "nifti"),
        ("dicom/cranium_ct", "invesalius_cranium_ct", "dicom"),
        ("ome-zarr/cryoet_tomo_v04.ome.zarr", "cryoet_tomo", "zarr"),
        ("tiff_slices/cryoet_tomo", "cryoet_tomo", "tiff"),
    ] {
        let out = dir.path().join(format!("{name}.json"));
        let st = std::process::Command::new(bin)
            .args(["convert"])
            .arg(root.join(input))
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            st.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&st.stderr)
        );
        let want = std::fs::read(root.join("..").join(raw).join(format!("{raw}.raw"))).unwrap();
        let got = std::fs::read(out.with_extension("raw")).unwrap();
        assert!(
            got == want,
            "{name}: converted samples differ from {raw}.raw"
        );
        let sc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        assert!(sc["original_format"].is_string(), "{name}: {sc}");
    }
    let info = std::process::Command::new(bin)
        .arg("info")
        .arg(root.join("ome-zarr/pycortex_s1_t1_v05.ome.zarr"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success() && text.contains("OME-Zarr"), "{text}");
    assert!(
        text.lines().filter(|l| l.starts_with("level")).count() >= 3,
        "{text}"
    );
}

fn shared_formats_dir() -> Option<std::path::PathBuf> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/formats");
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but the shared data directory {} is missing",
        dir.display()
    );
    eprintln!("skipping: shared data not found at {}", dir.display());
    None
}

/// `info` on an OME-Zarr 0.5 whose shape is forged huge over no stored
/// chunk: [2^31]^3 is refused, 2^16 a side (2^48 voxels of fill) is listed;
/// both at once (the scan used to read the declared voxels: 8 GiB for the
/// first slab).
#[test]
fn info_on_a_forged_huge_zarr_shape_returns_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    for (side, ok) in [(1u64 << 31, false), (1 << 16, true)] {
        let root = dir.path().join(format!("h{side}.ome.zarr"));
        std::fs::create_dir_all(root.join("0")).unwrap();
        std::fs::write(
            root.join("zarr.json"),
            r#"{"zarr_format":3,"node_type":"group","attributes":{"ome":{"version":"0.5","multiscales":[{"axes":[{"name":"z","type":"space"},{"name":"y","type":"space"},{"name":"x","type":"space"}],"datasets":[{"path":"0","coordinateTransformations":[{"type":"scale","scale":[1,1,1]}]}]}]}}}"#,
        )
        .unwrap();
        std::fs::write(
            root.join("0/zarr.json"),
            format!(
                r#"{{"zarr_format":3,"node_type":"array","shape":[{side},{side},{side}],"data_type":"uint16","chunk_grid":{{"name":"regular","configuration":{{"chunk_shape":[4,4,4]}}}},"chunk_key_encoding":{{"name":"default","configuration":{{"separator":"/"}}}},"fill_value":7,"codecs":[{{"name":"bytes","configuration":{{"endian":"little"}}}}]}}"#
            ),
        )
        .unwrap();
        let t = std::time::Instant::now();
        let mut child = Command::new(exe)
            .arg("info")
            .arg(&root)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if t.elapsed().as_secs() >= 20 {
                let _ = child.kill();
                panic!("info on a shape of {side}^3 still running after 20 s");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        let took = t.elapsed();
        let out = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(status.success(), ok, "{side}: {text}");
        if ok {
            assert!(text.contains("65536x65536x65536"), "{text}");
            assert!(text.contains("value range [7.0, 8.0]"), "{text}");
        }
        assert!(took.as_secs_f64() < 5.0, "{side}^3: info took {took:?}");
    }
}

/// Puts `bytes` at `url` on the Range HTTP test server (it stores PUTs).
#[cfg(feature = "remote")]
fn http_put(url: &str, bytes: &[u8]) {
    use std::io::{Read, Write};
    let rest = url.strip_prefix("http://").unwrap();
    let (host, path) = rest.split_once('/').unwrap();
    let mut s = std::net::TcpStream::connect(host).unwrap();
    write!(
        s,
        "PUT /{path} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        bytes.len()
    )
    .unwrap();
    s.write_all(bytes).unwrap();
    let mut resp = String::new();
    let _ = s.read_to_string(&mut resp);
    assert!(resp.starts_with("HTTP/1.1 201"), "PUT {url}: {resp}");
}

/// `info URL` describes a store over HTTP exactly as `info` on the file.
#[cfg(feature = "remote")]
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)"]
fn info_on_a_url_matches_info_on_the_file() {
    let http = match std::env::var("BRICKRAY_TEST_HTTP") {
        Ok(v) if !v.is_empty() => v,
        _ if std::env::var("CI").is_ok_and(|v| v == "true") => {
            panic!("CI=true but BRICKRAY_TEST_HTTP is unset (scripts/test.sh starts the server)")
        }
        _ => return eprintln!("skipping: BRICKRAY_TEST_HTTP is unset"),
    };
    let dir = tempfile::tempdir().unwrap();
    let dims = [19u32, 23, 11];
    let mut r = MemReader::new(dims, DType::U16, test_volume(dims, DType::U16, 9));
    let out = dir.path().join("v.brs");
    let o = brickray_store::BuildOptions {
        brick: 8,
        apron: 1,
        ..Default::default()
    };
    brickray_store::build(&mut r, &out, &o).unwrap();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    let url = format!(
        "{}/cli-{}-{nanos}/v.brs",
        http.trim_end_matches('/'),
        std::process::id()
    );
    http_put(&url, &std::fs::read(&out).unwrap());
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let run = |target: &str, extra: &[&str]| {
        Command::new(exe)
            .args(["info", "--bins", "5"])
            .args(extra)
            .arg(target)
            .output()
            .unwrap()
    };
    let local = run(out.to_str().unwrap(), &[]);
    let remote = run(&url, &["--allow-http"]);
    assert!(
        remote.status.success(),
        "{}",
        String::from_utf8_lossy(&remote.stderr)
    );
    let body = |o: &std::process::Output| {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| !l.starts_with("store "))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert!(String::from_utf8_lossy(&remote.stdout).contains(&url));
    assert_eq!(body(&local), body(&remote));
    assert!(body(&remote).contains("histogram"));
    // A missing object: a message naming the URL, a failure status.
    let missing = url.replace("v.brs", "absent.brs");
    let e = run(&missing, &["--allow-http"]);
    assert!(!e.status.success());
    let err = String::from_utf8_lossy(&e.stderr);
    assert!(err.contains(&missing) && err.contains("not found"), "{err}");
}

/// `info URL` of an OME-Zarr image on the HTTP server lists the levels
/// `info` lists for the local folder, and says it streams the image; `build
/// URL` writes the same store as `build` of the folder.
#[cfg(feature = "remote")]
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)"]
fn info_on_an_ome_zarr_url_lists_the_local_levels() {
    let http = match std::env::var("BRICKRAY_TEST_HTTP") {
        Ok(v) if !v.is_empty() => v,
        _ if std::env::var("CI").is_ok_and(|v| v == "true") => {
            panic!("CI=true but BRICKRAY_TEST_HTTP is unset (scripts/test.sh starts the server)")
        }
        _ => return eprintln!("skipping: BRICKRAY_TEST_HTTP is unset"),
    };
    let image = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/formats/ome-zarr/cells3d_nuclei_sharded_v05.ome.zarr");
    if !image.is_dir() {
        assert!(
            !std::env::var("CI").is_ok_and(|v| v == "true"),
            "CI=true but {} is missing",
            image.display()
        );
        return eprintln!("skipping: no shared data");
    }
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    let url = format!(
        "{}/cli-zarr-{}-{nanos}/cells.ome.zarr",
        http.trim_end_matches('/'),
        std::process::id()
    );
    fn files(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                files(&p, out);
            } else {
                out.push(p);
            }
        }
    }
    let mut all = Vec::new();
    files(&image, &mut all);
    for f in &all {
        let rel = f
            .strip_prefix(&image)
            .unwrap()
            .to_string_lossy()
            .into_owned();
        http_put(&format!("{url}/{rel}"), &std::fs::read(f).unwrap());
    }
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let run = |target: &str, extra: &[&str]| {
        Command::new(exe)
            .arg("info")
            .args(extra)
            .arg(target)
            .output()
            .unwrap()
    };
    let local = run(image.to_str().unwrap(), &[]);
    let remote = run(&url, &["--allow-http"]);
    let text = String::from_utf8_lossy(&remote.stdout);
    assert!(
        remote.status.success(),
        "{}",
        String::from_utf8_lossy(&remote.stderr)
    );
    assert!(
        text.contains(&url) && text.contains("OME-Zarr 0.5"),
        "{text}"
    );
    let levels: Vec<String> = String::from_utf8_lossy(&local.stdout)
        .lines()
        .filter(|l| l.starts_with("level ") || l.starts_with("volume "))
        .map(|l| l.split(", value range").next().unwrap().to_owned())
        .collect();
    assert!(levels.len() >= 3, "{levels:?}");
    for l in &levels {
        assert!(text.contains(l.as_str()), "{l:?} not in {text}");
    }
    // Without --allow-http (nor its variables): refused before any request.
    let e = Command::new(exe)
        .arg("info")
        .arg(&url)
        .env_remove("AWS_ALLOW_HTTP")
        .env_remove("BRICKRAY_ALLOW_HTTP")
        .output()
        .unwrap();
    assert!(!e.status.success());
    assert!(String::from_utf8_lossy(&e.stderr).contains("--allow-http"));
    // `build URL` writes the store `build` writes from the local folder.
    let dir = tempfile::tempdir().unwrap();
    let build = |input: &str, out: &std::path::Path, extra: &[&str]| {
        Command::new(exe)
            .args(["build", "--quiet", "--brick", "16"])
            .args(extra)
            .arg(input)
            .arg(out)
            .output()
            .unwrap()
    };
    let (a, b) = (dir.path().join("local.brs"), dir.path().join("remote.brs"));
    let l = build(image.to_str().unwrap(), &a, &[]);
    assert!(l.status.success(), "{}", String::from_utf8_lossy(&l.stderr));
    let r = build(&url, &b, &["--allow-http"]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let (a, b) = (
        brickray_store::open(&a).unwrap(),
        brickray_store::open(&b).unwrap(),
    );
    assert_eq!(a.desc(), b.desc());
    let mut nodes = 0;
    for rec in a.nodes() {
        assert_eq!(
            a.read_compressed(rec.key).unwrap(),
            b.read_compressed(rec.key).unwrap(),
            "{:?}",
            rec.key
        );
        nodes += 1;
    }
    assert_eq!(nodes, b.nodes().count());
    // A store URL is not an input.
    let e = build(
        &url.replace("cells.ome.zarr", "v.brs"),
        &dir.path().join("x.brs"),
        &["--allow-http"],
    );
    assert!(!e.status.success());
}

/// A plain-HTTP URL is refused unless allowed, before any request.
#[cfg(feature = "remote")]
#[test]
fn info_refuses_plain_http_unless_allowed() {
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = Command::new(exe)
        .args(["info", "http://127.0.0.1:9/x.brs"])
        .env_remove("AWS_ALLOW_HTTP")
        .env_remove("BRICKRAY_ALLOW_HTTP")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--allow-http"), "{err}");
    let out = Command::new(exe)
        .args(["info", "ftp://host/x.brs"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unsupported scheme"));
}

/// `--labels` builds a label store (`info` says so), and `info` whose
/// reader closes early (`| head`) ends quietly with SIGPIPE's status, not a
/// panic.
#[test]
fn labels_build_and_info_into_a_closed_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [20u32, 12, 9];
    let ids: Vec<f32> = (0..dims.iter().product::<u32>())
        .map(|i| (i / 37 % 5) as f32)
        .collect();
    std::fs::write(dir.path().join("l.raw"), encode(DType::U8, &ids)).unwrap();
    std::fs::write(
        dir.path().join("l.json"),
        r#"{"dims": [20, 12, 9], "dtype": "u8"}"#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let out = dir.path().join("l.brs");
    let st = Command::new(exe)
        .args(["build", "--labels", "--brick", "8", "--quiet"])
        .arg(dir.path().join("l.json"))
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let info = Command::new(exe).arg("info").arg(&out).output().unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("u8 labels"), "{text}");
    assert!(text.contains("filter Mode"), "{text}");
    // The reader closes before the tool writes.
    let mut child = Command::new(exe)
        .arg("info")
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let done = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&done.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(done.status.code(), Some(141), "{err}");
}

/// `build` into `NAME.channels.json` builds one store per channel (those
/// `--channels` lists) and the set; `info` on the set describes each.
#[test]
fn a_channel_set_builds_and_describes_its_channels() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [24u32, 20, 8];
    let mut bytes = Vec::new();
    for c in 0..3u8 {
        let mut v = test_volume(dims, DType::U8, 5 + c as u64);
        for b in &mut v {
            *b = b.wrapping_add(40 * c);
        }
        bytes.extend(v);
    }
    std::fs::write(dir.path().join("c.raw"), bytes).unwrap();
    std::fs::write(
        dir.path().join("c.json"),
        r#"{"dims": [24, 20, 8], "dtype": "u8", "spacing": [1, 1, 1], "channels": 3}"#,
    )
    .unwrap();
    let exe = env!("CARGO_BIN_EXE_brickray-store");
    let set = dir.path().join("cells.channels.json");
    let st = Command::new(exe)
        .args(["build", "--brick", "8", "--quiet", "--channels", "0,2"])
        .arg(dir.path().join("c.json"))
        .arg(&set)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let out = String::from_utf8_lossy(&st.stdout);
    assert!(out.contains("2 channels"), "{out}");
    assert!(dir.path().join("cells.c0.brs").exists());
    assert!(dir.path().join("cells.c2.brs").exists());
    assert!(!dir.path().join("cells.c1.brs").exists());
    let opened = brickray_store::open_channels(&set).unwrap();
    assert_eq!(opened.source.len(), 2);
    let info = Command::new(exe).arg("info").arg(&set).output().unwrap();
    assert!(
        info.status.success(),
        "{}",
        String::from_utf8_lossy(&info.stderr)
    );
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        text.contains("2 channels") && text.contains("channel 1"),
        "{text}"
    );
    assert!(
        text.contains("cells.c0.brs") && text.contains("cells.c2.brs"),
        "{text}"
    );
}
