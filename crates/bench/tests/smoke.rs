//! Smoke runs of benchmark suites: a suite at its smallest settings must
//! exit successfully and end with one JSON object holding its documented
//! keys (docs/benchmarks.md). They check that a suite still runs and still
//! says what it measures, never how fast: the figures of a smoke run are
//! not results. The suites whose smallest settings run in seconds are
//! here; all but soak read ../shared/data (reported as ignored in a
//! user's clone without it, never skipped with `CI=true`).
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
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
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

/// Runs a suite with `args` and checks that its JSON object has `keys`
/// (documented in docs/benchmarks.md; a value may be null where a smoke
/// run measures nothing) and some finite numbers.
fn smoke(args: &[&str], keys: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let fig = run(args);
    for key in keys {
        assert!(fig.contains_key(*key), "{args:?}: no {key} in {fig:?}");
    }
    let numbers = fig
        .values()
        .filter(|v| v.as_f64().is_some_and(f64::is_finite))
        .count();
    assert!(
        numbers >= 3,
        "{args:?}: {numbers} finite numbers in {fig:?}"
    );
    fig
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_accel_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let fig = smoke(
        &["accel", "--size", "32", "--rounds", "1"],
        &[
            "psnr_min_db",
            "speedup_ert_ess_opaque",
            "samples_per_ray_brute_opaque",
        ],
    );
    // Skipping and early termination change the image within tolerance.
    assert!(fig["psnr_min_db"].as_f64().unwrap() >= 40.0, "{fig:?}");
}

#[test]
fn the_soak_suite_runs() {
    let fig = smoke(
        &["soak", "--frames", "3", "--size", "32"],
        &["frames", "rss_growth_pct", "panics", "errors"],
    );
    assert_eq!(fig["frames"], serde_json::json!(3));
    assert_eq!(fig["panics"], serde_json::json!(0));
    assert_eq!(fig["errors"], serde_json::json!(0));
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_preint_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    smoke(
        &["preint", "--size", "32", "--rounds", "1"],
        &[
            "worst_ratio",
            "ms_corrected_table",
            "ms_preint_table_8_layers",
        ],
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_u8_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    smoke(
        &["u8", "--size", "32", "--rounds", "1"],
        &[
            "exact_over_fast_worst",
            "psnr_exact_dvr_db",
            "psnr_fast_dvr_db",
        ],
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_raw_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    smoke(
        &["raw", "--size", "32", "--rounds", "1"],
        &["accel_rate_per_sample_dvr", "buffer_tf_rate_ratio_dvr"],
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_ooc_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    smoke(
        &["ooc", "--size", "32", "--rounds", "1"],
        &[
            "finest_vs_incore_time_ratio",
            "frames_to_converge_after_jump",
        ],
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_labels_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let fig = smoke(
        &["labels", "--size", "32", "--rounds", "1"],
        &[
            "psnr_finest_db_min",
            "psnr_2px_db_min",
            "overlay_cost_ratio",
            "smooth_cost_ratio",
        ],
    );
    assert!(
        fig["psnr_finest_db_min"].as_f64().unwrap() >= 45.0,
        "{fig:?}"
    );
}
