//! The viewer out of core: a brick store and a procedural 4096^3 volume
//! opened and streamed (the store's converged screenshot against the
//! library's out-of-core rendering of the same store with the viewer's
//! budgets), `--gradients`, and the out-of-core settings a script reaches
//! (brick budget, level-of-detail rule, visibility, prediction).

use super::*;

#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn opens_a_store_and_a_procedural_volume_out_of_core() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let store = sphere_store(dir.path());
    let script = format!(
        "open {store}\nbackground 0 0 0\noverlays off\ntf grey\ncamera orbit -20 25 0.9\n\
         wait converged 600\nscreenshot {a}\nopen procedural:4096\ntf grey\nwait 4\nscreenshot {b}\nquit\n",
        store = store.display(),
        a = out("store.png").display(),
        b = out("procedural.png").display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));

    let (shot, w, h) = read_png(&out("store.png"));
    let (camera, _, _) = sidecar(&out("store.png"));
    let lib = library_store_image(&store, camera, w, h);
    let lit = lit_pixels(&shot);
    assert!(lit * 20 > (w * h) as usize, "store: only {lit} lit pixels");
    let cmp = brickray_reference::assert_close("viewer-store", &shot, &lib, w, h, MIN_PSNR_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewer store vs library: {cmp}");
    // The procedural volume streams: a coarse image shows at once.
    let (shot, w, h) = read_png(&out("procedural.png"));
    let lit = lit_pixels(&shot);
    assert!(
        lit * 20 > (w * h) as usize,
        "procedural: only {lit} lit pixels of {w}x{h}"
    );
}

/// `--gradients`: a streamed store keeps its texels' gradients and draws
/// shaded DVR as six reads do (`--gradients=never`; two runs of the same
/// script; the library's own test holds the two images 74-80 dB apart),
/// and they take their bytes from the GPU pool (a pool that holds the
/// finest cut without them holds a smaller working set with them). By
/// default (`auto`) the default pool keeps them and the small pool none:
/// with them it would not hold every brick (the screenshots' sidecars say
/// which, `gradients_kept`).
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn streamed_gradients_shade_as_six_reads() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let store = sphere_store(dir.path());
    let shot = |name: &str, args: &[&str]| {
        let script = format!(
            "open {store}\nbackground 0 0 0\noverlays off\ntf grey\nmode shaded\n\
             camera orbit -20 25 0.9\nwait converged 600\nscreenshot {a}\nquit\n",
            store = store.display(),
            a = out(name).display(),
        );
        run_script_with(dir.path(), &script, Duration::from_secs(120), args);
        read_png(&out(name))
    };
    let (kept, w, h) = shot("kept.png", &["--gradients"]);
    let (six, _, _) = shot("six.png", &["--gradients=never"]);
    let lit = lit_pixels(&kept);
    assert!(lit * 20 > (w * h) as usize, "only {lit} lit pixels");
    let db = brickray_reference::psnr(&kept, &six);
    eprintln!("viewer --gradients against six reads: {db:.2} dB");
    assert!(db >= 60.0, "{db} dB");
    // The gradients take their bytes from the pool: an 8 MiB pool holds the
    // store's finest cut (27 bricks) without them, not with them.
    shot("kept_small.png", &["--gradients", "--gpu-pool", "8"]);
    shot("six_small.png", &["--gpu-pool", "8"]);
    shot("never_small.png", &["--gradients=never", "--gpu-pool", "8"]);
    let bricks = |name: &str| {
        sidecar_json(&out(name))["working_set_bricks"]
            .as_u64()
            .expect("a streamed volume's working set")
    };
    let (small_kept, small_six) = (bricks("kept_small.png"), bricks("six_small.png"));
    // The sidecar says what each run decided (`auto` keeps them where the
    // default pool holds every brick with them, not in the 8 MiB one).
    shot("auto.png", &[]);
    let kept = |name: &str| sidecar_json(&out(name))["gradients_kept"].as_bool();
    assert_eq!(
        [
            kept("kept.png"),
            kept("six.png"),
            kept("auto.png"),
            kept("kept_small.png"),
            kept("six_small.png")
        ],
        [Some(true), Some(false), Some(true), Some(true), Some(false)]
    );
    assert_eq!(
        small_six,
        bricks("never_small.png"),
        "auto keeps no gradients where the pool would not hold every brick with them"
    );
    eprintln!(
        "working sets in an 8 MiB pool: {small_kept} bricks with gradients, {small_six} without"
    );
    assert!(small_kept < small_six, "{small_kept} vs {small_six}");
}

/// The script's `bricks N` caps the out-of-core working set (what the
/// sidecar of a screenshot reports), and `bricks off` lifts the cap.
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_brick_budget_caps_the_viewers_working_set() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let script = format!(
        "open procedural:256\ntf grey\nwait converged 600\nscreenshot {a}\n\
         bricks 40\nwait converged 600\nscreenshot {b}\n\
         bricks off\nwait converged 600\nscreenshot {c}\nquit\n",
        a = out("free.png").display(),
        b = out("capped.png").display(),
        c = out("lifted.png").display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(180));
    let bricks = |name: &str| -> u64 {
        sidecar_json(&out(name))["working_set_bricks"]
            .as_u64()
            .expect("a working set")
    };
    let (free, capped, lifted) = (
        bricks("free.png"),
        bricks("capped.png"),
        bricks("lifted.png"),
    );
    assert!(free > 40, "the unbudgeted working set holds {free} bricks");
    assert!(
        (1..=40).contains(&capped),
        "budget 40: {capped} bricks (unbudgeted {free})"
    );
    assert_eq!(lifted, free, "the cap lifted");
}

/// The script's `lod` chooses the level-of-detail rule and its budget, and
/// the screenshot sidecar reports them: on a store with error records, a
/// visible-error budget of 1e9 keeps the cut coarse, 0 refines it, and the
/// visible-error rule under a brick budget of 8 keeps within it and settles
/// (`wait converged` fails the script otherwise).
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn the_lod_rule_and_its_budget_reach_the_renderer() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let store = sphere_store(dir.path());
    let script = format!(
        "open {store}\ntf grey\ncamera orbit -20 25 0.9\n\
         lod visible 1e9\nwait converged 600\nscreenshot {a}\n\
         lod visible 0\nwait converged 600\nscreenshot {b}\n\
         lod visible 0\nbricks 8\nwait converged 600\nscreenshot {c}\n\
         lod geometric 2\nbricks off\nwait converged 600\nscreenshot {d}\nquit\n",
        store = store.display(),
        a = out("coarse.png").display(),
        b = out("fine.png").display(),
        c = out("visible.png").display(),
        d = out("geometric.png").display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(180));
    let read = |name: &str| sidecar_json(&out(name));
    let bricks = |v: &serde_json::Value| v["working_set_bricks"].as_u64().expect("a working set");
    let (coarse, fine, visible, geometric) = (
        read("coarse.png"),
        read("fine.png"),
        read("visible.png"),
        read("geometric.png"),
    );
    assert_eq!(coarse["lod"]["rule"], "visible error");
    assert_eq!(coarse["lod"]["error_budget"], 1e9);
    assert_eq!(fine["lod"]["error_budget"], 0.0);
    assert_eq!(visible["lod"]["rule"], "visible error");
    assert_eq!(geometric["lod"]["rule"], "geometric");
    assert_eq!(geometric["lod"]["tolerance_px"], 2.0);
    assert!(
        bricks(&coarse) < bricks(&fine),
        "error budget 1e9: {} bricks, 0: {}",
        bricks(&coarse),
        bricks(&fine)
    );
    assert!(
        (1..=8).contains(&bricks(&visible)),
        "brick budget 8: {} bricks",
        bricks(&visible)
    );
    eprintln!(
        "bricks: error budget 1e9 {}, 0 {}, visible under 8 {}, geometric 2 px {}",
        bricks(&coarse),
        bricks(&fine),
        bricks(&visible),
        bricks(&geometric)
    );
}

/// The script's `visibility` and `prediction` reach the renderer: on the
/// procedural noise volume under an opaque ramp, ray-guided visibility keeps
/// the bricks no ray reaches coarse, so the converged working set is smaller
/// than without it; on the sphere store's isosurface the exact prediction
/// buffer predicts (the renderer reports frames of history) and its image,
/// after the camera moved, equals the full traversal's at the same view
/// (PSNR >= 50 dB; measured: identical).
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn visibility_and_prediction_reach_the_renderer() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    let store = sphere_store(dir.path());
    let mut script = format!(
        "open procedural:256\ntf grey\nwait converged 600\nscreenshot {a}\n\
         visibility rayguided\nwait converged 600\nwait 8\nwait converged 600\nscreenshot {b}\n\
         open {store}\nbackground 0 0 0\noverlays off\ntf grey\nmode iso 0.5\nprediction exact\n\
         camera orbit -20 25 0.9\nwait converged 600\n",
        a = out("none.png").display(),
        b = out("rayguided.png").display(),
        store = store.display(),
    );
    for yaw in [-17, -14, -11] {
        script += &format!("camera orbit {yaw} 25 0.9\nwait 1\n");
    }
    script += &format!(
        "screenshot {p}\nprediction off\nwait 1\nscreenshot {f}\nquit\n",
        p = out("predicted.png").display(),
        f = out("full.png").display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(240));
    let (none, guided) = (
        sidecar_json(&out("none.png")),
        sidecar_json(&out("rayguided.png")),
    );
    assert_eq!(none["visibility"], "none");
    assert_eq!(guided["visibility"], "rayguided");
    let bricks = |v: &serde_json::Value| v["working_set_bricks"].as_u64().expect("a working set");
    assert!(
        bricks(&guided) < bricks(&none),
        "ray-guided {} bricks, none {}",
        bricks(&guided),
        bricks(&none)
    );
    let (predicted, full) = (
        sidecar_json(&out("predicted.png")),
        sidecar_json(&out("full.png")),
    );
    assert_eq!(predicted["prediction"]["setting"], "exact");
    let frames = predicted["prediction"]["frames"]
        .as_u64()
        .expect("the last frame predicted");
    assert!(frames >= 2, "{frames} frames of history");
    assert!(full["prediction"]["frames"].is_null(), "off still predicts");
    let (p, w, h) = read_png(&out("predicted.png"));
    let (f, fw, fh) = read_png(&out("full.png"));
    assert_eq!((w, h), (fw, fh));
    let db = brickray_reference::psnr(&p, &f);
    assert!(db >= 50.0, "exact prediction vs full traversal: {db:.1} dB");
    eprintln!(
        "bricks: none {}, ray-guided {}; prediction: {frames} frames, {db:.1} dB against the full traversal",
        bricks(&none),
        bricks(&guided)
    );
}
