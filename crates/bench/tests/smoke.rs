//! Smoke runs of the benchmark suites that time ray-cast frames: a suite
//! at its smallest settings must exit successfully and end with one JSON
//! object holding its documented keys (docs/benchmarks.md). They check that
//! a suite still runs and still says what it measures, never how fast: the
//! figures of a smoke run are not results. The suites that build, plan and
//! chart (build, formats, host, pareto, stability in two halves of its
//! cases) have theirs in `smoke_planning.rs`; every suite has one. Suites
//! that draw the shared head CT or MRI fall back to procedural stand-ins
//! without ../shared/data (`brickray_harness::stand_in`; accel, preint, u8,
//! raw, ooc, spread; prediction and visibility add their shared scenes
//! where present); those that need the shared files themselves (labels,
//! channels, remote) are reported as ignored in a user's clone without them
//! (never skipped with `CI=true`). The remote suite starts its own loopback
//! HTTP servers (and an S3 one where moto is installed). The vtk suite
//! needs VTK's Python package: its run is ignored in a plain `cargo test`
//! and runs in scripts/test.sh's second pass, which installs VTK.
#![allow(missing_docs)]

mod support;

use std::process::Command;
use support::{Fig, at, has_fields, row, rows, run, smoke, tmp};

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
    let fig = run(&["channels", "--size", "32", "--rounds", "1", "--adaptive"]);
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
    // The four modes, and DVR with the adaptive step (`--adaptive`), whose
    // error against its twin is in psnr_min_db.
    assert_eq!(fig["modes"].as_array().map(Vec::len), Some(5));
    assert_eq!(fig["modes"][1]["mode"], "dvr adaptive", "{fig:?}");
}

#[test]
fn the_accel_suite_runs() {
    let fig = smoke(
        &["accel", "--size", "32", "--rounds", "1"],
        &[
            "psnr_min_db",
            "speedup_ert_ess_max",
            "rows",
            "image_size",
            "rounds",
            "adapter",
            "gpu_timestamps",
        ],
    );
    // Three scenes, four variants each.
    assert_eq!(rows(&fig, "rows").len(), 12, "{fig:?}");
    has_fields(
        &fig,
        "rows",
        &[
            "scene",
            "variant",
            "samples_per_ray",
            "ms",
            "gpu_ms",
            "speedup",
            "psnr_db",
        ],
    );
    // Where the device has timestamps, the ray-cast pass takes at most the
    // frame's wall time (a medians' margin aside). Not asserted above 0:
    // lavapipe's timestamps now and then read about 0 on a loaded machine.
    if fig["gpu_timestamps"] == true {
        for r in rows(&fig, "rows") {
            let (gpu, wall) = (r["gpu_ms"].as_f64().unwrap(), r["ms"].as_f64().unwrap());
            assert!((0.0..=wall * 1.05 + 0.5).contains(&gpu), "{r:?}");
        }
    }
    // Skipping and early termination change the image within tolerance.
    assert!(fig["psnr_min_db"].as_f64().unwrap() >= 40.0, "{fig:?}");
}

/// The `accel` suite on the procedural head-CT stand-in (what a clone
/// without ../shared/data runs), forced where the shared data is present.
#[test]
fn the_accel_suite_runs_on_the_stand_in() {
    let out = Command::new(env!("CARGO_BIN_EXE_brickray-bench"))
        .args(["accel", "--size", "32", "--rounds", "1"])
        .env(brickray_harness::stand_in::FORCE_ENV, "1")
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fig: Fig = serde_json::from_str(stdout.lines().last().unwrap_or_default()).unwrap();
    assert_eq!(fig["volume"], "head_ct_phantom", "{fig:?}");
    assert_eq!(rows(&fig, "rows").len(), 12, "{fig:?}");
    // Early termination and skipping change the stand-in's image within
    // tolerance too.
    assert!(fig["psnr_min_db"].as_f64().unwrap() >= 40.0, "{fig:?}");
}

#[test]
fn the_soak_suite_runs() {
    let fig = smoke(
        &["soak", "--frames", "3", "--size", "32"],
        &[
            "frames",
            "rss_growth_pct",
            "panics",
            "errors",
            "feature_frames",
        ],
    );
    assert_eq!(fig["frames"], serde_json::json!(3));
    assert_eq!(fig["panics"], serde_json::json!(0));
    assert_eq!(fig["errors"], serde_json::json!(0));
}

#[test]
fn the_preint_suite_runs() {
    let fig = smoke(
        &[
            "preint",
            "--size",
            "32",
            "--rounds",
            "1",
            "--scenes",
            "noise",
            "--quality-size",
            "24",
            "--exact-div",
            "16",
        ],
        &[
            "worst_ratio",
            "ms_corrected_table",
            "ms_preint_table_8_layers",
            "cost",
            "spike",
            "scenes",
            "preint_gain_db_min",
            "preint_never_loses",
        ],
    );
    // Two modes at two steps; the spike scene at four steps; one pareto scene
    // at six steps, shaded and not.
    assert_eq!(rows(&fig, "cost").len(), 4, "{fig:?}");
    assert_eq!(rows(&fig, "spike").len(), 4, "{fig:?}");
    assert_eq!(rows(&fig, "scenes").len(), 12, "{fig:?}");
    has_fields(&fig, "cost", &["mode", "step", "plain", "preint", "ratio"]);
    has_fields(
        &fig,
        "scenes",
        &[
            "scene",
            "step",
            "gpu_plain_db",
            "gpu_preint_db",
            "cpu_preint_db",
        ],
    );
}

#[test]
fn the_shading_suite_runs() {
    let fig = smoke(
        &[
            "shading",
            "--size",
            "32",
            "--rounds",
            "1",
            "--quality-size",
            "24",
        ],
        &[
            "rows",
            "precomputed_over_six_reads_max",
            "precomputed_over_unshaded_max",
            "psnr_between_db_min",
        ],
    );
    // The head CT twice (two TFs) and the MRI, or their stand-ins.
    assert_eq!(rows(&fig, "rows").len(), 3, "{fig:?}");
    has_fields(
        &fig,
        "rows",
        &[
            "scene",
            "six_reads",
            "precomputed",
            "gradient_bytes",
            "psnr_between_db",
        ],
    );
    // The two shaded images agree (the GPU tests ask >= 70 dB at 96 px).
    let between = fig["psnr_between_db_min"].as_f64().unwrap();
    assert!(between >= 60.0, "{between} dB");
}

#[test]
fn the_skipping_suite_runs() {
    let fig = smoke(
        &["skipping", "--size", "32", "--rounds", "1", "--side", "24"],
        &[
            "rows",
            "rule_over_off_max",
            "always_over_off_max",
            "wrong_decisions",
            "ooc_rows",
            "ooc_rule_over_off_max",
            "ooc_always_over_off_max",
            "ooc_wrong_decisions",
            "dvr_rows",
            "dvr_rule_over_off_max",
            "dvr_always_over_off_max",
            "dvr_wrong_decisions",
            "dvr_shaded_rows",
            "dvr_shaded_wrong_decisions",
            "dvr_ooc_rows",
            "dvr_ooc_always_over_off_max",
            "dvr_shaded_ooc_rows",
            "dvr_shaded_ooc_wrong_decisions",
        ],
    );
    // Three ramps per volume, in core and out of core, unshaded and shaded.
    for key in [
        "dvr_rows",
        "dvr_shaded_rows",
        "dvr_ooc_rows",
        "dvr_shaded_ooc_rows",
    ] {
        assert_eq!(rows(&fig, key).len(), 3 * rows(&fig, "rows").len(), "{key}");
    }
    // The two procedural volumes, and the shared ones where present, in
    // core and out of core.
    assert!(rows(&fig, "rows").len() >= 2, "{fig:?}");
    assert_eq!(rows(&fig, "rows").len(), rows(&fig, "ooc_rows").len());
    for key in [
        "rows",
        "ooc_rows",
        "dvr_rows",
        "dvr_shaded_rows",
        "dvr_ooc_rows",
        "dvr_shaded_ooc_rows",
    ] {
        has_fields(
            &fig,
            key,
            &[
                "volume",
                "skip_share",
                "rule_skips",
                "off",
                "always",
                "rule",
            ],
        );
    }
}

#[test]
fn the_u8_suite_runs() {
    let fig = smoke(
        &["u8", "--size", "32", "--rounds", "1"],
        &["exact_over_fast_worst", "rows"],
    );
    assert_eq!(rows(&fig, "rows").len(), 3, "{fig:?}");
    let dvr = row(&fig, "rows", "scene", "dvr");
    assert!(dvr["psnr_exact_db"].as_f64().unwrap() > 0.0, "{fig:?}");
    assert!(dvr["exact"]["ms"].as_f64().unwrap() > 0.0, "{fig:?}");
}

/// The `spread` suite at 32 px, one round, one tolerance (stand-ins in a
/// clone without `../shared/data`).
#[test]
fn the_spread_suite_runs() {
    let fig = smoke(
        &[
            "spread",
            "--size",
            "32",
            "--rounds",
            "1",
            "--tolerances",
            "4",
        ],
        &["rows", "setup", "spread_over_plain_worst"],
    );
    assert_eq!(rows(&fig, "rows").len(), 3, "{fig:?}");
    let ct5 = row(&fig, "rows", "volume", "ct5");
    assert!(ct5["spread"]["ms"].as_f64().unwrap() > 0.0, "{fig:?}");
    assert!(ct5["bricks"].as_u64().unwrap() >= 1, "{fig:?}");
    // Bytes of the cut: spreads add to the values' bytes, never remove.
    let mb = |k: &str| ct5[k].as_f64().unwrap_or(-1.0);
    assert!(mb("upload_mb_plain") > 0.0, "{fig:?}");
    assert!(mb("upload_mb_spread") >= mb("upload_mb_plain"), "{fig:?}");
    assert!(mb("cpu_mb_spread") >= mb("cpu_mb_plain"), "{fig:?}");
    assert_eq!(rows(&fig, "setup").len(), 3, "{fig:?}");
}

#[test]
fn the_raw_suite_runs() {
    let fig = smoke(
        &["raw", "--size", "32", "--rounds", "1"],
        &["modes", "step_voxels"],
    );
    assert_eq!(rows(&fig, "modes").len(), 4, "{fig:?}");
    let dvr = row(&fig, "modes", "mode", "dvr");
    assert_eq!(dvr["variants"].as_array().map(Vec::len), Some(8));
    // Ratios of CPU times: null where a 32 px frame took under the 10 ms
    // tick of the process's CPU clock (a division by zero), as before.
    for k in [
        "accel_rate_per_sample",
        "buffer_tf_rate_ratio",
        "ooc_vs_incore",
    ] {
        assert!(dvr["ratios"].get(k).is_some(), "no {k} in {dvr:?}");
    }
}

#[test]
fn the_ooc_suite_runs() {
    let fig = smoke(
        &["ooc", "--size", "32", "--rounds", "1"],
        &[
            "finest_vs_incore_time_ratio",
            "psnr_finest_vs_incore_db",
            "frames_to_converge_after_jump",
            "p99_over_median",
            "head",
            "sensitivity",
            "path",
        ],
    );
    // Two TFs by two accelerations; far and close views; exact and 8-bit
    // texels.
    assert_eq!(rows(&fig, "head").len(), 4, "{fig:?}");
    assert_eq!(rows(&fig, "sensitivity").len(), 2, "{fig:?}");
    assert_eq!(rows(&fig, "path").len(), 2, "{fig:?}");
    has_fields(&fig, "head", &["incore", "ooc", "time_ratio", "psnr_db"]);
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
            "maps",
        ],
    );
    assert_eq!(rows(&fig, "maps").len(), 2, "{fig:?}");
    has_fields(&fig, "maps", &["map", "psnr_2px_db", "lod", "overlay"]);
    assert!(
        fig["psnr_finest_db_min"].as_f64().unwrap() >= 45.0,
        "{fig:?}"
    );
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
    let orbits = rows(&fig, "orbit");
    assert!(
        orbits
            .iter()
            .any(|o| o["scene"] == "nested_shells" && o["accel"] == "default"),
        "{fig:?}"
    );
    for o in orbits {
        let guard = o["variants"]
            .as_array()
            .and_then(|v| v.iter().find(|s| s["variant"] == "guard"))
            .unwrap_or_else(|| panic!("no guard in {o:?}"));
        assert_eq!(guard["wrong_max_pct"], serde_json::json!(0.0), "{o:?}");
    }
    assert!(dir.path().join("failure.svg").is_file());
    assert!(dir.path().join("classes.png").is_file());
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
            "scenes",
            "cut_opaque_rayguided",
            "cut_translucent_rayguided",
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
    let shells = row(&fig, "scenes", "scene", "shells");
    for k in [
        "kind",
        "baseline_converged",
        "oracle",
        "oracle_cut",
        "policies",
    ] {
        assert!(shells.get(k).is_some(), "shells: no {k} in {fig:?}");
    }
    let culled = shells["policies"]
        .as_array()
        .and_then(|p| p.iter().find(|r| r["policy"] == "rayguided"))
        .unwrap_or_else(|| panic!("no rayguided row in {fig:?}"));
    for k in ["cut", "oracle_ratio", "oracle_cut_ratio", "ms_per_frame"] {
        assert!(culled.get(k).is_some(), "rayguided: no {k} in {fig:?}");
    }
    if scenes.contains("head") {
        row(&fig, "scenes", "scene", "head_opaque");
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
            "cases",
            "worst_delay_ms",
            "first_image_s",
            "converged_ratio_vs_local",
            "bytes_ratio_vs_cut",
            "requests_per_brick",
            "p99_over_median_streaming",
            "p99_over_median_streaming_host",
            "slowest_streaming_frame_ms",
            "raycast",
            "fades",
            "background",
            "first_image_s_80ms",
            "converged_ratio_80ms_vs_local",
            "requests_saved_by_batching",
            "converged_ratio_unbatched_vs_batched",
            "disk_cache_second_visit_converged_ratio",
            "disk_cache_second_visit_requests",
            "zarr_disk_cache_second_visit_requests",
            "brs_converged_ratio_no_lookahead_vs_lookahead",
            "zarr_converged_ratio_no_lookahead_vs_lookahead",
        ],
    );
    assert_eq!(fig["worst_delay_ms"], serde_json::json!(0));
    // No case at 80 ms ran.
    assert!(fig["first_image_s_80ms"].is_null(), "{fig:?}");
    has_fields(
        &fig,
        "cases",
        &[
            "source",
            "transport",
            "variant",
            "first_image_s",
            "converged_ratio_vs_local",
            "requests",
            "p99_over_median",
        ],
    );
    for src in ["brs", "zarr"] {
        assert!(
            rows(&fig, "cases")
                .iter()
                .any(|c| c["source"] == src && c["delay_ms"] == 0 && c["variant"] == "batched"),
            "{src}: {fig:?}"
        );
    }
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

/// The `vtk` suite at 64 px, one round, the MRI's MIP at one step: its
/// keys, and VTK's images drawn where brickray draws the scene (the
/// placement, camera and TF the suite hands VTK): each mapper at least
/// 28 dB from the reference (measured: 31.6 and 32.5 dB; the same images
/// shifted by one pixel score 23.5-24.0, mirrored 21.2-21.5, flipped 12.7).
#[test]
#[ignore = "needs VTK's Python package (python3 -m pip install vtk numpy); scripts/test.sh installs it and runs this in its second pass"]
fn the_vtk_suite_runs() {
    if brickray_harness::shared_data_dir().is_none() {
        return;
    }
    let out = tmp();
    let charts = tmp();
    let fig = smoke(
        &[
            "vtk",
            "--size",
            "64",
            "--rounds",
            "1",
            "--scenes",
            "mri",
            "--modes",
            "mip",
            "--steps",
            "1",
            "--out",
            &at(&out, "vtk"),
            "--charts",
            &at(&charts, "charts"),
        ],
        &[
            "size",
            "rounds",
            "adapter",
            "vtk_version",
            "brickray_at_or_below_vtk_all",
            "worst_time_ratio",
            "scenes",
        ],
    );
    let scene = row(&fig, "scenes", "scene", "mri_mip");
    let vtk = scene["vtk"].as_array().expect("vtk points");
    assert_eq!(vtk.len(), 2, "{scene:?}");
    for p in vtk {
        let db = p["psnr_db"].as_f64().unwrap_or(f64::NAN);
        assert!(
            db >= 25.0,
            "VTK's {} image: {db} dB: {scene:?}",
            p["mapper"]
        );
    }
    // Out of core and in core at VTK's step and at brickray's own 6 and 8.
    let ours = scene["brickray"].as_array().expect("brickray points");
    assert_eq!(ours.len(), 6, "{scene:?}");
    assert!(ours.iter().any(|p| p["config"] == "in_core 8"), "{scene:?}");
}
