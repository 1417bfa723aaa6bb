"""How much of each camera's work the exact renders need, as the number of views grows.

Usage::

    python benchmarks/view_work.py --views 8,16,32 --resolution 128x224 --family street

Counts (the same on any machine) and one timing. For every view count, on the stand-in scene:

- *visible*: share of all Gaussians that survive a camera's culling (projection, binning and
  sorting work for that camera), mean over the cameras;
- *contributing*: share of a camera's visible Gaussians that add to at least one pixel of its
  full render (R_i) and of its exclusion render (R_i^-i), cameras 0 and V/2: the rest are
  hidden behind pixels that stopped (transmittance below 1e-4) before reaching them;
- *entries/px*: contributions each pixel adds before it stops, full render (compositing work a
  pixel needs);
- *prepare ns/G*: process CPU nanoseconds per Gaussian and camera of ``prepare`` (projection,
  culling, depth sort and tile binning) on one thread, median over the cameras (the one timing
  here: it shows that this work is per Gaussian, whatever the number of views);
- *list needed*: share of the (tile, Gaussian) pairs that tile-level early termination would
  leave to walk for R_i and R_i^-i to stay exact: each tile list cut to the shortest prefix of
  64, 128, ... entries that renders that tile identically (cameras 0 and V/2);
- *block cull*: share of all Gaussians that a conservative frustum test on blocks of 64 or 256
  consecutive Gaussians (a bounding sphere plus three times the largest scale, against the
  image borders widened by the largest footprint a Gaussian can have) could skip before
  projection, mean over the cameras, beside the share that is invisible.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clearsplat.filter.association import ViewIndex
from clearsplat.render import TILE, prepare
from clearsplat.render.native import PreparedView
from clearsplat.synth import make_world, reconstruct


def _tile_needed(pv: PreparedView, keep, full) -> float:
    """Share of the pairs that a per-tile prefix needs for the render of ``keep`` to stay
    identical, tile by tile (prefixes of 64, 128, ... entries)."""
    off, lst = pv._offsets, pv._lists
    lens = np.diff(off)
    h, w = pv.camera.height, pv.camera.width
    rows, cols = pv.grid

    def tiles(a):
        x = np.zeros((rows * TILE, cols * TILE) + a.shape[2:], a.dtype)
        x[:h, :w] = a
        return x.reshape(rows, TILE, cols, TILE, -1)

    ref = [tiles(getattr(full, k)) for k in ("rgb", "alpha", "depth")]
    need = np.full(lens.size, -1, dtype=np.int64)
    cut = 64
    while (need < 0).any():
        new = np.minimum(lens, cut)
        offsets = np.concatenate([[0], np.cumsum(new)]).astype(off.dtype)
        starts = np.repeat(off[:-1], new)
        within = np.arange(new.sum()) - np.repeat(offsets[:-1], new)
        view = PreparedView(camera=pv.camera, num_gaussians=pv.num_gaussians,
                            splats=pv._splats, rects=pv._rects, index=pv._index,
                            offsets=offsets, lists=lst[starts + within].astype(lst.dtype),
                            num_threads=pv._num_threads)
        r = view.render(keep=keep)
        same = np.ones((rows, cols), bool)
        for a, k in zip(ref, ("rgb", "alpha", "depth")):
            same &= (tiles(getattr(r, k)) == a).all(axis=(1, 3, 4))
        fresh = (need < 0) & same.ravel()
        need[fresh] = new[fresh]
        cut *= 2
    return float(need.sum() / max(lens.sum(), 1))


def _block_cull(scene, block: int) -> float:
    """Share of all Gaussians in blocks that a conservative per-camera test would skip."""
    g = scene.gaussians
    n = len(g)
    mu = g.means.astype(np.float64)
    s = np.abs(g.scales).max(axis=1).astype(np.float64)
    nb = -(-n // block)
    pad = nb * block - n
    mu_b = np.concatenate([mu, np.repeat(mu[-1:], pad, 0)]).reshape(nb, block, 3)
    s_b = np.concatenate([s, np.repeat(s[-1:], pad)]).reshape(nb, block)
    centre = (mu_b.min(1) + mu_b.max(1)) / 2
    radius = np.sqrt(((mu_b - centre[:, None]) ** 2).sum(-1)).max(1)
    smax = s_b.max(1)
    culled = 0
    for cam in scene.cameras:
        view = cam.world_to_camera[:3]
        rot, t = view[:, :3], view[:, 3]
        fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
        w, h = cam.width, cam.height
        limx, limy = 1.3 * w / (2 * fx), 1.3 * h / (2 * fy)
        reach = 1.01 * np.hypot(fx * (1 + limx), fy * (1 + limy))  # pixels per unit over z
        margin = 3 * np.sqrt(2 * 0.3 + 0.32) + 2

        def outside(nvec, d):   # n . x + d < 0 for the whole block, with the footprint
            return centre @ nvec + d + radius * np.linalg.norm(nvec) + 3 * smax * reach < 0

        planes = [(fx * rot[0] + (cx - 0.5 + margin) * rot[2], fx * t[0] + (cx - 0.5 + margin) * t[2]),
                  (-(fx * rot[0] + (cx - 0.5 - (w - 1) - margin) * rot[2]),
                   -(fx * t[0] + (cx - 0.5 - (w - 1) - margin) * t[2])),
                  (fy * rot[1] + (cy - 0.5 + margin) * rot[2], fy * t[1] + (cy - 0.5 + margin) * t[2]),
                  (-(fy * rot[1] + (cy - 0.5 - (h - 1) - margin) * rot[2]),
                   -(fy * t[1] + (cy - 0.5 - (h - 1) - margin) * t[2]))]
        skip = centre @ rot[2] + t[2] + radius < 0.01
        for nvec, d in planes:
            skip |= outside(nvec, d)
        culled += int(skip.sum()) * block
    return culled / (nb * block * len(scene.cameras))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", default="8,16,32")
    p.add_argument("--resolution", default="128x224", help="HxW")
    p.add_argument("--family", default="street")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    print(f"per-camera work of exact renders — {args.family} scenes at {w}x{h}, seed {args.seed}")
    print(f"{'views':>5} {'Gaussians':>10} {'visible':>8} {'contributing R / R^-i':>22} "
          f"{'entries/px':>11} {'prepare ns/G':>13} {'list needed R / R^-i':>21} "
          f"{'block cull 64 / 256':>20} "
          f"{'invisible':>10}")
    for v in [int(x) for x in args.views.split(",")]:
        world = make_world(args.family, num_views=v, seed=args.seed, height=h, width=w)
        scene = reconstruct(world.cameras, world.images, world.depths, seed=args.seed)
        n = len(scene)
        index = ViewIndex(scene)
        visible, ns = [], []
        for c in scene.cameras:
            t = time.process_time()
            pv = prepare(scene, c, num_threads=1)
            ns.append((time.process_time() - t) / n * 1e9)
            visible.append(pv.num_visible / n)
            del pv
        contrib_full, contrib_excl, entries, need_full, need_excl = [], [], [], [], []
        for i in sorted({0, v // 2}):
            pv = prepare(scene, scene.cameras[i])
            own = index.mask(i, n)
            everything = np.ones((h, w), bool)
            for keep, out in ((None, contrib_full), (~own, contrib_excl)):
                c = pv.contributions(everything, keep=keep)
                out.append(np.unique(c.gaussian).size / pv.num_visible)
                if keep is None:
                    entries.append(c.gaussian.size / (h * w))
            full, excl = pv.render_pair(keep=~own)
            need_full.append(_tile_needed(pv, None, full))
            need_excl.append(_tile_needed(pv, ~own, excl))
        print(f"{v:>5} {n:>10,} {np.mean(visible):>8.2f} "
              f"{f'{np.mean(contrib_full):.2f} / {np.mean(contrib_excl):.2f}':>22} "
              f"{np.mean(entries):>11.1f} {np.median(ns):>13.1f} "
              f"{f'{np.mean(need_full):.2f} / {np.mean(need_excl):.2f}':>21} "
              f"{f'{_block_cull(scene, 64):.3f} / {_block_cull(scene, 256):.3f}':>20} "
              f"{1 - np.mean(visible):>10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
