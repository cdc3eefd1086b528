//! Shared by the fuzz targets: one scratch folder per process.

use std::path::PathBuf;
use std::sync::OnceLock;

/// A folder of this process under the system's temporary folder, created once
/// (libFuzzer runs the target millions of times: no per-run temporary folder).
pub fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("brickray-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch folder");
        d
    })
}

/// Checks what a successful read promises.
#[allow(dead_code)] // not used by every target
pub fn check_volume(v: &brickray_core::Volume) {
    let d = v.desc();
    assert!(d.byte_len() <= 1 << 22, "{d:?}");
    assert!(d.spacing.iter().all(|s| s.is_finite() && *s > 0.0), "{d:?}");
    assert!(d.value_range.iter().all(|x| x.is_finite()), "{d:?}");
    assert!(d.value_range[0] < d.value_range[1], "{d:?}");
}
