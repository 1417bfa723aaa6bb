"""Helpers shared by the commands: progress bar, FilterConfig from options, warnings."""

from __future__ import annotations

import contextlib
import math
import signal
import sys

from ..errors import ClearsplatError

__all__ = ["Bar", "add_config_args", "add_filter_output_args", "config_from_args",
           "sigterm_as_interrupt", "warn", "one_line"]


class Bar:
    """A one-line progress bar on stderr (plain lines when stderr is not a terminal).

    Called as ``bar(stage, done, total)``, the signature of the library's ``progress=``.
    """

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = self.stream.isatty()
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


def config_from_args(args):
    """The :class:`~clearsplat.FilterConfig` that ``--preset``, ``--features``, ``--set`` name."""
    from ..filter.config import FilterConfig, parse_value

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


#: What ``--help`` says of each preset (``clearsplat.filter.PRESETS``).
PRESET_HELP = {
    "default": "clearsplat's default (weight-free 'local' features; docs/method.md)",
    "paper": "the paper's procedure exactly; needs DINOv3: pip install \"clearsplat[dino]\" "
             "and a local checkpoint (--checkpoint DIR)",
    "paper-local": "the paper's procedure with the weight-free 'local' features",
    "exact": "the default without its speed approximations (every view in every camera's "
             "renders, also from 24 views on)",
    "video": "for the frames of a video, where a passer-by stays several frames: the frames "
             "next to each view are left out of its references and do not verify it "
             "(leave_out=1; docs/method.md, \"Video\")",
    "fast": "one round, four neighbours per camera: 0.34-0.42 of the default's time at 8-16 "
            "views, finding less (the default's output up to five views; docs/method.md)",
}


def add_config_args(p) -> None:
    """``--preset``, ``--features``, ``--checkpoint``, ``--set``; the help lists every field."""
    import argparse

    from ..filter.config import FIELD_SPECS, PRESETS

    presets = "; ".join(f"{name}: {PRESET_HELP.get(name, '')}" for name in PRESETS)
    p.add_argument("--preset", default="default", metavar="NAME",
                   help=f"the filter's configuration (default: %(default)s). {presets}")
    p.add_argument("--features", help="feature extractor: "
                   + ", ".join(FIELD_SPECS["features"].choices) + " (default: the preset's)")
    p.add_argument("--checkpoint", help="local DINO checkpoint directory or cached model id "
                                        "(clearsplat never downloads weights)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a FilterConfig field, e.g. --set verify_base=full "
                        "(repeatable; the fields are listed below)")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    width = max(len(k) for k in FIELD_SPECS)
    lines = [f"  {k:<{width}}  {spec.allowed()}" for k, spec in FIELD_SPECS.items()]
    p.epilog = ("--set fields (docs/method.md explains each; true/false, null for None):\n"
                + "\n".join(lines))


def add_filter_output_args(p, *, into: str) -> None:
    """``--keep-all``, ``--report``, ``--copy-images``: what a filter output folder holds.

    ``into`` names that folder in the help (``"--out"``, ``"each output"``).
    """
    p.add_argument("--keep-all", action="store_true",
                   help="keep every Gaussian, removed ones with zero opacity")
    p.add_argument("--report", action="store_true", help="write diagnostic pictures and HTML")
    p.add_argument("--copy-images", action="store_true",
                   help=f"copy the input images into {into} (by default its cameras.json "
                        "refers to them where they are)")


@contextlib.contextmanager
def sigterm_as_interrupt():
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


def one_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def warn(message: str) -> None:
    print("clearsplat: warning: " + " ".join(str(message).split()), file=sys.stderr)
