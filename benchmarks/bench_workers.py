"""The benchmark grid on Ray: wall time with 1 and 2 workers (and in-process), in one run.

Usage::

    python benchmarks/bench_workers.py                      # object,street x 4,8 views x 2 seeds
    python benchmarks/bench_workers.py --seeds 0 --repeats 1 --resolution 128x224

Runs :func:`clearsplat.bench.run_suite` on the same grid in three ways, alternating them
``--repeats`` times: one cell after another in this process (``serial``), as Ray tasks on a
local Ray instance with 1 CPU (``ray-1``), and with 2 CPUs (``ray-2``). Wall times include
starting and stopping Ray. Every run must give the same rows (timings aside), so the printed
tables are the same whichever engine ran them. Needs ``pip install 'clearsplat[batch]'``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time


def _strip(rows):
    return [{k: v for k, v in r.items() if not k.startswith("time_")} for r in rows]


def main() -> None:
    from clearsplat.bench import format_tables, run_suite

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--families", default="object,street")
    p.add_argument("--views", default="4,8")
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--resolution", default="128x224")
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    h, w = (int(x) for x in a.resolution.split("x"))
    grid = dict(families=a.families.split(","), views=[int(v) for v in a.views.split(",")],
                seeds=[int(s) for s in a.seeds.split(",")], height=h, width=w)
    modes = {"serial": {}, "ray-1": {"workers": 1}, "ray-2": {"workers": 2}}
    times = {m: [] for m in modes}
    reference = None
    load_before = os.getloadavg()[0]
    for _ in range(a.repeats):
        for mode, kw in modes.items():
            t0 = time.perf_counter()
            rows = run_suite(**grid, **kw)
            times[mode].append(time.perf_counter() - t0)
            if reference is None:
                reference, tables = _strip(rows), format_tables(rows)
            elif _strip(rows) != reference:
                raise SystemExit(f"{mode}: the rows differ from the serial run's")
    cells = len(grid["families"]) * len(grid["views"]) * len(grid["seeds"])
    print(tables.split("\n\nRuntime")[0])
    print(f"\nGrid: {a.families} x views {a.views} x seeds {a.seeds} at {a.resolution} "
          f"({cells} cells); {a.repeats} repeats, alternating; identical rows in every run")
    print(f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, {platform.platform()}; "
          f"load average {load_before:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    base = statistics.median(times["ray-1"])
    print(f"{'engine':<8}{'median s':>10}{'min':>8}{'max':>8}{'vs ray-1':>10}")
    for mode, ts in times.items():
        med = statistics.median(ts)
        print(f"{mode:<8}{med:>10.1f}{min(ts):>8.1f}{max(ts):>8.1f}{base / med:>9.2f}x")


if __name__ == "__main__":
    main()
