"""Filter configs on the realism scenarios, one line per (scenario, family, config).

The quick measurement behind the ablation of the options for real backbones in
docs/method.md: cluttered and clean scene of each scenario, PSNR gain over the unfiltered
reconstruction (and its share of the gain of removing exactly the distractors), distractor
recall, share of the other Gaussians removed, and on the clean twin the PSNR change and share
removed.

    python benchmarks/realism_sweep.py --views 4 --realism pose,depth --families object \\
        default default+refine=depth

``--real-check`` adds the real-image check (Middlebury pair) of each config.
"""

from __future__ import annotations

import argparse
import time

from clearsplat.bench import _quality, parse_config
from clearsplat.filter import filter_distractors
from clearsplat.synth import make_world
from clearsplat.synth.realism import realistic_reconstruction


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("configs", nargs="+", help="PRESET[+key=value...] specs")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--realism", default="plain,pose,depth,all")
    ap.add_argument("--families", default="object,street")
    ap.add_argument("--resolution", default="256x448")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real-check", action="store_true",
                    help="also run the real-image check of each config")
    args = ap.parse_args()
    h, w = (int(x) for x in args.resolution.split("x"))
    for scenario in args.realism.split(","):
        for family in args.families.split(","):
            world = make_world(family, num_views=args.views, seed=args.seed, height=h, width=w)
            scene, truth = realistic_reconstruction(world, scenario, seed=args.seed)
            clean, _ = realistic_reconstruction(world, scenario, seed=args.seed, clean=True)

            def q(s, keep):
                return _quality(s, keep, world.test_cameras, world.test_images)["psnr"]
            base, exact, clean_base = q(scene, None), q(scene, ~truth), q(clean, None)
            for spec in args.configs:
                t0 = time.perf_counter()
                cfg = parse_config(spec)
                r = filter_distractors(scene, config=cfg)
                cr = filter_distractors(clean, config=cfg)
                gain = q(scene, r.keep) - base
                print(f"{scenario:8s} {family:6s} {args.views:2d} {spec:58s} gain {gain:+.2f} "
                      f"({100 * gain / (exact - base):4.0f}% of exact) "
                      f"recall {r.removed[truth].mean():.3f} "
                      f"other {100 * r.removed[~truth].mean():5.2f}% | clean "
                      f"{q(clean, cr.keep) - clean_base:+.3f} removed "
                      f"{100 * cr.removed.mean():.2f}% [{time.perf_counter() - t0:.0f} s]",
                      flush=True)
    if args.real_check:
        from clearsplat.bench import format_real_checks, run_real_checks
        print(format_real_checks(run_real_checks({c: parse_config(c) for c in args.configs})))


if __name__ == "__main__":
    main()
