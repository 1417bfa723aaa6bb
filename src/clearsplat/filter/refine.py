"""Refinement: keep of each candidate only the Gaussians that stand in front of the scene.

Paper, "Distractor Proposal", refinement of the regions: a Gaussian of view i belongs to a
distractor only where removing view i's Gaussians reveals a farther surface. The paper tests
this per patch; :func:`revealing_gaussians` tests it per Gaussian against a reference depth.
The reference is R_i^-i (``refine="depth"``) or, by default, the *static reference*
(``refine="static-depth"``): R_i^-i without any proposed Gaussian, so that another view's
distractor in front of view i's cannot hide it (:func:`static_reference`). The default reads
depth in each view's own scale and noise (:mod:`.robust`) and colour against each view's own
colour noise (:mod:`.explained`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .._threads import thread_map
from ..scene import Scene
from . import explained as _explained
from .association import ViewIndex
from .explained import (ColorNoise, box_distance, color_distances, misregistration,
                        tolerant_reference)
from .robust import view_depth_scales, widened_margin

__all__ = ["Refinement", "refine", "static_reference", "revealing_gaussians"]

# The default's refinement (``refine="static-depth"``; docs/method.md gives each its measurement).
#: "In front": a Gaussian's depth below (1 - MARGIN) times the reference depth at its pixel
#: (widened per view to 2.5 robust standard deviations of its depth ratio to the others).
MARGIN = 0.02
#: A Gaussian that touches the reference surface also qualifies where its view's input colour
#: differs from the reference colour by more than this (L1 over RGB): the foot of an object.
COLOR_THRESHOLD = 0.5
#: Passes of the static reference: the first leaves out every proposed Gaussian of the other
#: views, each later one only those the pass before kept, so that static content proposed
#: around another view's distractor returns to the reference.
PASSES = 2

#: Below this accumulated opacity the static reference (R_i^-i without any proposed Gaussian)
#: counts as a hole, and the plain exclusion render's depth is used instead.
_STATIC_MIN_ALPHA = 0.1
#: The colour test (``COLOR_THRESHOLD``) needs the static reference this opaque at the pixel.
_COLOR_MIN_ALPHA = 0.9


def revealing_gaussians(scene: Scene, index: ViewIndex, reference_depths: list[np.ndarray], *,
                        margin: float, reference_rgbs: list[np.ndarray] | None = None,
                        color_threshold: float | None = None, images: list | None = None,
                        align_scale: bool = False,
                        reference_rgbs_hi: list[np.ndarray] | None = None,
                        workers: int | None = None, members: tuple | None = None,
                        color_distance: np.ndarray | None = None,
                        by_depth: bool = False,
                        margins: list | None = None,
                        band_bounds: list | None = None) -> np.ndarray | tuple:
    """Gaussians in front of the surface that the other views show at their pixel, (N,) bool.

    The paper's depth condition asks, per patch, that excluding view i's Gaussians reveal a
    farther surface. This applies it per Gaussian: a Gaussian of view i qualifies when its
    camera-i depth is below ``(1 - margin)`` times the reference depth at its pixel (see
    :attr:`~clearsplat.filter.association.ViewIndex.image_pixels`). Where the reference
    shows nothing, nothing is revealed and it does not qualify.

    Parameters
    ----------
    reference_depths : list of (H, W) float
        Per input view, the expected depth of a render without that view's Gaussians (0 where
        empty).
    margin : float
        Relative depth gap that counts as "in front".
    reference_rgbs : list of (H, W, 3) float, optional
        Colours of the same reference renders; NaN where they should not be used.
    color_threshold : float, optional
        With ``reference_rgbs``: a Gaussian also qualifies when its view's input colour differs
        from the reference colour at its pixel by more than this (L1 over RGB) and it does not
        lie behind the reference surface (it touches it: the foot of an object on the floor).
    images : list of (H, W, 3) float, optional
        The input colours for the colour test (default: ``scene.images``).
    align_scale : bool
        Divide each view's depths by their median ratio to the reference depth first, and widen
        ``margin`` to 2.5 robust standard deviations of that ratio where the view's depth is
        noisier (:func:`clearsplat.filter.robust.view_depth_scales`): the test in the view's own
        depth scale and noise (the refinement always).
    reference_rgbs_hi : list of (H, W, 3) float, optional
        Upper bounds of the reference colours; ``reference_rgbs`` are then the lower bounds and
        the colour difference is the L1 distance to that box (the refinement's measured radius).
    workers : int, optional
        Threads, one view at a time each (default: the cores, at most ``OMP_NUM_THREADS``); the
        result does not depend on it.
    members : (depths, pixels), optional
        Per view, the Gaussians' depths and pixels (default: ``index.depths`` and
        ``index.image_pixels``).
    color_distance : (N,) float, optional
        :func:`color_distances` against the same reference colours, when the caller has them
        already (the colour test then reads them instead of measuring again).
    by_depth : bool
        Also return the Gaussians that qualify by the depth test alone (without the colour
        test): ``(qualify, in_front)``, both (N,) bool.
    margins : list, optional
        A list of one entry per view, filled with the margin the view's depth test used
        (``margin``, widened with ``align_scale``); None for a view without Gaussians.
    band_bounds : list of float or None, optional
        With ``color_distance``: per view, a colour distance. Where ``align_scale`` widens the
        view's margin, a Gaussian in front by more than ``margin`` but not by the widened
        margin also qualifies when its colour distance exceeds the view's entry (None: not in
        that view; the refinement's: its colour noise's ``explained.BEYOND`` quantile).
    """
    images = scene.images if images is None else images
    depths, pixels = (index.depths, index.image_pixels) if members is None else members

    def view_front(view: int) -> np.ndarray | None:
        members = index.members[view]
        if members.size == 0:
            return None
        z, pix = depths[view], pixels[view]
        behind = np.zeros(members.size)
        valid = pix >= 0
        behind[valid] = reference_depths[view].ravel()[pix[valid]]
        view_margin = margin
        if align_scale:
            scale, spread = view_depth_scales([z], [behind])[0]
            z = z / scale
            view_margin = widened_margin(margin, spread)
        if margins is not None:
            margins[view] = float(view_margin)
        front = (behind > 0) & (z > 0) & (z < (1.0 - view_margin) * behind)
        in_front = front.copy() if by_depth else None
        bound = None if band_bounds is None else band_bounds[view]
        if bound is not None and view_margin > margin:
            # In front, but within the view's depth noise: its colour decides.
            band = (behind > 0) & (z > 0) & (z < (1.0 - margin) * behind) & ~front
            with np.errstate(invalid="ignore"):
                front |= band & (color_distance[members] > bound)
        if color_threshold is not None and reference_rgbs is not None:
            image = images[view].reshape(-1, 3)
            ref = reference_rgbs[view].reshape(-1, 3)
            differ = np.zeros(members.size, dtype=bool)
            if color_distance is not None:
                diff = color_distance[members][valid]
            else:
                hi = (None if reference_rgbs_hi is None
                      else reference_rgbs_hi[view].reshape(-1, 3))
                diff = box_distance(image, ref, hi, pix[valid])
            differ[valid] = diff > color_threshold       # False where the reference is NaN
            touching = (behind > 0) & (z > 0) & (z < (1.0 + margin) * behind)
            front |= differ & touching
        return front, in_front

    out = np.zeros(len(scene), dtype=bool)
    depth_out = np.zeros(len(scene), dtype=bool) if by_depth else None
    # The views are independent (each writes its own Gaussians): one per core.
    fronts = thread_map(view_front, range(scene.num_views), workers=workers)
    for members, front in zip(index.members, fronts):
        if front is not None:
            out[members] = front[0]
            if by_depth:
                depth_out[members] = front[1]
    return (out, depth_out) if by_depth else out


@dataclass(eq=False)
class Refinement:
    """What refinement found.

    Attributes
    ----------
    revealing : (N,) bool or None
        The Gaussians in front of the reference: the only ones a candidate keeps (None with
        ``refine="none"``).
    front_pixels : list of (H, W) bool, or None
        Per view, the pixels holding one of its ``revealing`` Gaussians (what the expansion
        grows into; None with ``refine="none"``).
    noise : ColorNoise or None
        Each Gaussian's colour distance to the last static reference and each view's static
        ones (:mod:`.explained`; with ``refine="static-depth"``, else None).
    expandable : (N,) bool or None
        Of ``revealing``, those the expansion may take beyond a candidate's own Gaussians:
        those in front by depth alone, and those kept for their colour alone whose colour is
        beyond their view's noise (with ``refine="static-depth"``; None otherwise: the
        expansion takes every one of ``revealing``).
    margins : list of float, or None
        Per view, the margin of the last pass's depth test, widened by the view's depth noise
        (:func:`revealing_gaussians`; None with ``refine="none"``):
        what :func:`~clearsplat.filter.verify.seen_by_verifiers` widens its margins to.
    unreliable_pixels : list of (H, W) bool, or None
        Per view, the pixels its verification leaves out: those of ``revealing`` and of the
        silhouettes explained.
    """

    revealing: np.ndarray | None
    front_pixels: list | None = None
    noise: ColorNoise | None = None
    expandable: np.ndarray | None = None
    margins: list | None = None
    unreliable_pixels: list | None = None


def refine(state, renders, raw: list) -> Refinement:
    """The Gaussians that may belong to a candidate, and their pixels.

    Parameters
    ----------
    state : RoundState
    renders : ExclusionRenders
        Compared with the scene's input images.
    raw : list of (M_k,) int64
        Every candidate's Gaussians C_k before refinement (the proposed Gaussians).
    """
    margins = [None] * state.num_views
    found = _revealing(state, renders, state.scene.images, raw, margins)
    revealing, explained = found.revealing, found.explained
    front = unreliable = None
    if revealing is not None:
        front = [state.index.pixels_of(v, revealing) for v in range(state.num_views)]
        unreliable = front
        if explained is not None and explained.any():
            # The pixels of revealing | explained: those of either.
            unreliable = [f | state.index.pixels_of(v, explained)
                          for v, f in enumerate(front)]
    return Refinement(revealing, front, found.noise, found.expandable,
                      None if revealing is None else margins, unreliable)


class _Found(NamedTuple):
    """What :func:`_revealing` finds (None: not computed under the config)."""

    revealing: np.ndarray | None            # (N,) bool, in front of the reference
    noise: ColorNoise | None = None         # Refinement.noise
    expandable: np.ndarray | None = None    # Refinement.expandable
    explained: np.ndarray | None = None     # (N,) bool, silhouettes taken out of revealing


def _revealing(state, renders, images: list, raw: list, margins: list) -> _Found:
    """The Gaussians in front of the reference of ``config.refine``; with the static
    reference, less the silhouettes whose colour is explained (those as ``explained``), with
    the colour noise of the last pass and those the expansion may take. The last pass's
    margins go to ``margins`` (per view)."""
    config = state.config
    excl = renders.reference     # R_i^-i, or the reveal reference in its place
    if config.refine == "depth":    # no colour test: in front by depth is all there is
        revealing = revealing_gaussians(state.scene, state.index, [r.depth for r in excl],
                                        margin=MARGIN, align_scale=True,
                                        workers=config.num_threads, margins=margins)
        return _Found(revealing)    # no colour test: the expansion reads revealing
    if config.refine != "static-depth":
        return _Found(None)
    proposed = state.mask(*raw)
    # Each view's measured misregistration with the others: the colour test's radius.
    radii = thread_map(lambda i: misregistration(images[i], excl[i].rgb, excl[i].alpha),
                       range(state.num_views), workers=config.num_threads)
    members = state.index.depths, state.index.image_pixels     # the same in every pass
    noise = None
    for k in range(PASSES):
        # Each later pass builds the static reference without only the proposed Gaussians
        # that the previous pass kept, so that static content proposed by some view (around
        # another view's distractor) stays in the reference.
        reference = _static_tolerant(state, renders, proposed, radii)
        if k == PASSES - 1:     # the colour noise, measured once, read by every colour test
            noise = ColorNoise(color_distances(state.scene, state.index, reference[1], images,
                                               members[1], reference_rgbs_hi=reference[2]),
                               raw, state.index.members)
        revealing, in_front = _in_front(state, reference, images, members, noise,
                                        margins=margins)
        proposed &= revealing
        # This pass's references are not read again: dropped before the next pass makes its
        # own, so that two passes' (four images per view) are never held at once.
        reference = None
    # Beyond the candidates' own Gaussians the expansion takes those in front by depth, and
    # those kept for their colour alone only where it is beyond the view's noise.
    expandable = in_front | noise.beyond(revealing)
    # Flying pixels at a distractor's outline, in the colour of the surface behind, stay.
    explained = _explained.explained_silhouettes(state.scene, state.index, revealing, noise,
                                                 members[1])
    revealing &= ~explained
    expandable &= ~explained
    return _Found(revealing, noise, expandable, explained)


def _static_tolerant(state, renders, proposed: np.ndarray, radii: list) -> tuple:
    """:func:`static_reference` without ``proposed``, the reveal reference in its place
    wherever it applies (only the other pixels' tiles are composited again), made tolerant
    to each view's misregistration ``radii``: ``(depths, rgb_lo, rgb_hi)``.

    The colours within each view's misregistration; the depths at the Gaussian's own pixel:
    the nearest surface within a few pixels of a small object on a sloping floor is the floor
    in front of it (docs/method.md, "The depth test at the Gaussian's own pixel")."""
    needed = None if renders.reveal is None else [~valid for valid in renders.reveal_valid]
    depths, rgbs = static_reference(state, renders.excl, proposed, needed=needed)
    if renders.reveal is not None:
        _overlay_reveal(depths, rgbs, renders)
    return tolerant_reference(depths, rgbs, radii, depth_radius=0)


def static_reference(state, excl: list, proposed: np.ndarray, *,
                     needed: list | None = None) -> tuple[list, list]:
    """Per view i, the depth and colour of R_i^-i without the ``proposed`` Gaussians ((N,)
    bool): ``(depths, rgbs)``, (H, W) and (H, W, 3) each. Where that leaves a hole the depth
    falls back to R_i^-i's; colours are NaN where the other views do not cover the pixel.

    ``needed``: per view, (H, W) bool, the pixels whose reference is read (None: all). Tiles
    without any are not composited again: there the reference is R_i^-i's."""
    views, own = state.views, state.own
    reference, reference_rgb = [], []
    for i in range(state.num_views):
        others = proposed & ~own[i]
        tiles = None
        if views.sees(i, others):
            pv = views[i]
            tiles = pv.tiles_touched(others)
            if needed is not None:
                tiles = np.intersect1d(tiles, _tiles_of(needed[i], pv.grid, pv.tile_size))
        if tiles is not None and tiles.size:
            static = pv.rerender(excl[i], keep=~(own[i] | proposed), tiles=tiles)
        else:   # nothing proposed in this view (or nowhere needed): R_i^-i itself
            static = excl[i]
        # Where the proposals of the other views leave a hole, fall back to R_i^-i.
        solid = static.alpha > _STATIC_MIN_ALPHA
        reference.append(np.where(solid, static.depth, excl[i].depth))
        # Colours only where the other views cover the pixel fully: a partly covered pixel
        # (the edge of what they see) mixes in the background and proves nothing.
        covered = static.alpha >= _COLOR_MIN_ALPHA
        reference_rgb.append(np.where(covered[..., None], static.rgb, np.nan))
    return reference, reference_rgb


def _tiles_of(mask: np.ndarray, grid: tuple, size: int) -> np.ndarray:
    """Ids (int32, ascending) of the ``size``-pixel tiles of a ``grid`` (rows, columns) that
    hold any pixel of ``mask`` ((H, W) bool)."""
    rows, cols = grid
    padded = np.zeros((rows * size, cols * size), dtype=bool)
    padded[:mask.shape[0], :mask.shape[1]] = mask
    return np.flatnonzero(padded.reshape(rows, size, cols, size).any(axis=(1, 3))) \
        .astype(np.int32)


def _overlay_reveal(depths: list, rgbs: list, renders) -> None:
    """The static references (``depths``, ``rgbs``, per view, changed in place) replaced by the
    reveal reference wherever it applies (``reveal_reference="quantile"``): it outvotes the
    other views' passers-by, proposed or not, without leaving them out."""
    for i, (ref, valid) in enumerate(zip(renders.reveal, renders.reveal_valid)):
        if not valid.any():
            continue
        depths[i] = np.where(valid, ref.depth, depths[i])
        color = np.where((ref.alpha >= _COLOR_MIN_ALPHA)[..., None], ref.rgb, np.nan)
        rgbs[i] = np.where(valid[..., None], color, rgbs[i])


def _in_front(state, reference: tuple, images: list, members: tuple,
              noise: ColorNoise | None, margins: list) -> tuple:
    """:func:`revealing_gaussians` against the static reference ``(depths, rgb_lo, rgb_hi)``
    (:func:`~clearsplat.filter.explained.tolerant_reference`): ``(qualify, by_depth)``, both
    (N,) bool. With ``noise`` (the last pass) the colour test reads its distances, and within
    a view's depth noise a colour beyond the view's colour noise qualifies."""
    depths, rgb_lo, rgb_hi = reference
    return revealing_gaussians(
        state.scene, state.index, depths, margin=MARGIN, reference_rgbs=rgb_lo,
        color_threshold=COLOR_THRESHOLD, images=images, align_scale=True,
        reference_rgbs_hi=rgb_hi, workers=state.config.num_threads, members=members,
        color_distance=None if noise is None else noise.distances, by_depth=True,
        margins=margins, band_bounds=None if noise is None else noise.bounds(_explained.BEYOND))
