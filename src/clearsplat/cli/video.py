"""``clearsplat video``: a before | after video along a path through the input cameras."""

from __future__ import annotations

import warnings

from ._common import Bar, warn


def add_parser(sub) -> None:
    v = sub.add_parser("video", help="render a before | after MP4 along the input cameras")
    v.add_argument("scene", help="the input bundle that was filtered")
    v.add_argument("--filtered", required=True, help="the output folder of 'clearsplat filter'")
    v.add_argument("--out", required=True, help="the .mp4 file to write")
    v.add_argument("--frames", type=int, default=96,
                   help="frames on the path through the input cameras (default: %(default)s)")
    v.add_argument("--fps", type=float, default=24.0, help="frames per second (default: 24)")
    v.add_argument("--size", help="each half's size, WIDTH or WIDTHxHEIGHT (default: the input "
                                  "cameras', at most 640 wide)")
    v.add_argument("--force", action="store_true", help="replace an existing --out file")
    v.set_defaults(func=run)


def run(args) -> int:
    from ..camera_path import parse_size
    from ..errors import ClearsplatError
    from ..video import make_video
    from ._files import check_output_file, load_scene_and_keep

    if args.frames < 2:
        raise ClearsplatError(f"at least 2 frames, got {args.frames}", field="--frames")
    if not args.fps > 0 or args.fps > 240:
        raise ClearsplatError(f"must lie in (0, 240], got {args.fps}", field="--fps")
    size = parse_size(args.size) if args.size else None
    out = check_output_file(args.out, inputs=[args.scene, args.filtered], force=args.force,
                            suffixes=(".mp4",))
    scene, keep = load_scene_and_keep(args.scene, args.filtered)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        written = make_video(out, scene, keep, num_frames=args.frames, fps=args.fps, size=size,
                             progress=Bar())
    for w in caught:
        warn(str(w.message))
    print(f"wrote {written} ({args.frames} frames at {args.fps:g} fps; left: all "
          f"{len(keep):,} Gaussians, right: {int((~keep).sum()):,} removed)")
    return 0
