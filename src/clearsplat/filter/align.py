"""Depth alignment: each view's Gaussians moved along their camera rays to the others' scale.

A feed-forward model predicts each view's depth with its own error of scale (a few percent,
more under depth drift). The filter compares views with each other: a view whose surfaces lie
a few percent farther than the others' places its distractors behind the static surface that
the other views render, where no verification view sees them, and its static surfaces in
front of or behind the others', where the renders disagree for no reason.

``FilterConfig.align_depths`` runs the filter on a copy of the scene in which the Gaussians of
each view i are scaled about the centre of camera i by ``1 / s_i`` (positions along their
rays, and their sizes, so that camera i sees them at the same pixels with the same
footprints). :func:`view_depth_alignment` measures the ``s_i`` without rendering, from the
pixel-aligned predictions themselves: view j's depth map is the camera-j depth of its own
Gaussians at their pixels, so a sample of view i's Gaussians projected into camera j gives
ratios of depths on the same surface; their median is ``s_i / s_j`` and the ``s_i`` follow by
least squares over every pair, with their geometric mean 1. The filter's output (which
Gaussians to remove) refers to the input's Gaussians unchanged.
"""

from __future__ import annotations

import numpy as np

from ..scene import Gaussians, Scene
from .association import view_members

__all__ = ["view_depth_alignment", "aligned_scene"]

#: Gaussians sampled per view (evenly over its pixel-aligned members).
_SAMPLES = 4096
#: A sampled Gaussian counts as on the same surface as view j's at its pixel when their
#: depths differ by less than this factor.
_SAME_SURFACE = 1.25
#: A pair of views is measured from at least this many such Gaussians.
_MIN_PAIRS = 64


def _depth_maps(scene: Scene, members: list) -> list:
    """Per view, its (H*W,) camera depth map from its pixel-aligned Gaussians (the nearest at
    each pixel; 0 where none), or None for a view without pixel ids."""
    maps = []
    for v, m in enumerate(members):
        pid = scene.pixel_id[m]
        aligned = pid >= 0
        cam = scene.cameras[v]
        if not aligned.any():
            maps.append(None)
            continue
        z = cam.to_camera(scene.gaussians.means[m[aligned]])[:, 2]
        depth = np.full(cam.width * cam.height, np.inf)
        np.minimum.at(depth, pid[aligned], np.where(z > 0, z, np.inf))
        depth[~np.isfinite(depth)] = 0.0
        maps.append(depth)
    return maps


def view_depth_alignment(scene: Scene, *, samples: int = _SAMPLES) -> np.ndarray:
    """(V,) float64: each view's depth scale ``s_i`` relative to the others (geometric mean 1).

    ``s_i > 1``: view i places the surfaces it shares with the other views farther than they
    do. Views without pixel-aligned Gaussians, or sharing no surface with another view, get 1
    and take no part.
    """
    v_count = scene.num_views
    members = view_members(scene)
    maps = _depth_maps(scene, members)
    rows, values = [], []
    for i in range(v_count):
        if maps[i] is None:
            continue
        own = members[i][scene.pixel_id[members[i]] >= 0]
        pick = own[np.linspace(0, own.size - 1, min(samples, own.size)).astype(int)]
        pts = scene.gaussians.means[pick].astype(np.float64)
        for j in range(v_count):
            if j == i or maps[j] is None:
                continue
            cam = scene.cameras[j]
            uv, z = cam.project(pts)
            with np.errstate(invalid="ignore"):
                inside = ((z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width)
                          & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height))
            if np.count_nonzero(inside) < _MIN_PAIRS:
                continue
            px = (np.floor(uv[inside, 1]).astype(np.int64) * cam.width
                  + np.floor(uv[inside, 0]).astype(np.int64))
            theirs = maps[j][px]
            ok = theirs > 0
            ratio = np.log(z[inside][ok] / theirs[ok])
            ratio = ratio[np.abs(ratio) < np.log(_SAME_SURFACE)]
            if ratio.size < _MIN_PAIRS:
                continue
            rows.append((i, j))
            values.append(float(np.median(ratio)))
    scales = np.ones(v_count)
    if not rows:
        return scales
    # log s_i - log s_j = median log ratio, every measured pair; the mean of log s over the
    # views that take part is 0.
    taking = sorted({k for pair in rows for k in pair})
    col = {v: k for k, v in enumerate(taking)}
    a = np.zeros((len(rows) + 1, len(taking)))
    for r, (i, j) in enumerate(rows):
        a[r, col[i]], a[r, col[j]] = 1.0, -1.0
    a[-1, :] = 1.0
    b = np.append(values, 0.0)
    logs = np.linalg.lstsq(a, b, rcond=None)[0]
    scales[taking] = np.exp(logs)
    return scales


def aligned_scene(scene: Scene, scales: np.ndarray) -> Scene:
    """A copy of ``scene`` whose view-i Gaussians are scaled by ``1 / scales[i]`` about the
    centre of camera i: positions along their rays and sizes, so that camera i sees them at
    the same pixels with the same footprints. Everything else is shared."""
    g = scene.gaussians
    means, sizes = g.means.copy(), g.scales.copy()
    for view, members in enumerate(view_members(scene)):    # view by view: no (N, 3) float64
        factor = 1.0 / float(scales[view])
        if factor == 1.0 or members.size == 0:
            continue
        centre = scene.cameras[view].position
        means[members] = centre + (g.means[members].astype(np.float64) - centre) * factor
        sizes[members] *= np.float32(factor)
    moved = Gaussians(means, sizes, g.quats, g.opacities, g.sh, g.extra)
    return Scene(moved, scene.view_id, scene.pixel_id, scene.cameras, scene.images,
                 scene.render_settings)
