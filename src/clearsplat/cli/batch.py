"""``clearsplat batch``: filter many scene bundles at once on Ray."""

from __future__ import annotations

import sys

from ._common import Bar, add_config_args, config_from_args, warn


def add_parser(sub) -> None:
    b = sub.add_parser("batch", help="filter many scene bundles at once (on Ray)",
                       description="Filter many scene bundles, each a Ray task, into "
                                   "OUT/<scene folder name>/. A second run skips the scenes "
                                   "already done.")
    b.add_argument("scenes", nargs="+", metavar="SCENE",
                   help="bundle folders, glob patterns ('preds/*') or text files listing "
                        "folders (one per line)")
    b.add_argument("--out", required=True,
                   help="batch folder: OUT/<scene>/ as 'clearsplat filter' writes it, "
                        "OUT/summary.csv and OUT/summary.json")
    b.add_argument("--address",
                   help="join a running Ray cluster: 'auto', HOST:PORT or ray://HOST:PORT "
                        "(default: a local Ray instance, started and stopped by the command)")
    b.add_argument("--cpus-per-scene", type=float, default=1, metavar="N",
                   help="CPUs each scene asks Ray for (default: 1)")
    b.add_argument("--num-cpus", type=int, metavar="N",
                   help="CPUs of the local Ray instance (default: all; ignored with --address)")
    b.add_argument("--keep-all", action="store_true",
                   help="keep every Gaussian, removed ones with zero opacity")
    b.add_argument("--report", action="store_true", help="write diagnostic pictures and HTML")
    b.add_argument("--copy-images", action="store_true",
                   help="copy the input images into each output (by default its cameras.json "
                        "refers to them where they are)")
    b.add_argument("--force", action="store_true",
                   help="filter every scene again, replacing earlier outputs")
    add_config_args(b)
    b.set_defaults(func=run)


def run(args) -> int:
    from ..batch import find_scenes, run_batch

    config = config_from_args(args)
    scenes = find_scenes(args.scenes)
    print(f"{len(scenes)} scene{'s' * (len(scenes) != 1)} -> {args.out}")
    bar = Bar()

    def on_scene(row):
        if row["status"] == "failed":
            print(f"clearsplat: scene failed: {row['scene']}: {row['error']}", file=sys.stderr)
        for message in row.get("warnings") or []:
            warn(f"{row['scene']}: {message}")

    try:
        rows = run_batch(scenes, args.out, config=config, keep_all=args.keep_all,
                         report=args.report, copy_images=args.copy_images, force=args.force,
                         address=args.address,
                         num_cpus=args.num_cpus, cpus_per_scene=args.cpus_per_scene,
                         progress=bar, on_scene=on_scene)
    except KeyboardInterrupt:
        print("clearsplat: interrupted; the scenes that finished are kept (run the same "
              "command again to resume)", file=sys.stderr)
        return 130
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    width = max(len(r["scene"]) for r in rows)
    for r in rows:
        what = (f"removed {r['removed']:,} of {r['gaussians']:,}"
                if r["status"] in ("ok", "skipped") else r["error"])
        secs = f"{r['seconds']:6.1f} s" if isinstance(r["seconds"], float) else " " * 8
        print(f"  {r['scene']:<{width}}  {r['status']:<7} {secs}  {what}")
    print(f"{counts['ok']} filtered, {counts['skipped']} already done, {counts['failed']} "
          f"failed; wrote {args.out}/summary.csv")
    return 1 if counts["failed"] else 0
