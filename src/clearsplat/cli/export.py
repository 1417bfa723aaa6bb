"""``clearsplat export``: Gaussians of a bundle as .splat, .spz or a plain 3DGS PLY."""

from __future__ import annotations

from pathlib import Path

import numpy as np

FORMATS = {".splat": "web viewers' 32-byte layout", ".spz": "Niantic's compressed format",
           ".ply": "plain 3DGS PLY, no extra properties"}


def add_parser(sub) -> None:
    e = sub.add_parser("export", help="write a bundle's Gaussians as .splat, .spz or plain .ply")
    e.add_argument("bundle", help="bundle folder (an input, or the output of 'clearsplat filter')")
    e.add_argument("--to", required=True,
                   help="file to write; the format follows its suffix: "
                        + ", ".join(f"{k} ({v})" for k, v in FORMATS.items()))
    e.add_argument("--keep-all", action="store_true",
                   help="also write the Gaussians a 'filter --keep-all' output marks as "
                        "removed (by default they are dropped)")
    e.add_argument("--force", action="store_true", help="replace an existing --to file")
    e.set_defaults(func=run)


def run(args) -> int:
    from ..io import read_ply
    from ..io.bundle import GAUSSIANS_FILE
    from ..io.splat_formats import write_plain_ply, write_splat, write_spz
    from ..errors import ClearsplatError
    from ._files import check_output_file, removed_mask

    bundle = Path(args.bundle)
    ply = bundle / GAUSSIANS_FILE if bundle.is_dir() else bundle
    if not ply.is_file():
        raise ClearsplatError("Gaussians file not found", path=ply, field="gaussians")
    out = check_output_file(args.to, inputs=[args.bundle], force=args.force, field="--to",
                            suffixes=tuple(FORMATS))
    g, _, _ = read_ply(ply)
    dropped = 0
    removed = None
    if bundle.is_dir() and (bundle / "removed.npy").is_file():
        # a 'filter --keep-all' output holds every Gaussian, removed ones at zero opacity;
        # a default output holds only the kept ones (its removed.npy counts the input's)
        n_input = len(np.load(bundle / "removed.npy", mmap_mode="r"))
        if n_input == len(g):
            removed = removed_mask(bundle, len(g))
    if removed is not None and not args.keep_all and removed.any():
        g = g.subset(~removed)
        dropped = int(removed.sum())
    writer = {".splat": write_splat, ".spz": write_spz, ".ply": write_plain_ply}
    writer[out.suffix.lower()](out, g)
    print(f"wrote {out}: {len(g):,} Gaussians ({FORMATS[out.suffix.lower()]})"
          + (f"; {dropped:,} removed ones dropped" if dropped else ""))
    return 0
