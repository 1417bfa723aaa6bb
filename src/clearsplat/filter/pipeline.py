"""The whole filter: the paper's procedure, one call per step.

:func:`filter_distractors` runs rounds of :func:`run_round` (see ``docs/method.md``, "The
procedure", for every step and every option) on one scene and returns a
:class:`~clearsplat.filter.result.FilterResult`. Each step lives in the module of its stage:

=====================================  ==============================================
prepare views                          :mod:`.backend` (the renderer behind the stages)
exclusion renders R_i, R_i^-i          :mod:`.exclusion`
reveal reference (an option)           :mod:`.reveal`
proposals (s_i, g_i, B_i, M_k)         :mod:`.proposal`
regions to Gaussians (C_k)             :mod:`.association`
refinement                             :mod:`.refine` (colour: :mod:`.explained`)
individual verification (and scores)   :mod:`.verify`
expansion (hat C_k)                    :mod:`.expansion`
second range: additional, joint        :mod:`.verify`
next round                             :mod:`.rounds`
=====================================  ==============================================
"""

from __future__ import annotations

import dataclasses

import warnings

import numpy as np

from ..errors import ClearsplatError
from ..features import get_extractor
from ..scene import Scene
from .association import RegionMap
from .backend import backend_for
from .config import FilterConfig
from .exclusion import exclusion_renders
from .expansion import expand
from .proposal import propose
from .explained import reject_explained
from .refine import refine
from .neighbours import dense_options, view_plan
from .result import Candidate, FilterResult
from .rounds import Carry, held_bytes, in_round, kept_scene, merge_round, removed_pixels
from .state import Progress, RoundState
from .verify import (individual_tests, make_verifier, range_masks, second_range_tests,
                     seen_by_verifiers)

__all__ = ["Candidate", "FilterResult", "filter_distractors", "run_round", "resolve_auto"]

#: ``rounds="auto"`` runs a second round from this many views on (measured on the realism
#: scenarios: +0.58 dB at 16 views, +0.18 dB at 8 for 1.6 times the time, +0.02 dB at 4; with
#: ``min_relative_score`` it also keeps the 8-view recall, docs/method.md).
_SECOND_ROUND_MIN_VIEWS = 8


def resolve_auto(config: FilterConfig, num_views: int) -> FilterConfig:
    """``config`` with its ``"auto"`` choices (``rounds``, ``neighbours``, ``verify_views``)
    made as :func:`filter_distractors` makes them for a scene of ``num_views`` views (the
    same rules, :data:`_SECOND_ROUND_MIN_VIEWS` and :func:`~clearsplat.filter.neighbours.
    dense_options`): what a part of a larger capture runs so as to run what the whole would
    (:mod:`clearsplat.batch.windows`)."""
    rounds = config.rounds
    if rounds == "auto":
        rounds = 2 if num_views >= _SECOND_ROUND_MIN_VIEWS else 1
    neighbours, verify_views = dense_options(num_views, config.neighbours, config.verify_views)
    return dataclasses.replace(config, rounds=rounds, neighbours=neighbours,
                               verify_views=verify_views)


_NOTHING_VISIBLE = ("no Gaussian is in front of any input camera (wrong axes or poses?): "
                    "nothing can be verified, the scene is returned unchanged")


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
    backend = backend_for(config)
    rounds = config.rounds
    if rounds == "auto":
        rounds = 2 if scene.num_views >= _SECOND_ROUND_MIN_VIEWS else 1
    neighbours, verify_views = dense_options(scene.num_views, config.neighbours,
                                             config.verify_views)
    plan = view_plan(scene, neighbours=neighbours, verify_views=verify_views,
                     num_verify_views=config.num_verify_views, leave_out=config.leave_out)
    result, carry = run_round(scene, config, extractor, backend, report, hold=rounds > 1,
                              plan=plan)
    previous = None
    try:
        for round_ in range(2, rounds + 1):
            kept = np.flatnonzero(result.keep)
            if kept.size == n:          # nothing removed: a new round would find the same
                break
            previous, carry = carry, None
            light = previous is not None    # views made afresh come from the whole scene
            # Pixels whose input image still shows a distractor removed so far: verification
            # leaves them out (docs/method.md, "Later rounds").
            shown = removed_pixels(scene, ~result.keep)
            subset = kept_scene(scene, kept, light=light)
            if light:
                previous.source = (scene, result.keep.copy())
                # The round's views leave room for what stays held while it runs.
                previous.reserve = held_bytes(result, subset, kept, shown, previous.source[1])
            later, carry = run_round(subset, config, extractor, backend,
                                     in_round(report, round_), previous=previous,
                                     hold=round_ < rounds, plan=plan, removed=shown)
            subset = None               # not held beside the next round's
            previous = None             # spent (the round released it)
            merge_round(result, later, kept, round_)
            if later.keep.all():        # nothing new: a further round would find the same
                break
    finally:    # what was handed on and not taken, also when a round raises
        for c in (carry, previous):
            if c is not None:
                c.release()
    return result


def run_round(scene: Scene, config: FilterConfig, extractor, backend, report: Progress, *,
              previous: Carry | None = None, hold: bool = False, plan=None,
              removed: list | None = None) -> tuple[FilterResult, Carry | None]:
    """One run of the procedure on ``scene`` (at least two views and one Gaussian).

    ``previous``: what the round before handed on, ``scene`` being its kept Gaussians.
    ``removed``: per view, (H, W) bool, the pixels where the rounds before removed that
    view's Gaussians, left out of verification (None: none).
    ``hold``: hand this round's views and renders on (where the backend can) instead of
    releasing them. ``plan``: the views each camera's renders hold and each view's
    verification views (:func:`~clearsplat.filter.neighbours.view_plan`; None: the
    paper's). Returns the round's result and what it hands on (or None).
    """
    backend.check_memory(scene, previous)
    state = RoundState.begin(scene, config, backend, extractor, report)     # times "proposal"
    state.plan = plan
    state.views, touched = backend.prepare_views(scene, previous,
                                                 None if plan is None else plan.hoods,
                                                 index=state.index)
    renders = exclusion_renders(state, touched, previous)                 # R_i, R_i^-i
    if previous is not None:    # every view taken or prepared again: drop what is left
        previous.release()
    if not renders.any_visible:     # wrong axes or poses: the scene as it is
        warnings.warn(_NOTHING_VISIBLE, stacklevel=3)
        state.views.release()
        return FilterResult.unchanged(state.n, config, _NOTHING_VISIBLE,
                                      state.clock.timings), None
    proposals = propose(state, renders, extractor)                       # s_i, g_i, M_k
    region_map = RegionMap(state)
    regions = [r for p in proposals for r in p.regions]
    raw = [region_map(r.view, r.pixels) for r in regions]                # C_k
    state.lap("regions")
    refinement = refine(state, renders, raw)                             # in front only
    state.lap("refine")
    candidates = _candidates(config, regions, raw, proposals, refinement, removed)
    state.lap("regions")
    state.clock.end_stage()

    state.clock.stage("verification")
    if config.verify:
        verifier = make_verifier(state)
        q = range_masks(state, proposals)
        passed = individual_tests(state, candidates, q, verifier, renders)
        state.lap("individual")
    # hat C_k: of those that passed, and what accepting each of the others would remove
    # (clearsplat edit); only the accepted ones are removed.
    expand(state, candidates, proposals, region_map, refinement)
    if config.verify:
        if refinement.noise is not None:    # static content out of register
            passed = reject_explained(passed, refinement.noise)
        state.lap("expand")
        second_range_tests(state, passed, q[2], verifier, renders)     # additional, joint
        state.lap("second_range")
        if config.verify_hidden is not None:     # only what a verifying view sees
            seen_by_verifiers(state, candidates, config.verify_hidden,
                              refinement.margins)
            state.lap("hidden")
    else:
        state.lap("expand")
        for c in candidates:
            c.accepted, c.reason = True, "accepted without verification"
    keep = keep_mask(candidates, len(scene))
    state.clock.end_stage()
    return _finish(state, keep, candidates, proposals, renders, touched, hold)


def _candidates(config, regions: list, raw: list, proposals: list, refinement,
                removed: list | None) -> list:
    """C_k of every region, refined (only its Gaussians in front), as candidates; each
    proposal's ``unreliable`` set to the pixels its view's verification leaves out: its own
    Gaussians in front (its likely distractors, with refinement) and ``removed``'s."""
    revealing = refinement.revealing
    # Each candidate reads its pixels from its region (made from the grid cells when read).
    candidates = [Candidate(k, r.view, r.range, r, g if revealing is None
                            else g[revealing[g]]) for k, (r, g) in enumerate(zip(regions, raw))]
    for p in proposals:
        if config.refine != "none":
            p.unreliable = refinement.unreliable_pixels[p.view]
        if removed is not None:
            p.unreliable = (removed[p.view] if p.unreliable is None
                            else p.unreliable | removed[p.view])
    return candidates


def keep_mask(candidates: list, n: int) -> np.ndarray:
    """(N,) bool: False for the expanded Gaussians of every accepted candidate."""
    keep = np.ones(n, dtype=bool)
    for c in candidates:
        if c.accepted and c.expanded is not None:
            keep[c.expanded] = False
    return keep


def _finish(state: RoundState, keep, candidates, proposals, renders, touched: dict,
            hold: bool) -> tuple[FilterResult, Carry | None]:
    """The round's result, and its views and renders handed on (``hold``) or released."""
    views = state.views
    stats = views.stats(derived=len(touched))
    carry = None
    if hold and state.backend.hands_on:
        reveal = (None if renders.reveal is None else
                  list(zip(renders.reveal, renders.reveal_valid, renders.reveal_plan)))
        carry = Carry(views, renders.full, renders.excl, keep, reveal=reveal)
        views.hand_on()
    else:
        views.release()
    timings = state.clock.timings
    timings["total"] = timings["proposal"] + timings["verification"]
    return FilterResult(keep, candidates, proposals, timings, state.config, stats=stats), carry
