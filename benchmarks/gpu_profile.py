"""Where the filter's time goes on a GPU: kernels, launches, host syncs (torch backend).

Usage::

    python benchmarks/gpu_profile.py [--views 8] [--resolution 256x448] [--family object]
                                     [--device cuda] [--set KEY=VALUE ...] [--trace FILE]

One stand-in scene; the filter runs once to warm up (module loads, allocator, lookups) and
once under ``torch.profiler``. Prints the run's seconds, the seconds the device spent in
kernels and copies, the counts of the CUDA runtime calls (kernel launches, copies, syncs), the
filter's per-step seconds, and the ops that take the most device time and the most host time. When the kernels' time is a small share of the run, the run is bound by
launches and host work, not by the GPU. ``--trace`` writes a Chrome trace
(``chrome://tracing``, Perfetto). Also runs with ``--device cpu`` (no kernel rows then).
"""

from __future__ import annotations

import argparse
import collections
import time


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=8)
    p.add_argument("--resolution", default="256x448", help="HxW")
    p.add_argument("--family", default="object")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cuda")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a FilterConfig field, VALUE as in `clearsplat bench --config`")
    p.add_argument("--rows", type=int, default=15, help="ops listed per table")
    p.add_argument("--trace", help="write a Chrome trace to this file")
    args = p.parse_args(argv)

    import torch
    from torch.profiler import ProfilerActivity, profile

    from clearsplat.bench import parse_config
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world, reconstruct

    cfg = parse_config("+".join(["default", "backend=torch", f"device={args.device}"]
                                + args.set))
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    world = make_world(args.family, num_views=args.views, seed=args.seed, height=h, width=w)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=args.seed)
    extractor = get_extractor("local")
    cuda = args.device.startswith("cuda")

    t = time.perf_counter()
    filter_distractors(scene, config=cfg, extractor=extractor)
    warm = time.perf_counter() - t
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    if cuda:
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    with profile(activities=activities) as prof:
        t = time.perf_counter()
        result = filter_distractors(scene, config=cfg, extractor=extractor)
        if cuda:
            torch.cuda.synchronize()
        wall = time.perf_counter() - t
    events = prof.events()
    avg = prof.key_averages()
    # Device time: the device-side rows alone (kernels, copies, memsets), as the table's footer
    # sums them; the aten rows above them carry the same time again.
    device_us = sum(e.self_device_time_total for e in avg if str(e.device_type).endswith("CUDA"))
    # CUDA runtime calls on the host (launches, copies, syncs), by name and count.
    runtime = collections.Counter(e.name for e in events if e.name.startswith("cu"))
    aten = sum(1 for e in events if e.name.startswith("aten::"))
    print(f"clearsplat on {args.device}"
          + (f" ({torch.cuda.get_device_name()})" if cuda else "")
          + f" — {args.family}, {args.views} views at {w}x{h}, {len(scene):,} Gaussians, "
          f"torch {torch.__version__}; {len(result.candidates)} candidates, "
          f"{int(result.removed.sum()):,} removed")
    print(f"warm-up run {warm:.2f} s; profiled run {wall:.2f} s (the profiler adds overhead; "
          f"{result.timings['total']:.2f} s by the filter's own clock)")
    if cuda:
        print(f"device time {device_us / 1e6:.3f} s ({100 * device_us / 1e6 / wall:.1f} % of "
              f"the run); peak GPU memory {torch.cuda.max_memory_allocated() / 1e9:.2f} GB")
        print("CUDA runtime calls: " + ", ".join(f"{n} {c:,}" for n, c in runtime.most_common(8)))
    print(f"{aten:,} aten ops")
    print("\nper step (seconds, the filter's clock):")
    for k, v in result.timings.items():
        if "." in k:
            print(f"  {k:<32}{v:>8.2f}")
    if cuda:
        print(f"\nops by device time (top {args.rows}):")
        print(avg.table(sort_by="device_time_total", row_limit=args.rows, max_name_column_width=48))
    print(f"\nops by host time (top {args.rows}):")
    print(avg.table(sort_by="self_cpu_time_total", row_limit=args.rows, max_name_column_width=48))
    if args.trace:
        prof.export_chrome_trace(args.trace)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
