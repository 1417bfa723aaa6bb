"""``clearsplat edit``: flip the filter's verdict on candidates, into a new output folder."""

from __future__ import annotations


def add_parser(sub) -> None:
    e = sub.add_parser("edit", help="reject or accept candidates of a filter output",
                       description="Write a copy of a 'clearsplat filter' output with some "
                                   "candidates rejected (their Gaussians restored, except "
                                   "those another accepted candidate removes) or accepted "
                                   "(their expanded Gaussians removed). IDS are the "
                                   "candidates' indices in its summary.json, comma-separated.")
    e.add_argument("filtered", help="the output folder of 'clearsplat filter' (or of an "
                                    "earlier 'clearsplat edit'); only read")
    e.add_argument("--reject", metavar="IDS", help="candidates to reject, e.g. 3,5")
    e.add_argument("--accept", metavar="IDS", help="candidates to accept, e.g. 7")
    e.add_argument("--out", required=True,
                   help="the new output folder (created; written in full or not at all)")
    e.add_argument("--keep-all", action="store_true",
                   help="keep every Gaussian in gaussians.ply, removed ones with zero opacity")
    e.add_argument("--copy-images", action="store_true",
                   help="copy the input images into --out (default: only when FILTERED "
                        "holds its own copies)")
    e.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    e.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ClearsplatError
    from ..io.output import check_output_folder
    from ..review import edit_filter_output, parse_ids

    reject = parse_ids(args.reject, field="--reject")
    accept = parse_ids(args.accept, field="--accept")
    if not reject and not accept:
        raise ClearsplatError("nothing to edit: give --reject IDS and/or --accept IDS",
                              field="--reject/--accept")
    check_output_folder(args.out, inputs=[args.filtered], force=args.force)
    r = edit_filter_output(args.filtered, args.out, reject=reject, accept=accept,
                           keep_all=args.keep_all, copy_images=args.copy_images or None,
                           force=args.force)
    print(f"restored {r['restored']:,} and removed {r['removed']:,} Gaussians "
          f"({r['gaussians_removed']:,} removed now); wrote {args.out}")
    return 0
