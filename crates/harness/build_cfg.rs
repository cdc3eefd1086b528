// Included by the build scripts of the crates whose tests need the shared
// data or a display. Sets `cfg(no_shared_data)` when `../shared/data` (the shared real volumes
// next to the workspace) is absent, and `cfg(no_display)` when neither
// `DISPLAY` nor `WAYLAND_DISPLAY` is set, so that the tests that need them are
// reported as ignored, with the reason, instead of passing without running.
// With `CI=true` neither is set: there the tests run, and fail without the
// data (`brickray_harness::shared_data_dir`) or a display.
//
// Cargo re-runs this when `CI` changes or the shared folder changes; a clone
// that gains the folder later re-checks after `touch build.rs` (watching a
// path that does not exist would rebuild the tests on every run).

/// Emits the cfgs (see the file docs).
fn shared_cfg() {
    println!("cargo::rustc-check-cfg=cfg(no_shared_data)");
    println!("cargo::rustc-check-cfg=cfg(no_display)");
    println!("cargo::rerun-if-env-changed=CI");
    println!("cargo::rerun-if-env-changed=DISPLAY");
    println!("cargo::rerun-if-env-changed=WAYLAND_DISPLAY");
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
    let display = ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|d| !d.is_empty()));
    if !display && !ci {
        println!("cargo::rustc-cfg=no_display");
    }
}
