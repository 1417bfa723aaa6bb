"""Is a Gaussian's colour explained by the other views? One test, at each view's own noise.

The refinement, the expansion and the verdict on a candidate all ask the same question of the
default's refinement (``refine="static-depth"``): does view i's input show, at a Gaussian's
pixel, what the other views show there (the *static reference*: R_i^-i without any proposed
Gaussian, :func:`~clearsplat.filter.refine.static_reference`)? Real predictions never agree
exactly, so the answer is read against how closely the other views reproduce the view's
static content:

- **distance** (:func:`color_distances`): L1 over RGB from the view's input colour to the
  range of the reference colours within the view's measured misregistration
  (:func:`misregistration`, :func:`tolerant_reference`);
- **noise** (:class:`ColorNoise`): per view, the distribution of that distance over its
  Gaussians outside every proposal region;
- **explained**: a distance within the view's ``EXPLAINED`` quantile (what static content
  typically shows); **beyond**: above its ``BEYOND`` quantile (what static content almost never
  shows).

The refinement keeps a kept Gaussian at a distractor's outline in the scene when its colour is
explained (a flying pixel of the surface behind, :func:`explained_silhouettes`), and takes a
Gaussian in front by less than the view's depth noise when its colour is beyond; the expansion
takes a Gaussian kept for its colour alone only when its colour is beyond; a candidate whose
Gaussians' median colour is explained is rejected (:func:`explained_candidates`: static content
out of register).
"""

from __future__ import annotations

import numpy as np

from ..scene import Scene
from .association import ViewIndex
from .masks import dilate8

__all__ = ["EXPLAINED", "BEYOND", "ColorNoise", "misregistration", "box_extreme",
           "tolerant_reference", "box_distance", "color_distances", "explained_candidates",
           "reject_explained", "explained_silhouettes"]

#: A colour distance at most this quantile of the view's static distances is explained: the
#: verdict on a candidate (its median) and the silhouette test (per Gaussian).
EXPLAINED = 0.75
#: A colour distance above this quantile of the view's static distances is beyond its noise:
#: the band test of the refinement and the expansion's reach (per Gaussian).
BEYOND = 0.99

#: Pixels compared for a misregistration need the render this opaque.
_FIT_MIN_ALPHA = 0.9
#: A shift counts as misregistration when it lowers the mismatch by this share.
_SHIFT_GAIN = 0.1
#: Fewer usable pixels than this and no misregistration is measured.
_FIT_MIN_PIXELS = 64


class ColorNoise:
    """Per view, how closely the other views reproduce its static content: the colour
    distances (:func:`color_distances`) of its Gaussians outside every proposal region.

    Parameters
    ----------
    distances : (N,) float
        :func:`color_distances` of every Gaussian (NaN: none).
    raw : list of (M_k,) int
        Every candidate's Gaussians before refinement (what the proposals cover).
    members : list of (M_v,) int
        Per view, the indices of its Gaussians (``ViewIndex.members``).

    Attributes
    ----------
    static : (N,) bool
        The Gaussians outside every proposal region that have a distance.
    """

    def __init__(self, distances: np.ndarray, raw: list, members: list):
        self.distances, self.members = distances, members
        proposed = np.zeros(distances.shape, dtype=bool)
        for g in raw:
            proposed[g] = True
        self.static = ~proposed & np.isfinite(distances)
        self._bounds: dict = {}

    def bounds(self, quantile: float) -> list:
        """Per view, the ``quantile`` of its static distances (None: the view has none);
        computed once per quantile."""
        if quantile not in self._bounds:
            self._bounds[quantile] = [self.bound(v, quantile) for v in range(len(self.members))]
        return self._bounds[quantile]

    def bound(self, view: int, quantile: float) -> float | None:
        """The ``quantile`` of ``view``'s static distances; None where it has none."""
        m = self.members[view]
        ref = self.distances[m[self.static[m]]]
        return float(np.quantile(ref, quantile)) if ref.size else None

    def beyond(self, selected: np.ndarray, quantile: float | None = None) -> np.ndarray:
        """(N,) bool: the Gaussians of ``selected`` ((N,) bool) whose distance exceeds their
        view's ``quantile`` (default ``BEYOND``; NaN distances: not beyond)."""
        out = np.zeros(self.distances.shape, dtype=bool)
        bounds = self.bounds(BEYOND if quantile is None else quantile)
        for m, bound in zip(self.members, bounds):
            if bound is not None:
                with np.errstate(invalid="ignore"):
                    out[m] = selected[m] & (self.distances[m] > bound)
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
    gc = g[k:g.shape[0] - k, k:g.shape[1] - k]
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            sl = (slice(k + dy, g.shape[0] - k + dy), slice(k + dx, g.shape[1] - k + dx))
            cost = np.abs(gc - r[sl])[m[sl]].mean()
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
    """The static reference made tolerant to a misregistration of ``radius`` px (one radius
    for every view, or a list with one per view; 0 leaves a view as it is).

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


def box_distance(image: np.ndarray, lo: np.ndarray, hi: np.ndarray | None,
                 pixels: np.ndarray) -> np.ndarray:
    """L1 distance over RGB of ``image``'s colours at ``pixels`` to the box [lo, hi], (M,) float.

    ``image``, ``lo``, ``hi``: (H*W, 3); ``hi`` None: the box is the single colour ``lo``
    (plain L1 difference). NaN where the box is NaN (no reference colour there)."""
    x = image[pixels]
    low = lo[pixels]
    with np.errstate(invalid="ignore"):
        if hi is None:
            return np.abs(x - low).sum(-1)
        return (np.maximum(low - x, 0) + np.maximum(x - hi[pixels], 0)).sum(-1)


def color_distances(scene: Scene, index: ViewIndex, reference_rgbs: list, images: list,
                    pixels: list, *, reference_rgbs_hi: list | None = None) -> np.ndarray:
    """Per Gaussian, the distance of its view's input colour to the reference colours at its
    pixel, (N,) float32 (:func:`box_distance`). NaN where the Gaussian has no pixel or the
    reference no colour.

    Parameters
    ----------
    reference_rgbs : list of (H, W, 3) float
        Per view, the reference colours (the lower bounds with ``reference_rgbs_hi``).
    images : list of (H, W, 3) float
        The input colours.
    pixels : list of (M_v,) int or None
        Per view, :func:`~clearsplat.filter.association.member_pixels` (None for a view
        without Gaussians).
    reference_rgbs_hi : list of (H, W, 3) float, optional
        Upper bounds of the reference colours: the distance is then to that box.
    """
    out = np.full(len(scene), np.nan, dtype=np.float32)
    for view, members in enumerate(index.members):
        if members.size == 0:
            continue
        pix = pixels[view]
        valid = pix >= 0
        hi = None if reference_rgbs_hi is None else reference_rgbs_hi[view].reshape(-1, 3)
        d = np.full(members.size, np.nan, dtype=np.float32)
        d[valid] = box_distance(images[view].reshape(-1, 3),
                                reference_rgbs[view].reshape(-1, 3), hi, pix[valid])
        out[members] = d
    return out


def explained_candidates(candidates: list, noise: ColorNoise, *,
                         quantile: float | None = None) -> list:
    """The candidates whose removal would take away only what the other views already show:
    static content out of register.

    A candidate is explained when the median distance over its Gaussians that have one (its
    ``expanded`` Gaussians, hat C_k, what accepting it removes; its refined ``gaussians``
    where it has no expansion) is at most its view's ``quantile`` of ``noise`` (default
    ``EXPLAINED``). A candidate
    without any such Gaussian, or in a view without static distances, is not explained. Each
    candidate judged gets ``scores["color"]``, that median, and ``scores["color_bound"]``.

    Returns
    -------
    list of Candidate
        The explained ones, in order.
    """
    bounds, out = noise.bounds(EXPLAINED if quantile is None else quantile), []
    for c in candidates:
        d = noise.distances[c.gaussians if c.expanded is None else c.expanded]
        d = d[np.isfinite(d)]
        bound = bounds[c.view]
        if d.size == 0 or bound is None:
            continue
        median = float(np.median(d))
        c.scores["color"], c.scores["color_bound"] = median, bound
        if median <= bound:
            out.append(c)
    return out


def reject_explained(candidates: list, noise: ColorNoise) -> list:
    """``candidates`` less those the other views explain (:func:`explained_candidates`),
    which are rejected: static content out of register."""
    explained = explained_candidates(candidates, noise)
    for c in explained:
        c.reason = "explained by the other views: static content out of register"
    out = {c.index for c in explained}
    return [c for c in candidates if c.index not in out]


def explained_silhouettes(scene: Scene, index: ViewIndex, revealing: np.ndarray,
                          noise: ColorNoise, pixels: list, *,
                          quantile: float | None = None) -> np.ndarray:
    """The Gaussians of ``revealing`` on its silhouette whose colour the other views show,
    (N,) bool.

    A depth network blurs depth across an object's outline, so the Gaussians of the surface
    pixels next to a distractor float between it and that surface (flying pixels): they stand
    in front of the static reference, but show its colour. Per view, a Gaussian of
    ``revealing`` is on the silhouette where its pixel has an 8-neighbour holding Gaussians of
    the view but none of its ``revealing`` ones; it is explained where its distance is at most
    the view's ``quantile`` of ``noise`` (default ``EXPLAINED``). Only pixel-aligned
    Gaussians (``ViewIndex.pixels`` set) take part: the pixel a Gaussian's centre projects to
    draws no outline. NaN distances explain nothing.

    Parameters
    ----------
    revealing : (N,) bool
        What the refinement keeps.
    noise : ColorNoise
        The colour distances and each view's static ones.
    pixels : list of (M_v,) int64
        Per view, its Gaussians' pixels (-1: none); None for a view without Gaussians. Only
        those where ``index.pixels`` is set are read.
    """
    quantile = EXPLAINED if quantile is None else quantile
    out = np.zeros(revealing.shape, dtype=bool)
    for view, members in enumerate(index.members):
        if pixels[view] is None:         # a view without Gaussians
            continue
        pix = np.where(index.pixels[view] >= 0, pixels[view], -1)
        sel = revealing[members] & (pix >= 0)
        bound = noise.bound(view, quantile) if sel.any() else None
        if bound is None:
            continue
        cam = scene.cameras[view]
        held = np.zeros(cam.height * cam.width, dtype=bool)
        held[pix[sel]] = True
        # Outside: pixels of the view's other Gaussians, none of them kept (a pixel without
        # any Gaussian of the view is not outside).
        outside = np.zeros(cam.height * cam.width, dtype=bool)
        outside[pix[pix >= 0]] = True
        outside &= ~held
        edge = held.reshape(cam.height, cam.width) & dilate8(
            outside.reshape(cam.height, cam.width))
        on = sel.copy()
        on[sel] = edge.ravel()[pix[sel]]
        with np.errstate(invalid="ignore"):
            on &= noise.distances[members] <= bound
        out[members[on]] = True
    return out
