"""``clearsplat filter``: filter one scene bundle into an output folder."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np

from ..errors import ClearsplatError
from ._common import Bar, add_config_args, config_from_args, warn


def add_parser(sub) -> None:
    f = sub.add_parser("filter", help="filter a scene bundle")
    f.add_argument("scene", help="bundle folder: cameras.json or transforms.json, images/, "
                                 "gaussians.ply")
    f.add_argument("--out", required=True,
                   help="output folder (created; written in full or not at all)")
    f.add_argument("--keep-all", action="store_true",
                   help="keep every Gaussian, removed ones with zero opacity")
    f.add_argument("--report", action="store_true", help="write diagnostic pictures and HTML")
    f.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    add_config_args(f)
    f.set_defaults(func=run)


def write_outputs(folder, scene, result, *, keep_all: bool = False, report: bool = False,
                  source: str | None = None) -> None:
    """Write what ``clearsplat filter`` writes into ``folder`` (an existing, empty folder)."""
    from ..io import write_ply

    if keep_all:
        kept = result.apply(scene)
        write_ply(os.path.join(folder, "gaussians.ply"), kept.gaussians,
                  view_id=kept.view_id, pixel_id=kept.pixel_id)
    else:
        sub = scene.subset(result.keep)
        write_ply(os.path.join(folder, "gaussians.ply"), sub.gaussians,
                  view_id=sub.view_id, pixel_id=sub.pixel_id)
    np.save(os.path.join(folder, "removed.npy"), np.ascontiguousarray(result.removed, dtype=bool))
    with open(os.path.join(folder, "summary.json"), "w") as f:
        json.dump(result.summary(), f, indent=1)
    if report:
        from ..report import write_report
        write_report(os.path.join(folder, "report"), scene, result, source=source)


def run(args) -> int:
    from ..filter import filter_distractors
    from ..io import load_scene
    from ..io.output import check_output_folder, output_folder

    check_output_folder(args.out, inputs=[args.scene], force=args.force)
    config = config_from_args(args)
    scene = load_scene(args.scene)
    print(f"{len(scene):,} Gaussians, {scene.num_views} views")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = filter_distractors(scene, config=config, progress=Bar())
        except ClearsplatError as e:
            if e.path is None:          # an in-memory check: the scene is the file at fault
                raise ClearsplatError(e.reason, path=args.scene, field=e.field) from None
            raise
    shown = set()
    for message in [str(w.message) for w in caught] + list(result.warnings):
        if message not in shown:
            shown.add(message)
            warn(message)

    with output_folder(args.out, inputs=[args.scene], force=args.force,
                       command="filter") as tmp:
        write_outputs(tmp, scene, result, keep_all=args.keep_all, report=args.report,
                      source=args.scene)
    s = result.summary()
    print(f"removed {s['removed']:,} of {s['gaussians']:,} Gaussians "
          f"({s['accepted']} of {len(s['candidates'])} candidates); wrote {args.out}")
    return 0
