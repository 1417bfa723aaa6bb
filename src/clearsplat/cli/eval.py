"""``clearsplat eval``: score predictions and their filtered versions on the test views, in the
shape of the paper's main table."""

from __future__ import annotations

import json
import sys

from ..errors import ClearsplatError


def add_parser(sub) -> None:
    p = sub.add_parser("eval", help="score predictions and filtered predictions on test views "
                                    "(the paper's table)")
    p.add_argument("bundles", nargs="+", metavar="BUNDLE",
                   help="bundles written by 'clearsplat prepare' and filled by a backbone "
                        "(folders, glob patterns or text files listing folders)")
    p.add_argument("--filtered", metavar="DIR",
                   help="the 'clearsplat batch' folder of their filtered versions "
                        "(DIR/<bundle name>/)")
    p.add_argument("--label", default="Prediction",
                   help="the backbone's name in the table (default: %(default)s)")
    p.add_argument("--json", metavar="FILE", help="also write the per-bundle scores as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..batch import find_scenes
    from ..evaluate import evaluate_predictions, format_table
    from ..io.ply import atomic_write_bytes

    bundles = find_scenes(args.bundles)
    rows = evaluate_predictions(bundles, args.filtered,
                                log=lambda s: print("  " + s, file=sys.stderr))
    print(format_table(rows, label=args.label))
    if args.json:
        if args.json in [str(b) for b in bundles]:
            raise ClearsplatError("would overwrite an input", path=args.json, field="--json")
        atomic_write_bytes(args.json, (json.dumps(rows, indent=1) + "\n").encode())
        print(f"wrote {args.json}")
    return 0
