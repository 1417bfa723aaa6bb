"""The default filter's time against another installed version's, side by side.

Usage::

    python benchmarks/filter_versus.py --other /path/to/old/venv/bin/python
    python benchmarks/filter_versus.py --other OLD_PYTHON --views 8,16 --family object --pairs 8

Each case's scene (:func:`clearsplat.synth.make_world` and :func:`~clearsplat.synth.
reconstruct`, seed 0) is made once here and pickled; then this interpreter (A: this checkout)
and ``--other`` (B: another checkout's, such as an older release in its own virtual
environment) filter it in fresh processes, one after the other, A B A B ..., after one
untimed pair. Each run prints the seconds of ``filter_distractors(scene, config=FilterConfig(),
extractor=get_extractor("local"))`` alone (not the interpreter's start or the pickle's load)
and how many Gaussians it removed. The table gives the medians, the ratio of each pair (A / B:
pairing keeps a drifting machine's speed out of the ratio) and their median, and whether both
versions removed the same number of Gaussians.
"""

from __future__ import annotations

import argparse
import os
import pickle
import platform
import statistics
import subprocess
import sys
import tempfile

_RUN = """
import pickle, sys, time
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
with open(sys.argv[1], "rb") as f:
    scene = pickle.load(f)
start = time.perf_counter()
result = filter_distractors(scene, config=FilterConfig(), extractor=get_extractor("local"))
print(time.perf_counter() - start, int(result.removed.sum()))
"""


def _processor() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.system()


def _once(python: str, path: str) -> tuple[float, int]:
    out = subprocess.run([python, "-c", _RUN, path], capture_output=True, text=True, check=True)
    seconds, removed = out.stdout.split()[-2:]
    return float(seconds), int(removed)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--other", required=True, metavar="PYTHON",
                   help="the interpreter of the version to compare with (B)")
    p.add_argument("--views", default="8,16")
    p.add_argument("--family", default="street,object",
                   help="one family per view count, or one for all (default: street at the "
                        "first, object at the second)")
    p.add_argument("--resolution", default="256x448", metavar="HxW")
    p.add_argument("--pairs", type=int, default=8)
    args = p.parse_args(argv)
    from clearsplat.synth import make_world, reconstruct

    h, w = (int(x) for x in args.resolution.split("x"))
    views = [int(v) for v in args.views.split(",")]
    families = args.family.split(",")
    families = families * len(views) if len(families) == 1 else families
    version = subprocess.run([args.other, "-c", "import clearsplat; print(clearsplat.__version__)"],
                             capture_output=True, text=True, check=True).stdout.strip()
    import clearsplat
    print(f"filter time, A: {clearsplat.__version__} ({sys.executable}) against B: {version} "
          f"({args.other}); {os.cpu_count()} cores, {platform.machine()}, {_processor()}")
    print(f"{'family':8} {'views':>5} {'A s':>7} {'B s':>7}  {'A/B per pair':<48} "
          f"{'median':>6}  same removals")
    with tempfile.TemporaryDirectory() as tmp:
        for family, v in zip(families, views):
            world = make_world(family, num_views=v, seed=0, height=h, width=w)
            scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
            del world
            path = os.path.join(tmp, f"{family}-{v}.pkl")
            with open(path, "wb") as f:
                pickle.dump(scene, f)
            del scene
            _once(sys.executable, path), _once(args.other, path)     # untimed
            a, b = [], []
            for _ in range(args.pairs):
                a.append(_once(sys.executable, path))
                b.append(_once(args.other, path))
            ratios = [x[0] / y[0] for x, y in zip(a, b)]
            same = len({r for _, r in a + b}) == 1
            shown = " ".join(f"{r:.2f}" for r in ratios)
            print(f"{family:8} {v:5d} {statistics.median(x for x, _ in a):7.2f} "
                  f"{statistics.median(y for y, _ in b):7.2f}  {shown:<48} "
                  f"{statistics.median(ratios):6.3f}  {same}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
