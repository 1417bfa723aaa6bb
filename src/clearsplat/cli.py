"""The ``clearsplat`` command line: parses, calls public functions, prints.

Bad input is reported on one line (``clearsplat: error: ...``) with exit code 2, warnings on
one line each (``clearsplat: warning: ...``); ``docs/errors.md`` lists them. ``filter`` writes
its output into a hidden temporary folder beside ``--out`` and renames it into place at the
end, so a failed or interrupted run leaves nothing behind.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import signal
import sys
import tempfile
import time
import warnings

import numpy as np

from .errors import ClearsplatError
from .bench import parse_value
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


def _config(args) -> FilterConfig:
    overrides = {}
    for item in args.set or []:
        if "=" not in item:
            raise ClearsplatError(f"expected KEY=VALUE, got {item!r}", field="--set")
        k, v = item.split("=", 1)
        value = parse_value(v.strip())
        if isinstance(value, float) and not math.isfinite(value):
            raise ClearsplatError(f"non-finite value in {item!r}", field="--set")
        overrides[k.strip().replace("-", "_")] = value
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
    from .bench import (ABLATIONS, format_real_checks, format_tables, parse_config,
                        run_real_checks, run_suite, write_outputs)
    configs = {}
    if args.ablation:
        configs = {label: parse_config(spec) for label, spec in ABLATIONS.items()}
    for name in (args.configs.split(",") if args.configs else []):
        base = argparse.Namespace(**{**vars(args), "preset": name})
        configs[name] = _config(base)
    for item in args.config or []:
        label, _, spec = item.partition("=")
        if not spec:
            raise ClearsplatError(f"expected LABEL=PRESET[+key=value...], got {item!r}",
                                  field="--config")
        configs[label] = parse_config(spec)
    if not configs:
        configs[args.preset] = _config(args)
    try:
        h, w = (int(x) for x in args.resolution.lower().split("x"))
        views = [int(v) for v in args.views.split(",")]
        seeds = [int(v) for v in args.seeds.split(",")]
    except ValueError:
        raise ClearsplatError("expected --resolution HxW and comma-separated integers for "
                              "--views and --seeds", field="--resolution/--views/--seeds") from None
    t0 = time.perf_counter()

    def log(s):
        print("  " + s, file=sys.stderr)

    rows = run_suite(families=args.families.split(","), views=views, seeds=seeds,
                     configs=configs, height=h, width=w, log=log)
    print(format_tables(rows))
    real = None
    if not args.no_real_check:
        real = run_real_checks(configs, log=log)
        print("\n" + format_real_checks(real))
    paths = write_outputs(rows, args.out, real)
    print(f"\n{len(rows)} runs in {time.perf_counter() - t0:.0f} s; wrote " + ", ".join(paths))
    return 0


#: Files that mark a folder as the output of an earlier ``clearsplat filter``.
_OUTPUT_MARKERS = ("removed.npy", "summary.json")


def _check_out(out: str, scene: str, force: bool, given: str) -> None:
    """Refuse an --out that would replace the input or an unrelated non-empty folder."""
    real_out, real_scene = os.path.realpath(out), os.path.realpath(scene)
    if real_out == real_scene or real_scene.startswith(real_out.rstrip(os.sep) + os.sep):
        raise ClearsplatError("would replace the input bundle (it is or contains SCENE); "
                              "choose another folder", path=given, field="--out")
    if not os.path.lexists(out):
        return
    if not os.path.isdir(out) or os.path.islink(out):
        if not force:
            raise ClearsplatError("exists and is not a folder; pass --force to replace it",
                                  path=given, field="--out")
        return
    if not os.listdir(out):
        return
    if not force:
        raise ClearsplatError("exists and is not empty; pass --force to replace it",
                              path=given, field="--out")
    if not any(os.path.exists(os.path.join(out, m)) for m in _OUTPUT_MARKERS):
        raise ClearsplatError("refusing to replace a non-empty folder that is not the output "
                              "of clearsplat filter (no removed.npy or summary.json)",
                              path=given, field="--out")


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Turn SIGTERM into KeyboardInterrupt so that cleanup runs (main thread only)."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    try:
        old = signal.signal(signal.SIGTERM, handler)
    except (ValueError, AttributeError):      # not the main thread
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)


def _warn(message: str) -> None:
    print("clearsplat: warning: " + " ".join(str(message).split()), file=sys.stderr)


def _makedirs(parent: str) -> list:
    """Create ``parent`` and its missing ancestors; return those created, deepest first."""
    made = []
    p = parent
    while p and not os.path.exists(p):
        made.append(p)
        p = os.path.dirname(p.rstrip(os.sep))
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as e:
        raise ClearsplatError(f"cannot create the folder ({e.strerror})", path=parent,
                              field="--out") from None
    return made


def _write_outputs(tmp: str, args, scene, result) -> None:
    from .io import write_ply
    from .report import write_report

    if args.keep_all:
        kept = result.apply(scene)
        write_ply(os.path.join(tmp, "gaussians.ply"), kept.gaussians,
                  view_id=kept.view_id, pixel_id=kept.pixel_id)
    else:
        sub = scene.subset(result.keep)
        write_ply(os.path.join(tmp, "gaussians.ply"), sub.gaussians,
                  view_id=sub.view_id, pixel_id=sub.pixel_id)
    np.save(os.path.join(tmp, "removed.npy"), np.ascontiguousarray(result.removed, dtype=bool))
    with open(os.path.join(tmp, "summary.json"), "w") as f:
        json.dump(result.summary(), f, indent=1)
    if args.report:
        write_report(os.path.join(tmp, "report"), scene, result)


def _cmd_filter(args) -> int:
    from .filter import filter_distractors
    from .io import load_scene, swap_into_place

    out = os.path.abspath(args.out)
    _check_out(out, args.scene, args.force, args.out)
    config = _config(args)
    scene = load_scene(args.scene)
    print(f"{len(scene):,} Gaussians, {scene.num_views} views")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = filter_distractors(scene, config=config, progress=_Bar())
        except ClearsplatError as e:
            if e.path is None:          # an in-memory check: the scene is the file at fault
                raise ClearsplatError(e.reason, path=args.scene, field=e.field) from None
            raise
    shown = set()
    for message in [str(w.message) for w in caught] + list(result.warnings):
        if message not in shown:
            shown.add(message)
            _warn(message)

    parent = os.path.dirname(out) or "."
    made = _makedirs(parent)
    tmp = None
    try:
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.clearsplat-", dir=parent)
        _write_outputs(tmp, args, scene, result)
        swap_into_place(tmp, out)     # an existing --out was checked by _check_out
        tmp = None
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        for d in made:                  # deepest first; only if still empty
            with contextlib.suppress(OSError):
                os.rmdir(d)
        raise
    s = result.summary()
    print(f"removed {s['removed']:,} of {s['gaussians']:,} Gaussians "
          f"({s['accepted']} of {len(s['candidates'])} candidates); wrote {args.out}")
    return 0


class _Parser(argparse.ArgumentParser):
    """Usage errors on one line, like every other error (exit code 2)."""

    def error(self, message):
        self.exit(2, f"clearsplat: error: {self.prog}: {' '.join(message.split())} "
                     f"(see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="clearsplat", description=(
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
    b.add_argument("--views", default="4,8", help="comma-separated view counts (default: %(default)s)")
    b.add_argument("--seeds", default="0", help="comma-separated seeds (default: 0)")
    b.add_argument("--resolution", default="256x448", help="HxW (default: %(default)s)")
    b.add_argument("--configs", help="comma-separated presets to compare, e.g. default,paper-local")
    b.add_argument("--config", action="append", metavar="LABEL=PRESET[+key=value...]",
                   help="a named config, e.g. no-refine=default+refine=none (repeatable)")
    b.add_argument("--no-real-check", action="store_true",
                   help="skip the real-image check (Middlebury stereo pair with a pasted object)")
    b.add_argument("--ablation", action="store_true",
                   help="run the ablation of docs/method.md (clearsplat.bench.ABLATIONS)")
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
    """Run the command line; returns the exit code (0, 2 for bad input, 130 interrupted)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with _sigterm_as_interrupt():
            return args.func(args)
    except ClearsplatError as e:
        print(f"clearsplat: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"clearsplat: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except MemoryError:
        print("clearsplat: error: out of memory (see 'memory' in docs/errors.md)",
              file=sys.stderr)
        return 1
    except OSError as e:                # disk full, permissions: not the input's fault
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"clearsplat: error: {where}{e.strerror or _one_line(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("clearsplat: interrupted; nothing was written", file=sys.stderr)
        return 130


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


if __name__ == "__main__":
    sys.exit(main())
