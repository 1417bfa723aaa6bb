"""The ``clearsplat`` command line: parses, calls public functions, prints.

One module per command, each with ``add_parser(subparsers)`` and ``run(args) -> int``; add a
new command to :data:`COMMANDS`. Bad input is reported on one line (``clearsplat: error: ...``)
with exit code 2, warnings on one line each (``clearsplat: warning: ...``); ``docs/errors.md``
lists them. Commands that write a folder go through :func:`clearsplat.io.output.output_folder`:
a failed or interrupted run leaves nothing behind and nothing the user owns is replaced.
"""

from __future__ import annotations

import argparse
import importlib
import keyword
import sys

from ..errors import ClearsplatError
from ._common import one_line, sigterm_as_interrupt

__all__ = ["main", "build_parser", "COMMANDS"]

#: The commands, in the order ``clearsplat --help`` lists them; each is the module of that
#: name (with a trailing underscore where the name is a Python keyword: ``import_``).
COMMANDS = ("demo", "import", "filter", "edit", "view", "video", "render", "export", "batch",
            "bench", "prepare", "eval")


class _Parser(argparse.ArgumentParser):
    """Usage errors on one line, like every other error (exit code 2)."""

    def error(self, message):
        self.exit(2, f"clearsplat: error: {self.prog}: {' '.join(message.split())} "
                     f"(see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    p = _Parser(prog="clearsplat", description=(
        "Remove transient distractors from feed-forward 3D Gaussian Splatting predictions."),
        epilog="Run 'clearsplat COMMAND --help' for a command's options; docs/errors.md lists "
               "every error and exit code.")
    p.add_argument("--version", action="version", version=f"clearsplat {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = f"{name}_" if keyword.iskeyword(name) else name
        importlib.import_module(f"{__name__}.{module}").add_parser(sub)
    return p


def main(argv=None) -> int:
    """Run the command line; returns the exit code (0, 2 for bad input, 130 interrupted).

    ``clearsplat`` without a command prints the help and returns 0, as ``pip`` does: asking
    for nothing is asking what there is.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        with sigterm_as_interrupt():
            return args.func(args)
    except ClearsplatError as e:
        print(f"clearsplat: error: {one_line(e)}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"clearsplat: error: {one_line(e)}", file=sys.stderr)
        return 2
    except MemoryError:
        print("clearsplat: error: out of memory (see 'memory' in docs/errors.md)",
              file=sys.stderr)
        return 1
    except OSError as e:                # disk full, permissions: not the input's fault
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"clearsplat: error: {where}{e.strerror or one_line(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("clearsplat: interrupted; nothing was written", file=sys.stderr)
        return 130
