"""The ``clearsplat`` command line: parses, calls public functions, prints.

Bad input is reported on one line (``clearsplat: error: ...``) with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np

from .errors import ClearsplatError
from .filter import FilterConfig

__all__ = ["main"]


class _Bar:
    """A one-line progress bar on stderr (plain lines when stderr is not a terminal)."""

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = stream.isatty()
        self.last = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.tty:
            width = 24
            fill = int(width * done / max(total, 1))
            self.stream.write(f"\r  {stage:<11} [{'#' * fill}{'.' * (width - fill)}] "
                              f"{done}/{total}")
            if done >= total:
                self.stream.write("\n")
            self.stream.flush()
        elif done >= total and stage != self.last:
            self.stream.write(f"  {stage}: {total}/{total}\n")
            self.last = stage


def _parse_value(text: str):
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def _config(args) -> FilterConfig:
    overrides = {}
    for item in args.set or []:
        if "=" not in item:
            raise ClearsplatError(f"expected KEY=VALUE, got {item!r}", field="--set")
        k, v = item.split("=", 1)
        overrides[k.strip().replace("-", "_")] = _parse_value(v.strip())
    if getattr(args, "features", None):
        overrides["features"] = args.features
    if getattr(args, "checkpoint", None):
        overrides["checkpoint"] = args.checkpoint
    return FilterConfig.preset(args.preset).replace(**overrides)


def _add_config_args(p):
    p.add_argument("--preset", default="default", help="'default' or 'paper' (default: default)")
    p.add_argument("--features", help="feature extractor: local, rgb, dinov2, dinov3")
    p.add_argument("--checkpoint", help="local DINO checkpoint directory or cached model id")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a FilterConfig field, e.g. --set verify_base=full (repeatable)")


def _cmd_demo(args) -> int:
    from .demo import run_demo
    run_demo(args.out, family=args.family, num_views=args.views, seed=args.seed,
             config=_config(args), log=print, progress=_Bar())
    return 0


def _cmd_bench(args) -> int:
    from .bench import format_tables, run_suite, write_outputs
    configs = {}
    names = args.configs.split(",") if args.configs else [args.preset]
    for name in names:
        base = argparse.Namespace(**{**vars(args), "preset": name})
        configs[name] = _config(base)
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    t0 = time.perf_counter()
    rows = run_suite(families=args.families.split(","),
                     views=[int(v) for v in args.views.split(",")],
                     seeds=[int(s) for s in args.seeds.split(",")], configs=configs,
                     height=h, width=w, log=lambda s: print("  " + s, file=sys.stderr))
    print(format_tables(rows))
    paths = write_outputs(rows, args.out)
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s; wrote " + ", ".join(paths))
    return 0


def _cmd_filter(args) -> int:
    from .filter import filter_distractors
    from .io import load_scene, write_ply
    from .report import write_report

    out = os.path.abspath(args.out)
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)) and not args.force:
        raise ClearsplatError("exists and is not empty; pass --force to replace it",
                              path=args.out, field="--out")
    scene = load_scene(args.scene)
    config = _config(args)
    print(f"{len(scene):,} Gaussians, {scene.num_views} views", file=sys.stderr)
    result = filter_distractors(scene, config=config, progress=_Bar())
    parent = os.path.dirname(out) or "."
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=".clearsplat-", dir=parent)
    try:
        if args.keep_all:
            kept = result.apply(scene)
            write_ply(os.path.join(tmp, "gaussians.ply"), kept.gaussians,
                      view_id=kept.view_id, pixel_id=kept.pixel_id)
        else:
            sub = scene.subset(result.keep)
            write_ply(os.path.join(tmp, "gaussians.ply"), sub.gaussians,
                      view_id=sub.view_id, pixel_id=sub.pixel_id)
        np.save(os.path.join(tmp, "removed.npy"), result.removed)
        with open(os.path.join(tmp, "summary.json"), "w") as f:
            json.dump(result.summary(), f, indent=1)
        if args.report:
            write_report(os.path.join(tmp, "report"), scene, result)
        if os.path.exists(out):
            shutil.rmtree(out) if os.path.isdir(out) else os.remove(out)
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    s = result.summary()
    print(f"removed {s['removed']:,} of {s['gaussians']:,} Gaussians "
          f"({s['accepted']} of {len(s['candidates'])} candidates); wrote {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="clearsplat", description=(
        "Remove transient distractors from feed-forward 3D Gaussian Splatting predictions."))
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="build, reconstruct and filter one synthetic cluttered scene")
    d.add_argument("--out", default="clearsplat-demo", help="output folder (default: %(default)s)")
    d.add_argument("--family", default="object", choices=["object", "street"])
    d.add_argument("--views", type=int, default=8)
    d.add_argument("--seed", type=int, default=0)
    _add_config_args(d)
    d.set_defaults(func=_cmd_demo)

    b = sub.add_parser("bench", help="run the synthetic benchmark and print the paper's tables")
    b.add_argument("--families", default="object,street")
    b.add_argument("--views", default="4,8", help="comma-separated view counts (default: 4,8)")
    b.add_argument("--seeds", default="0", help="comma-separated seeds (default: 0)")
    b.add_argument("--resolution", default="128x224", help="HxW (default: %(default)s)")
    b.add_argument("--configs", help="comma-separated presets to compare, e.g. default,paper")
    b.add_argument("--out", default="bench-out", help="output folder (default: %(default)s)")
    _add_config_args(b)
    b.set_defaults(func=_cmd_bench)

    f = sub.add_parser("filter", help="filter a scene bundle")
    f.add_argument("scene", help="bundle folder: cameras.json or transforms.json, images/, "
                                 "gaussians.ply")
    f.add_argument("--out", required=True, help="output folder")
    f.add_argument("--keep-all", action="store_true",
                   help="keep every Gaussian, removed ones with zero opacity")
    f.add_argument("--report", action="store_true", help="write diagnostic pictures and HTML")
    f.add_argument("--force", action="store_true", help="replace a non-empty --out")
    _add_config_args(f)
    f.set_defaults(func=_cmd_filter)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ClearsplatError as e:
        print(f"clearsplat: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"clearsplat: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("clearsplat: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
