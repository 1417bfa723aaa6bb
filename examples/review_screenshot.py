"""A screenshot of the viewer's review panel with one candidate selected (docs/images).

Run after ``clearsplat demo --out clearsplat-demo``::

    python examples/review_screenshot.py clearsplat-demo --out docs/images

It serves the demo scene with its filter output (:func:`clearsplat.viewer.serve` with
``filtered=`` and ``select=``: the accepted candidate with the most Gaussians, unless
``--select`` names one), so the browser looks through that candidate's input view with its
Gaussians in the highlight colour and the panel shows its crops; headless Chromium (software
WebGL) photographs it.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

import clearsplat
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
    p.add_argument("--wait", type=int, default=40, help="seconds of page time (default: 40)")
    args = p.parse_args()
    browser = shutil.which("chromium") or shutil.which("google-chrome")
    if browser is None:
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
    try:
        with tempfile.TemporaryDirectory() as tmp:
            raw = Path(tmp) / "review.png"
            for budget in (1000 * args.wait, 2000 * args.wait, 4000 * args.wait):
                subprocess.run([browser, "--headless", "--no-sandbox", "--use-angle=swiftshader",
                                "--enable-unsafe-swiftshader", "--hide-scrollbars",
                                f"--user-data-dir={tmp}/profile", "--window-size=1200,900",
                                f"--virtual-time-budget={budget}", f"--screenshot={raw}",
                                viewer.url], check=True, capture_output=True, timeout=600)
                with Image.open(raw) as im:
                    rgb = np.asarray(im.convert("RGB")).astype(int)[:, :700]   # not the panel
                green = ((rgb[..., 1] > 80) & (rgb[..., 0] < 0.5 * rgb[..., 1])
                         & (rgb[..., 2] < 0.6 * rgb[..., 1]))
                if green.mean() > 0.002 and (rgb.max(-1) > 40).mean() > 0.3:
                    break
            with Image.open(raw) as im:
                im = im.convert("RGB").crop((0, 160, 1200, 900))
                im = im.resize((900, round(im.height * 900 / im.width)), Image.LANCZOS)
                im.quantize(256, method=Image.Quantize.MEDIANCUT).save(
                    out / "viewer_review.png", optimize=True)
    finally:
        viewer.stop()
    print(f"wrote {out}/viewer_review.png (candidate {k}, view {int(output.sets.view[k])}; "
          f"highlight colour {tuple(int(v) for v in target)})")


if __name__ == "__main__":
    main()
