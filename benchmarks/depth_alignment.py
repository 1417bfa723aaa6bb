"""How well ``align_depths`` measures each view's depth scale, and what it costs.

Usage::

    python benchmarks/depth_alignment.py [--realism depth,all] [--family street] [--views 8]
                                         [--resolution 256x448] [--seed 0]

Per realism scenario, one stand-in scene (``clearsplat.synth.realism``) and, per view: the
depth scale the scenario drew (the median ratio of the view's static Gaussians' depth to the
true depth, relative to the views' geometric mean), the scale that
:func:`clearsplat.filter.align.view_depth_alignment` measures, and their difference; then the
seconds to measure the scales and to move the scene (medians of 3). The scales are counts of
the data: the same on any machine; the seconds are this machine's.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np


def _drawn_scales(scene, world, truth) -> np.ndarray:
    """Per view, median (camera depth of its static pixel-aligned Gaussians / true depth),
    over the views' geometric mean."""
    out = []
    for v, cam in enumerate(scene.cameras):
        m = (scene.view_id == v) & (scene.pixel_id >= 0) & ~truth
        z = cam.to_camera(scene.gaussians.means[m])[:, 2]
        out.append(np.median(z / world.depths[v].ravel()[scene.pixel_id[m]]))
    out = np.array(out)
    return out / np.exp(np.log(out).mean())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realism", default="depth,all")
    p.add_argument("--family", default="street")
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--resolution", default="256x448", help="HxW")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    from clearsplat.filter.align import aligned_scene, view_depth_alignment
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction

    h, w = (int(x) for x in args.resolution.lower().split("x"))
    world = make_world(args.family, num_views=args.views, seed=args.seed, height=h, width=w)
    for name in args.realism.split(","):
        scene, truth = realistic_reconstruction(world, name, seed=args.seed)
        drawn = _drawn_scales(scene, world, truth)
        measured = view_depth_alignment(scene)
        print(f"{name} {args.family}, {args.views} views at {w}x{h}, seed {args.seed}, "
              f"{len(scene):,} Gaussians")
        print(f"{'view':>4} {'drawn':>7} {'measured':>9} {'diff %':>7}")
        for v, (d, m) in enumerate(zip(drawn, measured)):
            print(f"{v:>4} {d:7.4f} {m:9.4f} {100 * (m / d - 1):+7.2f}")
        print(f"largest difference {100 * np.abs(measured / drawn - 1).max():.2f} %; measured "
              f"range {measured.min():.3f}-{measured.max():.3f}")
        measure, move = [], []
        for _ in range(3):
            t0 = time.perf_counter()
            s = view_depth_alignment(scene)
            t1 = time.perf_counter()
            aligned_scene(scene, s)
            measure.append(t1 - t0)
            move.append(time.perf_counter() - t1)
        print(f"measure {statistics.median(measure):.3f} s, move "
              f"{statistics.median(move):.3f} s (medians of 3)\n")
    print(f"machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, "
          f"load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
