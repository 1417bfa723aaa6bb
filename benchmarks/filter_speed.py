"""Filter speed on stand-in scenes: per-stage seconds, incremental vs full verification, memory.

Usage::

    python benchmarks/filter_speed.py                       # 4, 8, 16 views at 256x448
    python benchmarks/filter_speed.py --views 8 --repeats 5 --full-repeats 1
    python benchmarks/filter_speed.py --views 8,16,32 --resolution 128x224 --family street
    python benchmarks/filter_speed.py --views 64 --repeats 1 --full-repeats 0   # dense capture
    python benchmarks/filter_speed.py --device cuda --views 4,8,16     # GPU, against the CPU
    python benchmarks/filter_speed.py --views 8,16 --preset fast      # one round, 4 neighbours

Each view count runs in a fresh subprocess so that its peak resident memory is its own.
Times are medians over ``--repeats`` runs of the default filter (incremental verification) and
over ``--full-repeats`` runs of the same filter with ``incremental=False`` (whole images
re-rendered for every candidate and view); both runs must produce identical output. With
``--device cuda`` the second set of runs is the native CPU filter instead, *GPU peak* the
most GPU memory PyTorch allocated during the device runs, and one untimed run on a small scene
comes first (CUDA's start and the kernels' loading stay out of the figures). *min-max* is the
range of the incremental runs' totals, *first* the first of them (on the CPU, a fresh process:
what a single ``clearsplat filter`` call sees, page faults of new memory included). *prepared*
counts camera preparations per run (the number of views, plus views prepared again because they did
not fit in ``--view-memory``; with several rounds, each round's), *derived* those of them that
a later round took from the round before without projecting again
(:meth:`~clearsplat.render.PreparedView.restrict`), *skipped* the (view, pass) visits left out because the view sees
none of the Gaussians concerned, *views GB* the most the prepared views held at once; *CPU s*
the process CPU time of a run (median; with ``--threads 1`` a measure of the work done that a
busy machine disturbs far less than wall-clock time); *proposed* the share of the input pixels
in proposal regions, mean over the views.
Full-render verification is skipped above 16 views (it re-renders every image per candidate).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time


def _case(views: int, height: int, width: int, repeats: int, full_repeats: int,
          family: str, seed: int, view_memory: float | None, threads: int | None,
          device: str = "cpu", overrides: tuple = (), preset: str = "default") -> dict:
    import numpy as np

    from clearsplat._memory import estimate_filter_memory
    from clearsplat.bench import parse_value
    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors
    from clearsplat.synth import make_world, reconstruct

    world = make_world(family, num_views=views, seed=seed, height=height, width=width)
    t0 = time.perf_counter()
    scene = reconstruct(world.cameras, world.images, world.depths, seed=seed)
    t_recon = time.perf_counter() - t0
    # The filter's process holds the scene, not the synthetic world's ground truth (its clean
    # images, depths and masks): the peak memory below is the filter's.
    del world
    extractor = get_extractor("local")
    options = {f.name for f in dataclasses.fields(FilterConfig)}
    cfg = FilterConfig.preset(preset).replace(
        num_threads=threads,
        **({"view_memory": view_memory} if "view_memory" in options else {}),
        **({"device": device} if device != "cpu" else {}))
    for item in overrides:   # --set KEY=VALUE, read as `clearsplat bench --config` reads it
        key, _, value = item.partition("=")
        cfg = cfg.replace(**{key: parse_value(value)})
    if views > 16 and device == "cpu":
        full_repeats = 0

    def run(config):
        # Keep what is reported, not the result: a caller holds one result at a time, and
        # holding all of them would make every run allocate fresh memory.
        cpu0 = time.process_time()
        r = filter_distractors(scene, config=config, extractor=extractor)
        cpu = time.process_time() - cpu0
        return {"timings": r.timings, "keep": r.keep, "candidates": len(r.candidates),
                "accepted": sum(c.accepted for c in r.candidates),
                "stats": getattr(r, "stats", {}),
                # Share of the input pixels in proposal regions (M_i^1 | M_i^2), mean over views.
                "proposed": float(np.mean([(p.mask1 | p.mask2).mean() for p in r.proposals]))
                if r.proposals else 0.0,
                "cpu": cpu}

    gpu = device != "cpu"
    if gpu:
        import torch

        # One untimed run on a small scene first: CUDA's start and the loading of each kernel
        # on first use would otherwise land in the first timed run.
        small = make_world(family, num_views=min(views, 4), seed=seed, height=64, width=112)
        filter_distractors(reconstruct(small.cameras, small.images, small.depths, seed=seed),
                           config=cfg, extractor=extractor)
        torch.cuda.synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)
    inc = [run(cfg) for _ in range(repeats)]
    gpu_peak = torch.cuda.max_memory_allocated(device) / 1e9 if gpu else None
    # On a GPU the second set of runs is the native CPU filter: the same decisions are expected.
    other = (cfg.replace(incremental=False) if not gpu
             else cfg.replace(device="cpu", backend="auto"))
    full = [run(other) for _ in range(full_repeats)]
    same = all(np.array_equal(inc[0]["keep"], r["keep"]) for r in inc + full)

    def med(runs, key):
        return statistics.median(r["timings"][key] for r in runs)

    out = {
        "views": views, "gaussians": len(scene), "family": family,
        "reconstruct_s": t_recon,
        "proposal_s": med(inc, "proposal"), "verification_s": med(inc, "verification"),
        "total_s": med(inc, "total"),
        "cpu_s": statistics.median(r["cpu"] for r in inc),
        # The first run of the process: what one `clearsplat filter` call sees (fresh memory).
        "first_total_s": inc[0]["timings"]["total"],
        "range_total_s": [min(r["timings"]["total"] for r in inc),
                          max(r["timings"]["total"] for r in inc)],
        "candidates": inc[0]["candidates"],
        "accepted": inc[0]["accepted"],
        "identical_output": bool(same),
        "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
        "gpu_peak_gb": gpu_peak,
        "views_prepared": inc[0]["stats"].get("views_prepared", 0),
        "views_derived": inc[0]["stats"].get("views_derived", 0),
        "views_skipped": inc[0]["stats"].get("views_skipped", 0),
        "views_peak_gb": inc[0]["stats"].get("views_peak_bytes", 0) / 1e9,
        "proposed_share": inc[0]["proposed"],
        "view_memory": view_memory,
        "memory_estimate_gb": estimate_filter_memory(
            len(scene), scene.cameras,
            **({"view_budget": None if view_memory is None else int(view_memory * 1e9)}
               if "view_memory" in options else {})) / 1e9,
    }
    out["steps"] = {k: med(inc, k) for k in inc[0]["timings"] if "." in k}
    if full:
        out["full_total_s"] = med(full, "total")
        out["full_verification_s"] = med(full, "verification")
        out["speedup"] = out["full_verification_s"] / out["verification_s"]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", default="4,8,16")
    p.add_argument("--resolution", default="256x448", help="HxW")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--full-repeats", type=int, default=1,
                   help="runs with full re-rendering (0 to skip; slow at 16 views)")
    p.add_argument("--family", default="object")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--view-memory", default="2.0",
                   help="FilterConfig.view_memory in GB, or 'none' (default 2.0, the default)")
    p.add_argument("--threads", type=int, help="FilterConfig.num_threads (default: all cores)")
    p.add_argument("--device", default="cpu",
                   help="FilterConfig.device, e.g. cuda (then the --full-repeats runs are the "
                        "CPU filter, and 'same output' compares the two)")
    p.add_argument("--preset", default="default",
                   help="the FilterConfig preset every run starts from (default: default)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a FilterConfig field for every run, VALUE as in `clearsplat bench --config` (e.g. backend=torch)")
    p.add_argument("--json", help="also write the rows to this file")
    p.add_argument("--_child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    view_memory = None if args.view_memory.lower() == "none" else float(args.view_memory)
    if args._child:
        row = _case(int(args._child), h, w, args.repeats, args.full_repeats, args.family,
                    args.seed, view_memory, args.threads, args.device, tuple(args.set),
                    args.preset)
        print(json.dumps(row))
        return 0
    rows = []
    for v in [int(x) for x in args.views.split(",")]:
        cmd = [sys.executable, os.path.abspath(__file__), "--_child", str(v),
               "--resolution", args.resolution, "--repeats", str(args.repeats),
               "--full-repeats", str(args.full_repeats), "--family", args.family,
               "--seed", str(args.seed), "--view-memory", args.view_memory,
               "--preset", args.preset]
        if args.threads:
            cmd += ["--threads", str(args.threads)]
        if args.device != "cpu":
            cmd += ["--device", args.device]
        for item in args.set:
            cmd += ["--set", item]
        res = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"  done: {v} views, {rows[-1]['total_s']:.2f} s", file=sys.stderr)
        if args.json:      # row by row, so that a run stopped early keeps what it measured
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
    print(f"clearsplat filter speed — {args.family} scenes at {w}x{h}, "
          f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}, load "
          f"{os.getloadavg()[0]:.1f}; medians of {args.repeats} (incremental) / "
          f"{args.full_repeats} ({'full' if args.device == 'cpu' else 'CPU'}) runs; "
          f"view_memory {args.view_memory} GB; device {args.device}"
          + (f"; preset {args.preset}" if args.preset != "default" else "")
          + "".join(f"; {item}" for item in args.set))
    hdr = (f"{'views':>5} {'Gaussians':>10} {'cands':>6} {'proposal s':>10} {'verify s':>9} "
           f"{'total s':>8} {'min-max':>11} {'first':>6} {'full verify s':>13} {'speedup':>8} {'peak RSS GB':>11} "
           f"{'same output':>11}")
    print(hdr)
    for r in rows:
        full = r.get("full_verification_s")
        print(f"{r['views']:>5} {r['gaussians']:>10,} {r['candidates']:>6} "
              f"{r['proposal_s']:>10.2f} {r['verification_s']:>9.2f} {r['total_s']:>8.2f} "
              f"{'%.2f-%.2f' % tuple(r['range_total_s']):>11} {r['first_total_s']:>6.2f} "
              f"{('%.2f' % full) if full else 'n/a':>13} "
              f"{('%.1fx' % r['speedup']) if full else 'n/a':>8} {r['peak_rss_gb']:>11.2f} "
              f"{str(r['identical_output']):>11}")
    base = next((r for r in rows if r["views"] == 8), rows[0])
    print(f"\n{'views':>5} {'CPU s':>7} {'x CPU':>6} {'x time':>7} {'x peak':>7} "
          f"{'prepared':>9} {'derived':>8} {'skipped':>8} {'views GB':>9} {'estimate GB':>12} "
          f"{'proposed':>9}   "
          f"(x: against {base['views']} views)")
    for r in rows:
        print(f"{r['views']:>5} {r['cpu_s']:>7.2f} {r['cpu_s'] / base['cpu_s']:>6.2f} "
              f"{r['total_s'] / base['total_s']:>7.2f} "
              f"{r['peak_rss_gb'] / base['peak_rss_gb']:>7.2f} {r['views_prepared']:>9} "
              f"{r.get('views_derived', 0):>8} {r['views_skipped']:>8} {r['views_peak_gb']:>9.2f} "
              f"{r['memory_estimate_gb']:>12.2f} {100 * r.get('proposed_share', 0.0):>8.1f}%"
              + (f"   GPU peak {r['gpu_peak_gb']:.2f} GB" if r.get("gpu_peak_gb") else ""))
    steps = list(dict.fromkeys(k for r in rows for k in r["steps"]))
    print("\nwhere the time goes (seconds, medians):")
    print(f"{'step':<32}" + "".join(f"{str(r['views']) + ' views':>10}" for r in rows))
    for k in steps:
        print(f"{k:<32}" + "".join(f"{r['steps'].get(k, 0.0):>10.2f}" for r in rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
