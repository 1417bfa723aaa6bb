"""A screenshot of the viewer's review panel with one candidate selected (docs/images).

Run after ``clearsplat demo --out clearsplat-demo``::

    python examples/review_screenshot.py clearsplat-demo --out docs/images

It serves the demo scene with its filter output (:func:`clearsplat.viewer.serve` with
``filtered=`` and ``select=``: the accepted candidate with the most Gaussians, unless
``--select`` names one), so the browser looks through that candidate's input view with its
Gaussians in the highlight colour and the panel shows its crops; headless Chromium (software
WebGL) photographs it once the highlight is drawn.
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path

import numpy as np
from PIL import Image

import clearsplat
from clearsplat.browser import HeadlessBrowser, find_browser
from clearsplat.review import load_filter_output
from clearsplat.viewer import SELECTED_COLOUR, serve


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("demo", help="the folder 'clearsplat demo --out' wrote")
    p.add_argument("--out", default="docs/images")
    p.add_argument("--select", type=int, help="the candidate to select")
    p.add_argument("--timeout", type=float, default=1800,
                   help="seconds to wait for the page to draw (default: 1800)")
    args = p.parse_args()
    if find_browser() is None:
        raise SystemExit("needs Chromium (Debian: apt-get install chromium)")
    demo, out = Path(args.demo), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = clearsplat.load_scene(demo / "scene")
    output = load_filter_output(demo / "filtered")
    k = args.select
    if k is None:
        k = max(np.flatnonzero(output.accepted), key=lambda k: output.sets.removal(k).size)
    viewer = serve(scene, filtered=demo / "filtered", port=free_port(), select=int(k))
    target = np.array(SELECTED_COLOUR) * 255

    def drawn(rgb) -> bool:             # the highlight, and the scene around it (not the panel)
        rgb = rgb[:, :700].astype(int)
        green = ((rgb[..., 1] > 80) & (rgb[..., 0] < 0.5 * rgb[..., 1])
                 & (rgb[..., 2] < 0.6 * rgb[..., 1]))
        return green.mean() > 0.002 and (rgb.max(-1) > 40).mean() > 0.3

    try:
        with HeadlessBrowser(size=(1200, 900)) as browser:
            browser.open(viewer.url)
            rgb = browser.wait_until(drawn, what=f"candidate {k} in the highlight colour",
                                     timeout=args.timeout)
        im = Image.fromarray(rgb).crop((0, 160, 1200, 900))
        im = im.resize((900, round(im.height * 900 / im.width)), Image.LANCZOS)
        im.quantize(256, method=Image.Quantize.MEDIANCUT).save(
            out / "viewer_review.png", optimize=True)
    finally:
        viewer.stop()
    print(f"wrote {out}/viewer_review.png (candidate {k}, view {int(output.sets.view[k])}; "
          f"highlight colour {tuple(int(v) for v in target)})")


if __name__ == "__main__":
    main()
