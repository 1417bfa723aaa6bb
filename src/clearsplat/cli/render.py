"""``clearsplat render``: render a scene from any camera, or along a camera path."""

from __future__ import annotations

import os

from ._common import Bar


def add_parser(sub) -> None:
    r = sub.add_parser("render", help="render a bundle from cameras in cameras.json format")
    r.add_argument("scene", help="bundle folder (an input, or the output of 'clearsplat filter')")
    what = r.add_mutually_exclusive_group(required=True)
    what.add_argument("--camera", help="JSON file: one frame of cameras.json (width, height, K, "
                                       "camera_to_world) or a {\"frames\": [...]} list")
    what.add_argument("--path", help="JSON file in cameras.json format: the key cameras of a "
                                     "path (rendered as they are, or --frames along a smooth "
                                     "path through them)")
    r.add_argument("--out", required=True, help="output folder (PNG per frame, cameras.json)")
    r.add_argument("--frames", type=int, help="with --path: this many frames on a smooth path "
                                              "through its cameras")
    r.add_argument("--filtered", help="render only the Gaussians this 'clearsplat filter' "
                                      "output kept")
    r.add_argument("--size", help="image size, WIDTH or WIDTHxHEIGHT (default: each camera's)")
    r.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    r.set_defaults(func=run)


def run(args) -> int:
    from ..camera_path import interpolate_cameras, parse_size, resize_camera
    from ..errors import ClearsplatError
    from ..io import load_cameras, save_cameras
    from ..io.output import check_output_folder, output_folder
    from ..render import render
    from ..report import write_png
    from ._files import load_scene_and_keep

    source = args.camera or args.path
    inputs = [p for p in (args.scene, source, args.filtered) if p]
    check_output_folder(args.out, inputs=inputs, force=args.force)
    if args.frames is not None and (args.camera or args.frames < 1):
        raise ClearsplatError("--frames takes a positive number and goes with --path",
                              field="--frames")
    cameras, _ = load_cameras(source)
    if args.frames is not None:
        cameras = interpolate_cameras(cameras, args.frames)
    if args.size:
        w, h = parse_size(args.size)
        cameras = [resize_camera(c, w, h) for c in cameras]
    scene, keep = load_scene_and_keep(args.scene, args.filtered)
    bar = Bar()
    digits = max(4, len(str(len(cameras) - 1)))
    names = [f"frame_{i:0{digits}d}.png" for i in range(len(cameras))]
    with output_folder(args.out, inputs=inputs, force=args.force, command="render") as tmp:
        for i, (cam, name) in enumerate(zip(cameras, names)):
            write_png(os.path.join(tmp, name), render(scene, cam, keep=keep).rgb)
            bar("render", i + 1, len(cameras))
        save_cameras(tmp / "cameras.json", cameras, [tmp / n for n in names])
    print(f"rendered {len(cameras)} view{'s' * (len(cameras) != 1)} of {len(scene):,} Gaussians"
          + (f" ({int((~keep).sum()):,} removed)" if keep is not None else "")
          + f"; wrote {args.out}")
    return 0
