"""``clearsplat filter``: filter one scene bundle into an output folder."""

from __future__ import annotations

import warnings

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
    f.add_argument("--copy-images", action="store_true",
                   help="copy the input images into --out (by default the output bundle's "
                        "cameras.json refers to them where they are)")
    f.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    add_config_args(f)
    f.set_defaults(func=run)


def run(args) -> int:
    from ..batch import write_filter_outputs
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
                       command="filter") as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")             # the video's GIF fallback
        write_filter_outputs(tmp, scene, result, keep_all=args.keep_all, report=args.report,
                             source=args.scene, located_at=args.out,
                             copy_images=args.copy_images)
    for w in caught:
        warn(str(w.message))
    s = result.summary()
    print(f"removed {s['removed']:,} of {s['gaussians']:,} Gaussians "
          f"({s['accepted']} of {len(s['candidates'])} candidates); wrote {args.out}")
    return 0
