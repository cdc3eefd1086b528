//! Smoke runs of the suites that build, plan, rank and chart rather than
//! time ray-cast frames (build, formats, host, lodrank, pareto, stability),
//! as in
//! `smoke.rs`: a suite at its smallest settings must exit successfully and
//! end with one JSON object holding its documented keys (docs/benchmarks.md);
//! never speed. `formats` needs ../shared/data (reported as ignored in a
//! clone without it, never skipped with `CI=true`).
#![allow(missing_docs)]

mod support;

use support::{at, has_fields, row, rows, run, smoke, tmp};

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
            "phase_ms_median",
            "working_set",
            "converge_frames",
            "path_plans",
            "path_plans_evolved",
        ],
    );
    // Inline every path frame is planned; no more plans evolved than were
    // applied.
    for r in rows(&fig, "rows") {
        let (plans, evolved) = (
            r["path_plans"].as_u64().unwrap(),
            r["path_plans_evolved"].as_u64().unwrap(),
        );
        assert!(evolved <= plans, "{r:?}");
        if r["background"] == serde_json::json!(false) {
            assert_eq!(plans, 3, "{r:?}");
        }
    }
    assert!(
        rows(&fig, "rows")
            .iter()
            .all(|r| r["working_set"].as_u64().unwrap() > 0),
        "{fig:?}"
    );
    // Planning's phases are timed: every one a number, refinement's
    // above 0 where planning ran in `prepare` (the medians are not rounded),
    // and together within the planning they are part of.
    for r in rows(&fig, "rows") {
        let p = &r["phase_ms_median"];
        for k in ["poll", "refine", "display", "place", "request", "stats"] {
            assert!(p[k].as_f64().is_some_and(|v| v >= 0.0), "{k}: {r:?}");
        }
        if r["background"] == serde_json::json!(false) {
            assert!(p["refine"].as_f64().unwrap() > 0.0, "{r:?}");
        }
        let sum: f64 = ["poll", "refine", "display", "place", "request", "stats"]
            .iter()
            .map(|k| p[k].as_f64().unwrap())
            .sum();
        let plan = r["plan_ms_p99"].as_f64().unwrap();
        assert!(
            sum <= 2.0 * plan + 0.05,
            "phases {sum} ms, planning {plan} ms: {r:?}"
        );
    }
    // The GPU-free streamers' path: numbers in the inline unculled row, a
    // changed share and the evolved cut's distance from the one refined from
    // the root within [0, 2] (added plus gone over the cut), the moving
    // frames evolved, null in the other rows.
    for r in rows(&fig, "rows") {
        let alone =
            r["background"] == serde_json::json!(false) && r["culled"] == serde_json::json!(false);
        for k in [
            "streamer_path_plan_ms_median",
            "streamer_path_refine_ms_median",
            "streamer_path_cut_change_median",
            "streamer_path_refine_ms_p99",
            "streamer_path_evolved_share",
            "streamer_path_exact_plan_ms_median",
            "streamer_path_exact_refine_ms_median",
            "streamer_path_exact_refine_ms_p99",
            "streamer_path_differs_from_exact_median",
            "streamer_path_differs_from_exact_max",
        ] {
            match alone {
                true => assert!(r[k].as_f64().is_some_and(|v| v >= 0.0), "{k}: {r:?}"),
                false => assert!(r[k].is_null(), "{k}: {r:?}"),
            }
        }
        if alone {
            let at = |k: &str| r[k].as_f64().unwrap();
            assert!(at("streamer_path_cut_change_median") <= 2.0, "{r:?}");
            assert!(at("streamer_path_differs_from_exact_max") <= 2.0, "{r:?}");
            assert!(at("streamer_path_evolved_share") > 0.0, "{r:?}");
            assert!(at("streamer_path_evolved_share") <= 1.0, "{r:?}");
        }
    }
    // No cut of 20,000 bricks ran.
    assert!(fig["host_ms_median_20k"].is_null(), "{fig:?}");
}

/// The `pareto` suite on the procedural Marschner-Lobb volume (32^3, bricks
/// of 16) at 32 px, one round, the step, pre-integration and adaptive-step
/// knobs; a
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
            "step,preint,adaptive",
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
            "visible_error_gain_db_at_equal_bricks",
            "visible_error_gain_db_at_equal_brick_budget",
            "octant_gain_db_at_equal_brick_budget",
            "preintegration_gain_db_at_step_2",
            "adaptive_step_time_ratio",
            "adaptive_step_psnr_gain_db",
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
    // The adaptive step was drawn and compared at the default step (DVR).
    for key in ["adaptive_step_time_ratio", "adaptive_step_psnr_gain_db"] {
        assert!(fig[key].as_f64().is_some_and(f64::is_finite), "{fig:?}");
    }
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

/// The `lodrank` suite on a 32^3 Marschner-Lobb volume at 16 px, bricks of
/// 8: its keys, and correlations and cost ratios in range.
#[test]
fn the_lodrank_suite_runs() {
    let fig = smoke(
        &[
            "lodrank",
            "--scenes",
            "ml",
            "--ml-side",
            "32",
            "--size",
            "16",
            "--brick",
            "8",
        ],
        &[
            "size",
            "brick",
            "rows",
            "rho_plain_median",
            "rho_spread_median",
        ],
    );
    has_fields(
        &fig,
        "rows",
        &[
            "scene",
            "finest_bricks",
            "nodes",
            "rho_plain",
            "rho_spread",
            "rho_costs",
            "cost_ratio",
            "seconds",
        ],
    );
    let r = row(&fig, "rows", "scene", "ml_dvr");
    assert!(r["nodes"].as_u64().unwrap() >= 2, "{r}");
    for k in ["rho_plain", "rho_spread", "rho_costs"] {
        let rho = r[k].as_f64().unwrap();
        assert!((-1.0..=1.0).contains(&rho), "{k}: {r}");
    }
    assert!(r["cost_ratio"].as_f64().unwrap() > 0.0, "{r}");
}
