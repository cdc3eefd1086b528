// In-core single-pass ray caster (compute), after common.wgsl and modes.wgsl.
// Krueger-Westermann 2003 accelerations: early ray termination and empty-space
// skipping over a min/max macro-cell grid, classified per transfer function by
// the opacity prefix-sum table. See docs/rendering-model.md.

// Group 2: the in-core volume (`InCore` in backend/incore.rs; a test checks the
// offsets).
struct VolumeParams {
    // Voxel dimensions.
    dims: vec3<f32>,
    // normalized = texel * value_scale + value_offset.
    value_scale: f32,
    // Macro cells per axis.
    cells: vec3<u32>,
    // Macro-cell side in voxels.
    cell_size: u32,
    value_offset: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

@group(2) @binding(0) var<uniform> vol: VolumeParams;
@group(2) @binding(1) var volume_tex: texture_3d<f32>;
@group(2) @binding(2) var volume_sampler: sampler;
// Normalized min/max of every macro cell (x fastest).
@group(2) @binding(3) var<storage, read> cell_ranges: array<vec2<f32>>;
// Per macro cell, for the current TF (DVR) or isovalue (iso): the Chebyshev
// distance in cells to the nearest cell that can contribute, 0 for those
// (MacroCellGrid::empty_distance); MIP reads the ranges instead.
@group(2) @binding(4) var<storage, read> cell_skip: array<u32>;
// Per-voxel gradients (gradients.wgsl; a 1x1x1 stand-in until a shaded DVR
// frame makes them), read with GRADIENTS.
@group(2) @binding(5) var gradient_tex: texture_3d<f32>;

fn sample_value(u: vec3<f32>) -> f32 {
    if LABELS {
        return label_texel(volume_tex, u, vol.dims) * vol.value_scale + vol.value_offset;
    }
    return textureSampleLevel(volume_tex, volume_sampler, u, 0.0).r * vol.value_scale + vol.value_offset;
}

// World-space gradient direction (unnormalized) and the voxel-space magnitude
// (a smooth label map: of its boundary's indicator): the central difference of
// the trilinear field one voxel apart, six taps, or with GRADIENTS one read of
// the per-voxel gradients, which interpolate to the same (gradients.wgsl).
fn gradient(u: vec3<f32>) -> vec4<f32> {
    if (LABELS && SMOOTH_LABELS) {
        let g = label_gradient(volume_tex, u, vol.dims);
        return vec4<f32>(frame.normal_mat * (g * vol.dims), length(g));
    }
    if (GRADIENTS) {
        // Within half a voxel of a face the six taps clamp their positions
        // where the per-voxel differences clamp their indices: there the
        // taps' difference along that axis falls linearly to half of the
        // nearest voxel's at the face (and to 0 half a voxel outside), which
        // this factor reproduces exactly.
        let x = u * vol.dims;
        let edge = clamp(min(x + 0.5, vol.dims + 0.5 - x), vec3<f32>(0.0), vec3<f32>(1.0));
        let g = textureSampleLevel(gradient_tex, volume_sampler, u, 0.0).xyz * edge;
        return vec4<f32>(frame.normal_mat * (g * vol.dims), length(g));
    }
    let e = 1.0 / vol.dims;
    let gx = (sample_value(u + vec3<f32>(e.x, 0.0, 0.0)) - sample_value(u - vec3<f32>(e.x, 0.0, 0.0))) * 0.5;
    let gy = (sample_value(u + vec3<f32>(0.0, e.y, 0.0)) - sample_value(u - vec3<f32>(0.0, e.y, 0.0))) * 0.5;
    let gz = (sample_value(u + vec3<f32>(0.0, 0.0, e.z)) - sample_value(u - vec3<f32>(0.0, 0.0, e.z))) * 0.5;
    let g = vec3<f32>(gx, gy, gz);
    return vec4<f32>(frame.normal_mat * (g * vol.dims), length(g));
}

// In core a sample depends on the ray alone.
struct Cursor {
    r: Ray,
}

fn cursor_value(c: Cursor, t: f32) -> f32 {
    return sample_value(tex_at(c.r, t));
}

// No spreads in this kernel (modes.wgsl's SPREAD is off): every sample is
// classified as the TF of its value.
fn cursor_spread(c: Cursor, t: f32) -> f32 {
    return 0.0;
}

fn cursor_gradient(c: Cursor, t: f32) -> vec4<f32> {
    return gradient(tex_at(c.r, t));
}

fn cell_of(u: vec3<f32>) -> vec3<u32> {
    let c = floor(u * vol.dims / f32(vol.cell_size));
    return vec3<u32>(clamp(c, vec3<f32>(0.0), vec3<f32>(vol.cells) - 1.0));
}

fn cell_index(c: vec3<u32>) -> u32 {
    return (c.z * vol.cells.y + c.y) * vol.cells.x + c.x;
}

fn cell_range(c: vec3<u32>) -> vec2<f32> {
    return cell_ranges[cell_index(c)];
}

// t at which the ray leaves the cube of macro cells within `reach - 1` of cell c
// (reach 1: the cell itself; `inv_dir`: safe_inverse(r.tex_dir)).
fn cell_exit(r: Ray, inv_dir: vec3<f32>, c: vec3<u32>, reach: u32) -> f32 {
    let s = f32(vol.cell_size) / vol.dims;
    let lo = (vec3<f32>(c) - f32(reach - 1u)) * s;
    let hi = (vec3<f32>(c) + f32(reach)) * s;
    return box_exit(r.tex_origin, r.tex_dir, inv_dir, lo, hi);
}

// The iso march from the ray start at step `dt`, skipping macro cells below the
// isovalue when `ess`: the one in-core iso loop. The kernel's iso mode is it at
// frame.dt; the prediction buffer's full traversal too, and its sparse one at
// pred.sparse_dt (incore_predict.wgsl). A cell is skipped when its values are
// all below the isovalue: a crossing needs a value at or above it, and the
// bracket's lower end may lie in the skipped cell.
fn iso_march(acc: ptr<function, Accum>, r: Ray, t0: f32, t1: f32, dt: f32, ess: bool) {
    let inv_dir = safe_inverse(r.tex_dir);
    let n = min(first_k_after(t1, t0, dt), frame.max_samples);
    var k = 0u;
    var k_cell = 0u;
    loop {
        if (k >= n) { break; }
        let t = grid_t(t0, k, dt);
        if (t >= t1) { break; }
        let u = tex_at(r, t);
        if (ess && k >= k_cell) {
            // A cell at skip distance d > 0 lies in an empty cube of side
            // 2d - 1, skipped with one test.
            let c = cell_of(u);
            let d = cell_skip[cell_index(c)];
            let k_exit = max(k + 1u, first_k_after(cell_exit(r, inv_dir, c, max(d, 1u)), t0, dt));
            if (d > 0u) {
                k = k_exit;
                continue;
            }
            k_cell = k_exit;
        }
        let v = sample_value(u);
        (*acc).samples = (*acc).samples + 1u;
        if (v >= frame.isovalue) {
            // The first sample inside is a capped cut, else the crossing
            // lies since the previous sample.
            iso_bracket(acc, select(t - dt, t, k == 0u), t);
            break;
        }
        k = k + 1u;
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = tile_pixel(wg.xy, li);
    if (px.x >= frame.viewport_size.x || px.y >= frame.viewport_size.y) {
        return;
    }
    let start = start_ray(px);
    // Iso with the prediction buffer: incore_predict.wgsl (an override: pipelines
    // without prediction compile none of it).
    if (MODE == MODE_ISO && PREDICT) {
        predict_ray(px, start);
        return;
    }
    let r = start.r;
    let t0 = start.t0;
    let t1 = start.t1;
    var acc = accum_new();
    let cur = Cursor(r);
    if (MODE == MODE_ISO && t1 > t0) {
        iso_march(&acc, r, t0, t1, frame.dt, ESS);
    } else if (t1 > t0) {
        let dt = frame.dt;
        let tf_v = tf_row(0.0);
        let inv_dir = safe_inverse(r.tex_dir);
        // The samples before t1 (out of core: those before the last leaf's
        // exit, t1).
        let n = min(first_k_after(t1, t0, dt), frame.max_samples);
        // DVR and MIP (iso: iso_march). Empty-space skipping tests a macro cell
        // once, when the ray enters it (k reaches k_cell), not at every sample:
        // the samples of a cell known to contribute run without tests. A cell is
        // skipped when it cannot contribute: transparent (DVR) or below the
        // running maximum (MIP). Skips land on the same sample grid, so skipping
        // never changes the image.
        var k = 0u;
        var k_cell = 0u;
        // Pre-integration: the last sample was taken in a cell that could be
        // skipped, only to composite the segment entering it.
        var forced = false;
        // The sample grid (StepGrid: DVR's adaptive step moves it). Each
        // trip advances at least one step of at least `dt` on the grid of
        // step `dt` from t0, so `n` bounds them.
        var grid = StepGrid(t0, dt, 0u, tf_v);
        var trips = 0u;
        loop {
            if (trips >= n) { break; }
            trips = trips + 1u;
            let t = grid_t(grid.tb, k, grid.dt);
            if (t >= t1) { break; }
            if (MODE == MODE_DVR && step_grid_adapt(&grid, acc.color.a, t, dt, tf_v)) {
                k = 0u;
                k_cell = 0u;
            }
            let u = tex_at(r, t);
            if (ESS && k >= k_cell) {
                let c = cell_of(u);
                // DVR: a cell at distance d > 0 from any cell that can
                // contribute lies in an empty cube of side 2d - 1: one test skips
                // it whole. MIP: the cell alone, by its range.
                var reach = 1u;
                var skip = false;
                if (MODE == MODE_MIP) {
                    skip = cell_range(c).y <= acc.max_v;
                } else {
                    let d = cell_skip[cell_index(c)];
                    skip = d > 0u;
                    reach = max(d, 1u);
                }
                let k_exit = max(k + 1u, first_k_after(cell_exit(r, inv_dir, c, reach), grid.tb, grid.dt));
                // Pre-integrated DVR: the segment from the last sample into a
                // skipped cell can still contribute; this sample is taken, and
                // the cell tested again at the next one.
                let force = PREINT && MODE == MODE_DVR && skip && !forced && preint_joined(acc, t, dt);
                forced = force;
                if (skip && !force) {
                    k = k_exit;
                    continue;
                }
                k_cell = select(k_exit, k + 1u, force);
            }
            let v = sample_value(u);
            acc.samples = acc.samples + 1u;
            if (MODE == MODE_DVR) {
                var front = v;
                // Pre-integration: the ray's first sample composites nothing.
                var first = false;
                if (PREINT) {
                    preint_fetch(&acc, cur, t, dt, t0);
                    first = preint_before_start(t, dt, t0);
                    front = preint_front(&acc, t, dt, v);
                }
                if (!first && dvr_sample(&acc, cur, r, t, t - grid.dt, front, v, grid.row, grid.dt, t1)) { break; }
            } else {
                if (mip_sample(&acc, t, v, dt)) { break; }
            }
            k = k + 1u;
        }
        if (PREINT && MODE == MODE_DVR) {
            preint_tail(&acc, cur, r, t1, acc.prev_t, dt, tf_v);
        }
        if (MODE == MODE_MIP && acc.max_v > -1.0e38) {
            let alt = vec2<f32>(acc.alt_t, acc.alt_v);
            mip_refine(&acc, cur, vec2<f32>(acc.max_t, acc.max_v), t0, t1, dt);
            if (alt.y > -1.0e38) {
                mip_refine(&acc, cur, alt, t0, t1, dt);
            }
        }
    }
    finish_ray(px, &acc, cur, r, start.host);
}
