//! The LOD oracle: what keeping one node coarse costs the image, exactly.
//!
//! Each node above the finest cut gets a cost: the image's squared error
//! (summed over pixels and RGB, 8-bit units, [`sse`]) when that one node is
//! drawn instead of its descendants ([`Resampler::splice`]), everything else
//! at the finest cut, against the finest cut's image. It is what keeping
//! that node coarse costs the image, not an estimate; a ranking of nodes by
//! it is the ideal of every order a refiner can express as a priority per
//! node (not of every cut: costs interact where nodes overlap on screen).
//! [`spearman`] compares other rankings with it.

use super::{LodModelError, Resampler, typed};
use brickray_core::{BrickSource, NodeKey, OctreeLayout, Volume};
use std::collections::{BTreeSet, HashSet};

/// A node above the finest cut and its oracle cost ([`node_costs`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeCost {
    /// The node.
    pub key: NodeKey,
    /// The squared RGB error ([`sse`]) of the image with this node drawn
    /// instead of its descendants, against the finest cut's image.
    pub cost: f64,
}

/// Every node above the cut `leaves`: each leaf's ancestors (the leaves
/// themselves only where one is another's ancestor), in key order.
pub fn nodes_above(layout: &OctreeLayout, leaves: &HashSet<NodeKey>) -> BTreeSet<NodeKey> {
    let mut inner = BTreeSet::new();
    for k in leaves {
        let mut p = layout.parent(*k);
        while let Some(q) = p {
            if !inner.insert(q) {
                break;
            }
            p = layout.parent(q);
        }
    }
    inner
}

/// The oracle cost of every node above the finest cut `finest_leaves` of
/// `source` ([`nodes_above`], in key order): `draw` renders a finest-grid
/// volume (in the source's type, [`typed`]) to an RGBA8 image, typically
/// [`render_reference`](crate::render_reference) composited with
/// [`Image::to_rgba8`](crate::Image::to_rgba8); the cost is the [`sse`] of
/// the image with the node spliced in against the image of the finest cut.
/// Every image must have the finest cut's size.
pub fn node_costs(
    source: &dyn BrickSource,
    finest_leaves: &HashSet<NodeKey>,
    draw: impl Fn(&Volume) -> Vec<u8>,
) -> Result<Vec<NodeCost>, LodModelError> {
    costs(source, finest_leaves, false, |v, _| draw(v))
}

/// [`node_costs`] with the levels drawn as the renderers draw a source with
/// spreads (docs/rendering-model.md, *Coarse levels*): `draw` also gets the
/// spread of every finest voxel ([`ReferenceOptions::with_spread`](crate::ReferenceOptions::with_spread)),
/// each node's spliced in with its values ([`Resampler::splice_spread`]);
/// those of the finest cut's leaves are 0 but where a leaf is coarser.
pub fn node_costs_spread(
    source: &dyn BrickSource,
    finest_leaves: &HashSet<NodeKey>,
    draw: impl Fn(&Volume, &[f32]) -> Vec<u8>,
) -> Result<Vec<NodeCost>, LodModelError> {
    costs(source, finest_leaves, true, |v, s| {
        draw(v, s.unwrap_or(&[]))
    })
}

fn costs(
    source: &dyn BrickSource,
    finest_leaves: &HashSet<NodeKey>,
    spread: bool,
    draw: impl Fn(&Volume, Option<&[f32]>) -> Vec<u8>,
) -> Result<Vec<NodeCost>, LodModelError> {
    let layout = source.layout();
    let mut resampler = Resampler::new(source)?;
    let samples = resampler.resample(finest_leaves)?;
    let spreads = match spread {
        true => Some(resampler.resample_spread(finest_leaves)?),
        false => None,
    };
    let finest_rgba = draw(&typed(layout, samples.clone())?, spreads.as_deref());
    nodes_above(layout, finest_leaves)
        .into_iter()
        .map(|key| {
            let mut s = samples.clone();
            resampler.splice(key, &mut s)?;
            let mut sp = spreads.clone();
            if let Some(sp) = sp.as_mut() {
                resampler.splice_spread(key, sp)?;
            }
            let rgba = draw(&typed(layout, s)?, sp.as_deref());
            if rgba.len() != finest_rgba.len() {
                return Err(LodModelError::ImageSize {
                    expected: finest_rgba.len(),
                    actual: rgba.len(),
                });
            }
            Ok(NodeCost {
                key,
                cost: sse(&rgba, &finest_rgba),
            })
        })
        .collect()
}

/// Squared RGB error between two RGBA8 images (8-bit units, alpha ignored),
/// over the pixels both hold.
pub fn sse(a: &[u8], b: &[u8]) -> f64 {
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p[k] as f64 - q[k] as f64).powi(2))
                .sum::<f64>()
        })
        .sum()
}

/// Spearman's rank correlation of two samples of equal length (ties ranked
/// by position): 1 for the same order, -1 for reversed ones. NaN where it is
/// undefined: samples of different lengths, fewer than two values.
pub fn spearman(a: &[f64], b: &[f64]) -> f64 {
    if a.len() != b.len() || a.len() < 2 {
        return f64::NAN;
    }
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
