"""Each view's depth noise: the refinement's depth test in the view's own scale.

Real feed-forward predictions disagree between views in ways that are not distractors: each
view's depth has its own scale and noise. :func:`view_depth_scales` measures, per view, the
scale of its depths relative to what the other views render and the spread of that ratio;
:func:`widened_margin` is the relative gap that counts as "in front" beyond that spread. The
colour's counterpart is :mod:`clearsplat.filter.explained`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["view_depth_scales", "widened_margin"]

#: Fewer usable pixels than this and nothing is measured (scale 1, spread 0).
_FIT_MIN_PIXELS = 64
#: "In front" means beyond this many robust standard deviations of the view's depth ratio to
#: the reference.
_SPREAD_FACTOR = 2.5


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


def widened_margin(margin: float, spread: float) -> float:
    """The relative depth gap that counts as "in front" in a view whose depth ratio to the
    reference spreads by ``spread`` (robust standard deviation of its log): beyond the view's
    own depth noise (2.5 robust SD), not only beyond ``margin``."""
    return max(margin, 1.0 - np.exp(-_SPREAD_FACTOR * spread))
