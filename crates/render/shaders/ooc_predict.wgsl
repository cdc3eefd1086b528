// Out-of-core traversals of the isosurface prediction buffer (predict.wgsl),
// after ooc.wgsl. Every traversal is `ooc_iso_march` over the index from some
// start: the traversal of the octree-with-ropes begins at any t by descending
// from the root, so a local search starts near the prediction without walking
// the leaves in front of it. Samples lie on the full traversal's grid, so a
// local hit that is the ray's first crossing has the full traversal's bracket
// (up to the bracket's lower end at a level change). See docs/prediction.md.

// One pixel of the iso mode with prediction, out of core: picks the traversal
// from last frame's entry, traverses, writes this frame's entry and class.
//
// Local: the march over the window of `pred.local_steps` full steps (finest
// level) either side of the prediction, from its front. It finds the first
// crossing in the window, entering from below (a first sample inside means
// the surface moved in front of the window: the search failed). Unguarded, a
// failed search takes the sparse traversal from the ray start: the march at
// the sparse step, its bracket bisected down to the full step's length in the
// brick where it was found (with the guard, the full step, as in core).
//
// Guarded: a probe walks the leaf and sub-cell ranges from the ray start to
// the window's front. Where it stops, a range may hold the isovalue (the guard
// rejects the prediction); before it, no sample can. The march from there to
// the ray's end is then the full traversal's remainder, so the result is the
// full traversal's whether the guard accepted or rejected: the guard costs a
// range walk and saves the sampling in front of the window.
fn ooc_predict_ray(px: vec2<u32>, start: RayStart) {
    let r = start.r;
    let t0 = start.t0;
    let t1 = start.t1;
    let pp = pred_begin(px, r);
    var acc = accum_new();
    var cur: Cursor;
    var kind = TRAVERSAL_NONE;
    feedback_stop(px, far_depth());
    if (t1 > t0) {
        cur.oo = r.tex_origin * ooc.octree_scale;
        cur.od = r.tex_dir * ooc.octree_scale;
        let choice = pred_choice(pp.last);
        kind = choice;
        // One march call serves every traversal (the local window, a march
        // after the guard's probe, the sparse and the full traversal): a SIMD
        // group of rays with mixed traversals runs one march loop (a second
        // trip only for lanes whose local search failed), not one per
        // traversal.
        var t_from = t0;
        var t_to = t1;
        var below = true;
        var tb = t1;
        if (choice == TRAVERSAL_LOCAL) {
            let tp = pred_decode_hit(pp.last) - pp.eye_offset;
            let w = f32(pred.local_steps) * frame.dt;
            let ta = clamp(tp - w, t0, t1);
            tb = clamp(tp + w, t0, t1);
            if (GUARD) {
                let tg = ooc_iso_march(&acc, &cur, t0, t0, ta, frame.dt, true, true, true);
                kind = select(TRAVERSAL_LOCAL, TRAVERSAL_GUARD_REJECTED, tg < ta);
                // Resume just before the probe's stop, so the march takes its
                // sample; everything before it is below the isovalue.
                t_from = max(t0, tg - 1.0e-3 * frame.dt);
            } else {
                t_from = ta;
                t_to = tb;
                below = ta <= t0;
            }
        }
        for (var attempt = 0u; attempt < 2u; attempt = attempt + 1u) {
            // Sparse: as in core (the full step with the guard).
            let sparse = kind == TRAVERSAL_SPARSE || kind == TRAVERSAL_LOCAL_MISSED;
            let coarse = sparse && !GUARD;
            let ess = select(ESS, select(true, SPARSE_ESS, coarse), sparse);
            ooc_iso_march(&acc, &cur, t0, t_from, t_to, select(frame.dt, pred.sparse_dt, coarse), ess, below, false);
            if (coarse && acc.hit) {
                sparse_refine(&acc, cur);
            }
            if (acc.hit || kind != TRAVERSAL_LOCAL || GUARD) {
                break;
            }
            // The local search failed: the sparse traversal from the ray start.
            kind = TRAVERSAL_LOCAL_MISSED;
            let spent = acc.samples;
            acc = accum_new();
            acc.samples = spent;
            t_from = t0;
            t_to = t1;
            below = true;
        }
        if (GUARD && kind == TRAVERSAL_LOCAL && !(acc.hit && acc.hit_b <= tb)) {
            kind = TRAVERSAL_LOCAL_MISSED;
        }
        feedback_stop(px, depth_at(r, select(t1, acc.hit_b, acc.hit)));
    }
    pred_store(pp.p, acc, t1 <= t0, pp.eye_offset, kind);
    finish_ray(px, &acc, cur, r, start.host);
}
