"""The whole filter: proposal, association, verification, removal.

:func:`filter_distractors` runs the paper's procedure (see ``docs/method.md`` for every step
and every option) on one scene and returns a :class:`FilterResult`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._memory import available_memory, check_memory, estimate_filter_memory
from ..errors import ClearsplatError
from ..features import get_extractor, upsample_nearest
from ..render import prepare
from ..scene import Scene
from .association import (ViewIndex, dilate, pixels_of, region_gaussians, revealing_gaussians,
                          verification_views)
from .config import FilterConfig
from .proposal import ViewProposal, label8, propose_view, touched_components
from .robust import (misregistration, photometric_alignment, tolerant_images,
                     tolerant_reference)
from .verify import Partial, Verifier, tile_pixels
from .views import PreparedViews

__all__ = ["Candidate", "FilterResult", "filter_distractors"]

Progress = Callable[[str, int, int], None]

#: Below this accumulated opacity the static reference (R_i^-i without any proposed Gaussian)
#: counts as a hole, and the plain exclusion render's depth is used instead.
_STATIC_MIN_ALPHA = 0.1
#: The colour test of ``refine_color`` needs the static reference this opaque at the pixel.
_COLOR_MIN_ALPHA = 0.9
#: ``verify_mask="auto"`` leaves the proposal regions in verification (``"revealing"``) from
#: this many views on (measured: needed at 8 and 16 views, harmful on clean 4-view scenes).
_REVEALING_MASK_MIN_VIEWS = 8
#: ``rounds="auto"`` runs a second round from this many views on (measured on the realism
#: scenarios: +0.58 dB at 16 views, +0.18 dB at 8 for 1.6 times the time, +0.02 dB at 4; with
#: ``min_relative_score`` it also keeps the 8-view recall, docs/method.md, departure 12).
_SECOND_ROUND_MIN_VIEWS = 8


@dataclass(eq=False)
class Candidate:
    """One candidate region and what verification made of it.

    Attributes
    ----------
    index : int
    view : int
        Input view it was proposed in.
    range : int
        Similarity range, 1 or 2.
    pixels : (H, W) bool
        The region [M_k].
    gaussians : (M,) int64
        Gaussians the region maps to [C_k].
    expanded : (M',) int64 or None
        Gaussians of the dilated region within the support [hat C_k], for candidates that
        passed the individual test.
    verify_views : list of int
        The verification views [V_i].
    scores : dict of str to float
        ``"individual"``, ``"additional"`` and ``"joint"`` where run.
    accepted : bool
    reason : str
        Why it was accepted or rejected.
    round : int
        The round of the procedure that found it (``FilterConfig.rounds``).
    """

    index: int
    view: int
    range: int
    pixels: np.ndarray
    gaussians: np.ndarray
    expanded: np.ndarray | None = None
    verify_views: list = field(default_factory=list)
    scores: dict = field(default_factory=dict)
    accepted: bool = False
    reason: str = "not verified"
    round: int = 1

    def __repr__(self) -> str:
        scores = ", ".join(f"{k} {v:+.4f}" for k, v in self.scores.items())
        return (f"Candidate({self.index}: view {self.view}, range {self.range}, "
                f"{int(self.pixels.sum()):,} pixels, {self.gaussians.size:,} Gaussians"
                f"{'; ' + scores if scores else ''}; {self.reason})")

    def record(self) -> dict:
        """A JSON-friendly summary."""
        return {
            "index": self.index, "view": self.view, "range": self.range,
            "pixels": int(self.pixels.sum()), "gaussians": int(self.gaussians.size),
            "expanded_gaussians": None if self.expanded is None else int(self.expanded.size),
            "verify_views": list(self.verify_views),
            "scores": {k: float(v) for k, v in self.scores.items()},
            "accepted": bool(self.accepted), "reason": self.reason, "round": self.round,
        }


@dataclass(eq=False)
class FilterResult:
    """What :func:`filter_distractors` found.

    Attributes
    ----------
    keep : (N,) bool
        False for the Gaussians to remove (set their opacity to zero).
    candidates : list of Candidate
    proposals : list of ViewProposal
        Per input view: similarity map, support, ranges, proposal masks (of the first round).
    timings : dict of str to float
        Seconds per stage.
    config : FilterConfig
    warnings : list of str
    stats : dict
        ``views_prepared``: camera preparations made (the number of views, plus those prepared
        again under ``config.view_memory``); ``views_derived``: those a later round took from
        the round before (restricted to the Gaussians it kept, not projected again);
        ``views_peak_bytes``: most bytes the prepared
        views held at once; ``views_skipped``: (view, removal) pairs left out because the view
        sees none of the removal's Gaussians; ``views_pruned_bytes``: bytes the views held right
        after ``config.prune_views`` pruned them (0 without it) (CPU only). With several
        rounds (``config.rounds``) the counts and ``timings`` add up over the rounds and the
        byte figures are the largest of any round.
    """

    keep: np.ndarray
    candidates: list
    proposals: list
    timings: dict
    config: FilterConfig
    warnings: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        accepted = sum(c.accepted for c in self.candidates)
        warned = f"; {len(self.warnings)} warning(s)" if self.warnings else ""
        return (f"FilterResult(removed {int((~self.keep).sum()):,} of {self.keep.size:,} "
                f"Gaussians; {accepted} of {len(self.candidates)} candidates accepted; "
                f"{self.config.describe()}; {self.timings.get('total', 0.0):.2f} s{warned})")

    @property
    def removed(self) -> np.ndarray:
        """(N,) bool: the Gaussians removed."""
        return ~self.keep

    def apply(self, scene: Scene) -> Scene:
        """The filtered scene: removed Gaussians get opacity zero, nothing else changes."""
        return scene.with_opacities(np.where(self.keep, scene.gaussians.opacities, 0.0))

    def summary(self) -> dict:
        """A JSON-friendly summary: config, counts, candidates, timings."""
        return {
            "config": self.config.to_dict(),
            "gaussians": int(self.keep.size),
            "removed": int((~self.keep).sum()),
            "candidates": [c.record() for c in self.candidates],
            "accepted": int(sum(c.accepted for c in self.candidates)),
            "timings": {k: round(float(v), 4) for k, v in self.timings.items()},
            "warnings": list(self.warnings),
        }


class _Laps:
    """Seconds per sub-stage, recorded as ``timings["<stage>.<step>"]``."""

    def __init__(self, timings: dict, stage: str):
        self.timings, self.stage, self.last = timings, stage, time.perf_counter()

    def __call__(self, step: str) -> None:
        now = time.perf_counter()
        key = f"{self.stage}.{step}"
        self.timings[key] = self.timings.get(key, 0.0) + now - self.last
        self.last = now


def filter_distractors(scene: Scene, *, config: FilterConfig | None = None,
                       extractor=None, progress: Progress | None = None) -> FilterResult:
    """Find the Gaussians of transient distractors in a feed-forward prediction.

    Parameters
    ----------
    scene : Scene
        Gaussians with their view association, the input cameras and the input images.
    config : FilterConfig, optional
        Options; ``FilterConfig()`` by default, ``FilterConfig.preset("paper")`` for the paper.
    extractor : FeatureExtractor, optional
        A ready extractor (otherwise built from ``config.features``).
    progress : callable(stage, done, total), optional
        Called as work advances.

    Returns
    -------
    FilterResult
        ``result.apply(scene)`` gives the filtered scene.
    """
    config = config or FilterConfig()
    if scene.images is None:
        raise ClearsplatError("the filter needs the input images", field="images")
    scene.validate()
    n = len(scene)
    if scene.num_views < 2 or n == 0:
        msg = ("a single input view: nothing can verify it, the scene is returned unchanged"
               if scene.num_views < 2 else "the scene has no Gaussians")
        warnings.warn(msg, stacklevel=2)
        return FilterResult(np.ones(n, bool), [], [], {"proposal": 0.0, "verification": 0.0},
                            config, [msg])
    if extractor is None:
        # Only the DINO extractors take a checkpoint; the others ignore a global --checkpoint.
        dino = config.features.startswith("dino") and config.checkpoint
        extractor = get_extractor(config.features,
                                  **({"checkpoint": config.checkpoint} if dino else {}))
    report = progress or (lambda stage, done, total: None)
    rounds = config.rounds
    if rounds == "auto":
        rounds = 2 if scene.num_views >= _SECOND_ROUND_MIN_VIEWS else 1
    result, carry = _filter_round(scene, config, extractor, report, hold=rounds > 1)
    previous = None
    try:
        for round_ in range(2, rounds + 1):
            kept = np.flatnonzero(result.keep)
            if kept.size == n:          # nothing removed: a new round would find the same
                break
            previous, carry = carry, None
            later, carry = _filter_round(scene.subset(kept), config, extractor,
                                         _in_round(report, round_), previous=previous,
                                         hold=round_ < rounds)
            previous = None             # spent (the round released it)
            _merge_round(result, later, kept, round_)
            if later.keep.all():        # nothing new: a further round would find the same
                break
    finally:    # what was handed on and not taken, also when a round raises
        for c in (carry, previous):
            if c is not None:
                c.release()
    return result


@dataclass
class _Carry:
    """What a round hands to the next on the CPU: its prepared views (those still held), its
    renders R_i and R_i^-i, and which of its Gaussians it kept ((N,) bool). The next round,
    on the kept Gaussians, takes its views from these (:meth:`PreparedView.restrict`) and
    composites again only the tiles that the removed Gaussians touched; both are exact."""

    views: PreparedViews
    full: list
    excl: list
    keep: np.ndarray

    def nbytes(self) -> int:
        """Bytes held: the views still kept and the renders not yet dropped."""
        renders = sum(a.nbytes for r in self.full + self.excl if r is not None for a in r)
        return self.views.held_bytes + renders

    def release(self) -> None:
        self.views.release()
        self.full.clear()
        self.excl.clear()


def _in_round(report: Progress, round_: int) -> Progress:
    """``report`` with the stage names of a later round marked as such."""
    return lambda stage, done, total: report(f"{stage} (round {round_})", done, total)


def _merge_round(result: FilterResult, later: FilterResult, kept: np.ndarray,
                 round_: int) -> None:
    """Fold a later round's result, run on the Gaussians ``kept`` ((M,) int indices), into
    ``result``: its removals, candidates (re-indexed to the whole scene), timings, stats."""
    result.keep[kept[~later.keep]] = False
    offset = len(result.candidates)
    for c in later.candidates:
        c.index += offset
        c.round = round_
        c.gaussians = kept[c.gaussians]
        if c.expanded is not None:
            c.expanded = kept[c.expanded]
        result.candidates.append(c)
    for k, v in later.timings.items():
        result.timings[k] = result.timings.get(k, 0.0) + v
    for k, v in later.stats.items():
        peak = k.endswith("_bytes")
        result.stats[k] = max(result.stats.get(k, 0), v) if peak else result.stats.get(k, 0) + v
    result.warnings.extend(w for w in later.warnings if w not in result.warnings)


def _filter_round(scene: Scene, config: FilterConfig, extractor, report, *,
                  previous: _Carry | None = None, hold: bool = False
                  ) -> tuple[FilterResult, _Carry | None]:
    """One run of the procedure on ``scene`` (at least two views and one Gaussian).

    ``previous``: what the round before handed on, ``scene`` being its kept Gaussians.
    ``hold``: hand this round's views and renders on (when the path allows it) instead of
    releasing them.
    """
    n = len(scene)
    timings = {"proposal": 0.0, "verification": 0.0}
    on_gpu = config.device != "cpu"
    # Tile patches are a CPU feature: on a GPU every verification render is a whole image.
    # The incremental path also leaves out the views a removal cannot change.
    incremental = config.incremental and not on_gpu
    budget = None if config.view_memory is None else int(config.view_memory * 1e9)
    if not on_gpu:  # the GPU path holds only images and masks on the host
        available = None
        if previous is not None:
            # What the previous round hands on becomes this round's views as they are taken
            # (and its renders are dropped view by view): count it as available.
            free = available_memory()
            available = None if free is None else free + previous.nbytes()
        check_memory(estimate_filter_memory(n, scene.cameras, view_budget=budget),
                     available=available)
    tau1 = extractor.tau1 if config.tau1 is None else config.tau1
    tau2 = extractor.tau2 if config.tau2 is None else config.tau2
    threads = config.num_threads

    # -- proposal -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    lap = _Laps(timings, "proposal")
    index = ViewIndex(scene)
    own = [index.mask(i, n) for i in range(scene.num_views)]
    full, excl = [], []
    touched: dict = {}      # view -> tiles the previous round's removals touched there
    if on_gpu:  # one upload of the Gaussians, shared by the views
        from ..render.gsplat import prepare_gsplat_views
        views = prepare_gsplat_views(scene, scene.cameras, device=config.device)
    else:
        def make(i: int):
            old = None if previous is None else previous.views.take(i)
            if old is None:
                return prepare(scene, scene.cameras[i], num_threads=threads)
            touched[i] = old.tiles_touched(~previous.keep)
            return old.restrict(previous.keep)

        views = PreparedViews(n, scene.cameras, make, budget=budget)
    # Per view j, how many centres of each view's Gaussians it sees inside its image (for the
    # choice of verification views), counted while the view is at hand.
    seen_counts = np.zeros((scene.num_views, scene.num_views), dtype=np.int64)
    any_visible = False
    for i in range(scene.num_views):
        pv = views[i]
        lap("prepare")
        any_visible |= pv.num_visible > 0
        if not on_gpu:
            seen_counts[i] = np.bincount(scene.view_id[pv.centres_inside()],
                                         minlength=scene.num_views)
        if i in touched:    # the previous round's renders, where its removals changed nothing
            r_full, r_excl = pv.render_pair(keep=~own[i], tiles=touched[i],
                                            start=previous.full[i])
            flat, inside = tile_pixels(pv, touched[i])
            outside = np.ones(r_excl.alpha.shape, dtype=bool)
            outside.reshape(-1)[flat[inside]] = False
            for a, b in zip(r_excl, previous.excl[i]):
                a[outside] = b[outside]
            previous.full[i] = previous.excl[i] = None     # no longer needed
        else:
            r_full, r_excl = pv.render_pair(keep=~own[i])     # R_i and R_i^-i in one pass
        full.append(r_full)
        excl.append(r_excl)
        lap("exclusion_renders")
        report("render", i + 1, scene.num_views)
    if previous is not None:    # every view taken or prepared again: drop what is left
        previous.release()
    if not any_visible:
        msg = ("no Gaussian is in front of any input camera (wrong axes or poses?): nothing "
               "can be verified, the scene is returned unchanged")
        warnings.warn(msg, stacklevel=3)
        if isinstance(views, PreparedViews):
            views.release()
        return FilterResult(np.ones(n, bool), [], [], timings, config, [msg]), None
    images = _aligned_images(scene, excl, config)
    pair = (np.stack(images), np.stack([r.rgb for r in excl]))
    # Threads as the rasterizer's (config.num_threads), for extractors that use them.
    sims = (extractor.similarity(*pair, workers=threads)
            if getattr(extractor, "pairs_in_threads", False) else extractor.similarity(*pair))
    lap("features")
    proposals: list[ViewProposal] = []
    for i in range(scene.num_views):
        proposals.append(propose_view(
            i, sims[i], excl[i].alpha, full[i].depth, excl[i].depth, eta=config.eta,
            tau1=tau1, tau2=tau2, second_range=config.second_range,
            single_threshold=config.single_threshold))
        proposals[-1].exclusion = excl[i].rgb
    # Pixel-aligned views map regions through pixel ids and need no prepared view.
    loose = [bool((p < 0).any()) for p in index.pixels]

    def region_to_gaussians(view: int, pixels: np.ndarray) -> np.ndarray:
        return region_gaussians(scene, view, pixels, index=index,
                                min_weight=config.association_min_weight,
                                prepared=views[view] if loose[view] else None)

    regions = [r for prop in proposals for r in prop.regions]
    raw = [region_to_gaussians(r.view, r.pixels) for r in regions]
    lap("regions")
    if isinstance(views, PreparedViews) and config.prune_views:
        # Every later render of camera j keeps all Gaussians but view j's own and those any
        # candidate (or its expansion) can take away: the views keep only what such renders
        # can reach. Views without pixel ids keep everything (their association composites
        # the view's own Gaussians alone).
        removable = _removable(proposals, region_to_gaussians, n, config.dilation,
                               tau2 if config.expand_connected else None)
        views.prune(lambda j: None if loose[j] else ~(own[j] | removable))
        lap("prune")
    revealing = None
    if config.refine == "depth":
        revealing = revealing_gaussians(scene, index, [r.depth for r in excl],
                                        margin=config.refine_margin,
                                        align_scale=config.depth_scale_align,
                                        scale_reach=config.depth_scale_reach, workers=threads)
    elif config.refine == "static-depth":
        proposed = np.zeros(n, dtype=bool)
        for g in raw:
            proposed[g] = True
        radii = config.refine_tolerance
        if radii == "auto":   # each view's measured misregistration with the others
            radii = [misregistration(images[i], excl[i].rgb, excl[i].alpha)
                     for i in range(scene.num_views)]
        for _ in range(config.refine_passes):
            # Each later pass (``refine_passes``) builds the static reference without only the
            # proposed Gaussians that the previous pass kept, so that static content proposed
            # by some view (around another view's distractor) stays in the reference.
            revealing = _static_revealing(scene, index, views, excl, own, proposed, images,
                                          radii, config, incremental)
            proposed &= revealing
    lap("refine")

    def refined(g: np.ndarray) -> np.ndarray:
        return g if revealing is None else g[revealing[g]]

    def to_gaussians(view: int, pixels: np.ndarray) -> np.ndarray:
        return refined(region_to_gaussians(view, pixels))

    if config.verify_mask != "proposals":
        for prop in proposals:
            prop.unreliable = pixels_of(scene, index, prop.view, revealing)
    candidates = [Candidate(k, r.view, r.range, r.pixels, refined(g))
                  for k, (r, g) in enumerate(zip(regions, raw))]
    lap("regions")
    timings["proposal"] = time.perf_counter() - t0

    # -- verification -------------------------------------------------------------------------
    t0 = time.perf_counter()
    lap = _Laps(timings, "verification")
    lo, hi = _verification_images(images, config)
    verifier = Verifier(views, lo, epsilon=config.epsilon,
                        incremental=incremental,
                        hole_alpha=config.eta if _skip_holes(config, scene) else 0.0,
                        images_hi=hi)
    support_px = [p.support_pixels for p in proposals]

    grown: dict = {}

    def expand(c: Candidate) -> np.ndarray:
        pixels = dilate(c.pixels, config.dilation) & support_px[c.view]
        if config.expand_connected and revealing is not None:
            pixels = _grow_connected(pixels, c.view, grown, scene, index, revealing,
                                     proposals[c.view], tau2)
        return to_gaussians(c.view, pixels)

    if not config.verify:
        for c in candidates:
            c.expanded = expand(c)
            c.accepted, c.reason = True, "accepted without verification"
    else:
        mode = config.verify_mask
        if mode == "auto":
            mode = ("revealing" if scene.num_views >= _REVEALING_MASK_MIN_VIEWS
                    else "proposals+revealing")
        q = {r: _exclusion_masks(proposals, r, mode) for r in (1, 2)}
        _individual_tests(scene, candidates, q, verifier, full, excl, own, seen_counts,
                          config, report)
        lap("individual")
        passed = [c for c in candidates if c.reason == "passed individual test"]
        for c in passed:
            c.expanded = expand(c)
        lap("expand")
        first = [c for c in passed if c.range == 1]
        second = [c for c in passed if c.range == 2]
        for c in first:
            c.accepted, c.reason = True, "accepted (first range)"
        if second:
            _second_range_tests(scene, first, second, q[2], verifier, full, excl, own, config,
                                report)
        lap("second_range")
    keep = np.ones(n, dtype=bool)
    for c in candidates:
        if c.accepted and c.expanded is not None:
            keep[c.expanded] = False
    timings["verification"] = time.perf_counter() - t0
    stats, carry = {}, None
    if isinstance(views, PreparedViews):
        stats = {"views_prepared": views.prepared, "views_derived": len(touched),
                 "views_peak_bytes": views.peak_bytes, "views_skipped": views.skipped,
                 "views_pruned_bytes": views.pruned_bytes}
        if hold and incremental and not config.prune_views:
            carry = _Carry(views, full, excl, keep)
        else:
            views.release()
    timings["total"] = timings["proposal"] + timings["verification"]
    return FilterResult(keep, candidates, proposals, timings, config, stats=stats), carry


def _static_revealing(scene, index, views, excl, own, proposed, images, radii, config,
                      incremental) -> np.ndarray:
    """(N,) bool: the Gaussians in front of the static reference (``refine="static-depth"``),
    the reference being each view's exclusion render without the ``proposed`` Gaussians."""
    reference, reference_rgb = [], []
    for i in range(scene.num_views):
        others = proposed & ~own[i]
        if _sees(views, i, others, incremental):
            pv = views[i]
            static = pv.rerender(excl[i], keep=~(own[i] | proposed),
                                 tiles=pv.tiles_touched(others))
        else:   # nothing proposed in this view: the reference is R_i^-i itself
            static = excl[i]
        # Where the proposals of the other views leave a hole, fall back to R_i^-i.
        solid = static.alpha > _STATIC_MIN_ALPHA
        reference.append(np.where(solid, static.depth, excl[i].depth))
        # Colours only where the other views cover the pixel fully: a partly covered pixel
        # (the edge of what they see) mixes in the background and proves nothing.
        covered = static.alpha >= _COLOR_MIN_ALPHA
        reference_rgb.append(np.where(covered[..., None], static.rgb, np.nan))
    reference_hi = None
    if radii != 0:
        nearest, reference_rgb, reference_hi = tolerant_reference(reference, reference_rgb,
                                                                  radii)
        if config.refine_tolerance_depth:
            reference = nearest
    return revealing_gaussians(scene, index, reference, margin=config.refine_margin,
                               reference_rgbs=reference_rgb,
                               color_threshold=config.refine_color, images=images,
                               align_scale=config.depth_scale_align,
                               reference_rgbs_hi=reference_hi,
                               scale_reach=config.depth_scale_reach,
                               color_grow=config.refine_color_grow,
                               workers=config.num_threads)


def _grow_connected(pixels: np.ndarray, view: int, labels: dict, scene, index,
                    revealing: np.ndarray, proposal, tau2) -> np.ndarray:
    """``pixels`` with every 8-connected component that it touches of the view's pixels whose
    Gaussians stand in front of the static reference, within the cells of similarity below
    tau2 (``expand_connected``); ``labels`` caches the components per view."""
    if view not in labels:
        grow = pixels_of(scene, index, view, revealing)
        h, w = grow.shape
        grow &= upsample_nearest(proposal.similarity < tau2, h, w)
        labels[view] = label8(grow)[0]
    return pixels | touched_components(labels[view], pixels)


def _removable(proposals, region_to_gaussians, n: int, dilation: float,
               grow_below: float | None = None) -> np.ndarray:
    """(N,) bool: every Gaussian a candidate or its expansion can hold, i.e. those the
    regions of each view map to, dilated within the support as expansion does, and with
    ``grow_below`` (``expand_connected``) those of every cell of similarity below it."""
    out = np.zeros(n, dtype=bool)
    for p in proposals:
        proposed = p.mask1 | p.mask2
        if proposed.any():
            pixels = (dilate(proposed, dilation) & p.support_pixels) | proposed
            if grow_below is not None:
                h, w = pixels.shape
                pixels |= upsample_nearest(p.similarity < grow_below, h, w)
            out[region_to_gaussians(p.view, pixels)] = True
    return out


def _aligned_images(scene: Scene, excl, config: FilterConfig) -> list:
    """The input images the comparisons use: as given, or (``photometric_align``) mapped to
    the colours of each view's exclusion render."""
    if not config.photometric_align:
        return scene.images
    return [photometric_alignment(im, r.rgb, r.alpha) for im, r in zip(scene.images, excl)]


def _verification_images(images: list, config: FilterConfig) -> tuple[list, list | None]:
    """Lower and upper bounds of the input colours for verification (``verify_tolerance``);
    the images themselves and None when the tolerance is 0."""
    if config.verify_tolerance <= 0:
        return images, None
    bounds = [tolerant_images(im, config.verify_tolerance) for im in images]
    return [b[0] for b in bounds], [b[1] for b in bounds]


def _passes(total: Partial, config: FilterConfig) -> bool:
    """A test's verdict: score above ``min_score`` and, where ``min_relative_score`` asks for
    it, a large enough share of the error it touches explained by the removal."""
    if not total.score > config.min_score:
        return False
    return config.min_relative_score <= 0 or total.relative_score > config.min_relative_score


def _skip_holes(config: FilterConfig, scene: Scene) -> bool:
    """Whether verification leaves out the holes a removal opens (``verify_holes``)."""
    if config.verify_holes == "auto":
        return scene.num_views <= 2
    return config.verify_holes == "skip"


def _exclusion_masks(proposals, rng: int, mode: str) -> list[np.ndarray]:
    """Q_j per view: M_j^1 for first-range candidates, M_j^1 | M_j^2 for second-range ones,
    plus the view's unreliable pixels where ``verify_mask`` asks for them; only the unreliable
    pixels with ``verify_mask="revealing"``."""
    out = []
    for p in proposals:
        if mode == "revealing":
            out.append(p.unreliable)
            continue
        q = p.mask1 if rng == 1 else (p.mask1 | p.mask2)
        out.append(q if p.unreliable is None else (q | p.unreliable))
    return out


def _sees(views, j: int, gaussians, skip: bool = True) -> bool:
    """Whether view ``j`` can be changed by removing ``gaussians`` (int indices or (N,) bool):
    False only when its camera sees none of them (then every score term there is 0 and the
    view is left out without being prepared). Always True without ``skip`` (the full-render
    reference path visits every view) and on the GPU."""
    if not skip or not isinstance(views, PreparedViews):
        return True
    g = np.asarray(gaussians)
    if views.sees_any(j, np.flatnonzero(g) if g.dtype == np.bool_ else g):
        return True
    views.skipped += 1
    return False


def _top_views(seen_counts: np.ndarray, view: int, count: int) -> list[int]:
    """The ``count`` other views that see the most centres of ``view``'s Gaussians inside
    their image (ties to the lower index): :func:`verification_views` from the counts the
    exclusion renders made."""
    others = [j for j in range(seen_counts.shape[0]) if j != view]
    ranked = sorted((-int(seen_counts[j, view]), j) for j in others)
    return [j for _, j in ranked[:count]]


def _individual_tests(scene, candidates, q, verifier, full, excl, own, seen_counts, config,
                      report):
    """Score every candidate on its verification views; mark those with a positive score.

    ``q[r][j]`` is the exclusion mask of view j for candidates of range r."""
    if isinstance(verifier.views, PreparedViews):
        views_of = {i: _top_views(seen_counts, i, config.num_verify_views)
                    for i in range(scene.num_views)}
    else:
        index = ViewIndex(scene)
        inside = [pv.centres_inside() for pv in verifier.views]
        views_of = {i: verification_views(scene, i, config.num_verify_views, index=index,
                                          inside=inside)
                    for i in range(scene.num_views)}
    n = len(scene)
    all_keep = np.ones(n, dtype=bool)
    totals = {c.index: Partial() for c in candidates}
    for c in candidates:
        c.verify_views = views_of[c.view]
    # Batch per verifying view: every candidate that view j verifies, in one native call.
    for j in range(scene.num_views):
        # Candidates that view j does not see score 0 there: left out (and the view with them).
        todo = [c for c in candidates if j in c.verify_views and c.gaussians.size
                and _sees(verifier.views, j, c.gaussians, verifier.incremental)]
        if not todo:
            report("individual", j + 1, scene.num_views)
            continue
        if config.verify_base == "full":
            base_keep, base = all_keep, full[j]
        else:
            base_keep, base = ~own[j], excl[j]
        for rng in (1, 2):
            batch = [c for c in todo if c.range == rng]
            parts = verifier.score_view(j, base_keep, base, [c.gaussians for c in batch],
                                        q[rng][j])
            for c, p in zip(batch, parts):
                totals[c.index].add(p)
        report("individual", j + 1, scene.num_views)
    for c in candidates:
        s = totals[c.index].score
        c.scores["individual"] = s
        if c.gaussians.size == 0:
            c.reason = ("no Gaussians in region" if config.refine == "none"
                        else "no Gaussians left: none survived refinement")
        elif _passes(totals[c.index], config):
            c.reason = "passed individual test"
        else:
            c.reason = "rejected by individual test"


def _second_range_tests(scene, first, second, q, verifier, full, excl, own, config, report):
    """The additional test of each second-range candidate, then their joint test; ``q[j]`` is
    view j's exclusion mask M_j^1 | M_j^2 (and its unreliable pixels)."""
    totals = {c.index: Partial() for c in second}
    for j in range(scene.num_views):
        # Candidates that view j does not see score 0 there: left out (and the view with them).
        todo = [c for c in second if _sees(verifier.views, j, c.expanded, verifier.incremental)]
        if not todo:
            report("additional", j + 1, scene.num_views)
            continue
        parts = verifier.score_view(j, ~own[j], excl[j], [c.expanded for c in todo], q[j])
        for c, p in zip(todo, parts):
            totals[c.index].add(p)
        report("additional", j + 1, scene.num_views)
    survivors = []
    for c in second:
        s = totals[c.index].score
        c.scores["additional"] = s
        if _passes(totals[c.index], config):
            survivors.append(c)
        else:
            c.reason = "rejected by additional test"
    if not survivors:
        return
    n = len(scene)
    removed_first = np.zeros(n, dtype=bool)
    for c in first:
        removed_first[c.expanded] = True
    joint = np.unique(np.concatenate([c.expanded for c in survivors]))
    jointly = np.zeros(n, dtype=bool)
    jointly[joint] = True
    total = Partial()
    for j in range(scene.num_views):
        if not _sees(verifier.views, j, joint, verifier.incremental):
            report("joint", j + 1, scene.num_views)        # every term would be 0
            continue
        pv = verifier.views[j]
        if config.joint_base == "full":
            base_keep, start = ~removed_first, full[j]
        else:
            base_keep, start = ~(removed_first | own[j]), excl[j]
        if verifier.incremental:
            # The score reads only the tiles the joint removal touches: composite the base and
            # the base without the joint removal there, in one pass.
            tiles = pv.tiles_touched(joint)
            base, after = pv.render_pair(first=base_keep, keep=base_keep & ~jointly,
                                         tiles=tiles, start=start)
            p = verifier.score_tiles(j, base, after, tiles, q[j])
        else:
            base = pv.render(keep=base_keep)
            (p,) = verifier.score_view(j, base_keep, base, [joint], q[j])
        total.add(p)
        report("joint", j + 1, scene.num_views)
    ok = _passes(total, config)
    for c in survivors:
        c.scores["joint"] = total.score
        c.accepted = ok
        c.reason = "accepted (second range, joint test)" if ok else "rejected by joint test"
