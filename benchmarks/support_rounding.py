"""How much of the support condition rounding decides.

Usage::

    python benchmarks/support_rounding.py [--views 8] [--resolution 256x448] [--family object]

One stand-in scene (seed 0). Per view, from the first round's R_i and R_i^-i: the patches whose
mean depths before and after the exclusion differ by less than 1e-5 of the depth (where rounding
decides the strict comparison), and how many of those the strict comparison passes. Counts only:
the same on any machine.
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--resolution", default="256x448", help="HxW")
    p.add_argument("--family", default="object")
    args = p.parse_args(argv)

    from clearsplat.features import get_extractor
    from clearsplat.features.base import grid_shape_for
    from clearsplat.filter.proposal import cell_index_map, patch_means
    from clearsplat.render import prepare
    from clearsplat.synth import make_world, reconstruct

    h, w = (int(x) for x in args.resolution.lower().split("x"))
    world = make_world(args.family, num_views=args.views, seed=0, height=h, width=w)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    extractor = get_extractor("local")
    grid = grid_shape_for(h, w, extractor.patch_size)
    cells = cell_index_map(grid, h, w)
    n = grid[0] * grid[1]
    print(f"{args.family}, {args.views} views at {w}x{h}, {len(scene):,} Gaussians; "
          f"{n} patches per view")
    print(f"{'view':>4} {'near-equal':>10} {'passed':>7}   (|z_after - z_before| < 1e-5 z)")
    for i, cam in enumerate(scene.cameras):
        pair = prepare(scene, cam).render_pair(keep=scene.view_id != i)
        both = (pair[0].depth > 0) & (pair[1].depth > 0)
        before, count = patch_means(pair[0].depth, cells, n, both)
        after, _ = patch_means(pair[1].depth, cells, n, both)
        near = (count > 0) & (np.abs(after - before) < 1e-5 * np.maximum(before, after))
        print(f"{i:>4} {int(near.sum()):>10} {int((near & (before < after)).sum()):>7}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
