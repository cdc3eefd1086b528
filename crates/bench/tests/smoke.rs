//! Smoke runs of benchmark suites: a suite at its smallest settings must
//! exit successfully and end with one JSON object holding its documented
//! keys (docs/benchmarks.md). They check that a suite still runs and still
//! says what it measures, never how fast: the figures of a smoke run are
//! not results. Suites join this file as they gain small settings.
#![allow(missing_docs)]

use std::process::Command;

/// Runs the bench with `args`; returns the JSON object of its last line.
fn run(args: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_brickray-bench"))
        .args(args)
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{args:?}: {:?}\n{stdout}\n{stderr}",
        out.status
    );
    let last = stdout.lines().last().unwrap_or_default();
    match serde_json::from_str(last) {
        Ok(serde_json::Value::Object(m)) => m,
        other => panic!("{args:?}: the last line is not a JSON object: {last:?} ({other:?})"),
    }
}

/// The `channels` suite at 32 px and one round: its keys, a cost ratio for
/// 2 and 4 channels, and its error against the reference (the error does not
/// depend on the timed size: >= 45 dB, as the GPU tests ask).
#[test]
fn the_channels_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let fig = run(&["channels", "--size", "32", "--rounds", "1"]);
    for key in [
        "bytes_per_voxel",
        "modes",
        "cost_ratio_2ch",
        "cost_ratio_4ch",
        "one_channel_overhead",
        "psnr_min_db",
    ] {
        assert!(fig.contains_key(key), "no {key} in {fig:?}");
    }
    let f = |k: &str| fig[k].as_f64().unwrap_or(f64::NAN);
    assert!(
        f("cost_ratio_2ch") > 0.0 && f("cost_ratio_4ch") > 0.0,
        "{fig:?}"
    );
    assert!(f("psnr_min_db") >= 45.0, "{fig:?}");
    assert_eq!(fig["bytes_per_voxel"], serde_json::json!([2, 4, 8]));
    assert_eq!(fig["modes"].as_array().map(Vec::len), Some(4));
}
