"""Saved classic-mode renders: the rasterizer's output before render settings existed.

``classic_renders.npz`` was written by running this file (``python
tests/data/classic_renders.py``) with the rasterizer as it was before the antialiased mode,
eps2d, radius clip and SH degree 4 were added; ``tests/test_render.py`` renders the same
scenes with the default (classic) settings and requires the same bits. Regenerate it only
when a change to the classic path is intended.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clearsplat import Camera, Gaussians
from clearsplat.cameras import look_at

FILE = Path(__file__).with_name("classic_renders.npz")


def cases():
    """(name, gaussians, camera, keep, background) of the saved renders."""
    out = []
    for seed, (w, h, k) in enumerate([(40, 24, 1), (33, 17, 9), (48, 32, 16), (24, 40, 4)]):
        rng = np.random.default_rng(100 + seed)
        n = 300
        means = rng.normal(size=(n, 3)) * 1.2
        means[: n // 10, 2] = rng.uniform(-6.0, -3.05, n // 10)
        scales = np.exp(rng.uniform(np.log(0.003), np.log(0.4), (n, 3)))  # some sub-pixel
        g = Gaussians(means=means, scales=scales, quats=rng.normal(size=(n, 4)),
                      opacities=rng.uniform(0, 1, n), sh=rng.normal(size=(n, k, 3)) * 0.4)
        cam = Camera(K=[[0.8 * w, 0, w / 2 + 0.3], [0, 0.9 * w, h / 2 - 0.2], [0, 0, 1]],
                     camera_to_world=look_at((0.3, 0.2, -3.0), (0.0, 0.0, 0.0),
                                             up=(0.0, -1.0, 0.0)), width=w, height=h)
        keep = rng.uniform(size=n) < 0.8 if seed % 2 else None
        out.append((f"case{seed}", g, cam, keep, (0.1, 0.2, 0.3)))
    return out


def main():
    from clearsplat.render import render
    arrays = {}
    for name, g, cam, keep, bg in cases():
        r = render(g, cam, keep=keep, background=bg)
        arrays[f"{name}_rgb"], arrays[f"{name}_alpha"], arrays[f"{name}_depth"] = r
    np.savez_compressed(FILE, **arrays)


if __name__ == "__main__":
    main()
