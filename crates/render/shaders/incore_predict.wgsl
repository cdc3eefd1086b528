// In-core traversals of the isosurface prediction buffer (predict.wgsl), after
// incore.wgsl. Local hits lie on the full traversal's sample grid t0 + k dt, so
// a local hit that is the first crossing has exactly the full traversal's
// bracket and pixel. See docs/prediction.md.

// The local traversal: from the full-step sample nearest the prediction `tp`,
// alternately one step back and one step forward (back only when that sample
// is inside the surface), until two neighbouring
// samples bracket an entering crossing (below, then at or above the isovalue)
// or `pred.local_steps` steps each way are spent. True when found (the bracket
// is in `acc`).
fn local_traversal(acc: ptr<function, Accum>, r: Ray, t0: f32, t1: f32, tp: f32) -> bool {
    let dt = frame.dt;
    let n = min(first_k_after(t1, t0, dt), frame.max_samples);
    if (n == 0u) {
        return false;
    }
    let kp = u32(clamp(round((tp - t0) / dt), 0.0, f32(n - 1u)));
    let inside_p = sample_value(tex_at(r, grid_t(t0, kp, dt))) >= frame.isovalue;
    (*acc).samples = (*acc).samples + 1u;
    var kb = kp;
    var in_b = inside_p;
    var kf = kp;
    var in_f = inside_p;
    let steps = min(pred.local_steps, n);
    for (var i = 0u; i < steps; i = i + 1u) {
        // One step back.
        if (kb > 0u) {
            let k = kb - 1u;
            let t = grid_t(t0, k, dt);
            let inside = sample_value(tex_at(r, t)) >= frame.isovalue;
            (*acc).samples = (*acc).samples + 1u;
            if (in_b && !inside) {
                // The bracket as the full traversal computes it from its upper
                // sample (t0 + (k + 1) dt, not t + dt, which can round
                // differently), so the hit and its pixel are bit-identical.
                let tb = grid_t(t0, kb, dt);
                iso_bracket(acc, tb - dt, tb);
                return true;
            }
            kb = k;
            in_b = inside;
        } else if (in_b) {
            // The first sample is inside: a capped cut, as the full traversal.
            iso_bracket(acc, t0, t0);
            return true;
        }
        // One step forward, only from a predicted sample below the isovalue:
        // from one at or above it, an entering crossing ahead lies behind an
        // exit from the surface, so it is never the ray's first.
        let t = grid_t(t0, kf + 1u, dt);
        if (!inside_p && kf + 1u < n && t < t1) {
            let inside = sample_value(tex_at(r, t)) >= frame.isovalue;
            (*acc).samples = (*acc).samples + 1u;
            if (inside && !in_f) {
                iso_bracket(acc, t - dt, t);
                return true;
            }
            kf = kf + 1u;
            in_f = inside;
        }
    }
    return false;
}

// The first-hit guard: can a sample of the full traversal in front of the
// local hit (upper sample k_hit) reach the isovalue? Walks the macro cells from
// the ray start; every cell before the hit's own must lie below the isovalue
// (else 0: the guard rejects the hit); the hit's own cell is sampled at the
// full step up to the hit, and an earlier crossing found there replaces the
// bracket (exactly the full traversal's). 1: the hit is the first crossing.
// The walk reads the cells' skip distances, as the full traversal does, and
// passes an empty cube with one read; each read is counted as a sample.
fn guard_first_hit(acc: ptr<function, Accum>, r: Ray, t0: f32) -> bool {
    let dt = frame.dt;
    let inv_dir = safe_inverse(r.tex_dir);
    let t_hit = (*acc).hit_b;
    let k_hit = u32(max(round((t_hit - t0) / dt), 0.0));
    let c_hit = cell_of(tex_at(r, t_hit));
    var k = 0u;
    loop {
        if (k >= k_hit) { break; }
        let t = grid_t(t0, k, dt);
        let c = cell_of(tex_at(r, t));
        // As the full traversal's skipping: a cell at skip distance d > 0 lies
        // in an empty cube of side 2d - 1 (no value at or above the isovalue),
        // passed with one test; the hit's own cell is never in one.
        let d = cell_skip[cell_index(c)];
        let k_exit = max(k + 1u, first_k_after(cell_exit(r, inv_dir, c, max(d, 1u)), t0, dt));
        if (all(c == c_hit)) {
            let k_end = min(k_exit, k_hit);
            for (var j = k; j < k_end; j = j + 1u) {
                let tj = grid_t(t0, j, dt);
                (*acc).samples = (*acc).samples + 1u;
                if (sample_value(tex_at(r, tj)) >= frame.isovalue) {
                    iso_bracket(acc, select(tj - dt, tj, j == 0u), tj);
                    return true;
                }
            }
            k = k_end;
            continue;
        }
        (*acc).samples = (*acc).samples + 1u;
        if (d == 0u) {
            return false;
        }
        k = k_exit;
    }
    return true;
}

// One pixel of the iso mode with prediction: picks the traversal from last
// frame's entry, traverses, writes this frame's entry and the pixel's class.
fn predict_ray(px: vec2<u32>, start: RayStart) {
    let r = start.r;
    let t0 = start.t0;
    let t1 = start.t1;
    let pp = pred_begin(px, r);
    var acc = accum_new();
    let cur = Cursor(r);
    var kind = TRAVERSAL_NONE;
    if (t1 > t0) {
        let choice = pred_choice(pp.last);
        kind = choice;
        // Every pixel that marches from the ray start (full, sparse, a failed
        // local search, a rejected guard) does so in one call below: a SIMD
        // group of rays with mixed traversals runs one march loop, not one per
        // traversal (lavapipe runs each loop a group reaches while any lane is
        // in it).
        var march = choice != TRAVERSAL_LOCAL;
        if (choice == TRAVERSAL_LOCAL) {
            let tp = pred_decode_hit(pp.last) - pp.eye_offset;
            if (!local_traversal(&acc, r, t0, t1, tp)) {
                kind = TRAVERSAL_LOCAL_MISSED;
                march = true;
            } else if (GUARD && !guard_first_hit(&acc, r, t0)) {
                // Something in front may hold the isovalue: the full march, so
                // the guarded result is the full traversal's.
                kind = TRAVERSAL_GUARD_REJECTED;
                march = true;
            }
            if (march) {
                let spent = acc.samples;
                acc = accum_new();
                acc.samples = spent;
            }
        }
        if (march) {
            // Sparse (missed the surface, or the box and the ray now enters it,
            // or a hole of the reprojection; or a failed local search): a
            // coarse step whose bracket is bisected down to the full step's
            // length. With the guard, the full step (with skipping, which never
            // changes the result): a coarse step can pass over a thin or
            // grazing crossing the full traversal finds, so only the full step
            // keeps the guarded variant exact.
            let sparse = kind == TRAVERSAL_SPARSE || kind == TRAVERSAL_LOCAL_MISSED;
            let coarse = sparse && !GUARD;
            let ess = select(ESS, select(ESS || SPARSE_ESS, SPARSE_ESS, coarse), sparse);
            iso_march(&acc, r, t0, t1, select(frame.dt, pred.sparse_dt, coarse), ess);
            if (coarse && acc.hit) {
                sparse_refine(&acc, cur);
            }
        }
    }
    pred_store(pp.p, acc, t1 <= t0, pp.eye_offset, kind);
    finish_ray(px, &acc, cur, r, start.host);
}
