//! Smoke runs of benchmark suites: a suite at its smallest settings must
//! exit successfully and end with one JSON object holding its documented
//! keys (docs/benchmarks.md). They check that a suite still runs and still
//! says what it measures, never how fast: the figures of a smoke run are
//! not results. Every suite has one here (lod one per `--by`, stability
//! two halves of its cases); those that read ../shared/data are reported
//! as ignored in a user's clone without it (never skipped with `CI=true`),
//! except where the suite falls back to procedural volumes (prediction,
//! visibility). The remote suite starts its own loopback HTTP servers (and
//! an S3 one where moto is installed).
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

/// A fresh temporary directory for a suite's charts and files.
fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// The path of `name` in `dir`, as an argument.
fn at(dir: &tempfile::TempDir, name: &str) -> String {
    dir.path().join(name).to_string_lossy().into_owned()
}

/// The `build` suite at `--smoke` (generated inputs 16x smaller per side,
/// the large one under a 1 MiB bound: built in bands). The shared volumes
/// are built where present.
#[test]
fn the_build_suite_runs() {
    let fig = smoke(
        &["build", "--smoke"],
        &[
            "build_mvoxel_per_s_u8_1024",
            "peak_rss_mb",
            "ratio_u8_1024",
            "build_mvoxel_per_s_u8_1024_noise",
            "build_mvoxel_per_s_u16_1024x1024x540",
            "ratio_u16_1024x1024x540",
            "decode_gb_per_s",
            "read_latency_us_mean",
            "read_latency_us_p99",
            "build_mvoxel_per_s_u8_4gib",
            "build_mvoxel_per_s_u8_4gib_bound128",
            "peak_rss_mb_4gib_bound128",
            "memory_bound_mb",
        ],
    );
    // The phantoms are half air: their stores are smaller than their input.
    assert!(fig["ratio_u8_1024"].as_f64().unwrap() > 1.0, "{fig:?}");
    assert!(
        fig["ratio_u16_1024x1024x540"].as_f64().unwrap() > 1.0,
        "{fig:?}"
    );
    assert_eq!(fig["memory_bound_mb"], serde_json::json!(1024));
}

/// The `formats` suite, one round: a store from each of the ten inputs.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_formats_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let fig = smoke(&["formats", "--rounds", "1"], &["memory_bound_mb"]);
    for prefix in ["mvoxel_per_s_", "peak_rss_mb_"] {
        let rows: Vec<f64> = fig
            .iter()
            .filter(|(k, _)| k.starts_with(prefix))
            .map(|(_, v)| v.as_f64().unwrap_or(f64::NAN))
            .collect();
        assert_eq!(rows.len(), 10, "{prefix}: {fig:?}");
        assert!(rows.iter().all(|&x| x > 0.0), "{prefix}: {fig:?}");
    }
    assert_eq!(fig["memory_bound_mb"], serde_json::json!(8));
}

/// The `host` suite: a cut of 1000 bricks at 32 px, three path frames,
/// planned inline and in the background, and drawn under ray-guided
/// visibility (`--culling`).
#[test]
fn the_host_suite_runs() {
    let mut keys = Vec::new();
    for suffix in ["1k", "1k_inline", "1k_culled", "1k_culled_inline"] {
        for figure in [
            "host_ms_median",
            "host_ms_p99",
            "plan_ms_median",
            "upload_ms_median",
            "encode_ms_median",
            "working_set",
            "converge_frames",
        ] {
            keys.push(format!("{figure}_{suffix}"));
        }
    }
    let keys: Vec<&str> = keys.iter().map(String::as_str).collect();
    let fig = smoke(
        &[
            "host",
            "--size",
            "32",
            "--frames",
            "3",
            "--cuts",
            "1000",
            "--culling",
            "--culling-size",
            "32",
        ],
        &keys,
    );
    assert_eq!(fig["frames"], serde_json::json!(3));
    assert!(fig["working_set_1k"].as_u64().unwrap() > 0, "{fig:?}");
}

/// The `pareto` suite on the procedural Marschner-Lobb volume (32^3, bricks
/// of 16) at 32 px, one round, the step and pre-integration knobs; a
/// one-ray-per-pixel reference.
#[test]
fn the_pareto_suite_runs() {
    let dir = tmp();
    let out = at(&dir, "out");
    let fig = smoke(
        &[
            "pareto",
            "--size",
            "32",
            "--rounds",
            "1",
            "--scenes",
            "ml",
            "--ml-side",
            "32",
            "--brick",
            "16",
            "--supersample",
            "1",
            "--knobs",
            "step,preint",
            "--out",
            &out,
            "--charts",
            &out,
        ],
        &[
            "suite",
            "size",
            "rounds",
            "brick",
            "default_on_front_all",
            "default_on_out_of_core_front_all",
            "error_aware_gain_db_at_equal_bricks",
            "visible_error_gain_db_at_equal_brick_budget",
            "octant_gain_db_at_equal_brick_budget",
            "preintegration_gain_db_at_step_2",
            "anisotropic_ct_bricks_at_1px",
            "scenes",
        ],
    );
    assert_eq!(fig["suite"], serde_json::json!("pareto"));
    for scene in ["ml_dvr", "ml_iso"] {
        let s = &fig["scenes"][scene];
        for key in ["default_ms", "default_psnr_db", "default_bricks", "front"] {
            assert!(s.get(key).is_some(), "{scene}: no {key} in {fig:?}");
        }
        // The default step against the f64 reference at 1/8 voxel (35 and
        // 27 dB when written).
        assert!(s["default_psnr_db"].as_f64().unwrap() >= 20.0, "{fig:?}");
    }
    // A pre-integrated step of 2 voxels is closer to the reference than a
    // plain one (5.9 dB when written).
    assert!(
        fig["preintegration_gain_db_at_step_2"].as_f64().unwrap() > 0.0,
        "{fig:?}"
    );
    assert!(dir.path().join("out/pareto.csv").is_file());
    assert!(dir.path().join("out/ml_dvr.svg").is_file());
}

/// The `stability` suite's cases with `cases` at 32 px (volumes of 32^3;
/// the LOD paths' 128^3), charts into a temporary directory.
fn stability(cases: &str, keys: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let dir = tmp();
    let charts = at(&dir, "charts");
    let mut all = vec![
        "holes_max",
        "cases_with_bound",
        "cases_total",
        "image_size",
        "adapter",
    ];
    all.extend_from_slice(keys);
    let fig = run(&[
        "stability",
        "--size",
        "32",
        "--cases",
        cases,
        "--charts",
        &charts,
    ]);
    for key in all {
        assert!(fig.contains_key(key), "{cases}: no {key} in {fig:?}");
    }
    // No frame of any case drew a leaf without its brick.
    assert_eq!(fig["holes_max"], serde_json::json!(0), "{fig:?}");
    fig
}

/// Stability cases 1-5 (streaming, memory pressure, a high-frequency TF,
/// thin structures, grazing rays). Their bounds are not asserted: the
/// streaming case's is a frame-time ratio.
#[test]
fn the_stability_suite_runs_cases_1_to_5() {
    let fig = stability(
        "1,2,3,4,5",
        &["streaming", "pressure", "hf_tf", "thin", "grazing"],
    );
    assert_eq!(fig["cases_total"], serde_json::json!(5));
}

/// Stability cases 6-9 (precision at 65536^3, early ray termination, the
/// prediction buffer and disocclusion, level-of-detail transitions). Early
/// termination keeps its bound (an error no larger than the opacity left),
/// whatever the machine.
#[test]
fn the_stability_suite_runs_cases_6_to_9() {
    let fig = stability(
        "6,7,8,9",
        &[
            "precision",
            "ert",
            "temporal",
            "fly-through",
            "zoom-in",
            "temporal_excess_db_fades",
            "temporal_excess_db_no_fades",
            "pops_fades",
            "pops_no_fades",
        ],
    );
    assert_eq!(fig["cases_total"], serde_json::json!(5));
    assert_eq!(fig["ert"]["kept"], serde_json::json!(true), "{fig:?}");
}

/// The `prediction` suite in core at 32 px, orbits of two frames, without
/// the brute-force baseline: the head CT and the MRI where present, the
/// procedural shells and occluder always. The guarded variant draws what
/// the full traversal draws, on every frame of every path.
#[test]
fn the_prediction_suite_runs() {
    let dir = tmp();
    let (chart, png) = (at(&dir, "failure.svg"), at(&dir, "classes.png"));
    let fig = smoke(
        &[
            "prediction",
            "--size",
            "32",
            "--frames",
            "2",
            "--brute",
            "0",
            "--chart",
            &chart,
            "--classes-png",
            &png,
        ],
        &[
            "size",
            "backend",
            "kappa",
            "frames",
            "speedup_paper",
            "speedup_paper_vs_brute",
            "wrong_pixels_mean_paper_orbit",
            "speedup_best_exact",
            "best_exact",
            "wrong_pixels_max_paper",
            "wrong_pixels_max_guarded",
            "recovery_frames_paper",
            "orbit",
            "failure",
            "translate_zoom",
        ],
    );
    assert_eq!(fig["backend"], serde_json::json!("incore"));
    assert_eq!(fig["wrong_pixels_max_guarded"], serde_json::json!(0.0));
    let orbits = fig["orbit"].as_object().unwrap();
    assert!(orbits.contains_key("nested_shells_default"), "{fig:?}");
    for (path, o) in orbits {
        assert_eq!(
            o["guard"]["wrong_max_pct"],
            serde_json::json!(0.0),
            "{path}: {fig:?}"
        );
    }
    assert!(dir.path().join("failure.svg").is_file());
    assert!(dir.path().join("classes.png").is_file());
}

/// The `aniso` suite on the central 64 x 64 voxels of the 4.5 mm head CT's
/// slices, 16 px, budgets of 8 bricks (the finest cut) and 4. The finest
/// cut's image is the finest data's, in both layouts and orders.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_aniso_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let dir = tmp();
    let chart = at(&dir, "aniso.svg");
    let fig = smoke(
        &[
            "aniso",
            "--size",
            "16",
            "--crop",
            "64",
            "--budgets",
            "8,4",
            "--chart",
            &chart,
        ],
        &[
            "anisotropic_ct_bricks_at_1px",
            "before_bricks_at_1px",
            "after_psnr_at_2px",
            "before_geometric_worst_budget_step_share",
            "after_error-aware_worst_budget_step_share",
        ],
    );
    for octree in ["before", "after"] {
        for order in ["geometric", "error-aware"] {
            let key = format!("{octree}_{order}_rmse_at_budget_8");
            assert_eq!(
                fig.get(&key),
                Some(&serde_json::json!(0.0)),
                "{key}: {fig:?}"
            );
            let key = format!("{octree}_{order}_rmse_at_budget_4");
            assert!(fig.contains_key(&key), "no {key} in {fig:?}");
        }
    }
    assert!(dir.path().join("aniso.svg").is_file());
}

/// The `lod` suite by knob (the GPU sweeps) on the procedural
/// Marschner-Lobb volume, 32^3 in bricks of 8, at 32 px. The finest cut
/// (tolerance 0) against the CPU reference: 36.8 dB when written.
#[test]
fn the_lod_suite_runs_by_knob() {
    let fig = smoke(
        &[
            "lod",
            "--size",
            "32",
            "--scenes",
            "ml",
            "--brick",
            "8",
            "--ml-side",
            "32",
        ],
        &[
            "median_gain_db",
            "ml_median_gain_db",
            "ml_bound_median_gain_db",
            "ml_points",
            "ml_matched_points",
            "image_size",
            "brick",
            "adapter",
        ],
    );
    let points = fig["ml_points"].as_array().unwrap();
    let finest = points
        .iter()
        .find(|p| p["metric"] == "geometric" && p["knob"] == 0.0)
        .unwrap();
    assert!(finest["psnr_db"].as_f64().unwrap() >= 30.0, "{finest:?}");
}

/// The `lod` suite by brick budget (GPU-free), as by knob.
#[test]
fn the_lod_suite_runs_by_budget() {
    let fig = run(&[
        "lod",
        "--by",
        "budget",
        "--size",
        "32",
        "--scenes",
        "ml",
        "--brick",
        "8",
        "--ml-side",
        "32",
    ]);
    for key in [
        "error_aware_gain_db_at_equal_budget",
        "visible_error_aware_gain_db_at_equal_budget",
        "ml_budget_median_gain_db",
        "ml_budget_visible_median_gain_db",
        "ml_budget_points",
    ] {
        assert!(fig.contains_key(key), "no {key} in {fig:?}");
    }
    // The whole budget is the finest cut: its image is the finest data's
    // (PSNR capped at 99).
    let first = &fig["ml_budget_points"][0];
    for order in ["geometric", "error_aware", "visible"] {
        assert_eq!(first[format!("{order}_psnr_db")], 99.0, "{first:?}");
    }
}

/// The `lod` suite by the oracle (GPU-free): every node costed, as by knob.
#[test]
fn the_lod_suite_runs_by_oracle() {
    let fig = run(&[
        "lod",
        "--by",
        "oracle",
        "--size",
        "32",
        "--scenes",
        "ml",
        "--brick",
        "8",
        "--ml-side",
        "32",
    ]);
    for key in [
        "visible_gain_db_at_equal_budget",
        "oracle_gain_db_at_equal_budget",
        "ml_dvr_oracle_gain_db",
        "ml_iso_visible_gain_db",
        "ml_dvr_points",
    ] {
        assert!(fig.contains_key(key), "no {key} in {fig:?}");
    }
}

/// The `visibility` suite: the procedural shells (4096^3) at 128 px, and
/// the head CT's scenes at 32 px where ../shared/data is present; holds of
/// at most 60 frames, a half turn in 2. Culling never changes the
/// converged image (74 dB or identical when written).
#[test]
fn the_visibility_suite_runs() {
    let dir = tmp();
    let svg = at(&dir, "visibility.svg");
    let scenes = if cfg!(no_shared_data) {
        "shells"
    } else {
        "head,shells"
    };
    let fig = smoke(
        &[
            "visibility",
            "--scenes",
            scenes,
            "--size",
            "32",
            "--shell-size",
            "128",
            "--hold",
            "60",
            "--turn",
            "2",
            "--gpu-mib",
            "128",
            "--cpu-mib",
            "128",
            "--svg",
            &svg,
        ],
        &[
            "cut_shells_rayguided",
            "oracle_ratio_shells_rayguided",
            "oracle_cut_ratio_shells_rayguided",
            "oracle_shells",
            "oracle_cut_shells",
            "baseline_converged_shells",
            "oracle_ratio_best",
            "oracle_cut_ratio_best",
            "psnr_min_culled_db",
            "disocclusion_frames_max",
            "image_size",
            "adapter",
        ],
    );
    assert!(
        fig["psnr_min_culled_db"].as_f64().unwrap() >= 50.0,
        "{fig:?}"
    );
    if scenes.contains("head") {
        assert!(fig.contains_key("cut_head_opaque_rayguided"), "{fig:?}");
    }
    assert!(dir.path().join("visibility.svg").is_file());
}

/// The `remote` suite at 32 px, no added delay, one round, two loader
/// threads: the shared MRI's store and OME-Zarr image over loopback HTTP
/// servers the suite starts (python3), and S3 where moto is installed.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn the_remote_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let fig = smoke(
        &[
            "remote",
            "--size",
            "32",
            "--delays",
            "0",
            "--rounds",
            "1",
            "--threads",
            "2",
        ],
        &[
            "first_image_s_0ms",
            "converged_ratio_0ms_vs_local",
            "bytes_ratio_vs_cut",
            "requests_per_brick",
            "p99_over_median_streaming",
            "slowest_streaming_frame_ms",
            "requests_saved_by_batching",
            "converged_ratio_unbatched_vs_batched",
            "disk_cache_second_visit_converged_ratio",
            "disk_cache_second_visit_requests",
            "zarr_disk_cache_second_visit_requests",
            "brs_converged_ratio_no_lookahead_vs_lookahead",
            "zarr_converged_ratio_no_lookahead_vs_lookahead",
            "brs_first_image_s_0ms",
            "zarr_converged_ratio_0ms_vs_local",
        ],
    );
    // Every brick drawn was fetched (with the store's header and table).
    assert!(
        fig["bytes_ratio_vs_cut"].as_f64().unwrap() >= 1.0,
        "{fig:?}"
    );
    // A second visit through the disk cache reads its bricks from it (one
    // request when written: the store's validation).
    assert!(
        fig["disk_cache_second_visit_requests"].as_u64().unwrap() <= 2,
        "{fig:?}"
    );
}
