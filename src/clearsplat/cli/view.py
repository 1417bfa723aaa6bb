"""``clearsplat view``: the scene before and after filtering in an interactive browser viewer."""

from __future__ import annotations

import time


def add_parser(sub) -> None:
    v = sub.add_parser("view", help="open an interactive 3D viewer (viser) in the browser")
    v.add_argument("scene", help="bundle folder (an input, or the output of 'clearsplat filter')")
    v.add_argument("--filtered", help="the output folder of 'clearsplat filter' (or 'clearsplat "
                                      "edit') on SCENE: adds the filtered and the removed "
                                      "Gaussians, and the panel that reviews its candidates")
    v.add_argument("--port", type=int, default=8080, help="port (default: %(default)s; the next "
                                                          "free one when taken)")
    v.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default: %(default)s, this machine only; "
                        "0.0.0.0 shares the viewer on the network)")
    v.add_argument("--show", choices=["original", "filtered", "removed"],
                   help="what is shown first (default: filtered with --filtered)")
    v.add_argument("--select", type=int, metavar="ID",
                   help="with --filtered: the candidate selected from the start")
    v.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ClearsplatError
    from ..viewer import serve
    from ._files import load_scene_and_keep

    if not 0 < args.port < 65536:
        raise ClearsplatError(f"must lie in 1..65535, got {args.port}", field="--port")
    if args.show in ("filtered", "removed") and not args.filtered:
        raise ClearsplatError(f"--show {args.show} needs --filtered", field="--show")
    if args.select is not None and not args.filtered:
        raise ClearsplatError("--select needs --filtered", field="--select")
    _check_host(args.host)
    scene, keep = load_scene_and_keep(args.scene, args.filtered)
    try:
        viewer = serve(scene, keep=keep, filtered=args.filtered, host=args.host,
                       port=args.port, show=args.show, select=args.select)
    except OSError as e:
        raise ClearsplatError(f"cannot serve on {args.host}:{args.port} ({e.strerror or e})",
                              field="--host/--port") from None
    print(f"clearsplat viewer: {viewer.url}  ({len(scene):,} Gaussians, {scene.num_views} "
          "cameras; Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        viewer.stop()


def _check_host(host: str) -> None:
    """Refuse an address this machine cannot serve on (viser would try port after port)."""
    import socket

    from ..errors import ClearsplatError
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as s:
            s.bind(infos[0][4])
    except OSError as e:
        raise ClearsplatError(f"cannot serve on {host!r} ({e.strerror or e})",
                              field="--host") from None
