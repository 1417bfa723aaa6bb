"""``clearsplat bench``: the synthetic benchmark's tables."""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time

from ..errors import ClearsplatError
from ._common import add_config_args, config_from_args, warn


def add_parser(sub) -> None:
    b = sub.add_parser("bench", help="run the synthetic benchmark and print the paper's tables")
    b.add_argument("--families", default="object,street")
    b.add_argument("--views", default="4,8", help="comma-separated view counts (default: %(default)s)")
    b.add_argument("--seeds", default="0", help="comma-separated seeds (default: 0)")
    b.add_argument("--resolution", default="256x448", help="HxW (default: %(default)s)")
    b.add_argument("--configs", help="comma-separated presets to compare, e.g. default,paper-local")
    b.add_argument("--config", action="append", metavar="LABEL=PRESET[+key=value...]",
                   help="a named config, e.g. no-refine=default+refine=none (repeatable)")
    b.add_argument("--realism", default="plain",
                   help="comma-separated backbone scenarios: plain, soft, depth, multi, exposure, "
                        "pose, coarse, all (default: %(default)s; see clearsplat.synth.realism)")
    b.add_argument("--occlusion", default="medium", choices=("low", "medium", "high"),
                   help="how many transients the worlds hold (default: %(default)s)")
    b.add_argument("--transients", default="shots", choices=("shots", "video"),
                   help="shots: each view's transients are its own; video: passers-by stay for "
                        "2-5 consecutive views (street only) (default: %(default)s)")
    b.add_argument("--no-real-check", action="store_true",
                   help="skip the real-image check (Middlebury stereo pair with a pasted object)")
    b.add_argument("--ablation", action="store_true",
                   help="run the ablation of docs/method.md (clearsplat.bench.ABLATIONS)")
    b.add_argument("--workers", type=int, metavar="N",
                   help="run the grid's cells as Ray tasks on N local CPUs (default: one "
                        "after another in this process)")
    b.add_argument("--address", help="run the grid's cells on this Ray cluster ('auto', "
                                     "HOST:PORT or ray://HOST:PORT)")
    b.add_argument("--out", default="bench-out", help="output folder (default: %(default)s)")
    b.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    add_config_args(b)
    b.set_defaults(func=run)


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def check_dependencies(configs: dict, *, real_check: bool) -> None:
    """Raise ImportError (exit 2) for what the run will need and lacks, before any work."""
    need = {}
    if real_check:
        need["skimage"] = ('the real-image check needs scikit-image: pip install '
                           '"clearsplat[bench]" (or pass --no-real-check)')
    for label, cfg in configs.items():
        if cfg.features.startswith("dino"):
            for module in ("torch", "transformers"):
                need.setdefault(module, f"config {label!r} uses the {cfg.features!r} features, "
                                        f'which need torch and transformers: pip install '
                                        f'"clearsplat[dino]" and give --checkpoint DIR')
        if cfg.backend == "torch":
            need.setdefault("torch", f"config {label!r} uses the torch backend, which needs "
                                     'torch: pip install "clearsplat[gpu]"')
        elif cfg.device != "cpu":
            for module in ("torch", "gsplat"):
                need.setdefault(module, f"config {label!r} renders on {cfg.device!r}, which "
                                        f'needs torch with CUDA and gsplat: pip install '
                                        f'"clearsplat[gpu]"')
    for module, message in need.items():
        if not _installed(module):
            raise ImportError(message)
    if not _installed("matplotlib"):
        warn('matplotlib is not installed: gain.png will not be drawn (pip install '
             '"clearsplat[bench]")')


def run(args) -> int:
    from ..bench import (ABLATIONS, format_real_checks, format_tables, parse_config,
                         run_real_checks, run_suite, write_outputs)
    configs = {}
    if args.ablation:
        configs = {label: parse_config(spec) for label, spec in ABLATIONS.items()}
    for name in (args.configs.split(",") if args.configs else []):
        base = argparse.Namespace(**{**vars(args), "preset": name})
        configs[name] = config_from_args(base)
    for item in args.config or []:
        label, _, spec = item.partition("=")
        if not spec:
            raise ClearsplatError(f"expected LABEL=PRESET[+key=value...], got {item!r}",
                                  field="--config")
        configs[label] = parse_config(spec)
    if not configs:
        configs[args.preset] = config_from_args(args)
    try:
        h, w = (int(x) for x in args.resolution.lower().split("x"))
        views = [int(v) for v in args.views.split(",")]
        seeds = [int(v) for v in args.seeds.split(",")]
    except ValueError:
        raise ClearsplatError("expected --resolution HxW and comma-separated integers for "
                              "--views and --seeds", field="--resolution/--views/--seeds") from None
    if args.workers is not None and args.workers < 1:
        raise ClearsplatError(f"must be at least 1, got {args.workers}", field="--workers")
    from ..io.output import check_output_folder, output_folder
    check_output_folder(args.out, force=args.force)
    check_dependencies(configs, real_check=not args.no_real_check)
    t0 = time.perf_counter()

    def log(s):
        print("  " + s, file=sys.stderr)

    rows = run_suite(families=args.families.split(","), views=views, seeds=seeds,
                     configs=configs, height=h, width=w, log=log, workers=args.workers,
                     address=args.address, occlusion=args.occlusion,
                     transients=args.transients,
                     realism=[r.strip() for r in args.realism.split(",") if r.strip()])
    print(format_tables(rows))
    real = None
    if not args.no_real_check:
        real = run_real_checks(configs, log=log)
        print("\n" + format_real_checks(real))
    with output_folder(args.out, force=args.force, command="bench") as tmp:
        names = [os.path.basename(p) for p in write_outputs(rows, tmp, real)]
    paths = [os.path.join(args.out, n) for n in names]
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s; wrote " + ", ".join(paths))
    return 0
