"""Whole-process time of ``clearsplat filter`` on a saved scene bundle (imports, loading,
filtering, writing).

Usage::

    python benchmarks/cli_speed.py                       # 16 views at 192x128 (393,216 Gaussians)
    python benchmarks/cli_speed.py --views 8 --repeats 5
    python benchmarks/cli_speed.py --preset fast

Builds a stand-in object scene once into a temporary folder (not timed), runs the
``clearsplat`` command on it ``--repeats`` times (each a fresh process, output replaced with
``--force``) and prints the median wall-clock seconds, their range, the median CPU seconds
(all threads; less disturbed by a busy machine) and the peak resident memory. Also times ``python -c "import clearsplat.cli"`` alone (the fixed cost of
starting). Python's bytecode cache is used as an installed package would (the environment
variable PYTHONDONTWRITEBYTECODE is cleared for the runs).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time


def _timed(cmd: list, env: dict) -> tuple[float, float, float]:
    """Wall seconds, CPU seconds (all threads) and peak RSS (GB) of one child process, from
    that child's own resource usage (``RUSAGE_CHILDREN`` would also hold whatever this
    process inherited, e.g. from a shell that ran a larger command before it)."""
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - t0
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode:
        raise subprocess.CalledProcessError(child.returncode, cmd)
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 2**20


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=16)
    p.add_argument("--resolution", default="128x192", help="HxW (default 128x192)")
    p.add_argument("--family", default="object")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--keep", help="build the bundle in (and keep) this folder")
    p.add_argument("--preset", default="default",
                   help="passed on to clearsplat filter (default: default)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a filter option, passed on to clearsplat filter (repeatable)")
    args = p.parse_args(argv)
    h, w = (int(x) for x in args.resolution.lower().split("x"))

    from clearsplat.io import save_scene
    from clearsplat.synth import make_world, reconstruct

    root = args.keep or tempfile.mkdtemp(prefix="clearsplat-cli-speed-")
    bundle, out = os.path.join(root, "scene"), os.path.join(root, "filtered")
    if not os.path.exists(os.path.join(bundle, "gaussians.ply")):
        world = make_world(args.family, num_views=args.views, seed=0, height=h, width=w)
        save_scene(reconstruct(world.cameras, world.images, world.depths, seed=0), bundle,
                   overwrite=True)
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    exe = [sys.executable, "-m", "clearsplat"]
    _timed([sys.executable, "-c", "import clearsplat.cli"], env)      # warm the bytecode cache
    imports = [_timed([sys.executable, "-c", "import clearsplat.cli"], env)
               for _ in range(args.repeats)]
    options = ["--preset", args.preset] + [a for kv in args.set for a in ("--set", kv)]
    runs = [_timed(exe + ["filter", bundle, "--out", out, "--force"] + options, env)
            for _ in range(args.repeats)]
    walls = [r[0] for r in runs]
    print(f"clearsplat filter, whole process — {args.family}, {args.views} views at {w}x{h}, "
          f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}, load "
          f"{os.getloadavg()[0]:.1f}; {args.repeats} runs"
          + (f"; preset {args.preset}" if args.preset != "default" else "")
          + (f"; {' '.join(args.set)}" if args.set else ""))
    print(f"  wall s: median {statistics.median(walls):.2f}, range {min(walls):.2f}-"
          f"{max(walls):.2f}; CPU s (all threads): median "
          f"{statistics.median(r[1] for r in runs):.2f}; peak RSS {max(r[2] for r in runs):.2f} GB")
    print(f"  'import clearsplat.cli' alone: wall median "
          f"{statistics.median(r[0] for r in imports):.2f} s, CPU median "
          f"{statistics.median(r[1] for r in imports):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
