"""Diagnostic pictures and an HTML page for a filter run.

Per input view: the input, the render before filtering R_i, the render after filtering, the
exclusion render R_i^-i, the similarity map, the proposals by range (range 1 red, range 2
yellow, unsupported patches dimmed) and what was removed (the pixels whose Gaussians the filter
removed, red; accepted regions outlined green, rejected ones blue). The page names the input
and the configuration, gives the units of the scores, and repeats the legend under every view.
"""

from __future__ import annotations

import html
import os

import numpy as np
from PIL import Image
from scipy import ndimage

from .features import upsample_nearest

__all__ = ["to_uint8", "colormap", "overlay", "outline", "removed_pixels", "write_png",
           "write_report"]


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


def outline(mask: np.ndarray, width: int = 1) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` within ``width`` of its border."""
    mask = np.asarray(mask, dtype=bool)
    return mask & ~ndimage.binary_erosion(mask, iterations=width, border_value=1)


def removed_pixels(scene, removed: np.ndarray, view: int, before=None, after=None, *,
                   epsilon: float = 0.0) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` whose Gaussians were removed.

    For a pixel-aligned scene, the pixels (``pixel_id``) of the view's own removed Gaussians:
    exactly what the filter took out of this view's prediction. Otherwise the pixels where
    the render after filtering differs from the render before by more than ``epsilon`` (L1 over
    RGB), i.e. where the removal is visible (``before`` and ``after`` are then needed).
    """
    cam = scene.cameras[view]
    own = (scene.view_id == view) & removed
    pix = scene.pixel_id[own]
    if pix.size == 0 or (pix >= 0).all():
        out = np.zeros(cam.height * cam.width, dtype=bool)
        out[pix[pix < out.size]] = True
        return out.reshape(cam.height, cam.width)
    return np.abs(before.rgb - after.rgb).sum(-1) > epsilon


#: Captions under each view's pictures: the legend, repeated for every row.
CAPTIONS = {
    "input": "input image",
    "before": "render before filtering (R<sub>i</sub>)",
    "after": "render after filtering",
    "exclusion": "exclusion render R<sub>i</sub><sup>-i</sup> (without this view's Gaussians)",
    "similarity": "similarity of input and R<sub>i</sub><sup>-i</sup> (blue low, yellow high)",
    "proposals": "proposals: red range 1, yellow range 2, dimmed unsupported",
    "removed": "red: pixels whose Gaussians were removed; outlines: green accepted region, "
               "blue rejected region",
}

#: What a candidate's scores are, for the page.
SCORE_UNITS = ("Scores are the change-weighted mean reduction of the per-pixel L1 RGB error "
               "(|dR|+|dG|+|dB|, colours in [0, 1], so between -3 and 3) against the input "
               "image, over the verification views' pixels that the removal changes by more "
               "than epsilon; positive means the render without the candidate is closer to the "
               "input. A test passes above 0.")


def write_report(out_dir: str, scene, result, *, source: str | None = None,
                 video: str | None = None) -> str:
    """Write the per-view pictures and ``report.html`` into ``out_dir``; return the HTML path.

    Parameters
    ----------
    out_dir : str
        Folder for the pictures and the page (created if missing).
    scene : Scene
        The scene as filtered (before filtering).
    result : FilterResult
    source : str, optional
        What the scene came from (a bundle path, or a description), named on the page.
    video : str, optional
        A before | after video (``.mp4``, or a ``.gif``), relative to ``out_dir``, shown
        above the per-view pictures.
    """
    from .render import prepare

    os.makedirs(out_dir, exist_ok=True)
    rows = []
    for prop in result.proposals:
        i = prop.view
        img = scene.images[i]
        h, w = img.shape[:2]
        before, after = prepare(scene, scene.cameras[i]).render_pair(keep=result.keep)
        excl = prop.exclusion            # R_i^-i as the filter rendered it
        if excl is None:
            from .render import render
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
        removed = removed_pixels(scene, result.removed, i, before, after,
                                 epsilon=result.config.epsilon)
        verdict = overlay(img, [(removed, (1.0, 0.1, 0.1))], strength=0.6)
        verdict[outline(rejected)] = (0.2, 0.4, 1.0)
        verdict[outline(accepted)] = (0.1, 1.0, 0.2)
        names = {"input": img, "before": before.rgb, "after": after.rgb, "exclusion": excl,
                 "similarity": sim, "proposals": proposals, "removed": verdict}
        files = {}
        for name, pic in names.items():
            fn = f"view{i:03d}_{name}.png"
            write_png(os.path.join(out_dir, fn), pic)
            files[name] = fn
        own = scene.view_id == i
        counts = {"accepted": sum(1 for c in result.candidates if c.view == i and c.accepted),
                  "candidates": sum(1 for c in result.candidates if c.view == i),
                  "removed": int(np.count_nonzero(result.removed & own)),
                  "own": int(np.count_nonzero(own)), "pixels": int(removed.sum())}
        rows.append((i, files, counts))
    path = os.path.join(out_dir, "report.html")
    summary = result.summary()
    legend = "".join(f"<li><b>{k}</b>: {v}</li>" for k, v in CAPTIONS.items())
    parts = ["<!doctype html><meta charset='utf-8'><title>clearsplat report</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}"
             "figure{display:inline-block;width:13.6%;margin:0.2%;vertical-align:top}"
             "figure img{width:100%}figcaption{font-size:0.72em;color:#333}"
             "h2{margin-top:1.2em;font-size:1.05em}td,th{padding:2px 8px;text-align:right}"
             ".video video,.video img{width:min(100%,1100px)}</style>",
             "<h1>clearsplat filter report</h1>",
             f"<p>Input: {html.escape(source or 'an in-memory scene', quote=False)} "
             f"({len(scene):,} Gaussians, {scene.num_views} views).<br>"
             f"Configuration: {html.escape(result.config.describe(), quote=False)} "
             f"(every field in <code>summary.json</code>).</p>",
             f"<p><b>{summary['removed']:,} of {summary['gaussians']:,} Gaussians removed</b>; "
             f"{summary['accepted']} of {len(summary['candidates'])} candidate regions accepted "
             f"(of an accepted region only the Gaussians that passed the refinement "
             f"<code>refine={result.config.refine!r}</code> are removed). Proposal "
             f"{summary['timings'].get('proposal', 0):.2f} s, verification "
             f"{summary['timings'].get('verification', 0):.2f} s.</p>",
             *_video_html(video),
             f"<p>Pictures per view, left to right:</p><ul>{legend}</ul>"]
    for i, files, n in rows:
        parts.append(f"<h2>View {i}: {n['accepted']} of {n['candidates']} candidates "
                     f"accepted; {n['removed']:,} of its {n['own']:,} Gaussians removed "
                     f"({n['pixels']:,} pixels)</h2><div>")
        parts += [f"<figure><img src='{html.escape(f)}' alt='{k}' title='{k}'>"
                  f"<figcaption>{CAPTIONS[k]}</figcaption></figure>" for k, f in files.items()]
        parts.append("</div>")
    parts.append(f"<h2>Candidates</h2><p>{SCORE_UNITS}</p><table><tr><th>#</th><th>view</th>"
                 "<th>range</th><th>pixels</th><th>Gaussians after refinement</th>"
                 "<th>Gaussians removed (dilated region)</th><th>individual</th><th>additional</th>"
                 "<th>joint</th><th>verdict</th></tr>")
    for c in summary["candidates"]:
        s = c["scores"]
        removed = c["expanded_gaussians"] if c["accepted"] else 0
        cells = [c["index"], c["view"], c["range"], c["pixels"], c["gaussians"],
                 "" if removed is None else removed]
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
    return ["<h2>Before | after, along a path through the input cameras (novel views between "
            "them)</h2>", f"<div class='video'>{tag}</div>"]
