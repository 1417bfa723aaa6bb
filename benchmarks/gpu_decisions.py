"""The filter on a GPU against the CPU filter: the same decisions? (needs CUDA; gsplat too unless
``--set backend=torch``)

Usage::

    python benchmarks/gpu_decisions.py [--views 8,16] [--resolution 256x448] [--family object]
                                       [--set KEY=VALUE ...]

For each view count, one stand-in scene; the default config (with the ``--set`` options) runs
twice with ``device="cuda"`` (the GPU path must agree with itself) and once with the native CPU
filter (``--set backend=torch`` measures the torch backend on the GPU against it). Prints
the seconds of each run, the Gaussians each removes, how many differ, the candidate counts and
the largest difference of an individual score between candidates at the same index.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clearsplat.features import get_extractor
from clearsplat.filter import filter_distractors
from clearsplat.synth import make_world, reconstruct


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", default="8,16")
    p.add_argument("--resolution", default="256x448", help="HxW")
    p.add_argument("--family", default="object")
    p.add_argument("--device", default="cuda")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a FilterConfig field for every run (repeatable), as clearsplat bench "
                        "reads it")
    args = p.parse_args(argv)
    from clearsplat.bench import parse_config
    base = parse_config("+".join(["default"] + args.set))
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    extractor = get_extractor("local")
    print(f"{'views':>5} {'run':>5} {'seconds':>8} {'removed':>9}")
    for views in (int(v) for v in args.views.split(",")):
        world = make_world(args.family, num_views=views, seed=0, height=h, width=w)
        scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
        runs = {}
        for name, cfg in (("gpu1", base.replace(device=args.device)),
                          ("gpu2", base.replace(device=args.device)),
                          ("cpu", base.replace(device="cpu", backend="auto"))):
            t = time.perf_counter()
            runs[name] = filter_distractors(scene, config=cfg, extractor=extractor)
            print(f"{views:>5} {name:>5} {time.perf_counter() - t:>8.2f} "
                  f"{int(runs[name].removed.sum()):>9,}")
        g1, g2, c = runs["gpu1"], runs["gpu2"], runs["cpu"]
        diff = max((abs(a.scores.get("individual", 0.0) - b.scores.get("individual", 0.0))
                    for a, b in zip(g1.candidates, c.candidates)), default=0.0)
        print(f"{views:>5} GPU runs identical: {np.array_equal(g1.keep, g2.keep)}; GPU = CPU: "
              f"{np.array_equal(g1.keep, c.keep)} ({int((g1.keep != c.keep).sum()):,} Gaussians "
              f"differ); candidates {len(g1.candidates)} GPU, {len(c.candidates)} CPU; largest "
              f"individual-score difference at the same index {diff:.2g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
