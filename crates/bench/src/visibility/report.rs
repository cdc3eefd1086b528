//! What the `visibility` suite reports: each scene's policies against the
//! unculled baseline and the oracle, the headline over the scenes, the chart.

use super::*;

/// One policy on one scene.
#[derive(Debug, Serialize)]
pub(crate) struct PolicyRow {
    /// none, rayguided, occlusion or both.
    policy: &'static str,
    /// Working set converged at the start view (and at the back view).
    working_set_converged: f64,
    working_set_back: Option<u64>,
    /// Share of the unculled working set cut away (start, back).
    cut: f64,
    cut_back: Option<f64>,
    /// Working set along the path: median and peak.
    working_set_median: f64,
    working_set_peak: f64,
    uploaded_mb: f64,
    frames_to_converge: Option<usize>,
    /// Medians along the path: whole frame and `prepare` alone, ms.
    ms_per_frame: f64,
    host_ms_per_frame: f64,
    /// The ray-cast pass by GPU timestamps (null without).
    gpu_ms_per_frame: Option<f64>,
    /// Working set over the oracle (bricks a ray reaches) and over the
    /// smallest hole-free cut holding them.
    oracle_ratio: f64,
    oracle_cut_ratio: f64,
    /// Against the unculled images (start, back), capped at 999.
    psnr_start_db: f64,
    psnr_back_db: Option<f64>,
    /// Frames until the back view (the jump back) is within 50 dB of the
    /// unculled image.
    disocclusion_frames: Option<usize>,
    disocclusion_jump_frames: Option<usize>,
}

/// One scene.
#[derive(Debug, Serialize)]
pub(crate) struct SceneResult {
    scene: &'static str,
    /// opaque or translucent.
    kind: &'static str,
    /// Whether the unculled run converged at the start view within the hold.
    baseline_converged: bool,
    /// Bricks a ray reaches in the unculled cut, and the smallest hole-free
    /// cut holding them.
    oracle: usize,
    oracle_cut: usize,
    policies: Vec<PolicyRow>,
}

/// The smallest hole-free cut holding `reached` (leaves of the unculled cut
/// `cut`): every strict ancestor of a reached leaf is split; each child of a
/// split node that is not split itself is a leaf, a data leaf when some data
/// leaf of `cut` lies in it. Returns its data leaves.
fn oracle_cut(cut: &[NodeKey], reached: &[NodeKey]) -> usize {
    let mut split: HashSet<NodeKey> = HashSet::new();
    for k in reached {
        let mut p = k.parent();
        while let Some(a) = p {
            if !split.insert(a) {
                break;
            }
            p = a.parent();
        }
    }
    // Nodes holding some data leaf of the cut (the leaves and their ancestors).
    let mut has_data: HashSet<NodeKey> = HashSet::new();
    for k in cut {
        let mut p = Some(*k);
        while let Some(a) = p {
            if !has_data.insert(a) {
                break;
            }
            p = a.parent();
        }
    }
    if split.is_empty() {
        return reached.len();
    }
    split
        .iter()
        .flat_map(|s| s.children())
        .filter(|c| !split.contains(c) && has_data.contains(c))
        .count()
}

pub(super) fn report(
    scene: &Scene,
    policies: &[VisibilityPolicy],
    tracks: &[Track],
) -> Result<SceneResult, String> {
    let base = &tracks[0];
    let (base_start, base_s) = base.start.as_ref().ok_or("no start image")?;
    // `--start-only` runs have no back view.
    let base_back = base.back.as_ref();
    if base.converge_start.is_none() {
        println!(
            "  WARNING: the unculled run did not converge at the start view within --hold frames: its working set, and so every cut below, is understated"
        );
    }
    // The oracle from the unculled converged cut's usage.
    let usage = base.oracle_usage.clone().unwrap_or_default();
    let cut: Vec<NodeKey> = usage.iter().map(|(k, _)| *k).collect();
    let reached: Vec<NodeKey> = usage
        .iter()
        .filter(|(_, c)| *c > 0)
        .map(|(k, _)| *k)
        .collect();
    let oracle = reached.len().max(1);
    let oracle_cut = oracle_cut(&cut, &reached).max(1);
    println!(
        "  oracle (start view): {} bricks reached by a ray of {} in the unculled cut; smallest hole-free cut {}",
        reached.len(),
        cut.len(),
        oracle_cut
    );
    println!(
        "  {:<10} {:>8} {:>6} {:>9} {:>7} {:>8} {:>8} {:>8} {:>7} {:>7} {:>8} {:>8} {:>7} {:>5}",
        "policy",
        "ws_conv",
        "cut",
        "ws_med",
        "ws_pk",
        "MB_up",
        "conv_f",
        "ms/f",
        "host",
        "/orc",
        "/orccut",
        "psnr_s",
        "disocc",
        "jump"
    );
    let disocc = |t: &Track| {
        let (base_back, _) = base_back?;
        t.back_frames
            .iter()
            .position(|img| brickray_reference::psnr(img, base_back) >= SAME_DB)
            .map(|i| i + 1)
    };
    let jump = |t: &Track| {
        t.jump_frames
            .iter()
            .position(|img| brickray_reference::psnr(img, base_start) >= SAME_DB)
            .map(|i| i + 1)
    };
    let mut rows = Vec::new();
    for (p, t) in policies.iter().zip(tracks) {
        let (img, s) = t.start.as_ref().ok_or("no start image")?;
        let ws = s.cache.working_set_bricks as f64;
        let cut_frac = 1.0 - ws / (base_s.cache.working_set_bricks.max(1) as f64);
        // Back view: (working set, cut, PSNR), when it was run.
        let back = t
            .back
            .as_ref()
            .zip(base_back)
            .map(|((bimg, bs), (base_img, base_bs))| {
                let n = bs.cache.working_set_bricks;
                let cut = 1.0 - n as f64 / base_bs.cache.working_set_bricks.max(1) as f64;
                (n, cut, brickray_reference::psnr(bimg, base_img))
            });
        let psnr_s = brickray_reference::psnr(img, base_start);
        let d = disocc(t);
        let peak = t.working.iter().cloned().fold(0.0, f64::max);
        println!(
            "  {:<10} {:>8} {:>5.0}% {:>9.0} {:>7.0} {:>8.1} {:>8} {:>8.1} {:>7.2} {:>7.2} {:>8.2} {:>8.1} {:>7} {:>5}",
            p.name(),
            ws,
            cut_frac * 100.0,
            median(&t.working),
            peak,
            t.uploaded as f64 / 1e6,
            t.converge_start.map_or("-".into(), |f| f.to_string()),
            median(&t.ms),
            median(&t.host_ms),
            ws / oracle as f64,
            ws / oracle_cut as f64,
            psnr_s.min(999.0),
            d.map_or("-".into(), |f| f.to_string()),
            jump(t).map_or("-".into(), |f| f.to_string()),
        );
        rows.push(PolicyRow {
            policy: p.name(),
            working_set_converged: ws,
            working_set_back: back.map(|b| b.0 as u64),
            cut: r2(cut_frac),
            cut_back: back.map(|b| r2(b.1)),
            working_set_median: median(&t.working),
            working_set_peak: peak,
            uploaded_mb: r2(t.uploaded as f64 / 1e6),
            frames_to_converge: t.converge_start,
            ms_per_frame: r2(median(&t.ms)),
            host_ms_per_frame: r2(median(&t.host_ms)),
            gpu_ms_per_frame: (!t.gpu_ms.is_empty()).then(|| r2(median(&t.gpu_ms))),
            oracle_ratio: r2(ws / oracle as f64),
            oracle_cut_ratio: r2(ws / oracle_cut as f64),
            psnr_start_db: r2(psnr_s.min(999.0)),
            psnr_back_db: back.map(|b| r2(b.2.min(999.0))),
            disocclusion_frames: d,
            disocclusion_jump_frames: jump(t),
        });
    }
    Ok(SceneResult {
        scene: scene.name,
        kind: scene.kind,
        baseline_converged: base.converge_start.is_some(),
        oracle: reached.len(),
        oracle_cut,
        policies: rows,
    })
}

/// The headline figures over the scenes.
#[derive(Debug)]
pub(super) struct Headline {
    /// opaque occlusion, opaque ray-guided, translucent occlusion,
    /// translucent ray-guided.
    pub(super) cuts: [Option<f64>; 4],
    pub(super) oracle_ratio_best: Option<f64>,
    pub(super) oracle_cut_ratio_best: Option<f64>,
    pub(super) psnr_min: Option<f64>,
    pub(super) disocclusion_max: Option<usize>,
}

/// The headline figures over the scenes: worst cut per kind and policy, the
/// best oracle ratio on opaque scenes, the lowest PSNR of a culled policy, the
/// longest disocclusion latency.
pub(super) fn headline(scenes: &[SceneResult]) -> Headline {
    fn rows<'a>(s: &'a SceneResult, pol: &'a str) -> impl Iterator<Item = &'a PolicyRow> {
        s.policies.iter().filter(move |r| r.policy == pol)
    }
    let mut cuts = [None; 4];
    for (i, (kind, pol)) in [
        ("opaque", "occlusion"),
        ("opaque", "rayguided"),
        ("translucent", "occlusion"),
        ("translucent", "rayguided"),
    ]
    .into_iter()
    .enumerate()
    {
        // The smallest cut over the scenes of the kind (null when not run).
        cuts[i] = scenes
            .iter()
            .filter(|s| s.kind == kind)
            .flat_map(|s| rows(s, pol).map(|r| r.cut))
            .reduce(f64::min);
    }
    let culled = ["occlusion", "rayguided", "both"];
    let (mut oracle_ratio_best, mut oracle_cut_ratio_best) = (None::<f64>, None::<f64>);
    let (mut psnr_min, mut disocclusion_max) = (None::<f64>, None::<usize>);
    for s in scenes {
        let culled_rows = || s.policies.iter().filter(|r| culled.contains(&r.policy));
        // The better policy of the scene, then the worst scene.
        let best = culled_rows().map(|r| r.oracle_ratio).reduce(f64::min);
        let best_cut = culled_rows().map(|r| r.oracle_cut_ratio).reduce(f64::min);
        for r in culled_rows() {
            for p in std::iter::once(r.psnr_start_db).chain(r.psnr_back_db) {
                psnr_min = Some(psnr_min.map_or(p, |m| m.min(p)));
            }
            for d in r
                .disocclusion_frames
                .into_iter()
                .chain(r.disocclusion_jump_frames)
            {
                disocclusion_max = Some(disocclusion_max.map_or(d, |m| m.max(d)));
            }
        }
        if s.kind == "opaque" {
            if let Some(b) = best {
                oracle_ratio_best = Some(oracle_ratio_best.map_or(b, |m| m.max(b)));
            }
            if let Some(b) = best_cut {
                oracle_cut_ratio_best = Some(oracle_cut_ratio_best.map_or(b, |m| m.max(b)));
            }
        }
    }
    Headline {
        cuts,
        oracle_ratio_best,
        oracle_cut_ratio_best,
        psnr_min,
        disocclusion_max,
    }
}

/// Working set along the path, per scene and policy, as an SVG.
pub(super) fn write_chart(path: &str, chart: &[Chart]) -> Result<(), String> {
    use crate::chart::{Panel, Series};
    let panels: Vec<Panel> = chart
        .iter()
        .map(|(title, series)| {
            let mut p = Panel::new(
                title,
                "frame along the path (all policies interleaved)",
                "working-set bricks",
                series
                    .iter()
                    .map(|(name, ws)| Series::indexed(name.as_str(), ws.iter().copied()))
                    .collect(),
            );
            p.y_from_zero = true;
            p
        })
        .collect();
    crate::chart::draw(std::path::Path::new(path), 720, 260, &panels)
}
