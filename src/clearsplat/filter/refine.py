"""Refinement: keep of each candidate only the Gaussians that stand in front of the scene.

Paper, "Distractor Proposal", refinement of the regions: a Gaussian of view i belongs to a
distractor only where removing view i's Gaussians reveals a farther surface. The paper tests
this per patch; :func:`revealing_gaussians` tests it per Gaussian against a reference depth.
The reference is R_i^-i (``refine="depth"``) or, by default, the *static reference*
(``refine="static-depth"``): R_i^-i without any proposed Gaussian, so that another view's
distractor in front of view i's cannot hide it (:func:`static_reference`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from .._threads import thread_map
from ..scene import Scene
from .association import ViewIndex
from .masks import dilate8
from .robust import misregistration, tolerant_reference

__all__ = ["Refinement", "refine", "static_reference", "revealing_gaussians", "widened_margin",
           "member_depths", "member_pixels", "centre_pixels", "pixels_of", "removed_pixels",
           "box_distance", "color_distances", "explained_candidates", "static_mask",
           "static_color_bound", "static_color_bounds", "explained_silhouettes",
           "beyond_static_colors"]

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
#: Quantiles of a view's colour distances outside every proposal region (how closely the other
#: views reproduce its static content), each the bound of one colour test; None: that test off.
#: A candidate whose expansion's median distance is within this is explained: rejected.
EXPLAINED_QUANTILE = 0.75
#: A kept Gaussian at the outline of what stands in front, within this, is a flying pixel of
#: the surface behind: kept in the scene.
SILHOUETTE_QUANTILE = 0.75
#: Within the margin a view's depth noise adds, a colour beyond this qualifies.
BAND_QUANTILE = 0.99
#: Beyond the candidate's own Gaussians the expansion takes those kept for their colour alone
#: only beyond this.
EXPAND_QUANTILE = 0.99

#: Below this accumulated opacity the static reference (R_i^-i without any proposed Gaussian)
#: counts as a hole, and the plain exclusion render's depth is used instead.
_STATIC_MIN_ALPHA = 0.1
#: The colour test (``COLOR_THRESHOLD``) needs the static reference this opaque at the pixel.
_COLOR_MIN_ALPHA = 0.9
#: With ``align_scale``: "in front" means beyond this many robust standard deviations of the
#: view's depth ratio to the reference.
_SPREAD_FACTOR = 2.5


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
    :func:`member_pixels`). Where the reference shows nothing, nothing is revealed and it does
    not qualify.

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
        :func:`member_depths` of ``scene`` and ``index``, when the caller has them already.
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
        that view; ``BAND_QUANTILE``).
    """
    from .robust import view_depth_scales
    images = scene.images if images is None else images
    depths, pixels = member_depths(scene, index) if members is None else members

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


def widened_margin(margin: float, spread: float) -> float:
    """The relative depth gap that counts as "in front" in a view whose depth ratio to the
    reference spreads by ``spread`` (robust standard deviation of its log): beyond the view's
    own depth noise (2.5 robust SD), not only beyond ``margin``."""
    return max(margin, 1.0 - np.exp(-_SPREAD_FACTOR * spread))


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
    pixel, (N,) float32 (:func:`box_distance`): the colour half of :func:`revealing_gaussians`
    on its own. NaN where the Gaussian has no pixel or the reference no colour.

    Parameters
    ----------
    reference_rgbs : list of (H, W, 3) float
        Per view, the reference colours (the lower bounds with ``reference_rgbs_hi``), as in
        :func:`revealing_gaussians`.
    images : list of (H, W, 3) float
        The input colours.
    pixels : list of (M_v,) int or None
        Per view, :func:`member_pixels` (None for a view without Gaussians).
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


def explained_candidates(candidates: list, raw: list, distances: np.ndarray,
                         members: list, *, quantile: float,
                         bounds: list | None = None) -> list:
    """The candidates whose removal would take away only what the other views already show:
    static content out of register (``EXPLAINED_QUANTILE``).

    Each candidate judged gets ``scores["color"]``, the median distance over its Gaussians,
    and ``scores["color_bound"]``, its view's quantile.

    Parameters
    ----------
    candidates : list of Candidate
        After expansion: each is judged on its ``expanded`` Gaussians [hat C_k], what accepting
        it removes (its refined ``gaussians`` where it has no expansion).
    raw : list of (M_k,) int
        Every candidate's Gaussians before refinement (what the proposals cover).
    distances : (N,) float
        :func:`color_distances`.
    members : list of (M_v,) int
        Per view, the indices of its Gaussians (``ViewIndex.members``).
    quantile : float
        A candidate is explained when the median distance over its Gaussians that have a
        reference colour is at most this quantile of the distances of its view's Gaussians
        outside every proposal region (those with a reference colour). A candidate without
        any such Gaussian, or in a view without any such static Gaussian, is not explained.
    bounds : list of float or None, optional
        Those quantiles, one per view (None: that view judges nothing), where they were
        computed already (``Refinement.color_bounds(quantile)``; None: from ``raw`` and
        ``distances`` here).

    Returns
    -------
    list of Candidate
        The explained ones, in order.
    """
    if bounds is None:
        bounds = static_color_bounds(distances, static_mask(distances, raw), members)(quantile)
    elif len(bounds) != len(members):
        raise ValueError(f"explained_candidates: {len(bounds)} bounds for {len(members)} views")
    out = []
    for c in candidates:
        d = distances[c.gaussians if c.expanded is None else c.expanded]
        d = d[np.isfinite(d)]
        bound = bounds[c.view]
        if d.size == 0 or bound is None:
            continue
        median = float(np.median(d))
        c.scores["color"], c.scores["color_bound"] = median, bound
        if median <= bound:
            out.append(c)
    return out


def static_mask(distances: np.ndarray, raw: list) -> np.ndarray:
    """(N,) bool: the Gaussians outside every proposal region (``raw``, the candidates'
    Gaussians before refinement) that have a colour distance."""
    proposed = np.zeros(distances.shape, dtype=bool)
    for g in raw:
        proposed[g] = True
    return ~proposed & np.isfinite(distances)


def static_color_bounds(distances: np.ndarray, static: np.ndarray, members: list) -> Callable:
    """Per view (``members``), :func:`static_color_bound` at a quantile: ``bounds(q)`` gives
    the list, computed once per quantile (the colour rules of one refinement share them)."""
    made: dict = {}

    def bounds(quantile: float) -> list:
        if quantile not in made:
            made[quantile] = [static_color_bound(distances, static, m, quantile)
                              for m in members]
        return made[quantile]
    return bounds


def static_color_bound(distances: np.ndarray, static: np.ndarray, members: np.ndarray,
                       quantile: float) -> float | None:
    """The ``quantile`` of the colour distances (:func:`color_distances`, (N,)) of one view's
    Gaussians (``members``) that are ``static`` ((N,) bool: outside every proposal region, with
    a distance): how closely the other views reproduce that view's static content. None
    where the view has no such Gaussian."""
    ref = distances[members[static[members]]]
    return float(np.quantile(ref, quantile)) if ref.size else None


def explained_silhouettes(scene: Scene, index: ViewIndex, revealing: np.ndarray,
                          distances: np.ndarray, pixels: list, static: np.ndarray, *,
                          quantile: float) -> np.ndarray:
    """The Gaussians of ``revealing`` on its silhouette whose colour the other views show,
    (N,) bool (``SILHOUETTE_QUANTILE``).

    A depth network blurs depth across an object's outline, so the Gaussians of the surface
    pixels next to a distractor float between it and that surface (flying pixels): they stand
    in front of the static reference, but show its colour. Per view, a Gaussian of
    ``revealing`` is on the silhouette where its pixel has an 8-neighbour holding Gaussians of
    the view but none of its ``revealing`` ones; it is explained where its colour distance is
    at most the view's :func:`static_color_bound` at ``quantile``. Only pixel-aligned
    Gaussians (``ViewIndex.pixels`` set: the backbone's own pixel) take part: the pixel a
    Gaussian's centre projects to draws no outline. NaN distances (no reference colour)
    explain nothing.

    Parameters
    ----------
    revealing : (N,) bool
        What the refinement keeps.
    distances : (N,) float
        :func:`color_distances` to the static reference.
    pixels : list of (M_v,) int64
        Per view, its Gaussians' pixels (:func:`member_pixels`; -1: none); None for a view
        without Gaussians (as :func:`member_depths` gives them). Only those where
        ``index.pixels`` is set (pixel-aligned) are read.
    static : (N,) bool
        :func:`static_mask`: the Gaussians outside every proposal region, with a distance.
    quantile : float
        Of the view's static colour distances.
    """
    out = np.zeros(revealing.shape, dtype=bool)
    for view, members in enumerate(index.members):
        pix = pixels[view]
        if pix is None:         # a view without Gaussians
            continue
        # The outline is drawn on the pixel grid of a pixel-aligned prediction: a Gaussian
        # placed by its centre (no ``pixel_id``) is never explained, nor counts as outside.
        pix = np.where(index.pixels[view] >= 0, pix, -1)
        sel = revealing[members] & (pix >= 0)
        if not sel.any():
            continue
        bound = static_color_bound(distances, static, members, quantile)
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
            on &= distances[members] <= bound
        out[members[on]] = True
    return out


@dataclass(eq=False)
class Refinement:
    """What refinement found.

    Attributes
    ----------
    revealing : (N,) bool or None
        The Gaussians in front of the reference: the only ones a candidate keeps (None with
        ``refine="none"``).
    front_pixels : list of (H, W) bool, or None
        Per view, the pixels holding one of its ``revealing`` Gaussians (what verification
        leaves out and the expansion grows into; None with ``refine="none"``).
    color_distance : (N,) float32 or None
        Per Gaussian, :func:`color_distances` to the last static reference (with
        ``EXPLAINED_QUANTILE``, ``SILHOUETTE_QUANTILE`` or ``BAND_QUANTILE``; None
        otherwise).
    expandable : (N,) bool or None
        Of ``revealing``, those the expansion may take beyond a candidate's own Gaussians:
        those that qualify by depth alone, and with ``EXPAND_QUANTILE`` also those kept for
        their colour alone whose colour distance exceeds their view's bound (with
        ``refine="static-depth"`` and ``EXPAND_QUANTILE``; None otherwise: the expansion
        takes every one of ``revealing``).
    margins : list of float, or None
        Per view, the margin of the last pass's depth test, widened by the view's depth noise
        (:func:`revealing_gaussians`; None with ``refine="none"``):
        what :func:`~clearsplat.filter.verify.seen_by_verifiers` widens its margins to.
    color_bounds : callable or None
        ``color_bounds(q)``: per view, the ``q`` quantile of the colour distances of its
        Gaussians outside every proposal region (:func:`static_color_bounds`; with
        ``color_distance``, else None), what ``EXPLAINED_QUANTILE`` selects.
    """

    revealing: np.ndarray | None
    front_pixels: list | None = None
    color_distance: np.ndarray | None = None
    expandable: np.ndarray | None = None
    margins: list | None = None
    unreliable_pixels: list | None = None
    color_bounds: Callable | None = None


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
        front = [pixels_of(state.scene, state.index, v, revealing)
                 for v in range(state.num_views)]
        unreliable = front
        if explained is not None and explained.any():
            # The pixels of revealing | explained: those of either.
            unreliable = [f | pixels_of(state.scene, state.index, v, explained)
                          for v, f in enumerate(front)]
    return Refinement(revealing, front, found.distances, found.expandable,
                      None if revealing is None else margins, unreliable, found.bounds)


class _Found(NamedTuple):
    """What :func:`_revealing` finds (None: not computed under the config)."""

    revealing: np.ndarray | None    # (N,) bool, in front of the reference
    distances: np.ndarray | None = None     # Refinement.color_distance
    expandable: np.ndarray | None = None    # Refinement.expandable
    explained: np.ndarray | None = None     # (N,) bool, silhouettes taken out of revealing
    bounds: Callable | None = None          # Refinement.color_bounds


def _revealing(state, renders, images: list, raw: list, margins: list) -> _Found:
    """The Gaussians in front of the reference of ``config.refine``, less the silhouettes it
    explains (``SILHOUETTE_QUANTILE``; those as ``explained``); with any of the colour tests'
    quantiles, each Gaussian's colour distance to the last static reference and the per-view
    quantiles of the static ones; with ``EXPAND_QUANTILE``, those the expansion may take
    (``Refinement.expandable``). The last pass's margins go to ``margins`` (per view)."""
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
    revealing = distances = in_front = None
    members = member_depths(state.scene, state.index)     # the same in every pass
    silhouettes, band = SILHOUETTE_QUANTILE, BAND_QUANTILE
    explain = ((EXPLAINED_QUANTILE is not None and config.verify)
               or silhouettes is not None or band is not None or EXPAND_QUANTILE is not None)
    bands = static = bounds = None
    for k in range(PASSES):
        last = k == PASSES - 1
        # Each later pass builds the static reference without only the
        # proposed Gaussians that the previous pass kept, so that static content proposed
        # by some view (around another view's distractor) stays in the reference.
        # The reveal reference replaces the static one wherever it applies: only the other
        # pixels' tiles are composited again.
        needed = (None if renders.reveal is None
                  else [~valid for valid in renders.reveal_valid])
        depths, rgbs = static_reference(state, renders.excl, proposed, needed=needed)
        if renders.reveal is not None:
            _overlay_reveal(depths, rgbs, renders)
        # The colours within each view's misregistration; the depths at the Gaussian's own
        # pixel: the nearest surface within a few pixels of a small object on a sloping floor
        # is the floor in front of it (docs/method.md, "The depth test at the Gaussian's own
        # pixel").
        reference = tolerant_reference(depths, rgbs, radii, depth_radius=0)
        if explain and last:   # measured once, read by both tests
            _, lo, hi = reference
            distances = color_distances(state.scene, state.index, lo, images, members[1],
                                        reference_rgbs_hi=hi)
            static = static_mask(distances, raw)    # what each view's bounds read
            bounds = static_color_bounds(distances, static, state.index.members)
            if band is not None:
                bands = bounds(band)
        revealing, in_front = _in_front(state, reference, images, members, distances,
                                        by_depth=last and EXPAND_QUANTILE is not None,
                                        margins=margins, band_bounds=bands)
        proposed &= revealing
        # This pass's references are not read again: dropped before the next pass makes its
        # own, so that two passes' (four images per view) are never held at once.
        depths = rgbs = reference = None
    expandable = in_front       # by depth; with ``EXPAND_QUANTILE`` far-off colours too
    if expandable is not None:
        expandable = expandable | beyond_static_colors(distances, revealing,
                                                       state.index.members,
                                                       bounds(EXPAND_QUANTILE))
    explained = None
    if silhouettes is not None:     # flying pixels at a distractor's outline stay
        explained = explained_silhouettes(state.scene, state.index, revealing, distances,
                                          members[1], static, quantile=silhouettes)
        revealing &= ~explained
        if expandable is not None:
            expandable &= ~explained
    return _Found(revealing, distances, expandable, explained, bounds)


def beyond_static_colors(distances: np.ndarray, selected: np.ndarray, members: list,
                         bounds: list) -> np.ndarray:
    """(N,) bool: the Gaussians of ``selected`` whose colour distance (:func:`color_distances`)
    exceeds their view's entry of ``bounds`` (per view, as :func:`static_color_bounds` gives
    them; None: none of that view)."""
    out = np.zeros(distances.shape, dtype=bool)
    for m, bound in zip(members, bounds):
        if bound is not None:
            with np.errstate(invalid="ignore"):     # NaN distances: not beyond
                out[m] = selected[m] & (distances[m] > bound)
    return out


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
              distances: np.ndarray | None = None, by_depth: bool = False,
              margins: list | None = None, band_bounds: list | None = None) -> tuple:
    """:func:`revealing_gaussians` against the static reference ``(depths, rgb_lo, rgb_hi)``
    (:func:`~clearsplat.filter.robust.tolerant_reference`), and with ``by_depth`` those it keeps by depth alone (else None)."""
    config = state.config
    depths, rgb_lo, rgb_hi = reference
    out = revealing_gaussians(state.scene, state.index, depths, margin=MARGIN,
                              reference_rgbs=rgb_lo, color_threshold=COLOR_THRESHOLD,
                              images=images, align_scale=True,
                              reference_rgbs_hi=rgb_hi,
                              workers=config.num_threads, members=members,
                              color_distance=distances, by_depth=by_depth,
                              margins=margins, band_bounds=band_bounds)
    return out if by_depth else (out, None)


def member_pixels(scene: Scene, index: ViewIndex, view: int) -> np.ndarray:
    """Flat pixel of each Gaussian of ``view`` in that view's image, (M,) int64, -1 if none.

    ``pixel_id`` where the model is pixel-aligned, otherwise the pixel its centre projects to.
    """
    members = index.members[view]
    pix = index.pixels[view].astype(np.int64)
    loose = pix < 0
    if loose.any():
        pix[loose] = _centre_pixels(scene.cameras[view], scene.gaussians.means[members[loose]])
    return pix


def _centre_pixels(cam, means: np.ndarray) -> np.ndarray:
    """Flat pixel of ``cam``'s image that each centre ((M, 3)) projects to, (M,) int64; -1
    behind the camera or outside the image."""
    return centre_pixels(cam, means)[0]


def centre_pixels(cam, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(pixels, depths)``: the flat pixel of ``cam``'s image that each centre ((M, 3))
    projects to, (M,) int64, -1 behind the camera or outside the image; and its camera depth,
    (M,) float."""
    uv, z = cam.project(means)
    with np.errstate(invalid="ignore"):
        col = np.floor(np.nan_to_num(uv[:, 0], nan=-1.0, posinf=-1.0, neginf=-1.0))
        row = np.floor(np.nan_to_num(uv[:, 1], nan=-1.0, posinf=-1.0, neginf=-1.0))
    ok = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
    return np.where(ok, row * cam.width + col, -1).astype(np.int64), z


def removed_pixels(scene: Scene, removed: np.ndarray) -> list[np.ndarray]:
    """Per input view, (H, W) bool: the pixels of its own Gaussians among ``removed`` ((N,)
    bool), where its input image shows what was removed (``pixel_id``, or the pixel a
    Gaussian's centre projects to where the model is not pixel-aligned)."""
    where = np.flatnonzero(removed)
    views, pix = scene.view_id[where], scene.pixel_id[where].astype(np.int64)
    out = []
    for v, cam in enumerate(scene.cameras):
        mask = np.zeros(cam.height * cam.width, dtype=bool)
        sel = views == v
        p = pix[sel]
        loose = p < 0
        if loose.any():
            p[loose] = _centre_pixels(cam, scene.gaussians.means[where[sel][loose]])
        mask[p[p >= 0]] = True
        out.append(mask.reshape(cam.height, cam.width))
    return out


def pixels_of(scene: Scene, index: ViewIndex, view: int, selected: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` holding one of its ``selected`` ((N,) bool) Gaussians."""
    cam = scene.cameras[view]
    out = np.zeros(cam.height * cam.width, dtype=bool)
    pix = member_pixels(scene, index, view)
    pix = pix[selected[index.members[view]] & (pix >= 0)]
    out[pix] = True
    return out.reshape(cam.height, cam.width)
