//! What the image shows of each octree node, measured on the CPU from the
//! finest data ([`visible_weights`]): for every pixel's ray, the
//! transmittance-weighted length through each node (finest voxels), summed
//! over pixels, at the default step. An isosurface ray counts its length up
//! to its first sample inside; a MIP ray only its length through the nodes
//! that hold its maximum, the sample that decides its pixel. It is the
//! measure `RefineEnv::visible_weight` asks a renderer for (the out-of-core
//! kernel measures it per brick, `shaders/feedback.wgsl`), taken here without
//! a GPU: the CPU twin of that measure (`tests/gpu_weights.rs` compares them)
//! and the benchmarks' visibility-weighted order.

use brickray_core::tf::corrected_alpha;
use brickray_core::{
    Camera, NodeKey, OctreeLayout, RenderMode, TransferFunction, Volume, VolumeFrame,
};
use std::collections::HashMap;

/// Transmittance below which a ray counts as stopped: the reference images
/// the suite compares have no early ray termination, so neither has the
/// weight (at the renderers' 0.99 the nodes behind it weigh nothing, yet change
/// the reference image by up to 1%: 2.7 dB lost at the finest budget of the
/// MRI).
const STOP: f64 = 1e-4;

/// The visible weight of every node any ray reaches (see the module docs).
pub fn visible_weights(
    vol: &Volume,
    layout: &OctreeLayout,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    camera: &Camera,
    mode: RenderMode,
    size: u32,
) -> HashMap<NodeKey, f64> {
    let step = 0.5f64;
    let dims = vol.dims().map(f64::from);
    let rays = camera.rays(1.0);
    let inv_model = frame.model.as_dmat4().inverse();
    let dt = step * frame.voxel_world as f64;
    let b = layout.brick as f64;
    // Per level: nodes per axis and the finest voxels a node spans per axis.
    let levels: Vec<([usize; 3], [f64; 3])> = (0..layout.levels)
        .map(|l| {
            let f = layout.voxel_factor(l);
            let n = std::array::from_fn(|a| (dims[a] / (b * f[a])).ceil().max(1.0) as usize);
            (n, std::array::from_fn(|a| b * f[a]))
        })
        .collect();
    let mut acc: Vec<Vec<f64>> = levels
        .iter()
        .map(|(n, _)| vec![0.0; n[0] * n[1] * n[2]])
        .collect();
    let mip = matches!(mode, RenderMode::Mip);
    let iso = match mode {
        RenderMode::Iso { value, .. } => Some(value as f64),
        _ => None,
    };
    for py in 0..size {
        for px in 0..size {
            let ray = rays.pixel_ray(&inv_model, px as f64, py as f64, size, size);
            let Some((t0, t1)) = ray.clip_unit_box() else {
                continue;
            };
            let mut trans = 1.0f64;
            let mut k = 0u64;
            // MIP: the ray's maximum and where it lies.
            let mut best = (f64::NEG_INFINITY, [0.0; 3]);
            loop {
                let t = t0 + k as f64 * dt;
                if t >= t1 || trans < STOP {
                    break;
                }
                k += 1;
                let u = ray.tex_origin + ray.tex_dir * t;
                let pos = [u.x * dims[0], u.y * dims[1], u.z * dims[2]];
                let v = vol.sample_trilinear([pos[0] - 0.5, pos[1] - 0.5, pos[2] - 0.5]);
                if mip {
                    if v > best.0 {
                        best = (v, pos);
                    }
                    continue;
                }
                for (l, (n, span)) in levels.iter().enumerate() {
                    acc[l][node_index(pos, n, span)] += trans * step;
                }
                match iso {
                    Some(value) => {
                        if v >= value {
                            break;
                        }
                    }
                    None => trans *= 1.0 - corrected_alpha(tf.lookup(v)[3], step),
                }
            }
            // A MIP ray counts its length through the nodes that hold its
            // maximum only: the samples there are what decide its pixel.
            if mip && best.0 > f64::NEG_INFINITY {
                let held: Vec<usize> = levels
                    .iter()
                    .map(|(n, span)| node_index(best.1, n, span))
                    .collect();
                for j in 0..k {
                    let u = ray.tex_origin + ray.tex_dir * (t0 + j as f64 * dt);
                    let pos = [u.x * dims[0], u.y * dims[1], u.z * dims[2]];
                    for (l, (n, span)) in levels.iter().enumerate() {
                        if node_index(pos, n, span) == held[l] {
                            acc[l][held[l]] += step;
                        }
                    }
                }
            }
        }
    }
    let mut out = HashMap::new();
    for (l, ((n, _), a)) in levels.iter().zip(&acc).enumerate() {
        for z in 0..n[2] {
            for y in 0..n[1] {
                for x in 0..n[0] {
                    let w = a[x + n[0] * (y + n[1] * z)];
                    if w > 0.0 {
                        out.insert(NodeKey::new(l as u8, x as u32, y as u32, z as u32), w);
                    }
                }
            }
        }
    }
    out
}

/// The index, within its level's grid of `n` nodes spanning `span` finest
/// voxels each, of the node holding `pos` (finest voxels).
fn node_index(pos: [f64; 3], n: &[usize; 3], span: &[f64; 3]) -> usize {
    let i: [usize; 3] =
        std::array::from_fn(|a| ((pos[a] / span[a]).floor().max(0.0) as usize).min(n[a] - 1));
    i[0] + n[0] * (i[1] + n[1] * i[2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::synthetic;

    fn weights(tf: &TransferFunction) -> (OctreeLayout, HashMap<NodeKey, f64>) {
        let vol = synthetic::sphere(32);
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.0, 0.0);
        let w = visible_weights(&vol, &layout, &frame, tf, &camera, RenderMode::Dvr, 32);
        (layout, w)
    }

    /// The weight is a sum over ray samples, so a node's is its children's
    /// summed; an opaque TF takes weight from the nodes behind the ones in
    /// front, and a clear one leaves every node its ray length.
    #[test]
    fn weights_add_up_and_opacity_hides() {
        let clear = TransferFunction::from_points(
            &[(0.0, [1.0, 1.0, 1.0, 0.0]), (1.0, [1.0, 1.0, 1.0, 0.0])],
            16,
        );
        let opaque = TransferFunction::from_points(&[(0.0, [1.0; 4]), (1.0, [1.0; 4])], 16);
        for tf in [&clear, &opaque] {
            let (layout, w) = weights(tf);
            for l in 0..layout.levels - 1 {
                for (k, &v) in w.iter().filter(|(k, _)| k.level == l) {
                    let sum: f64 = k.children().iter().filter_map(|c| w.get(c)).sum();
                    assert!(
                        (sum - v).abs() <= 1e-9 * v.max(1.0),
                        "{k:?}: {v} vs children {sum}"
                    );
                }
            }
        }
        let (_, wc) = weights(&clear);
        let (_, wo) = weights(&opaque);
        let total = |w: &HashMap<NodeKey, f64>| w.get(&NodeKey::ROOT).copied().unwrap_or(0.0);
        assert!(
            total(&wo) < 0.1 * total(&wc),
            "opaque {} clear {}",
            total(&wo),
            total(&wc)
        );
        // The camera looks along an axis: of the eight level-1 nodes the four
        // nearer it keep their weight, the four behind them get none.
        let level1 = |w: &HashMap<NodeKey, f64>| -> Vec<f64> {
            NodeKey::ROOT
                .children()
                .iter()
                .map(|c| w.get(c).copied().unwrap_or(0.0))
                .collect()
        };
        let (c1, o1) = (level1(&wc), level1(&wo));
        assert!(c1.iter().all(|&v| v > 0.0), "clear: {c1:?}");
        assert!(
            o1.iter().filter(|&&v| v < 1e-6 * total(&wo)).count() >= 4,
            "opaque: {o1:?}"
        );
    }

    /// A MIP ray counts only its length through the nodes that hold its
    /// maximum: the root still gets every ray's whole length (as under a
    /// clear transfer function), and so does the level-1 node of a ball (every
    /// ray that crosses it peaks in it), but the node in front of the ball's
    /// along the view keeps less than half its clear weight (measured: 26%):
    /// its rays that go on through the ball count there. (Rays that see
    /// nothing count at their entry, where their first sample is their
    /// maximum.)
    #[test]
    fn mip_weights_go_to_the_maximum() {
        let vol = synthetic::u8_field(32, |[x, y, z]| {
            let d =
                ((x as f64 - 8.0).powi(2) + (y as f64 - 8.0).powi(2) + (z as f64 - 8.0).powi(2))
                    .sqrt();
            1.0 - d / 12.0
        });
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        // Looking down z from above the volume (z = 1 is the near half).
        let camera = Camera::orbit(frame.center(), 2.0, 0.0, 0.0);
        let clear = TransferFunction::from_points(
            &[(0.0, [1.0, 1.0, 1.0, 0.0]), (1.0, [1.0, 1.0, 1.0, 0.0])],
            16,
        );
        let at = |mode| visible_weights(&vol, &layout, &frame, &clear, &camera, mode, 32);
        let (mip, dvr) = (at(RenderMode::Mip), at(RenderMode::Dvr));
        let get = |w: &HashMap<NodeKey, f64>, k: NodeKey| w.get(&k).copied().unwrap_or(0.0);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
        let root = NodeKey::ROOT;
        assert!(get(&dvr, root) > 0.0);
        assert!(close(get(&mip, root), get(&dvr, root)));
        let ball = NodeKey::new(1, 0, 0, 0);
        assert!(get(&dvr, ball) > 0.0);
        assert!(
            close(get(&mip, ball), get(&dvr, ball)),
            "ball {} of {}",
            get(&mip, ball),
            get(&dvr, ball)
        );
        let front = NodeKey::new(1, 0, 0, 1);
        assert!(
            get(&mip, front) < 0.5 * get(&dvr, front),
            "in front of the ball: {} of {}",
            get(&mip, front),
            get(&dvr, front)
        );
    }
}
