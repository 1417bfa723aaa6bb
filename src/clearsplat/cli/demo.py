"""``clearsplat demo``: one cluttered synthetic scene, reconstructed, filtered, measured."""

from __future__ import annotations

from ._common import Bar, add_config_args, config_from_args


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="build, reconstruct and filter one synthetic cluttered scene")
    d.add_argument("--out", default="clearsplat-demo",
                   help="output folder (default: %(default)s; written in full or not at all)")
    d.add_argument("--force", action="store_true",
                   help="replace an --out folder that an earlier clearsplat run wrote")
    d.add_argument("--family", default="object", choices=["object", "street"])
    d.add_argument("--views", type=int, default=8, help="input views, at least 2 "
                                                        "(default: %(default)s)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--resolution", default="256x448", help="HxW (default: %(default)s)")
    add_config_args(d)
    d.set_defaults(func=run)


def run(args) -> int:
    from ..demo import run_demo
    from ..errors import ClearsplatError
    try:
        height, width = (int(x) for x in args.resolution.lower().split("x"))
    except ValueError:
        raise ClearsplatError(f"expected HxW, e.g. 256x448, got {args.resolution!r}",
                              field="--resolution") from None
    if args.views < 2:
        raise ClearsplatError(f"got {args.views}; the demo needs at least 2 input views (one "
                              f"view cannot verify another)", field="--views")
    run_demo(args.out, family=args.family, num_views=args.views, seed=args.seed,
             height=height, width=width,
             config=config_from_args(args), log=print, progress=Bar(), force=args.force)
    return 0
