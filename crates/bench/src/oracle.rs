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
//! ct5, mri, nuclei, ml, noise; every mode of each). Diagnostics:
//! `--nodes FILE.csv` writes every costed node (scene, level, position, cost,
//! per-sample expected error, visible weight) for fits against other
//! estimates; `--costs off` skips the oracle (its columns read NaN), which
//! makes the visible and geometric orders cheap to compare at large sizes;
//! `--shading off` draws DVR unshaded, to see what shading adds to the costs.
//! `--octants on` adds three cuts a budget: the per-node order by each
//! node's error measured on the data (`crate::octant::data_error`) instead
//! of the store's estimate, and octant-granular cuts (`crate::octant`)
//! ranked by the store's per-node errors and by per-octant errors measured
//! on the data: whether a better estimate or a finer-grained cut is what the
//! per-node order lacks.

use crate::Figures;
use crate::cut::{CutView, Resampler, cut_volume, refine_cut, typed};
use crate::runner::{median, round2};
use brickray_core::{LodMetric, NodeKey, TfErrorTable, Volume, node_visible_error};
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use serde_json::json;
use std::collections::{HashMap, HashSet};

/// Fractions of the finest cut's data leaves compared.
const FRACTIONS: [f64; 9] = [0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1];

/// Figure names of `--octants`' three orders: per-node by errors measured
/// on the data, octant-granular by the store's errors and by the data's.
const OCTANT_KEYS: [&str; 3] = ["node_data", "octant_store", "octant_data"];

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

/// What `lod --by oracle` runs.
pub(crate) struct OracleOptions {
    pub(crate) size: u32,
    pub(crate) brick: u32,
    pub(crate) scenes: String,
    /// Voxels per side of the procedural volumes (`ml`, `noise`).
    pub(crate) ml_side: u32,
    /// Cost every node (the oracle order); off: geometric and visible only.
    pub(crate) costs: bool,
    /// DVR shaded, as the pareto suite draws it.
    pub(crate) shading: bool,
    /// Where to write the per-node CSV, if anywhere.
    pub(crate) nodes: Option<std::path::PathBuf>,
    /// Octant-granular cuts (`crate::octant`) and the per-node order by
    /// errors measured on the data.
    pub(crate) octants: bool,
}

impl OracleOptions {
    pub(crate) fn parse(
        args: &[String],
        size: u32,
        brick: u32,
        scenes: &str,
        ml_side: u32,
    ) -> Result<Self, String> {
        let on_off = |name: &str, default: &str| -> Result<bool, String> {
            match crate::arg(args, name, default.to_string())?.as_str() {
                "on" => Ok(true),
                "off" => Ok(false),
                other => Err(format!("{name} {other}: on or off")),
            }
        };
        let nodes: String = crate::arg(args, "--nodes", String::new())?;
        Ok(OracleOptions {
            size,
            brick,
            scenes: scenes.to_string(),
            ml_side,
            costs: on_off("--costs", "on")?,
            shading: on_off("--shading", "on")?,
            nodes: (!nodes.is_empty()).then(|| nodes.into()),
            octants: on_off("--octants", "off")?,
        })
    }
}

pub(crate) fn run(o: &OracleOptions) -> Result<Figures, String> {
    let (size, brick) = (o.size, o.brick);
    let wanted: Vec<String> = o.scenes.split(',').map(str::to_string).collect();
    let scenes = crate::pareto::scenes(&wanted, o.ml_side)?;
    println!(
        "lod by oracle: {size}x{size}, bricks {brick}, budgets {FRACTIONS:?} of the finest cut; \
         PSNR against the finest cut's image (f64 reference, one ray per pixel)"
    );
    if !o.costs {
        println!("  --costs off: no oracle order (its columns read NaN)");
    }
    if !o.shading {
        println!("  --shading off: DVR unshaded");
    }
    let mut csv = String::from("scene,level,x,y,z,cost,expected_error,visible_weight\n");
    let mut fig = Figures::new();
    let (mut vis_all, mut oracle_all) = (Vec::new(), Vec::new());
    let mut octant_all: [Vec<f64>; 3] = Default::default();
    for scene in &scenes {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let path = dir.path().join("v.brs");
        scene.build_store(brick, &path)?;
        let store = brickray_store::open(&path).map_err(|e| e.to_string())?;
        let layout = store.layout().clone();
        for (mode_name, mode, tf) in &scene.modes {
            let name = format!("{}_{}", scene.name, mode_name);
            let t = std::time::Instant::now();
            let mut settings = crate::pareto::base_settings(*mode);
            settings.shading.enabled &= o.shading;
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
            // Without costs (--costs off) every node's cost reads NaN.
            for &k in &inner {
                let cost = if o.costs {
                    let mut s = samples.clone();
                    resampler.splice(k, &mut s)?;
                    sse(&draw(&typed(&layout, s)?), &finest_rgba)
                } else {
                    f64::NAN
                };
                let info = store.info(k).map_err(|e| e.to_string())?;
                // The refiner ranks by weight x 255 x expected error / brick^2
                // (unranked where the expected error is 0).
                let e = node_visible_error(&info, *mode, &table, &layout).unwrap_or(1.0);
                costs.push((k, cost, e));
                if e > 0.0 && o.costs {
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
            for (k, c, e) in &costs {
                let w = weights.get(k).copied().unwrap_or(0.0);
                let (l, x, y, z) = (k.level, k.x, k.y, k.z);
                csv.push_str(&format!("{name},{l},{x},{y},{z},{c:.6e},{e:.6e},{w:.6e}\n"));
            }
            println!(
                "\n{name}: finest cut {n} bricks, {} nodes above it, in {:.0} s",
                inner.len(),
                t.elapsed().as_secs_f64()
            );
            if o.costs {
                let visible_priority: Vec<f64> = costs
                    .iter()
                    .map(|(k, _, e)| weights.get(k).copied().unwrap_or(0.0) * e)
                    .collect();
                let cost: Vec<f64> = costs.iter().map(|c| c.1).collect();
                let rho = spearman(&cost, &visible_priority);
                println!(
                    "  {unranked} with a cost but no expected error (the refiner cannot rank \
                     them); rank correlation of the visible order's priority with the cost {rho:.2}"
                );
                fig.insert(
                    format!("{name}_visible_rank_correlation"),
                    round2(rho).into(),
                );
            }
            println!(
                "  {:>7} {:>17} {:>17} {:>17} {:>8} {:>8}",
                "budget",
                "geometric b / dB",
                "visible b / dB",
                "oracle b / dB",
                "vis gain",
                "or gain"
            );
            // With --octants: each node's error measured on the data, as
            // the weight that makes the refiner's weight x expected error
            // equal to visible weight x measured error.
            let data_weights = if o.octants {
                println!(
                    "  {:>7} {:>17} {:>17} {:>17} {:>8} {:>8} {:>8}",
                    "",
                    "node (data) b/dB",
                    "oct (store) b/dB",
                    "oct (data) b/dB",
                    "gain",
                    "gain",
                    "gain"
                );
                let mut r = Resampler::new(&store);
                let mut dw: HashMap<NodeKey, f64> = HashMap::new();
                for (k, _, e) in &costs {
                    let measured =
                        crate::octant::data_error(&mut r, *k, *k, *mode, &table, &scene.volume)?;
                    if *e > 0.0 {
                        dw.insert(*k, weights.get(k).copied().unwrap_or(0.0) * measured / e);
                    }
                }
                Some(dw)
            } else {
                None
            };
            let mut octant_gains: [Vec<f64>; 3] = Default::default();
            let mut octant_rows = Vec::new();
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
                let (ob, op) = if o.costs {
                    one(Some(&oracle), by_error)?
                } else {
                    (0, f64::NAN)
                };
                println!(
                    "  {budget:>7} {gb:>7} / {gp:>7.2} {vb:>7} / {vp:>7.2} {ob:>7} / {op:>7.2} {:>8.2} {:>8.2}",
                    vp - gp,
                    op - gp
                );
                if let Some(dw) = &data_weights {
                    // The per-node order by errors measured on the data, and
                    // octant-granular cuts by the store's and the data's.
                    let (nb, np) = one(Some(dw), by_error)?;
                    let octant = |error| -> Result<(u32, f64), String> {
                        let (set, bricks) =
                            crate::octant::octant_cut(&store, *mode, tf, &weights, budget, error)?;
                        let s = Resampler::new(&store).resample_deepest(&set)?;
                        Ok((
                            bricks,
                            psnr(&draw(&typed(&layout, s)?), &finest_rgba).min(99.0),
                        ))
                    };
                    let (sb, sp) = octant(crate::octant::OctantError::Store)?;
                    let (db, dp) = octant(crate::octant::OctantError::Data(&scene.volume))?;
                    println!(
                        "  {:>7} {nb:>7} / {np:>7.2} {sb:>7} / {sp:>7.2} {db:>7} / {dp:>7.2} {:>8.2} {:>8.2} {:>8.2}",
                        "",
                        np - gp,
                        sp - gp,
                        dp - gp
                    );
                    for (g, p) in octant_gains.iter_mut().zip([np, sp, dp]) {
                        g.push(p - gp);
                    }
                    octant_rows.push(json!({"budget": budget, "node_data_bricks": nb,
                        "node_data_psnr_db": round2(np), "octant_store_bricks": sb,
                        "octant_store_psnr_db": round2(sp), "octant_data_bricks": db,
                        "octant_data_psnr_db": round2(dp)}));
                }
                vg.push(vp - gp);
                if o.costs {
                    og.push(op - gp);
                }
                rows.push(json!({"budget": budget, "geometric_bricks": gb,
                    "geometric_psnr_db": round2(gp), "visible_bricks": vb,
                    "visible_psnr_db": round2(vp), "oracle_bricks": ob,
                    "oracle_psnr_db": round2(op)}));
            }
            let v = median(&vg);
            println!("  median gain over the geometric order: visible {v:+.2} dB");
            vis_all.push(v);
            fig.insert(format!("{name}_visible_gain_db"), round2(v).into());
            if o.costs {
                let om = median(&og);
                println!("  median gain over the geometric order: oracle {om:+.2} dB");
                oracle_all.push(om);
                fig.insert(format!("{name}_oracle_gain_db"), round2(om).into());
            }
            fig.insert(format!("{name}_points"), rows.into());
            if o.octants {
                let m = octant_gains.each_ref().map(|g| median(g));
                println!(
                    "  median gain over the geometric order: per-node (data) {:+.2} dB, octants \
                     (store) {:+.2} dB, octants (data) {:+.2} dB",
                    m[0], m[1], m[2]
                );
                for (all, (key, v)) in octant_all.iter_mut().zip(OCTANT_KEYS.iter().zip(m)) {
                    all.push(v);
                    fig.insert(format!("{name}_{key}_gain_db"), round2(v).into());
                }
                fig.insert(format!("{name}_octant_points"), octant_rows.into());
            }
        }
    }
    if let Some(path) = &o.nodes {
        std::fs::write(path, csv).map_err(|e| format!("{}: {e}", path.display()))?;
        println!("per-node costs written to {}", path.display());
    }
    let v = median(&vis_all);
    println!("\nmedian over the scenes: visible {v:+.2} dB");
    fig.insert("visible_gain_db_at_equal_budget".into(), round2(v).into());
    if o.costs {
        let or = median(&oracle_all);
        println!("median over the scenes: oracle {or:+.2} dB");
        fig.insert("oracle_gain_db_at_equal_budget".into(), round2(or).into());
    }
    if o.octants {
        let m = octant_all.each_ref().map(|g| median(g));
        println!(
            "median over the scenes: per-node (data) {:+.2} dB, octants (store) {:+.2} dB, \
             octants (data) {:+.2} dB",
            m[0], m[1], m[2]
        );
        for (key, v) in OCTANT_KEYS.iter().zip(m) {
            fig.insert(format!("{key}_gain_db_at_equal_budget"), round2(v).into());
        }
    }
    Ok(fig)
}
