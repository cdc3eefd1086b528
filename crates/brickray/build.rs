//! Sets `cfg(no_shared_data)` when `../shared/data` (the shared real volumes
//! next to the workspace) is absent, so that the tests that need it are
//! reported as ignored, with the reason, instead of passing without running.
//! With `CI=true` it is never set: there the tests run, and fail without the
//! data (`brickray_harness::shared_data_dir`).
//!
//! Cargo re-runs this when `CI` changes or the shared folder changes; a clone
//! that gains the folder later re-checks after `touch build.rs` (watching a
//! path that does not exist would rebuild the tests on every run).

fn main() {
    println!("cargo::rustc-check-cfg=cfg(no_shared_data)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-changed=build.rs");
    let manifest = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    let shared = std::path::Path::new(&manifest).join("../../../shared");
    if shared.is_dir() {
        println!("cargo::rerun-if-changed={}", shared.display());
    }
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    if !shared.join("data").is_dir() && !ci {
        println!("cargo::rustc-cfg=no_shared_data");
    }
}
