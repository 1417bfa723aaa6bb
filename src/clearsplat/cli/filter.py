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
    f.add_argument("--copy-images", action="store_true",
                   help="copy the input images into --out (by default the output bundle's "
                        "cameras.json refers to them where they are)")
    f.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    add_config_args(f)
    f.set_defaults(func=run)


def write_outputs(folder, scene, result, *, keep_all: bool = False, report: bool = False,
                  source: str | None = None, located_at=None,
                  copy_images: bool = False) -> None:
    """Write what ``clearsplat filter`` writes into ``folder`` (an existing, empty folder).

    With ``source`` (the input bundle) the folder is itself a bundle: ``cameras.json`` refers
    to the input's images (or copies them, ``copy_images``) so that it loads again from
    ``located_at`` (where ``folder`` is moved to; default ``folder``).
    """
    from ..io import load_cameras, save_bundle_cameras, write_ply

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
    if source is not None:
        cameras, image_paths = load_cameras(source)
        save_bundle_cameras(folder, cameras, image_paths, located_at=located_at,
                            copy_images=copy_images, render=scene.render_settings)
    if report:
        from ..report import write_report
        from ..video import make_video
        os.makedirs(os.path.join(folder, "report"), exist_ok=True)
        with warnings.catch_warnings(record=True) as caught:     # the GIF fallback's
            warnings.simplefilter("always")
            video = make_video(os.path.join(folder, "report", "video.mp4"), scene,
                               result.keep, num_frames=48)
        for w in caught:
            warn(str(w.message))
        write_report(os.path.join(folder, "report"), scene, result, source=source,
                     video=video.name)


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
                      source=args.scene, located_at=args.out, copy_images=args.copy_images)
    s = result.summary()
    print(f"removed {s['removed']:,} of {s['gaussians']:,} Gaussians "
          f"({s['accepted']} of {len(s['candidates'])} candidates); wrote {args.out}")
    return 0
