"""Exclusion renders: each input camera rendered with and without its own Gaussians.

Paper, "Distractor Proposal": R_i renders every Gaussian from camera i, R_i^-i every Gaussian
but those predicted from view i. Both come from one compositing pass per view
(``render_pair``). A later round takes the round before's renders and composites again only
the tiles its removals touched; elsewhere they are unchanged, so the result is exact.

With ``reveal_reference="quantile"`` each view also gets its reveal reference
(:mod:`.reveal`), which the proposal and refinement read in place of R_i^-i; a later round
makes it again only in the same tiles, where the round before rendered the same neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import reveal as rv
from .reveal import reveal_plan, reveal_reference

__all__ = ["ExclusionRenders", "exclusion_renders"]


@dataclass(eq=False)
class ExclusionRenders:
    """The renders of every input camera.

    Attributes
    ----------
    full : list of RenderResult
        R_i: every Gaussian of the round, from camera i ((H, W, 3) rgb, (H, W) alpha, depth).
    excl : list of RenderResult
        R_i^-i: without the Gaussians of view i.
    seen : (V, V) int64
        ``seen[j, v]``: how many centres of view v's Gaussians camera j sees inside its image
        (the choice of verification views V_i).
    any_visible : bool
        Whether any Gaussian is in front of any camera.
    reveal : list of RenderResult, or None
        Per view, its reveal reference (``reveal_reference="quantile"``, :mod:`.reveal`);
        None: R_i^-i is the reference.
    reveal_valid : list of (H, W) bool, or None
        Per view, where the reveal reference is not R_i^-i.
    reveal_plan : list of list of int, or None
        Per view, the neighbours its reveal reference renders.
    """

    full: list
    excl: list
    seen: np.ndarray
    any_visible: bool
    reveal: list | None = None
    reveal_valid: list | None = None
    reveal_plan: list | None = None

    @property
    def reference(self) -> list:
        """What the proposal and refinement compare with: the reveal references where made,
        else R_i^-i."""
        return self.excl if self.reveal is None else self.reveal


def exclusion_renders(state, touched: dict, previous=None) -> ExclusionRenders:
    """R_i and R_i^-i of every view of ``state.views``, and the counts for V_i.

    ``touched``: per view taken from ``previous`` (the round before), the tiles its removals
    touched (filled as the views are read); there only is anything composited again.
    """
    scene, views, own = state.scene, state.views, state.own
    config = state.config
    seen = np.zeros((scene.num_views, scene.num_views), dtype=np.int64)
    full, excl = [], []
    reveal = valid = plan = None
    if config.reveal_reference == "quantile":
        reveal, valid = [], []
        # A neighbour R_i^-i leaves in, among those view i's renders hold (the view plan).
        allowed = ~state.left_out
        if state.plan is not None and state.plan.hoods is not None:
            allowed = allowed & np.array(state.plan.hoods)
        plan = reveal_plan(scene, count=rv.VIEWS, max_angle=rv.MAX_ANGLE,
                           allowed=allowed, depths=state.index.depths)
    any_visible = False
    for i in range(scene.num_views):
        pv = views[i]
        state.lap("prepare")
        any_visible |= pv.num_visible > 0
        inside = scene.view_id[pv.centres_inside()]
        seen[i] = np.bincount(inside[inside >= 0], minlength=scene.num_views)   # not shared
        if i in touched:    # the previous round's renders, where its removals changed nothing
            r_full, r_excl = _update_pair(pv, own[i], touched[i], previous, i)
        else:
            r_full, r_excl = pv.render_pair(keep=~own[i])     # R_i and R_i^-i in one pass
            if previous is not None:    # prepared afresh: the round before's are not read
                previous.full[i] = previous.excl[i] = None
        full.append(r_full)
        excl.append(r_excl)
        state.lap("exclusion_renders")
        if reveal is not None:
            start = _held_reveal(previous, i, plan[i], i in touched)
            ref, where = _reveal(state, plan[i], i, r_excl, start, touched.get(i))
            reveal.append(ref)
            valid.append(where)
            state.lap("reveal")
        state.report("render", i + 1, scene.num_views)
    return ExclusionRenders(full, excl, seen, bool(any_visible), reveal, valid, plan)


def _held_reveal(previous, i: int, others: list, derived: bool) -> tuple | None:
    """The previous round's reveal reference of view ``i`` and where it applies, if that
    round rendered the same neighbours ``others`` and the view was ``derived`` from its (not
    prepared afresh, whose renders are made whole); None otherwise. Dropped from ``previous``
    either way."""
    if previous is None or previous.reveal is None or previous.reveal[i] is None:
        return None
    held = previous.reveal[i]
    previous.reveal[i] = None
    return held[:2] if derived and held[2] == others else None


def _reveal(state, others: list, i: int, r_excl, start=None, tiles=None):
    """View ``i``'s reveal reference from the neighbours ``others`` and where it is not
    R_i^-i (:func:`~clearsplat.filter.reveal.reveal_reference`); from ``start`` (the previous
    round's, the same neighbours) again only in ``tiles``."""
    # Each neighbour's Gaussians from its members (not a comparison over every Gaussian),
    # as one array of layer ids rather than a mask per neighbour.
    layers = np.full(state.n, -1, dtype=np.int8)
    for k, j in enumerate(others):
        layers[state.index.members[j]] = k
    return reveal_reference(state.views[i], layers, r_excl,
                            quantile=rv.QUANTILE, min_views=rv.MIN_VIEWS,
                            tiles=tiles, start=start)


def _update_pair(pv, own, tiles, previous, i: int):
    """View ``i``'s R_i and R_i^-i from the previous round's, composited again in ``tiles``
    (which the previous round's removals touched); the previous renders are dropped."""
    r_full, r_excl = pv.render_pair(keep=~own, tiles=tiles, start=previous.full[i])
    flat, inside = pv.tile_pixels(tiles)
    outside = np.ones(r_excl.alpha.shape, dtype=bool)
    outside.reshape(-1)[flat[inside]] = False
    for a, b in zip(r_excl, previous.excl[i]):
        a[outside] = b[outside]
    previous.full[i] = previous.excl[i] = None     # no longer needed
    return r_full, r_excl
