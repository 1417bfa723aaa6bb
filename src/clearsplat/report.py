"""Diagnostic pictures and an HTML page for a filter run.

Per input view: the input, the exclusion render R_i^-i, the similarity map, the proposals by
range (range 1 red, range 2 yellow, unsupported patches dimmed) and the accepted regions.
"""

from __future__ import annotations

import html
import os

import numpy as np
from PIL import Image

from .features import upsample_nearest

__all__ = ["to_uint8", "colormap", "overlay", "write_png", "write_report"]


def to_uint8(img: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] to uint8 (rounded, clipped)."""
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def colormap(values: np.ndarray, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """Map (H, W) values to RGB (H, W, 3) float32: dark blue (low) to yellow (high)."""
    t = np.clip((np.asarray(values, dtype=np.float32) - lo) / max(hi - lo, 1e-12), 0, 1)
    stops = np.array([[0.05, 0.03, 0.35], [0.15, 0.45, 0.55], [0.45, 0.8, 0.35],
                      [1.0, 0.95, 0.2]], dtype=np.float32)
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)
    f = (x - i)[..., None]
    return stops[i] * (1 - f) + stops[i + 1] * f


def overlay(image: np.ndarray, masks: list[tuple[np.ndarray, tuple]], *,
            strength: float = 0.55) -> np.ndarray:
    """Tint the pixels of each mask with its colour; returns (H, W, 3) float32."""
    out = np.asarray(image, dtype=np.float32).copy()
    for mask, color in masks:
        c = np.asarray(color, dtype=np.float32)
        out[mask] = (1 - strength) * out[mask] + strength * c
    return out


def write_png(path: str, img: np.ndarray) -> None:
    """Write a float RGB image in [0, 1] as an 8-bit PNG."""
    Image.fromarray(to_uint8(img)).save(path)


def write_report(out_dir: str, scene, result, *, video: str | None = None) -> str:
    """Write the per-view pictures and ``report.html`` into ``out_dir``; return the HTML path.

    Parameters
    ----------
    scene : Scene
    result : FilterResult
    video : str, optional
        A before | after video (``.mp4`` or ``.gif``), relative to ``out_dir``, shown at the top.
    """
    from .render import render

    os.makedirs(out_dir, exist_ok=True)
    rows = []
    for prop in result.proposals:
        i = prop.view
        img = scene.images[i]
        h, w = img.shape[:2]
        excl = prop.exclusion            # R_i^-i as the filter rendered it
        if excl is None:
            excl = render(scene, scene.cameras[i], keep=scene.view_id != i).rgb
        sim = colormap(upsample_nearest(prop.similarity, h, w), -0.2, 1.0)
        unsupported = ~prop.support_pixels
        proposals = overlay(img * np.where(unsupported, 0.45, 1.0)[..., None],
                            [(prop.mask1, (1, 0.1, 0.1)), (prop.mask2, (1, 0.9, 0.1))])
        accepted = np.zeros((h, w), bool)
        rejected = np.zeros((h, w), bool)
        for c in result.candidates:
            if c.view == i:
                (accepted if c.accepted else rejected)[:] |= c.pixels
        verdict = overlay(img, [(rejected, (0.2, 0.4, 1.0)), (accepted, (0.1, 1.0, 0.2))])
        names = {"input": img, "exclusion": excl, "similarity": sim, "proposals": proposals,
                 "accepted": verdict}
        files = {}
        for name, pic in names.items():
            fn = f"view{i:03d}_{name}.png"
            write_png(os.path.join(out_dir, fn), pic)
            files[name] = fn
        n_acc = sum(1 for c in result.candidates if c.view == i and c.accepted)
        n_all = sum(1 for c in result.candidates if c.view == i)
        rows.append((i, files, n_acc, n_all))
    path = os.path.join(out_dir, "report.html")
    summary = result.summary()
    parts = ["<!doctype html><meta charset='utf-8'><title>clearsplat report</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}img{width:19%;margin:0.2%}"
             "h2{margin-top:1.2em;font-size:1.05em}td,th{padding:2px 8px;text-align:right}"
             ".video video,.video img{width:min(100%,1100px)}</style>",
             "<h1>clearsplat filter report</h1>",
             f"<p>{summary['removed']} of {summary['gaussians']} Gaussians removed; "
             f"{summary['accepted']} of {len(summary['candidates'])} candidates accepted. "
             f"Proposal {summary['timings'].get('proposal', 0):.2f} s, verification "
             f"{summary['timings'].get('verification', 0):.2f} s.</p>",
             *_video_html(video),
             "<p>Columns: input &middot; exclusion render R<sub>i</sub><sup>-i</sup> &middot; "
             "similarity (blue low, yellow high) &middot; proposals (red: range 1, yellow: range "
             "2, dimmed: unsupported) &middot; verdict (green: accepted, blue: rejected)</p>"]
    for i, files, n_acc, n_all in rows:
        parts.append(f"<h2>View {i}: {n_acc} of {n_all} candidates accepted</h2><div>")
        parts += [f"<img src='{html.escape(f)}' alt='{k}' title='{k}'>" for k, f in files.items()]
        parts.append("</div>")
    parts.append("<h2>Candidates</h2><table><tr><th>#</th><th>view</th><th>range</th>"
                 "<th>pixels</th><th>Gaussians</th><th>individual</th><th>additional</th>"
                 "<th>joint</th><th>verdict</th></tr>")
    for c in summary["candidates"]:
        s = c["scores"]
        cells = [c["index"], c["view"], c["range"], c["pixels"], c["gaussians"]]
        cells += [f"{s[k]:+.4f}" if k in s else "" for k in ("individual", "additional", "joint")]
        cells.append(html.escape(c["reason"]))
        parts.append("<tr>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>")
    parts.append("</table>")
    with open(path, "w") as f:
        f.write("\n".join(parts))
    return path


def _video_html(video) -> list:
    if not video:
        return []
    src = html.escape(str(video).replace(os.sep, "/"))
    tag = (f"<img src='{src}' alt='before | after'>" if src.lower().endswith(".gif") else
           f"<video src='{src}' controls autoplay loop muted playsinline></video>")
    return ["<h2>Before | after, along a path through the input cameras</h2>",
            f"<div class='video'>{tag}</div>"]
