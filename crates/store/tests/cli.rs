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
    // Errors: a message and a failure status, never a panic.
    let bad = Command::new(exe)
        .args(["info"])
        .arg(dir.path().join("v.raw"))
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
