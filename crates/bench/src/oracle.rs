//! `lod --by oracle`: how much any ranking of nodes could gain at equal brick
//! budgets, on the Pareto suite's scenes (its volumes, transfer functions and
//! view; GPU-free).
//!
//! Each node above the finest cut gets an *oracle* cost: the image's squared
//! error (summed over pixels and RGB, 8-bit units) when that one node is drawn
//! instead of its descendants, everything else at the finest cut, rendered by
//! the f64 reference. It is what keeping that node coarse costs the image,
//! exactly, not an estimate. Refinement then ranks nodes by it (passed to
//! `LodMetric::VisibleError` as the weight that makes weight x expected error
//! equal to it), under the same budgets of data leaves as the geometric order
//! and the visible order (`crate::visible`'s weights x
//! `brickray_core::node_visible_error`), and each cut's image is compared
//! with the finest cut's (PSNR, capped at 99). The suite also prints the rank
//! correlation (Spearman) of the visible order's priorities with the costs.
//!
//! The oracle is a greedy top-down ranking by single-node costs: the ideal
//! of every order the refiner can express (a priority per node), not of every
//! cut (costs interact where nodes overlap on screen). Where it gains little,
//! no per-node ranking gains much.
//!
//! `cargo run --release -p brickray-bench -- lod --by oracle --size 128
//! --brick 16 --scenes noise,ml,nuclei` (volumes of the pareto suite: ct,
//! ct5, mri, nuclei, ml, noise; every mode of each).

use crate::Figures;
use crate::cut::{CutView, Resampler, cut_volume, refine_cut, typed};
use crate::runner::{median, round2};
use brickray_core::{LodMetric, NodeKey, TfErrorTable, Volume, node_visible_error};
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use serde_json::json;
use std::collections::{HashMap, HashSet};

/// Fractions of the finest cut's data leaves compared.
const FRACTIONS: [f64; 9] = [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1];

/// Squared RGB error between two RGBA8 images (8-bit units).
fn sse(a: &[u8], b: &[u8]) -> f64 {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p[k] as f64 - q[k] as f64).powi(2))
                .sum::<f64>()
        })
        .sum()
}

/// Spearman's rank correlation of two samples (ties ranked by position).
fn spearman(a: &[f64], b: &[f64]) -> f64 {
    let rank = |v: &[f64]| {
        let mut idx: Vec<usize> = (0..v.len()).collect();
        idx.sort_by(|&i, &j| v[i].total_cmp(&v[j]));
        let mut r = vec![0.0; v.len()];
        for (pos, &i) in idx.iter().enumerate() {
            r[i] = pos as f64;
        }
        r
    };
    let (ra, rb) = (rank(a), rank(b));
    let m = (a.len() as f64 - 1.0) / 2.0;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in ra.iter().zip(&rb) {
        sab += (x - m) * (y - m);
        saa += (x - m) * (x - m);
        sbb += (y - m) * (y - m);
    }
    sab / (saa * sbb).sqrt()
}

pub(crate) fn run(size: u32, brick: u32, scenes: &str) -> Result<Figures, String> {
    let wanted: Vec<String> = scenes.split(',').map(str::to_string).collect();
    let scenes = crate::pareto::scenes(&wanted, crate::pareto::ML_SIDE)?;
    println!(
        "lod by oracle: {size}x{size}, bricks {brick}, budgets {FRACTIONS:?} of the finest cut; \
         PSNR against the finest cut's image (f64 reference, one ray per pixel)"
    );
    let mut fig = Figures::new();
    let (mut vis_all, mut oracle_all) = (Vec::new(), Vec::new());
    for scene in &scenes {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let path = dir.path().join("v.brs");
        scene.build_store(brick, &path)?;
        let store = brickray_store::open(&path).map_err(|e| e.to_string())?;
        let layout = store.layout().clone();
        for (mode_name, mode, tf) in &scene.modes {
            let name = format!("{}_{}", scene.name, mode_name);
            let t = std::time::Instant::now();
            let settings = crate::pareto::base_settings(*mode);
            let opts = ReferenceOptions::new(size, size);
            let draw = |v: &Volume| {
                render_reference(v, &scene.frame, tf, &scene.camera, &settings, &opts)
                    .to_rgba8([0.0; 3])
            };
            let view = CutView {
                store: &store,
                tf,
                mode: *mode,
                camera: &scene.camera,
                frame: &scene.frame,
                size,
                visible: None,
            };
            // The finest cut, its samples and its image.
            let finest = refine_cut(&view, 0.0, u32::MAX / 2, LodMetric::Geometric);
            let n = finest.data_leaves;
            let leaves: HashSet<NodeKey> = finest.leaves.iter().map(|l| l.key).collect();
            let mut resampler = Resampler::new(&store);
            let samples = resampler.resample(&leaves)?;
            let finest_rgba = draw(&typed(&layout, samples.clone())?);
            // Every node above the finest cut, and its oracle cost.
            let mut inner: HashSet<NodeKey> = HashSet::new();
            for k in &leaves {
                let mut p = layout.parent(*k);
                while let Some(q) = p {
                    if !inner.insert(q) {
                        break;
                    }
                    p = layout.parent(q);
                }
            }
            let table = TfErrorTable::new(tf);
            let norm = (layout.brick as f64).powi(2).max(1.0);
            let mut oracle: HashMap<NodeKey, f64> = HashMap::new();
            let mut unranked = 0;
            // (node, its cost, its per-sample expected error)
            let mut costs = Vec::new();
            for &k in &inner {
                let mut s = samples.clone();
                resampler.splice(k, &mut s)?;
                let cost = sse(&draw(&typed(&layout, s)?), &finest_rgba);
                let info = store.info(k).map_err(|e| e.to_string())?;
                // The refiner ranks by weight x 255 x expected error / brick^2
                // (unranked where the expected error is 0).
                let e = node_visible_error(&info, *mode, &table, &layout).unwrap_or(1.0);
                costs.push((k, cost, e));
                if e > 0.0 {
                    oracle.insert(k, cost * norm / (255.0 * e));
                } else if cost > 0.0 {
                    unranked += 1;
                }
            }
            let weights = brickray_reference::visible_weights(
                &scene.volume,
                &layout,
                &scene.frame,
                tf,
                &scene.camera,
                *mode,
                size,
            );
            let visible_priority: Vec<f64> = costs
                .iter()
                .map(|(k, _, e)| weights.get(k).copied().unwrap_or(0.0) * e)
                .collect();
            let cost: Vec<f64> = costs.iter().map(|c| c.1).collect();
            let rho = spearman(&cost, &visible_priority);
            println!(
                "\n{name}: finest cut {n} bricks, {} nodes above it costed ({unranked} with a cost \
                 but no expected error: the refiner cannot rank them) in {:.0} s; rank \
                 correlation of the visible order's priority with the cost {rho:.2}",
                inner.len(),
                t.elapsed().as_secs_f64()
            );
            fig.insert(
                format!("{name}_visible_rank_correlation"),
                round2(rho).into(),
            );
            println!(
                "  {:>7} {:>17} {:>17} {:>17} {:>8} {:>8}",
                "budget",
                "geometric b / dB",
                "visible b / dB",
                "oracle b / dB",
                "vis gain",
                "or gain"
            );
            let (mut vg, mut og, mut rows) = (Vec::new(), Vec::new(), Vec::new());
            for f in FRACTIONS {
                let budget = ((n as f64 * f).round() as u32).max(1);
                let one = |visible, metric| -> Result<(u32, f64), String> {
                    let v = CutView { visible, ..view };
                    let (vol, bricks, _) = cut_volume(&v, 0.0, budget, metric)?;
                    Ok((bricks, psnr(&draw(&vol), &finest_rgba).min(99.0)))
                };
                let by_error = LodMetric::VisibleError { budget: 0.0 };
                let (gb, gp) = one(None, LodMetric::Geometric)?;
                let (vb, vp) = one(Some(&weights), by_error)?;
                let (ob, op) = one(Some(&oracle), by_error)?;
                println!(
                    "  {budget:>7} {gb:>7} / {gp:>7.2} {vb:>7} / {vp:>7.2} {ob:>7} / {op:>7.2} {:>8.2} {:>8.2}",
                    vp - gp,
                    op - gp
                );
                vg.push(vp - gp);
                og.push(op - gp);
                rows.push(json!({"budget": budget, "geometric_bricks": gb,
                    "geometric_psnr_db": round2(gp), "visible_bricks": vb,
                    "visible_psnr_db": round2(vp), "oracle_bricks": ob,
                    "oracle_psnr_db": round2(op)}));
            }
            let (v, o) = (median(&vg), median(&og));
            println!(
                "  median gain over the geometric order: visible {v:+.2} dB, oracle {o:+.2} dB"
            );
            vis_all.push(v);
            oracle_all.push(o);
            fig.insert(format!("{name}_visible_gain_db"), round2(v).into());
            fig.insert(format!("{name}_oracle_gain_db"), round2(o).into());
            fig.insert(format!("{name}_points"), rows.into());
        }
    }
    let (v, o) = (median(&vis_all), median(&oracle_all));
    println!("\nmedian over the scenes: visible {v:+.2} dB, oracle {o:+.2} dB");
    fig.insert("visible_gain_db_at_equal_budget".into(), round2(v).into());
    fig.insert("oracle_gain_db_at_equal_budget".into(), round2(o).into());
    Ok(fig)
}
