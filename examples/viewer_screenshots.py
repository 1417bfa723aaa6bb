"""Screenshots of the viewer and a frame of the before | after video, as in the README.

Run after ``clearsplat demo --out clearsplat-demo`` (which writes the scene and the filter's
output as bundles, and the video)::

    python examples/viewer_screenshots.py clearsplat-demo --out docs/images

It serves the demo scene with :func:`clearsplat.viewer.serve` showing the original, the
filtered and the removed Gaussians in turn, photographs each with headless Chromium (software
WebGL, no GPU needed) and writes small PNGs; then it takes one frame of ``report/video.mp4``.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

import clearsplat
from clearsplat.browser import HeadlessBrowser
from clearsplat.viewer import serve


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def drawn(rgb) -> bool:
    """Some of the scene is lit, and the page is not viser's white page of a client loading."""
    return (rgb.max(-1) > 40).mean() > 0.05 and (rgb.min(-1) > 230).mean() < 0.5


def small_png(src: Path, dest: Path, *, box=None, width: int = 640) -> None:
    """Crop, shrink to ``width`` and store with a 256-colour palette (docs stay small)."""
    with Image.open(src) as im:
        im = im.convert("RGB")
        if box is not None:
            im = im.crop(box)
        im = im.resize((width, round(im.height * width / im.width)), Image.LANCZOS)
        im.quantize(256, method=Image.Quantize.MEDIANCUT).save(dest, optimize=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("demo", help="the folder 'clearsplat demo --out' wrote")
    p.add_argument("--out", default="docs/images")
    p.add_argument("--modes", default="original,filtered,removed")
    p.add_argument("--timeout", type=float, default=1800,
                   help="seconds to wait for each page to draw (default: 1800)")
    args = p.parse_args()
    demo, out = Path(args.demo), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = clearsplat.load_scene(demo / "scene")
    keep = ~np.load(demo / "filtered" / "removed.npy")
    with tempfile.TemporaryDirectory() as tmp, HeadlessBrowser(size=(1000, 640)) as browser:
        for mode in args.modes.split(","):
            viewer = serve(scene, keep=keep, port=free_port(), show=mode)
            raw = Path(tmp) / f"{mode}.png"
            try:
                # software WebGL is slow with a million Gaussians: photograph the page until
                # they show (below the browser's notice) and it has stopped changing
                browser.open(viewer.url)
                rgb = browser.wait_until(lambda rgb: drawn(rgb[160:]), what=f"the {mode} "
                                         "Gaussians", timeout=args.timeout)
                Image.fromarray(rgb).save(raw)
            finally:
                viewer.stop()
            # below the browser's "software WebGL" notice, the viewer's panel kept
            small_png(raw, out / f"viewer_{mode}.png", box=(0, 160, 1000, 640))
        ffmpeg = __import__("imageio_ffmpeg").get_ffmpeg_exe()
        frame = Path(tmp) / "frame.png"
        subprocess.run([ffmpeg, "-v", "error", "-i", str(demo / "report" / "video.mp4"),
                        "-vf", "select=eq(n\\,30)", "-vframes", "1", "-y", str(frame)],
                       check=True)
        small_png(frame, out / "video_frame.png", width=900)
    print(f"wrote {out}/viewer_{{original,filtered,removed}}.png and {out}/video_frame.png")


if __name__ == "__main__":
    main()
