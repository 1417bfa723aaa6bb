"""Options that make the filter hold on what real backbones predict.

Real feed-forward predictions disagree between views in ways that are not distractors: each
view's depth has its own scale, and estimated cameras are off by a fraction of a degree. Each
function here undoes one of those before the paper's comparisons, and each is switched by a
:class:`FilterConfig` field (off in the ``paper`` presets):

- :func:`view_depth_scales` (the refinement's depth test): the scale of each view's depths relative to
  what the other views render, so that "in front of the static surface" is judged in the
  view's own depth scale.
- :func:`misregistration` and :func:`tolerant_reference` (the refinement's colour test): how many
  pixels a view's input and the other views' render are out of register, and the refinement's
  static reference widened by that radius (nearest surface, range of colours), so that static
  edges a few pixels off do not count as standing in front.
- ``min_relative_score`` (in :mod:`clearsplat.filter.verify`): a test passes
  only if the removal takes away a large enough share of the error it touches.
"""

from __future__ import annotations

import numpy as np

__all__ = ["view_depth_scales", "tolerant_reference", "box_extreme", "misregistration"]

#: Pixels compared for a misregistration need the render this opaque.
_FIT_MIN_ALPHA = 0.9
#: A shift counts as misregistration when it lowers the mismatch by this share.
_SHIFT_GAIN = 0.1
#: Fewer usable pixels than this and nothing is measured (scale 1, no misregistration).
_FIT_MIN_PIXELS = 64


def view_depth_scales(own_depths: list[np.ndarray], reference_depths: list[np.ndarray]
                      ) -> list[tuple[float, float]]:
    """Per view, the median ratio of its own depth to the reference depth at the same pixels,
    and the spread of that ratio.

    Parameters
    ----------
    own_depths : list of (M_i,) float
        Camera-i depths of view i's Gaussians, at pixels where the reference is valid.
    reference_depths : list of (M_i,) float
        The reference depth (what the other views render) at those pixels, positive.

    Returns
    -------
    list of (scale, spread)
        ``scale = exp(median(log(own / reference)))`` and ``spread`` the robust standard
        deviation (1.4826 times the median absolute deviation) of ``log(own / reference)``;
        ``(1, 0)`` where nothing can be compared. Median and MAD ignore the minority of pixels
        where a distractor stands in front.
    """
    out = []
    for z, ref in zip(own_depths, reference_depths):
        ok = (z > 0) & (ref > 0)
        if ok.sum() < _FIT_MIN_PIXELS:
            out.append((1.0, 0.0))
            continue
        r = np.log(z[ok] / ref[ok])
        med = float(np.median(r))
        out.append((float(np.exp(med)), float(1.4826 * np.median(np.abs(r - med)))))
    return out


def misregistration(image: np.ndarray, render_rgb: np.ndarray, render_alpha: np.ndarray, *,
                    max_shift: int = 8) -> int:
    """How many pixels ``image`` and a render of the same camera are out of register.

    Finds the integer image shift (within ``max_shift`` pixels, searched at half resolution on
    grey levels) that best matches the opaque part of the render (accumulated opacity >= 0.9)
    to the image in mean absolute difference, and returns its Chebyshev length in pixels: 0
    for views that agree (exact cameras), a few pixels where the cameras handed to the filter
    are off (estimated poses) or a view's depth scale disagrees with the others'.
    """
    grey = np.asarray(image, np.float64).mean(-1)
    ref = np.asarray(render_rgb, np.float64).mean(-1)
    ok = np.asarray(render_alpha) >= _FIT_MIN_ALPHA
    h, w = (grey.shape[0] // 2) * 2, (grey.shape[1] // 2) * 2

    def half(a):
        return a[:h, :w].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
    g, r, m = half(grey), half(ref), half(ok.astype(np.float64)) == 1.0
    k = max(int(max_shift) // 2, 1)
    if m[k:-k, k:-k].sum() < _FIT_MIN_PIXELS:
        return 0
    best, best_cost, zero_cost = (0, 0), np.inf, np.inf
    core = (slice(k, g.shape[0] - k), slice(k, g.shape[1] - k))
    gc = g[core]
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            sl = (slice(k + dy, g.shape[0] - k + dy), slice(k + dx, g.shape[1] - k + dx))
            valid = m[sl]
            cost = np.abs(gc - r[sl])[valid].mean()
            if dy == 0 and dx == 0:
                zero_cost = cost
            if cost < best_cost:
                best, best_cost = (dy, dx), cost
    # No misregistration unless a shift explains the difference clearly better than none
    # (parallax and disocclusions favour small shifts by a little on any pair of views).
    if best_cost > (1.0 - _SHIFT_GAIN) * zero_cost:
        return 0
    return 2 * max(abs(best[0]), abs(best[1]))


def box_extreme(a: np.ndarray, radius: int, op=np.minimum) -> np.ndarray:
    """The minimum (``op=np.minimum``) or maximum (``np.maximum``) of ``a`` over the
    (2 radius + 1)-pixel square around each pixel of its first two axes, the border repeated
    outwards (``scipy.ndimage.minimum_filter(a, size=(s, s, 1...), mode="nearest")``, without
    importing SciPy). Separable: the rows, then the columns."""
    out = np.asarray(a)
    if radius <= 0:
        return out.copy()
    size = 2 * radius + 1
    for axis in (0, 1):
        pad = [(0, 0)] * out.ndim
        pad[axis] = (radius, radius)
        padded = np.pad(out, pad, mode="edge")
        n = out.shape[axis]
        lead = (slice(None),) * axis
        acc = padded[lead + (slice(0, n),)].copy()
        for k in range(1, size):
            op(acc, padded[lead + (slice(k, k + n),)], out=acc)
        out = acc
    return out


def tolerant_reference(depths: list[np.ndarray], rgbs: list[np.ndarray], radius, *,
                       depth_radius=None) -> tuple[list, list, list]:
    """The static reference of ``refine`` made tolerant to a misregistration of ``radius`` px
    (one radius for every view, or a list with one per view; 0 leaves a view as it is).

    Returns ``(depths, rgb_lo, rgb_hi)``: per view, the nearest reference depth within
    ``depth_radius`` (the same form; default ``radius``: a Gaussian is in front only if it is
    in front of every surface the other views show nearby; 0 stays "nothing there" where the
    whole window is empty), and the per-channel range of the reference colours within
    ``radius`` (NaN where the pixel's own colour is NaN).
    """
    def per_view(r):
        return [r] * len(depths) if np.isscalar(r) else list(r)
    radii = per_view(radius)
    depth_radii = radii if depth_radius is None else per_view(depth_radius)
    out_d, out_lo, out_hi = [], [], []
    for d, rgb, r, rd in zip(depths, rgbs, radii, depth_radii):
        if rd <= 0:
            out_d.append(d)
        else:
            near = box_extreme(np.where(d > 0, d, np.inf), int(rd), np.minimum)
            out_d.append(np.where(np.isfinite(near), near, 0.0))
        if r <= 0:
            out_lo.append(rgb)
            out_hi.append(rgb)
            continue
        missing = np.isnan(rgb)
        lo = box_extreme(np.where(missing, np.inf, rgb), int(r), np.minimum)
        hi = box_extreme(np.where(missing, -np.inf, rgb), int(r), np.maximum)
        out_lo.append(np.where(missing, np.nan, lo))
        out_hi.append(np.where(missing, np.nan, hi))
    return out_d, out_lo, out_hi
