"""Candidate verification: the rendering-change-weighted error reduction.

Paper, "Candidate Verification". For a removal C and a view j rendered from some base
representation B:

    E(p)   = |B_j(p) - I_j(p)|_1          E'(p) = |B_j^-C(p) - I_j(p)|_1
    delta  = E - E'                        w(p)  = |B_j^-C(p) - B_j(p)|_1
    Omega  = {p not in Q_j, w(p) > epsilon}   (and, with ``verify_holes="skip"``, the render
                                               after removal keeps opacity >= eta at p)
    score  = sum_{j, p in Omega} w delta / sum_{j, p in Omega} w      (0 when the sum is 0)

A removal changes only the tiles its Gaussians touch, so the incremental path re-composites
only those (exactly; see ``PreparedView.rerender_tiles``) and the full path re-renders whole
images. Both visit the changed pixels in the same (row-major) order and sum in float64, so they
give identical scores.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..render import PreparedView, RenderResult

__all__ = ["Partial", "change_weighted_terms", "Verifier"]


@dataclass
class Partial:
    """Numerator and denominator of one removal's score, summed over some views."""

    num: float = 0.0
    den: float = 0.0
    #: Sum of ``w * E`` (the change-weighted error before the removal), for
    #: :attr:`relative_score`.
    err: float = 0.0

    def add(self, other: "Partial") -> None:
        self.num += other.num
        self.den += other.den
        self.err += other.err

    @property
    def relative_score(self) -> float:
        """The share of the change-weighted error before the removal that it takes away:
        ``sum(w delta) / sum(w E)`` (0 when there is none). Near 1 for a removal that explains
        what it touches (a distractor), near 0 where it only trades one error for another."""
        return self.num / self.err if self.err > 0 else 0.0

    @property
    def score(self) -> float:
        """The pooled score: 0 when no pixel carries weight."""
        return self.num / self.den if self.den > 0 else 0.0


def change_weighted_terms(base_rgb: np.ndarray, removed_rgb: np.ndarray, image: np.ndarray,
                          excluded: np.ndarray, epsilon: float,
                          removed_alpha: np.ndarray | None = None,
                          min_alpha: float = 0.0, image_hi: np.ndarray | None = None) -> Partial:
    """Sum of ``w * delta`` and ``w`` over the valid pixels of matching pixel arrays.

    Parameters
    ----------
    base_rgb, removed_rgb, image : (M, 3) float32
        The same M pixels, in row-major order, before and after the removal, and the input.
    excluded : (M,) bool
        Pixels of the exclusion mask Q.
    removed_alpha : (M,) float32, optional
        Accumulated opacity after the removal; pixels below ``min_alpha`` are holes that no
        remaining Gaussian explains, and are left out.
    image_hi : (M, 3) float32, optional
        With it, ``image`` and ``image_hi`` are per-channel lower and upper bounds of the input
        (``FilterConfig.verify_tolerance``) and the error of a colour is its L1 distance to that
        box (0 inside).
    """
    base = base_rgb.astype(np.float64)
    after = removed_rgb.astype(np.float64)
    img = image.astype(np.float64)
    w = np.abs(after - base).sum(axis=-1)
    valid = (w > epsilon) & ~excluded
    if removed_alpha is not None and min_alpha > 0:
        valid &= removed_alpha >= min_alpha
    if not valid.any():
        return Partial()
    w = w[valid]
    if image_hi is not None:
        return _tolerant_terms(w, base[valid], after[valid], img[valid],
                               image_hi[valid].astype(np.float64))
    e_before = np.abs(base[valid] - img[valid]).sum(-1)
    delta = e_before - np.abs(after[valid] - img[valid]).sum(-1)
    return Partial(float(np.sum(w * delta)), float(np.sum(w)), float(np.sum(w * e_before)))


def _tolerant_terms(w, base, after, lo, hi) -> Partial:
    """``change_weighted_terms`` with the error measured to the box [lo, hi] per channel."""
    def err(x):
        return (np.maximum(lo - x, 0.0) + np.maximum(x - hi, 0.0)).sum(-1)
    e_before = err(base)
    delta = e_before - err(after)
    return Partial(float(np.sum(w * delta)), float(np.sum(w)), float(np.sum(w * e_before)))


def tile_pixels(view: PreparedView, tiles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat pixel indices of ``tiles`` in tile-major, row-major order, and which exist.

    Returns ``(flat, inside)``, both shaped (T * t * t,) for tile size t; ``flat`` is 0 where
    the tile reaches past the image border.
    """
    t = view.tile_size
    cols = view.grid[1]
    height, width = view.camera.height, view.camera.width
    ty, tx = np.divmod(tiles.astype(np.int64), cols)
    yy, xx = np.mgrid[0:t, 0:t]
    rows = ty[:, None, None] * t + yy[None]
    cc = tx[:, None, None] * t + xx[None]
    inside = ((rows < height) & (cc < width)).ravel()
    flat = np.where(inside, (rows * width + cc).ravel(), 0)
    return flat, inside


class Verifier:
    """Scores removals against the input views, incrementally or by full re-renders.

    Parameters
    ----------
    views : list of PreparedView
        One per input camera, prepared from the whole scene.
    images : list of (H, W, 3) float32
        The input images.
    epsilon : float
    incremental : bool
    hole_alpha : float
        Pixels whose accumulated opacity after a removal stays below this are left out.
    images_hi : list of (H, W, 3) float32, optional
        Upper bounds of the input colours; ``images`` are then the lower bounds.
    """

    def __init__(self, views: list[PreparedView], images: list[np.ndarray], *, epsilon: float,
                 incremental: bool = True, hole_alpha: float = 0.0,
                 images_hi: list[np.ndarray] | None = None):
        self.views = views
        self.images = [im.reshape(-1, 3) for im in images]
        # With upper bounds, ``images`` are the lower bounds of a tolerant error.
        self.images_hi = None if images_hi is None else [im.reshape(-1, 3) for im in images_hi]
        self.epsilon = float(epsilon)
        self.incremental = incremental
        self.hole_alpha = float(hole_alpha)

    def score_tiles(self, j: int, base: RenderResult, after: RenderResult, tiles: np.ndarray,
                    excluded: np.ndarray) -> Partial:
        """Score terms of ``after`` against ``base`` on view ``j``, read only in ``tiles``.

        For renders that can differ only inside ``tiles`` (and are exact there); visits the
        pixels in row-major order like the other paths, so the sums agree with them exactly.
        """
        flat, inside = tile_pixels(self.views[j], np.asarray(tiles))
        idx = np.sort(flat[inside])
        return change_weighted_terms(base.rgb.reshape(-1, 3)[idx],
                                     after.rgb.reshape(-1, 3)[idx], self.images[j][idx],
                                     excluded.ravel()[idx], self.epsilon,
                                     after.alpha.reshape(-1)[idx], self.hole_alpha,
                                     self._hi(j, idx))

    def score_view(self, j: int, base_keep: np.ndarray, base: RenderResult,
                   removals: list[np.ndarray], excluded: np.ndarray) -> list[Partial]:
        """Score terms of each removal on view ``j``.

        Parameters
        ----------
        base_keep : (N,) bool
            The base representation B.
        base : RenderResult
            Its render from camera j.
        removals : list of int64 arrays
            Gaussians removed from B, one set per removal.
        excluded : (H, W) bool
            The exclusion mask Q_j.
        """
        if not removals:
            return []
        base_rgb = base.rgb.reshape(-1, 3)
        q = excluded.ravel()
        out = []
        if self.incremental:
            patches = self.views[j].rerender_tiles(keep=base_keep, removals=removals, base=base)
            for patch in patches:
                flat, inside = tile_pixels(self.views[j], patch.tiles)
                flat = flat[inside]
                order = np.argsort(flat, kind="stable")
                idx = flat[order]
                after = patch.rgb.reshape(-1, 3)[inside][order]
                alpha = patch.alpha.reshape(-1)[inside][order]
                out.append(change_weighted_terms(base_rgb[idx], after, self.images[j][idx],
                                                 q[idx], self.epsilon, alpha, self.hole_alpha,
                                                 self._hi(j, idx)))
            return out
        for removal in removals:
            keep = base_keep.copy()
            keep[removal] = False
            r = self.views[j].render(keep=keep)
            out.append(change_weighted_terms(base_rgb, r.rgb.reshape(-1, 3), self.images[j], q,
                                             self.epsilon, r.alpha.reshape(-1), self.hole_alpha,
                                             self._hi(j, slice(None))))
        return out

    def _hi(self, j: int, idx) -> np.ndarray | None:
        return None if self.images_hi is None else self.images_hi[j][idx]
