//! Smoke runs of benchmark suites: a suite at its smallest settings must
//! exit successfully and end with one JSON object holding its documented
//! keys (docs/benchmarks.md). They check that a suite still runs and still
//! says what it measures, never how fast: the figures of a smoke run are
//! not results. Every suite has one here (stability two halves of its
//! cases). Suites that draw the shared head CT or MRI fall back to
//! procedural stand-ins without ../shared/data (`brickray_harness::stand_in`;
//! accel, preint, u8, raw, ooc; prediction and visibility add their shared
//! scenes where present); those that need the shared files themselves
//! (labels, channels, formats, remote) are reported as ignored in a user's
//! clone without them (never skipped with `CI=true`). The remote suite starts its own loopback HTTP servers (and
//! an S3 one where moto is installed).
#![allow(missing_docs)]

use std::process::Command;

/// A suite's JSON line.
type Fig = serde_json::Map<String, serde_json::Value>;

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

/// The rows of the array `key` of a suite's JSON object.
fn rows<'a>(fig: &'a Fig, key: &str) -> &'a Vec<serde_json::Value> {
    fig.get(key)
        .and_then(|v| v.as_array())
        .unwrap_or_else(|| panic!("no array {key} in {fig:?}"))
}

/// The row of the array `key` whose `field` is `value`.
fn row<'a>(fig: &'a Fig, key: &str, field: &str, value: &str) -> &'a serde_json::Value {
    rows(fig, key)
        .iter()
        .find(|r| r[field] == value)
        .unwrap_or_else(|| panic!("no {key} row with {field} {value} in {fig:?}"))
}

/// Checks that every row of `key` has `fields`.
fn has_fields(fig: &Fig, key: &str, fields: &[&str]) {
    for r in rows(fig, key) {
        for f in fields {
            assert!(r.get(*f).is_some(), "{key}: no {f} in {r:?}");
        }
    }
}

/// Runs a suite with `args` and checks that its JSON object has `keys`
/// (documented in docs/benchmarks.md; a value may be null where a smoke
/// run measures nothing) and some finite numbers (anywhere in it, rows
/// included).
fn smoke(args: &[&str], keys: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let fig = run(args);
    for key in keys {
        assert!(fig.contains_key(*key), "{args:?}: no {key} in {fig:?}");
    }
    fn finite(v: &serde_json::Value) -> usize {
        match v {
            serde_json::Value::Number(n) => usize::from(n.as_f64().is_some_and(f64::is_finite)),
            serde_json::Value::Array(a) => a.iter().map(finite).sum(),
            serde_json::Value::Object(m) => m.values().map(finite).sum(),
            _ => 0,
        }
    }
    let numbers: usize = fig.values().map(finite).sum();
    assert!(
        numbers >= 3,
        "{args:?}: {numbers} finite numbers in {fig:?}"
    );
    fig
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
        &["preint", "--size", "32", "--rounds", "1"],
        &[
            "worst_ratio",
            "ms_corrected_table",
            "ms_preint_table_8_layers",
            "cost",
            "spike",
        ],
    );
    // Two modes at two steps; the spike scene at four steps.
    assert_eq!(rows(&fig, "cost").len(), 4, "{fig:?}");
    assert_eq!(rows(&fig, "spike").len(), 4, "{fig:?}");
    has_fields(&fig, "cost", &["mode", "step", "plain", "preint", "ratio"]);
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
            "scale",
            "rows",
            "decode_gb_per_s",
            "read_latency_us_mean",
            "read_latency_us_p50",
            "read_latency_us_p99",
        ],
    );
    assert_eq!(fig["scale"], serde_json::json!(16));
    has_fields(
        &fig,
        "rows",
        &[
            "input",
            "memory_bound_mb",
            "mvoxel_per_s",
            "peak_rss_mb",
            "ratio",
        ],
    );
    // The phantoms are half air: their stores are smaller than their input.
    for input in ["u8", "u16"] {
        let r = row(&fig, "rows", "input", input);
        assert!(r["ratio"].as_f64().unwrap() > 1.0, "{fig:?}");
    }
    assert_eq!(
        row(&fig, "rows", "input", "u8_4gib")["memory_bound_mb"],
        serde_json::json!(1024)
    );
    assert_eq!(
        row(&fig, "rows", "input", "u8_4gib_bound128")["memory_bound_mb"],
        serde_json::json!(1)
    );
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
    let fig = smoke(&["formats", "--rounds", "1"], &["memory_bound_mb", "rows"]);
    assert_eq!(rows(&fig, "rows").len(), 10, "{fig:?}");
    for r in rows(&fig, "rows") {
        for k in ["mvoxel_per_s", "peak_rss_mb"] {
            assert!(r[k].as_f64().unwrap_or(f64::NAN) > 0.0, "{k}: {r:?}");
        }
    }
    assert_eq!(fig["memory_bound_mb"], serde_json::json!(8));
}

/// The `host` suite: a cut of 1000 bricks at 32 px, three path frames,
/// planned inline and in the background, and drawn under ray-guided
/// visibility (`--culling`).
#[test]
fn the_host_suite_runs() {
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
        &[
            "size",
            "frames",
            "adapter",
            "rows",
            "host_ms_median_20k",
            "host_ms_p99_20k",
            "plan_ms_median_20k",
        ],
    );
    assert_eq!(fig["frames"], serde_json::json!(3));
    // Inline and in the background, unculled and culled.
    assert_eq!(rows(&fig, "rows").len(), 4, "{fig:?}");
    has_fields(
        &fig,
        "rows",
        &[
            "budget",
            "background",
            "culled",
            "host_ms_median",
            "host_ms_p99",
            "plan_ms_median",
            "upload_ms_median",
            "encode_ms_median",
            "working_set",
            "converge_frames",
        ],
    );
    assert!(
        rows(&fig, "rows")
            .iter()
            .all(|r| r["working_set"].as_u64().unwrap() > 0),
        "{fig:?}"
    );
    // No cut of 20,000 bricks ran.
    assert!(fig["host_ms_median_20k"].is_null(), "{fig:?}");
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
    for scene in ["ml_dvr", "ml_iso"] {
        let s = row(&fig, "scenes", "scene", scene);
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
    let all = [
        "holes_max",
        "cases_with_bound",
        "cases_total",
        "image_size",
        "adapter",
        "lod_paths",
        "cases",
    ];
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
    for name in keys {
        let case = row(&fig, "cases", "name", name);
        for k in [
            "varied",
            "fails",
            "by",
            "shipped",
            "bound",
            "kept",
            "holes_max",
            "figures",
        ] {
            assert!(case.get(k).is_some(), "{name}: no {k} in {case:?}");
        }
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
    assert!(fig["lod_paths"].is_null(), "{fig:?}");
}

/// Stability cases 6-9 (precision at 65536^3, early ray termination, the
/// prediction buffer and disocclusion, level-of-detail transitions). Early
/// termination keeps its bound (an error no larger than the opacity left),
/// whatever the machine.
#[test]
fn the_stability_suite_runs_cases_6_to_9() {
    let fig = stability(
        "6,7,8,9",
        &["precision", "ert", "temporal", "fly-through", "zoom-in"],
    );
    assert_eq!(fig["cases_total"], serde_json::json!(5));
    let ert = row(&fig, "cases", "name", "ert");
    assert_eq!(ert["kept"], serde_json::json!(true), "{fig:?}");
    for k in [
        "rows",
        "temporal_excess_db_fades",
        "temporal_excess_db_no_fades",
        "pops_fades",
        "pops_no_fades",
        "holes_max",
    ] {
        assert!(fig["lod_paths"].get(k).is_some(), "no {k} in {fig:?}");
    }
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
