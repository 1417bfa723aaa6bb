"""``clearsplat filter``: filter one scene bundle into an output folder."""

from __future__ import annotations

from ._common import (Bar, add_config_args, add_filter_output_args, config_from_args,
                      warn)


def add_parser(sub) -> None:
    f = sub.add_parser("filter", help="filter a scene bundle")
    f.add_argument("scene", help="bundle folder: cameras.json or transforms.json, images/, "
                                 "gaussians.ply")
    f.add_argument("--out", required=True,
                   help="output folder (created; written in full or not at all)")
    add_filter_output_args(f, into="--out")
    f.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    w = f.add_argument_group(
        "long captures", "from 96 views on the capture is filtered in windows of about 32 "
        "consecutive views (memory bounded by a window; a killed run resumes where it "
        "stopped); these spread the windows over Ray")
    w.add_argument("--num-cpus", type=int, metavar="N",
                   help="run the windows as tasks of a local Ray instance with N CPUs")
    w.add_argument("--address",
                   help="run the windows on a running Ray cluster: 'auto', HOST:PORT or "
                        "ray://HOST:PORT (the bundle and --out must be at the same paths on "
                        "every node)")
    add_config_args(f)
    f.set_defaults(func=run)


def run(args) -> int:
    from ..batch import filter_scene
    from ..io.output import check_output_folder

    check_output_folder(args.out, inputs=[args.scene], force=args.force)
    r = filter_scene(args.scene, args.out, config=config_from_args(args),
                     keep_all=args.keep_all, report=args.report, copy_images=args.copy_images,
                     force=args.force, progress=Bar(), log=print, workers=args.num_cpus,
                     address=args.address)
    for message in r["warnings"]:
        warn(message)
    print(f"removed {r['removed']:,} of {r['gaussians']:,} Gaussians "
          f"({r['accepted']} of {r['candidates']} candidates); wrote {args.out}")
    return 0
