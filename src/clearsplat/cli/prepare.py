"""``clearsplat prepare``: the paper's view configurations of RobustNeRF / NeRF On-the-go scenes,
written as bundles-to-be for a backbone to fill in."""

from __future__ import annotations

import sys

from ..errors import ClearsplatError


def add_parser(sub) -> None:
    p = sub.add_parser("prepare", help="write the paper's view configurations of RobustNeRF / "
                                       "NeRF On-the-go scenes as bundles for a backbone",
                       description="For each scene and input count, four configurations of "
                                   "input (clutter) and test (extra) views picked by COLMAP "
                                   "sparse-point co-visibility, each written as "
                                   "OUT/<dataset>/<scene>-<N>v-c<K>/ (cameras.json, images/, "
                                   "test/, view_config.json). The backbone adds gaussians.ply.")
    p.add_argument("scenes", nargs="+", metavar="SCENE",
                   help="scene folders in the RobustNeRF (images/, sparse/0) or NeRF On-the-go "
                        "(images/, transforms.json, split.json) layout")
    p.add_argument("--out", required=True, help="output folder (written in full or not at all)")
    p.add_argument("--views", default="4,8,16",
                   help="comma-separated input counts (default: %(default)s)")
    p.add_argument("--configs", type=int, default=4,
                   help="configurations per scene and input count (default: 4)")
    p.add_argument("--test-views", type=int, default=3,
                   help="test views per configuration (default: 3)")
    p.add_argument("--images", default="images",
                   help="image folder of each scene, e.g. images_4 (default: images)")
    p.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..evaluate import write_configurations
    from ..io.datasets import read_dataset

    try:
        views = [int(v) for v in args.views.split(",")]
    except ValueError:
        raise ClearsplatError(f"expected comma-separated integers, got {args.views!r}",
                              field="--views") from None
    for name, value in (("--configs", args.configs), ("--test-views", args.test_views)):
        if value < 1:
            raise ClearsplatError(f"must be at least 1, got {value}", field=name)
    datasets = [read_dataset(s, images=args.images) for s in args.scenes]
    for d in datasets:
        print(f"{d.kind} {d.name}: {len(d.train)} training (clutter), {len(d.test)} test "
              f"(extra) images")
    folders = write_configurations(datasets, args.out, views=views, count=args.configs,
                                   num_test=args.test_views,
                                   log=lambda s: print("  " + s, file=sys.stderr))
    print(f"wrote {len(folders)} bundles to {args.out}; add each backbone's gaussians.ply, "
          "then: clearsplat batch '{out}/*/*' --out FILTERED; clearsplat eval '{out}/*/*' "
          "--filtered FILTERED".replace("{out}", str(args.out)))
    return 0
