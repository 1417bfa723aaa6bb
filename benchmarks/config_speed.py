"""Filter time of several configs on one stand-in scene, interleaved in one process.

For A/B comparisons on a shared machine: the configs run in turn, ``--repeats`` rounds, on the
same scene and extractor, so that load changes affect them alike. Prints per config the median
of the totals and of the main stages (seconds).

    python benchmarks/config_speed.py --views 16 default \\
        one-round=default+rounds=1
"""

from __future__ import annotations

import argparse
import statistics

from clearsplat.bench import parse_config
from clearsplat.features import get_extractor
from clearsplat.filter import filter_distractors
from clearsplat.synth import make_world, reconstruct

STAGES = ("total", "proposal", "proposal.refine", "verification")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("configs", nargs="+", help="[LABEL=]PRESET[+key=value...]")
    ap.add_argument("--views", type=int, default=16)
    ap.add_argument("--family", default="object")
    ap.add_argument("--resolution", default="256x448")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    h, w = (int(x) for x in args.resolution.split("x"))
    world = make_world(args.family, num_views=args.views, seed=0, height=h, width=w)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    extractor = get_extractor("local")
    configs = {}
    for spec in args.configs:
        label, _, rest = spec.partition("=") if "=" in spec.split("+")[0] else ("", "", spec)
        configs[label or spec] = parse_config(rest or spec)
    times = {k: {s: [] for s in STAGES} for k in configs}
    for _ in range(args.repeats):
        for label, cfg in configs.items():
            r = filter_distractors(scene, config=cfg, extractor=extractor)
            for s in STAGES:
                times[label][s].append(r.timings.get(s, 0.0))
    print(f"{args.family}, {args.views} views, {args.resolution}, {args.repeats} rounds "
          f"(medians, s)")
    print(f"{'config':20s}" + "".join(f"{s:>18s}" for s in STAGES))
    for label, t in times.items():
        print(f"{label:20s}" + "".join(f"{statistics.median(t[s]):18.2f}" for s in STAGES))


if __name__ == "__main__":
    main()
