#!/usr/bin/env python3
"""How much a coarse level of a label map can gain from how its voxels are
chosen or classified (docs/labels.md, "Known gaps").

Each shared label map is drawn by one small orthographic ray caster (nearest
voxel, opacity 0.3 per finest voxel for every label but the background 0,
random colours, 128 x 128, step 0.5 voxel of the level drawn) at its finest
level and at levels 1 and 2, whose voxels are chosen or classified five ways:

  modes of modes    the store's pyramid: each level the mode of 2x2x2 of the
                    level below, ties to the smallest id
  mode of finest    the mode of the whole finest block, ties to the smallest
  ties to objects   the same, ties to the largest id (objects over background)
  coverage          the most frequent id but the background, its extinction
                    scaled by the share of the block that is not background
  average           no id at all: the block's mean extinction and
                    extinction-weighted colour (what any per-voxel model of
                    the block's classification can reach at best)

and each image is compared with the finest level's (PSNR, dB). The caster is
the same for every variant, so the figures compare the variants, not
brickray's renderer. Needs numpy and ../shared/data beside the repository.

    python3 scripts/studies/label_levels.py
"""
import os
import numpy as np

from caster import print_variants, render

DATA = os.path.join(os.path.dirname(__file__), "../../../shared/data/labels")
MAPS = [("mricron_brodmann_labels", (181, 217, 181), np.uint8),
        ("cells3d_nuclei_labels", (256, 256, 60), np.uint32)]
ALPHA = 0.3


def load(name, dims, dtype):
    raw = np.fromfile(os.path.join(DATA, name, name + ".raw"), dtype=dtype)
    return raw.reshape(dims[2], dims[1], dims[0]).transpose(2, 1, 0).astype(np.int64)


def lookup(grid, scale, p):
    """The voxel of `grid` (voxels `scale` finest voxels wide) holding p, and
    whether p lies inside it."""
    i = np.floor(p / scale).astype(int)
    n = np.array(grid.shape[:3])
    inside = np.all((i >= 0) & (i < n), axis=-1)
    i = np.clip(i, 0, n - 1)
    return (i[..., 0], i[..., 1], i[..., 2]), inside


def counts(labels, s, ids):
    """Per block of s^3 finest voxels, the count of each id."""
    pad = [(0, (-n) % s) for n in labels.shape]
    lp = np.pad(labels, pad, mode="edge")
    cd = [n // s for n in lp.shape]
    blocks = lp.reshape(cd[0], s, cd[1], s, cd[2], s)
    out = np.zeros((*cd, ids), np.int32)
    gx, gy, gz = np.meshgrid(*(np.arange(c) for c in cd), indexing="ij")
    for dx in range(s):
        for dy in range(s):
            for dz in range(s):
                np.add.at(out, (gx, gy, gz, blocks[:, dx, :, dy, :, dz]), 1)
    return out


def halve_by_mode(labels, ids):
    c = counts(labels, 2, ids)
    return c.argmax(-1)  # argmax takes the first (smallest) of equal counts


def main():
    rng = np.random.default_rng(1)
    for name, dims, dtype in MAPS:
        labels = load(name, dims, dtype)
        ids = int(labels.max()) + 1
        colors = rng.random((ids, 3))
        sigma = np.full(ids, -np.log(1 - ALPHA))
        sigma[0] = 0.0

        def by_id(grid, scale):
            def f(p):
                ix, inside = lookup(grid, scale, p)
                lab = np.where(inside, grid[ix], 0)
                return colors[lab], sigma[lab]
            return f

        finest = render(by_id(labels, 1), dims, 0.5)
        chained = labels
        for level in (1, 2):
            s = 2 ** level
            chained = halve_by_mode(chained, ids)
            c = counts(labels, s, ids)
            reversed_ids = c[..., ::-1].argmax(-1)
            not_background = c.copy()
            not_background[..., 0] = -1
            share = 1 - c[..., 0] / s ** 3
            ext = (c * sigma).sum(-1) / s ** 3
            rgb = (c[..., None] * (sigma[:, None] * colors)).sum(-2) / s ** 3
            rgb /= np.maximum(ext, 1e-12)[..., None]
            coverage_ids = not_background.argmax(-1)

            def coverage(p):
                ix, inside = lookup(coverage_ids, s, p)
                lab = coverage_ids[ix]
                return colors[lab], np.where(inside, sigma[lab] * share[ix], 0.0)

            def average(p):
                ix, inside = lookup(ext, s, p)
                return np.where(inside[..., None], rgb[ix], 0.0), np.where(inside, ext[ix], 0.0)

            variants = [
                ("modes of modes", by_id(chained, s)),
                ("mode of finest", by_id(c.argmax(-1), s)),
                ("ties to objects", by_id(ids - 1 - reversed_ids, s)),
                ("coverage", coverage),
                ("average", average),
            ]
            print_variants(f"{name} level {level}:", variants, dims, 0.5 * s, finest)


if __name__ == "__main__":
    main()
