"""``clearsplat demo``: one cluttered synthetic scene, reconstructed, filtered, measured."""

from __future__ import annotations

from ._common import Bar, add_config_args, config_from_args


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="build, reconstruct and filter one synthetic cluttered scene")
    d.add_argument("--out", default="clearsplat-demo", help="output folder (default: %(default)s)")
    d.add_argument("--family", default="object", choices=["object", "street"])
    d.add_argument("--views", type=int, default=8)
    d.add_argument("--seed", type=int, default=0)
    add_config_args(d)
    d.set_defaults(func=run)


def run(args) -> int:
    from ..demo import run_demo
    run_demo(args.out, family=args.family, num_views=args.views, seed=args.seed,
             config=config_from_args(args), log=print, progress=Bar())
    return 0
