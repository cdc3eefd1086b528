#!/usr/bin/env python3
"""What a coarse level of an intensity volume loses to classification and
what to resolution (issue 35, item 2; docs/accuracy.md, "Coarse levels").

One small orthographic ray caster (trilinear, front to back, 128 x 128)
draws the shared head CT, the same CT with every third slice (4.5 mm) and
the T1 MRI at their finest level (step 0.5 voxel) and at their first two
coarse levels (each level halves the axes whose voxels are finest, as the
anisotropic pyramid does; step 0.5 voxel of the level), every coarse level
four ways:

  finest at the level's step  the finest data, the coarse level's step: the
                              share of the loss that is the step's
  TF of the mean              each coarse voxel the mean of its finest block,
                              classified after interpolation (brickray's
                              levels without spreads)
  spread                      the mean and the block's standard deviation,
                              classified by the TF convolved with that
                              Gaussian (the spread model)
  averaged classification     no value at all: each coarse voxel the block's
                              mean extinction and extinction-weighted colour,
                              interpolated (the bound of any per-voxel model
                              of the block's classification: Younesy et al.'s
                              Gaussian, Sicat et al.'s sparse PDFs)

each against the finest level's image (PSNR, dB). The caster is the same for
every variant, so the figures compare models, not brickray's renderer. Needs
numpy and ../shared/data beside the repository.

    python3 scripts/studies/coarse_classification.py
"""
import json
import os
import numpy as np

from caster import print_variants, render

DATA = os.path.join(os.path.dirname(__file__), "../../../shared/data")


def load(name):
    meta = json.load(open(os.path.join(DATA, name, name + ".json")))
    dt = {"i16": "<i2", "u8": "u1", "u16": "<u2", "f32": "<f4"}[meta["dtype"]]
    x, y, z = meta["dims"]
    raw = np.fromfile(os.path.join(DATA, name, name + ".raw"), dtype=dt)
    return raw.reshape(z, y, x).transpose(2, 1, 0).astype(np.float64), np.array(meta["spacing"], float)


def ramp(points):
    """A piecewise-linear TF over raw values: (value, opacity per finest
    voxel, grey) points; returns extinction and colour functions."""
    xs = np.array([p[0] for p in points], float)
    alpha = np.array([p[1] for p in points], float)
    grey = np.array([p[2] for p in points], float)

    def ext(v):
        a = np.interp(v, xs, alpha)
        return -np.log1p(-np.minimum(a, 0.999))

    def rgb(v):
        g = np.interp(v, xs, grey)
        return np.stack([g, 0.85 * g + 0.1, 0.7 * g + 0.05], -1)
    return ext, rgb


def trilinear(grid, f, p):
    """Trilinear interpolation of `grid` (voxels f finest voxels wide, centres
    at (i + 0.5) f) at finest index points p (clamped at the faces); grid may
    carry trailing channels. Also whether p lies in the finest box."""
    n = np.array(grid.shape[:3])
    q = p / f - 0.5
    i0 = np.floor(q).astype(int)
    t = q - i0
    out = 0.0
    for c in range(8):
        o = np.array([c & 1, c >> 1 & 1, c >> 2 & 1])
        i = np.clip(i0 + o, 0, n - 1)
        w = np.prod(np.where(o == 1, t, 1 - t), axis=-1)
        g = grid[i[..., 0], i[..., 1], i[..., 2]]
        out = out + (w[..., None] * g if g.ndim > w.ndim else w * g)
    return out


def blocks(vol, f):
    """vol's finest blocks of f voxels (edge-repeated), as (coarse dims, f^3)."""
    pad = [(0, (-n) % k) for n, k in zip(vol.shape, f)]
    v = np.pad(vol, pad, mode="edge")
    cd = [n // k for n, k in zip(v.shape, f)]
    b = v.reshape(cd[0], f[0], cd[1], f[1], cd[2], f[2]).transpose(0, 2, 4, 1, 3, 5)
    return b.reshape(*cd, -1)


def convolved(ext, rgb, lo, hi, sigmas):
    """The extinction and extinction-weighted colour averaged over a Gaussian
    of each sigma, tabulated over values lo..hi."""
    xs = np.linspace(lo, hi, 2048)
    e, c = ext(xs), rgb(xs) * ext(xs)[:, None]
    rows_e, rows_c = [], []
    for s in sigmas:
        if s <= 0:
            rows_e.append(e)
            rows_c.append(c)
            continue
        dx = xs[1] - xs[0]
        r = int(4 * s / dx) + 1
        k = np.exp(-0.5 * (np.arange(-r, r + 1) * dx / s) ** 2)
        k /= k.sum()
        pad_e = np.pad(e, r, mode="edge")
        pad_c = np.pad(c, ((r, r), (0, 0)), mode="edge")
        rows_e.append(np.convolve(pad_e, k, mode="valid"))
        rows_c.append(np.stack([np.convolve(pad_c[:, j], k, mode="valid") for j in range(3)], -1))
    return xs, np.array(sigmas), np.array(rows_e), np.array(rows_c)


def main():
    ct, ct_spacing = load("invesalius_cranium_ct")
    mri, mri_spacing = load("pycortex_s1_t1_mri")
    bone = ramp([(-2000, 0, 0), (100, 0, 0.2), (150, 0.02, 0.5), (300, 0.5, 1.0), (4000, 0.5, 1.0)])
    mri_tf = ramp([(0, 0, 0), (40, 0, 0.1), (90, 0.05, 0.6), (160, 0.3, 1.0), (255, 0.3, 1.0)])
    scenes = [
        ("head CT", ct, ct_spacing, bone),
        ("head CT 4.5 mm", ct[:, :, ::3], ct_spacing * [1, 1, 3], bone),
        ("T1 MRI", mri, mri_spacing, mri_tf),
    ]
    for name, vol, spacing, (ext, rgb) in scenes:
        box = np.array(vol.shape, float)
        lo, hi = vol.min(), vol.max()
        def classified(grid, f):
            """Values interpolated on `grid`, then classified (one read each)."""
            def sample(p):
                v = trilinear(grid, f, p)
                return rgb(v), ext(v)
            return sample

        finest = render(classified(vol, 1), box, 0.5)
        f = np.ones(3, int)
        sp = spacing.copy()
        for level in (1, 2):
            halve = sp <= sp.min() * 1.5  # the anisotropic pyramid halves the finest axes
            f = f * np.where(halve, 2, 1)
            sp = sp * np.where(halve, 2, 1)
            step = 0.5 * f.min()
            b = blocks(vol, f)
            mean, std = b.mean(-1), b.std(-1)
            e_b = ext(b)
            ext_avg = e_b.mean(-1)
            col_avg = (e_b[..., None] * rgb(b)).mean(-2)
            sig_rows = np.concatenate([[0], np.geomspace(max(std[std > 0].min(), 1e-3), std.max(), 48)])
            xs, sig, tab_e, tab_c = convolved(ext, rgb, lo, hi, sig_rows)

            def spread(p):
                m = trilinear(mean, f, p)
                s = trilinear(std, f, p)
                j = np.clip(np.searchsorted(sig, s), 0, len(sig) - 1)
                i = np.clip(((m - lo) / (hi - lo) * (len(xs) - 1)).round().astype(int), 0, len(xs) - 1)
                e = tab_e[j, i]
                return tab_c[j, i] / np.maximum(e, 1e-12)[..., None], e

            def averaged(p):
                e = trilinear(ext_avg, f, p)
                return trilinear(col_avg, f, p) / np.maximum(e, 1e-12)[..., None], e

            variants = [
                ("finest at the level's step", classified(vol, 1)),
                ("TF of the mean", classified(mean, f)),
                ("spread", spread),
                ("averaged classification", averaged),
            ]
            label = f"{name} level {level} ({'x'.join(str(k) for k in f)} finest voxels, step {step:g}):"
            print_variants(label, variants, box, step, finest)


if __name__ == "__main__":
    main()
