#!/usr/bin/env python3
"""Why pre-integration loses on the CT and MRI, and what a segment needs to
know to stop losing (issue 35, item 5; docs/rendering-model.md,
"Pre-integration").

One small orthographic caster (64 x 64 rays through the volume's box in
voxel units, trilinear, front to back, unshaded) draws the shared head CT
with two transfer functions and the T1 MRI at steps 1/8 to
4 voxels seven ways, each against the exact integral (the plain sum at 1/32
voxel) as PSNR in dB:

  plain          a point sample every step, standing for the step after it
                 (brickray's plain DVR)
  linear         each segment between two samples integrated with the value
                 running linearly from one to the other, the last piece to
                 the box's exit constant (brickray's pre-integration)
  midpoint       the same over two halves through a midpoint value taken
                 from the four samples around the segment (Catmull-Rom:
                 (9 (s1 + s2) - s0 - s3) / 16; no texture read more, the
                 segment composited one sample late)
  quadratic      the same through the midpoint of the parabola through the
                 segment's two samples and the one before them
                 ((-s0 + 6 s1 + 3 s2) / 8: no sample after the segment, so
                 no latency)
  parabola, 4 pieces
                 four linear pieces along that parabola (what the renderers
                 now do: docs/rendering-model.md, "The value along a
                 segment")
  cubic          the segment integrated along that Catmull-Rom cubic (what
                 any model built from the samples along the ray can reach at
                 best with this interpolant)
  sampled mid    two linear halves through the true midpoint value (one
                 texture read more per sample: pre-integration at half the
                 step, for scale)

Every segment is integrated numerically (16 sub-steps), so the figures are
the models', not a table's. The transfer functions: the pareto suite's
for the CT's DVR (soft tissue, a transparent notch at 300 HU, bone from
500 HU) and the MRI's, and issue 35's
bone ramp on the CT in grey; the suite's colours matter (a first version
in grey had the MRI's segments win where brickray's lose). Needs numpy and ../shared/data beside the
repository; about 4 minutes on two idle cores.

    python3 scripts/studies/preint_segments.py
"""
import numpy as np

from caster import psnr, ray_grid
from coarse_classification import load, ramp, trilinear

H = 1.0 / 32  # the exact integral's step, voxels
SIZE = 64
SUB = 16  # sub-steps per segment
STEPS = [0.125, 0.25, 0.5, 1.0, 2.0, 4.0]


def coloured(points):
    """A piecewise-linear TF over raw values with colours: (value, opacity
    per voxel, (r, g, b)) points; returns extinction and colour functions."""
    xs = np.array([p[0] for p in points], float)
    alpha = np.array([p[1] for p in points], float)
    cols = np.array([p[2] for p in points], float)

    def ext(v):
        return -np.log1p(-np.minimum(np.interp(v, xs, alpha), 0.999))

    def rgb(v):
        return np.stack([np.interp(v, xs, cols[:, k]) for k in range(3)], -1)
    return ext, rgb


def rays(box):
    """Origins, the shared direction, and each ray's [t0, t1] in the box."""
    origin, d, _ = ray_grid(box, SIZE, 0.7)
    origin = origin.reshape(-1, 3)
    box = np.array(box, float)
    with np.errstate(divide="ignore"):
        a = (0 - origin) / d
        b = (box - origin) / d
    t0 = np.max(np.minimum(a, b), axis=1)
    t1 = np.min(np.maximum(a, b), axis=1)
    t0 = np.maximum(t0, 0)
    return origin, d, t0, np.maximum(t1, t0)


def values(vol, origin, d, t0, t1):
    """The values at t0 + j H, j = 0..J (NaN past t1), shape (J + 1, rays)."""
    jmax = int(np.ceil((t1 - t0).max() / H)) + 1
    out = np.full((jmax + 1, len(t0)), np.nan, np.float32)
    for j in range(jmax + 1):
        t = t0 + j * H
        ok = t <= t1 + 1e-9
        if not ok.any():
            break
        p = origin + d * t[:, None]
        # Voxel centres at i + 0.5 (trilinear with f = 1).
        out[j, ok] = trilinear(vol, 1.0, p[ok])
    return out


def segment(ext, rgb, s_of_x, length):
    """The associated colour and opacity of one segment whose value is
    s_of_x(x) for x in [0, 1] (arrays over rays), `length` voxels long,
    integrated over SUB sub-steps (midpoint rule)."""
    c = 0.0
    tr = 1.0
    dl = length / SUB
    for i in range(SUB):
        s = s_of_x((i + 0.5) / SUB)
        a = 1 - np.exp(-ext(s) * dl)
        c = c + (tr * a)[..., None] * rgb(s)
        tr = tr * (1 - a)
    return c, 1 - tr


def draw(vals, ext, rgb, t0, t1, step, how):
    k = int(round(step / H))
    s = vals[::k]  # samples at t0 + i step
    n = s.shape[0]
    rays_n = s.shape[1]
    color = np.zeros((rays_n, 3))
    tr = np.ones(rays_n)
    length = t1 - t0

    def add(rgbp, a, mask):
        nonlocal color, tr
        a = np.where(mask, a, 0.0)
        color += np.where(mask[:, None], tr[:, None] * rgbp, 0.0)
        tr *= 1 - a

    def at(i):
        return s[min(max(i, 0), n - 1)]

    if how == "plain":
        for i in range(n):
            v = s[i]
            ok = ~np.isnan(v)
            vv = np.nan_to_num(v)
            a = 1 - np.exp(-ext(vv) * step)
            add(a[:, None] * rgb(vv), a, ok)
        return color
    for i in range(1, n):
        s1, s2 = s[i - 1], s[i]
        ok = ~np.isnan(s2)
        if not ok.any():
            break
        s1 = np.nan_to_num(s1)
        s2 = np.nan_to_num(s2)
        # Neighbours, clamped at the ray's ends (NaN past t1: the last sample).
        s0 = np.where(np.isnan(at(i - 2)), s1, np.nan_to_num(at(i - 2))) if i >= 2 else s1
        s3 = at(i + 1) if i + 1 < n else s2
        s3 = np.where(np.isnan(s3), s2, np.nan_to_num(s3))
        mid_cr = (9 * (s1 + s2) - s0 - s3) / 16
        if how == "linear":
            c, a = segment(ext, rgb, lambda x: s1 + (s2 - s1) * x, step)
        elif how == "parabola, 4 pieces":
            b = 0.5 * (s2 - s0)
            q = 0.5 * (s2 - 2 * s1 + s0)
            xs = [s1 + (b + q * (j / 4)) * (j / 4) for j in range(5)]
            c = 0.0
            a = np.zeros_like(s1)
            for j in range(4):
                cj, aj = segment(ext, rgb, (lambda u, w: (lambda x: u + (w - u) * x))(xs[j], xs[j + 1]), step / 4)
                c = c + (1 - a)[:, None] * cj
                a = a + (1 - a) * aj
        elif how in ("midpoint", "quadratic", "sampled mid"):
            if how == "midpoint":
                m = mid_cr
            elif how == "quadratic":
                m = (-s0 + 6 * s1 + 3 * s2) / 8
            else:
                m = np.nan_to_num(vals[(i - 1) * k + k // 2])
            ca, aa = segment(ext, rgb, lambda x: s1 + (m - s1) * x, step / 2)
            cb, ab = segment(ext, rgb, lambda x: m + (s2 - m) * x, step / 2)
            c = ca + (1 - aa)[:, None] * cb
            a = 1 - (1 - aa) * (1 - ab)
        else:  # cubic (Catmull-Rom through s0..s3)
            def cr(x):
                return 0.5 * ((2 * s1) + (-s0 + s2) * x + (2 * s0 - 5 * s1 + 4 * s2 - s3) * x * x
                              + (-s0 + 3 * s1 - 3 * s2 + s3) * x ** 3)
            c, a = segment(ext, rgb, cr, step)
        add(c, a, ok)
    # The last piece, from the last sample to t1: constant.
    last_i = np.floor(length / step + 1e-9).astype(int)
    last_i = np.minimum(last_i, n - 1)
    v = np.nan_to_num(s[last_i, np.arange(rays_n)])
    piece = length - last_i * step
    a = 1 - np.exp(-ext(v) * piece)
    add(a[:, None] * rgb(v), a, piece > 0)
    return color


def exact(vals, ext, rgb):
    color = np.zeros((vals.shape[1], 3))
    tr = np.ones(vals.shape[1])
    for j in range(vals.shape[0]):
        v = vals[j]
        ok = ~np.isnan(v)
        vv = np.nan_to_num(v)
        a = np.where(ok, 1 - np.exp(-ext(vv) * H), 0.0)
        color += (tr * a)[:, None] * rgb(vv)
        tr *= 1 - a
    return color


def main():
    ct, _ = load("invesalius_cranium_ct")
    mri, _ = load("pycortex_s1_t1_mri")
    # The pareto suite's CT DVR (soft tissue, a transparent notch at 300 HU,
    # bone from 500 HU) and MRI transfer functions with their colours
    # (crates/harness), and issue 35's bone ramp in grey.
    soft = coloured([(-3000, 0, (.6, .3, .2)), (-500, 0, (.6, .3, .2)), (-100, 0.02, (.8, .5, .4)),
                     (150, 0.03, (.9, .6, .5)), (300, 0.0, (1, 1, .9)), (500, 0.3, (1, 1, .95)),
                     (5000, 0.3, (1, 1, .95))])
    bone = ramp([(-2000, 0, 0), (100, 0, 0.2), (150, 0.02, 0.5), (300, 0.5, 1.0), (4000, 0.5, 1.0)])
    top = 248  # the MRI's value range, 0..248
    mri_tf = coloured([(0, 0, (.3, .12, .06)), (0.12 * top, 0, (.3, .12, .06)),
                       (0.35 * top, 0.08, (.9, .5, .3)), (0.7 * top, 0.4, (1, .9, .8)),
                       (top + 10, 0.4, (1, .9, .8))])
    scenes = [
        ("head CT, soft tissue", ct, soft),
        ("head CT, bone ramp", ct, bone),
        ("T1 MRI", mri, mri_tf),
    ]
    hows = ["plain", "linear", "midpoint", "quadratic", "parabola, 4 pieces", "cubic", "sampled mid"]
    print("| volume | step (voxels) | " + " | ".join(hows) + " |")
    print("|---|---:|" + "---:|" * len(hows))
    for name, vol, (ext, rgb) in scenes:
        origin, d, t0, t1 = rays(vol.shape)
        vals = values(vol, origin, d, t0, t1)
        ref = exact(vals, ext, rgb).reshape(SIZE, SIZE, 3)
        for step in STEPS:
            row = [psnr(draw(vals, ext, rgb, t0, t1, step, h).reshape(SIZE, SIZE, 3), ref) for h in hows]
            print(f"| {name} | {step:g} | " + " | ".join(f"{p:.2f}" for p in row) + " |", flush=True)


if __name__ == "__main__":
    main()
