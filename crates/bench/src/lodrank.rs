//! The `lodrank` suite (GPU-free): how well the refiner's priorities rank
//! nodes by what they cost the image, with coarse levels drawn as the TF of
//! their mean and with their spreads (docs/rendering-model.md, *Coarse
//! levels*; the model of the consistent classification).
//!
//! For each DVR scene of the pareto suite (its volume, transfer function,
//! camera and shading) the store is built with spreads, bricks of `--brick`
//! (16), and every node above the finest cut gets its exact cost to the
//! image (the LOD oracle, `brickray_reference::lod::node_costs`: the squared
//! RGB error of the f64 reference's image with that one node drawn instead
//! of its descendants, `--size` (64) px), once with the node drawn as the TF
//! of its values and once with its spreads
//! (`brickray_reference::lod::node_costs_spread`). The refiner's priority of
//! a node under `LodMetric::VisibleError` is its visible weight (the CPU
//! twin of the kernel's, `brickray_reference::visible_weights`) times its
//! per-sample error from the store's records
//! (`brickray_core::node_visible_error`); the suite prints Spearman's rank
//! correlation of the priorities with each set of costs, and of the two sets
//! of costs with each other.
//!
//! `cargo run --release -p brickray-bench -- lodrank [--size PX] [--brick N]
//! [--scenes ct,ct5,mri,nuclei,ml,noise]`

use brickray_core::{
    BrickSource, LodMetric, NodeKey, RenderMode, TfErrorTable, Volume, node_visible_error,
};
use brickray_reference::lod::{
    CutView, node_costs, node_costs_spread, nodes_above, refine_cut, spearman,
};
use brickray_reference::{ReferenceOptions, render_reference};
use serde::Serialize;
use std::collections::HashSet;
use std::time::Instant;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 64, value_parser = crate::image_side)]
    size: u32,
    /// Brick side of the stores.
    #[arg(long, default_value_t = 16)]
    brick: u32,
    /// Scenes (pareto's volumes), comma-separated.
    #[arg(long, default_value = "ct,ct5,mri,nuclei,ml,noise")]
    scenes: String,
    /// Side of the Marschner-Lobb volume.
    #[arg(long, default_value_t = 128)]
    ml_side: u32,
}

/// One scene's figures.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    scene: String,
    /// Data leaves of the finest cut, and the nodes above it (those ranked).
    finest_bricks: u32,
    nodes: usize,
    /// Spearman's rank correlation of the priorities with the costs, levels
    /// drawn as the TF of their values (`plain`) and with their spreads.
    rho_plain: f64,
    rho_spread: f64,
    /// Of the two sets of costs with each other.
    rho_costs: f64,
    /// The costs summed over the nodes, spreads over plain.
    cost_ratio: f64,
    seconds: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct LodRankResult {
    size: u32,
    brick: u32,
    rows: Vec<Row>,
    rho_plain_median: f64,
    rho_spread_median: f64,
}

pub(crate) fn run(a: &Args) -> Result<LodRankResult, String> {
    let wanted: Vec<String> = a.scenes.split(',').map(str::to_string).collect();
    let scenes = crate::pareto::scenes(&wanted, a.ml_side)?;
    println!(
        "lodrank: {0}x{0} px, bricks of {1}; Spearman's rank correlation of the \
         visible-error priority with each node's exact cost",
        a.size, a.brick
    );
    println!(
        "| scene | finest bricks | nodes ranked | rho, TF of the mean | rho, spreads | \
         rho, costs with each other | cost, spreads / mean | s |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut rows = Vec::new();
    for scene in &scenes {
        for (mode_name, mode, tf) in &scene.modes {
            if !matches!(mode, RenderMode::Dvr) {
                continue;
            }
            let t = Instant::now();
            let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
            let path = dir.path().join("v.brs");
            scene.build_store_with(a.brick, &path, true)?;
            let store = brickray_store::open(&path).map_err(|e| e.to_string())?;
            let layout = store.layout().clone();
            let settings = crate::pareto::base_settings(*mode);
            let view = CutView {
                source: &store,
                tf,
                mode: *mode,
                camera: &scene.camera,
                frame: &scene.frame,
                size: a.size,
                visible: None,
            };
            let finest = refine_cut(&view, 0.0, u32::MAX / 2, LodMetric::Geometric)
                .map_err(|e| e.to_string())?;
            let leaves: HashSet<NodeKey> = finest.leaves.iter().map(|l| l.key).collect();
            let draw = |v: &Volume, spread: Option<&[f32]>| {
                let opts = ReferenceOptions::new(a.size, a.size);
                let opts = match spread {
                    Some(s) => opts.with_spread(s),
                    None => opts,
                };
                render_reference(v, &scene.frame, tf, &scene.camera, &settings, &opts)
                    .to_rgba8([0.0; 3])
            };
            let plain =
                node_costs(&store, &leaves, |v| draw(v, None)).map_err(|e| e.to_string())?;
            let spread = node_costs_spread(&store, &leaves, |v, s| draw(v, Some(s)))
                .map_err(|e| e.to_string())?;
            let weights = brickray_reference::visible_weights(
                &scene.volume,
                &layout,
                &scene.frame,
                tf,
                &scene.camera,
                *mode,
                a.size,
            );
            let table = TfErrorTable::new(tf);
            let mut priority = Vec::new();
            for key in nodes_above(&layout, &leaves) {
                let info = store.node(key).map_err(|e| e.to_string())?;
                let e = node_visible_error(&info, *mode, &table, &layout).unwrap_or(1.0);
                priority.push(weights.get(&key).copied().unwrap_or(0.0) * e);
            }
            let c_plain: Vec<f64> = plain.iter().map(|c| c.cost).collect();
            let c_spread: Vec<f64> = spread.iter().map(|c| c.cost).collect();
            let sum = |v: &[f64]| v.iter().sum::<f64>();
            let row = Row {
                scene: format!("{}_{}", scene.name, mode_name),
                finest_bricks: finest.data_leaves,
                nodes: c_plain.len(),
                rho_plain: round3(spearman(&c_plain, &priority)),
                rho_spread: round3(spearman(&c_spread, &priority)),
                rho_costs: round3(spearman(&c_plain, &c_spread)),
                cost_ratio: round3(sum(&c_spread) / sum(&c_plain).max(f64::MIN_POSITIVE)),
                seconds: t.elapsed().as_secs_f64().round(),
            };
            println!(
                "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.0} |",
                row.scene,
                row.finest_bricks,
                row.nodes,
                row.rho_plain,
                row.rho_spread,
                row.rho_costs,
                row.cost_ratio,
                row.seconds
            );
            rows.push(row);
        }
    }
    let median = |f: fn(&Row) -> f64| {
        let v: Vec<f64> = rows.iter().map(f).collect();
        round3(crate::report::median_or_nan(&v))
    };
    Ok(LodRankResult {
        size: a.size,
        brick: a.brick,
        rho_plain_median: median(|r| r.rho_plain),
        rho_spread_median: median(|r| r.rho_spread),
        rows,
    })
}

fn round3(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}
