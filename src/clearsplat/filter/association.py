"""From image regions to Gaussians.

Paper, end of "Distractor Proposal": a region M_k of view i maps to the Gaussians C_k that
view i predicted there (:func:`region_gaussians`; :class:`RegionMap` for a round). Each
Gaussian's view and pixel (:func:`member_pixels`: its ``pixel_id``, or the pixel its centre
projects to) is what every stage reads of the association.
"""

from __future__ import annotations

import numpy as np

from ..render import contributions
from ..scene import Scene


__all__ = ["ViewIndex", "RegionMap", "view_members", "region_gaussians", "member_pixels",
           "member_depths"]


class ViewIndex:
    """Per-view lists of Gaussian indices, their pixel ids, and their pixels and depths in
    their view's camera, built once per round."""

    def __init__(self, scene: Scene):
        # Indices and pixel ids are held as int32 where they fit (half the memory of int64 at
        # millions of Gaussians); what the methods return is int64.
        self.members = view_members(scene, narrow=True)
        #: The Gaussians shared by several views (view id -1): in no view's members.
        self.shared = _narrow(np.flatnonzero(scene.view_id < 0), len(scene))
        self.pixels = [_narrow(scene.pixel_id[m], cam.width * cam.height)
                       for m, cam in zip(self.members, scene.cameras)]
        # Pixel -> Gaussians of each view as CSR (pixel-aligned Gaussians only): a region's
        # Gaussians are then gathered in time proportional to the region, not the view.
        self._by_pixel = []
        for i, cam in enumerate(scene.cameras):
            pid = self.pixels[i]
            aligned = np.flatnonzero(pid >= 0)
            by = aligned[np.argsort(pid[aligned], kind="stable")]
            starts = np.searchsorted(pid[by], np.arange(cam.width * cam.height + 1))
            self._by_pixel.append((self.members[i][by], _narrow(starts, len(scene))))
        self.n = len(scene)
        self.shapes = [(cam.height, cam.width) for cam in scene.cameras]
        #: Per view, its Gaussians' camera depths and pixels in its image (:func:`member_depths`):
        #: what every depth and colour test of a round reads.
        self.depths, self.image_pixels = member_depths(scene, self)

    def pixels_of(self, view: int, selected: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels of ``view`` holding one of its ``selected`` ((N,) bool)
        Gaussians."""
        h, w = self.shapes[view]
        out = np.zeros(h * w, dtype=bool)
        pix = self.image_pixels[view]
        if pix is not None:
            out[pix[selected[self.members[view]] & (pix >= 0)]] = True
        return out.reshape(h, w)

    def at_pixels(self, view: int, flat_pixels: np.ndarray) -> np.ndarray:
        """Pixel-aligned Gaussians of ``view`` at the given flat pixel indices (unsorted)."""
        gaussians, starts = self._by_pixel[view]
        lo, hi = starts[flat_pixels], starts[flat_pixels + 1]
        counts = hi - lo
        if counts.sum() == 0:
            return np.empty(0, dtype=np.int64)
        # Concatenate the ranges [lo, hi) without a Python loop.
        offsets = np.repeat(lo.astype(np.int64) - np.cumsum(counts) + counts, counts)
        return gaussians[offsets + np.arange(counts.sum())].astype(np.int64)

    def mask(self, view: int, n: int) -> np.ndarray:
        """(N,) bool mask of the Gaussians of ``view``."""
        out = np.zeros(n, dtype=bool)
        out[self.members[view]] = True
        return out

    def views_mask(self, views: np.ndarray, n: int) -> np.ndarray:
        """(N,) bool mask of the Gaussians of the views where ``views`` ((V,) bool) is set:
        ``views[scene.view_id]``, in time proportional to those views' Gaussians."""
        out = np.zeros(n, dtype=bool)
        for v in np.flatnonzero(views):
            out[self.members[v]] = True
        return out


def view_members(scene: Scene, *, narrow: bool = False) -> list[np.ndarray]:
    """Per view, the indices of its Gaussians in ascending order: (M_i,) int64, or int32 with
    ``narrow`` where the scene's size fits."""
    order = np.argsort(scene.view_id, kind="stable")
    if narrow:
        order = _narrow(order, len(scene))
    bounds = np.searchsorted(scene.view_id[order], np.arange(scene.num_views + 1))
    return [order[bounds[i]:bounds[i + 1]] for i in range(scene.num_views)]


#: A Gaussian without ``pixel_id`` belongs to a region where its blending weight (alpha * T),
#: compositing only its view's Gaussians from that view's camera, reaches this at some pixel of
#: the region: the front surface of that view's prediction.
MIN_WEIGHT = 0.05


def _narrow(values: np.ndarray, bound: int) -> np.ndarray:
    """``values`` (known to lie in [-1, ``bound``]) as int32 where ``bound`` fits, else as
    they are."""
    return values.astype(np.int32) if bound < 2**31 - 1 else values


def region_gaussians(scene: Scene, view: int, pixels: np.ndarray, *, index: ViewIndex,
                     min_weight: float = MIN_WEIGHT, prepared=None) -> np.ndarray:
    """Gaussians of ``view`` that a pixel region maps to [C_k], sorted int64 indices.

    Pixel-aligned Gaussians map through their ``pixel_id`` (several per pixel allowed). The
    others (``pixel_id == -1``) map through the rasterizer association: compositing only the
    Gaussians of ``view`` from its own camera, those whose blending weight (alpha * T) reaches
    ``min_weight`` at some pixel of the region (the front surface of that view's prediction).

    Parameters
    ----------
    pixels : (H, W) bool
        The region in the image of ``view``.
    prepared : prepared view, optional
        ``view``'s camera prepared from the whole scene; reused instead of projecting the
        scene again for every region.
    """
    members, pid = index.members[view], index.pixels[view]
    flat = pixels.ravel()
    chosen = np.sort(index.at_pixels(view, np.flatnonzero(flat)))
    aligned = pid >= 0
    if aligned.all() or not flat.any():
        return chosen
    own = np.zeros(len(scene), dtype=bool)
    own[members] = True
    if prepared is None:
        contrib = contributions(scene, scene.cameras[view], pixels, keep=own)
    else:
        contrib = prepared.contributions(pixels, keep=own)
    g = contrib.gaussian[(contrib.weight >= min_weight)]
    g = g[(scene.view_id[g] == view) & (scene.pixel_id[g] < 0)]
    return np.union1d(chosen, g).astype(np.int64)


class RegionMap:
    """A round's map from regions to Gaussians: ``region_map(view, pixels)`` is
    :func:`region_gaussians` of the round's scene, with the round's prepared view where the
    view has Gaussians without pixel ids (pixel-aligned views need no prepared view).

    Parameters
    ----------
    state : RoundState
    """

    def __init__(self, state):
        self.scene, self.index, self.views = state.scene, state.index, state.views
        self.min_weight = MIN_WEIGHT
        self.loose = [bool((p < 0).any()) for p in self.index.pixels]
        self._by_pixel: dict = {}

    def __call__(self, view: int, pixels: np.ndarray) -> np.ndarray:
        """(M,) int64: the Gaussians of ``view`` that the (H, W) bool ``pixels`` map to."""
        chosen = np.sort(self.index.at_pixels(view, np.flatnonzero(pixels.ravel())))
        if not self.loose[view] or not pixels.any():
            return chosen
        gaussians, starts = self._loose_by_pixel(view)
        flat = np.flatnonzero(pixels.ravel())
        lo, hi = starts[flat], starts[flat + 1]
        counts = hi - lo
        offsets = np.repeat(lo - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
        return np.union1d(chosen, gaussians[offsets]).astype(np.int64)

    def _loose_by_pixel(self, view: int) -> tuple:
        """Per pixel of ``view`` (CSR: Gaussians, starts), its Gaussians without ``pixel_id``
        whose blending weight reaches ``min_weight`` there, compositing only the view's own
        Gaussians (:func:`region_gaussians`): made once per view, from one pass over the whole
        image, instead of once per region."""
        if view not in self._by_pixel:
            h, w = self.index.shapes[view]
            own = self.index.mask(view, self.index.n)
            contrib = self.views[view].contributions(np.ones((h, w), dtype=bool), keep=own)
            g = contrib.gaussian
            sel = (contrib.weight >= self.min_weight) & (self.scene.pixel_id[g] < 0)
            pixel = contrib.pixel[sel]      # ordered by pixel
            starts = np.searchsorted(pixel, np.arange(h * w + 1)).astype(np.int64)
            self._by_pixel[view] = (g[sel], starts)
        return self._by_pixel[view]


def member_pixels(scene: Scene, index: ViewIndex, view: int) -> np.ndarray:
    """Flat pixel of each Gaussian of ``view`` in that view's image, (M,) int64, -1 if none.

    ``pixel_id`` where the model is pixel-aligned, otherwise the pixel its centre projects to.
    """
    members = index.members[view]
    pix = index.pixels[view].astype(np.int64)
    loose = pix < 0
    if loose.any():
        pix[loose] = scene.cameras[view].flat_pixels(scene.gaussians.means[members[loose]])[0]
    return pix


def member_depths(scene: Scene, index: ViewIndex) -> tuple[list, list]:
    """Per view, the camera depth (M,) float64 and the pixel (M,) int64 (:func:`member_pixels`)
    of each of its Gaussians (None for a view without any): what every depth test of a round
    reads. Computed in the calling thread: matrix products, left to BLAS as they are, whose
    own threads must not depend on ours."""
    # The z column copied out, so that the (M, 3) camera coordinates are not held with it.
    depths = [scene.cameras[view].to_camera(scene.gaussians.means[members])[:, 2].copy()
              if members.size else None for view, members in enumerate(index.members)]
    pixels = [member_pixels(scene, index, view) if members.size else None
              for view, members in enumerate(index.members)]
    return depths, pixels
