"""The small orthographic ray caster the studies in this folder share: rays
through a box [0, box] along one oblique direction, front to back, with a
sample function giving each point's colour and extinction."""
import numpy as np


def ray_grid(box, size, span=1.0):
    """The size x size rays' origins (a plane in front of the box [0, box],
    `span` times the box's half diagonal each way), their shared oblique
    direction and that half diagonal."""
    box = np.array(box, float)
    d = np.array([0.8, 0.45, 0.4])
    d /= np.linalg.norm(d)
    u = np.cross(d, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(u, d)
    radius = np.linalg.norm(box) / 2
    s = np.linspace(-span * radius, span * radius, size)
    uu, vv = np.meshgrid(s, s)
    origin = box / 2 + uu[..., None] * u + vv[..., None] * v - d * radius * 1.01
    return origin, d, radius


def render(sample, box, step, size=128):
    """A size x size image of the box [0, box] (finest voxel units) drawn at
    `step`: `sample(points)` returns (rgb, extinction per unit length) at an
    array of points; points outside the box add nothing."""
    origin, d, radius = ray_grid(box, size)
    box = np.array(box, float)
    color = np.zeros((size, size, 3))
    trans = np.ones((size, size))
    for k in range(int(2.02 * radius / step)):
        p = origin + d * (k + 0.5) * step
        inside = np.all((p >= 0) & (p <= box), axis=-1)
        rgb, ext = sample(p)
        a = np.where(inside, 1 - np.exp(-ext * step), 0.0)
        color += (trans * a)[..., None] * rgb
        trans *= 1 - a
    return color


def print_variants(label, variants, box, step, finest):
    """Prints one line: `label`, then each (name, sample) variant drawn at
    `step` and its PSNR against the image `finest`."""
    row = [label]
    for name, sample in variants:
        row.append(f"{name} {psnr(render(sample, box, step), finest):.2f} dB;")
    print(" ".join(row), flush=True)


def psnr(a, b):
    """PSNR of two images in 0..1 as 8-bit RGB, dB (inf when equal)."""
    mse = ((np.clip(a, 0, 1) * 255 - np.clip(b, 0, 1) * 255) ** 2).mean()
    return float("inf") if mse == 0 else 10 * np.log10(255 ** 2 / mse)
