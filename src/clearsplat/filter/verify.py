"""Candidate verification: the scores, the individual test, the second range's additional and
joint tests.

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

Each candidate is scored on its verification views V_i (the views that see the most of view
i's Gaussians, :func:`verification_views`), from the base B_j = R_j^-j:

1. :func:`individual_tests`: every candidate alone; those with a positive score pass.
2. (:mod:`clearsplat.filter.expansion` expands those that passed.)
3. :func:`second_range_tests`: first-range candidates that passed are accepted; each
   second-range one must also pass the *additional* test (its expansion removed from R_j^-j)
   and then all survivors together the *joint* test, from a base without the accepted
   first-range Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import Scene
from .association import ViewIndex

__all__ = ["Partial", "change_weighted_terms", "Verifier", "verification_views", "top_views",
           "make_verifier", "exclusion_masks", "range_masks", "passes", "median_relative_score",
           "seen_by_verifiers", "own_depth_map",
           "individual_tests", "second_range_tests"]

#: With refinement, verification leaves the proposal regions in (``"revealing"``) from
#: this many views on (measured: needed at 8 and 16 views, harmful on clean 4-view scenes).
_REVEALING_MASK_MIN_VIEWS = 8


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
                          min_alpha: float = 0.0) -> Partial:
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
    e_before = np.abs(base[valid] - img[valid]).sum(-1)
    delta = e_before - np.abs(after[valid] - img[valid]).sum(-1)
    return Partial(float(np.sum(w * delta)), float(np.sum(w)), float(np.sum(w * e_before)))


class Verifier:
    """Scores removals against the input views, incrementally or by full re-renders.

    Parameters
    ----------
    views : view set
        One per input camera, prepared from the whole scene.
    images : list of (H, W, 3) float32
        The input images.
    epsilon : float
    incremental : bool
    hole_alpha : float
        Pixels whose accumulated opacity after a removal stays below this are left out.
    """

    def __init__(self, views, images: list[np.ndarray], *, epsilon: float,
                 incremental: bool = True, hole_alpha: float = 0.0):
        self.views = views
        self.images = [im.reshape(-1, 3) for im in images]
        self.epsilon = float(epsilon)
        self.incremental = incremental
        self.hole_alpha = float(hole_alpha)

    def score_tiles(self, j: int, base, after, tiles: np.ndarray,
                    excluded: np.ndarray) -> Partial:
        """Score terms of ``after`` against ``base`` on view ``j``, read only in ``tiles``.

        For renders that can differ only inside ``tiles`` (and are exact there); visits the
        pixels in row-major order like the other paths, so the sums agree with them exactly.
        """
        flat, inside = self.views[j].tile_pixels(np.asarray(tiles))
        idx = np.sort(flat[inside])
        return change_weighted_terms(base.rgb.reshape(-1, 3)[idx],
                                     after.rgb.reshape(-1, 3)[idx], self.images[j][idx],
                                     excluded.ravel()[idx], self.epsilon,
                                     after.alpha.reshape(-1)[idx], self.hole_alpha)

    def score_view(self, j: int, base_keep: np.ndarray, base,
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
                flat, inside = self.views[j].tile_pixels(patch.tiles)
                flat = flat[inside]
                order = np.argsort(flat, kind="stable")
                idx = flat[order]
                after = patch.rgb.reshape(-1, 3)[inside][order]
                alpha = patch.alpha.reshape(-1)[inside][order]
                out.append(change_weighted_terms(base_rgb[idx], after, self.images[j][idx],
                                                 q[idx], self.epsilon, alpha, self.hole_alpha))
            return out
        for removal in removals:
            keep = base_keep.copy()
            keep[removal] = False
            r = self.views[j].render(keep=keep)
            out.append(change_weighted_terms(base_rgb, r.rgb.reshape(-1, 3), self.images[j], q,
                                             self.epsilon, r.alpha.reshape(-1), self.hole_alpha))
        return out


def verification_views(scene: Scene, view: int, count: int, *, index: ViewIndex,
                       inside: list | None = None) -> list[int]:
    """The ``count`` other views that see the most centres of ``view``'s Gaussians [V_i].

    Centres count when they have positive depth and fall inside the image; ties go to the
    lower view index; ``view`` itself is never chosen.

    ``inside``, optional: per view, the (N,) bool :meth:`PreparedView.centres_inside
    <clearsplat.render.PreparedView.centres_inside>` of its prepared view. The counts then
    come from the projections already made (about 4x faster at 16 views) and leave out
    the Gaussians the rasterizer culls (alpha below 1/255, closer than its near plane).
    """
    others = [j for j in range(scene.num_views) if j != view]
    if not others:
        return []
    if inside is not None:
        members = index.members[view]
        counts = sorted((-int(np.count_nonzero(inside[j][members])), j) for j in others)
        return [j for _, j in counts[:count]]
    means = scene.gaussians.means[index.members[view]]
    # All cameras in one product: (M, 3) @ (3, 3V) plus translations, in float32.
    w2c = np.stack([scene.cameras[j].world_to_camera for j in others]).astype(np.float32)
    pc = means @ w2c[:, :3, :3].transpose(2, 0, 1).reshape(3, -1) + w2c[:, :3, 3].reshape(-1)
    pc = pc.reshape(len(means), len(others), 3)
    cams = [scene.cameras[j] for j in others]
    fx, fy, cx, cy, w, h = (np.array([getattr(c, a) for c in cams], dtype=np.float32)
                            for a in ("fx", "fy", "cx", "cy", "width", "height"))
    x, y, z = pc[..., 0], pc[..., 1], pc[..., 2]
    front = z > 0
    zf = np.where(front, z, np.float32(1.0))
    u = fx * x / zf + cx
    v = fy * y / zf + cy
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    counts = sorted(zip((-inside.sum(axis=0)).tolist(), others))
    return [j for _, j in counts[:count]]


def top_views(seen: np.ndarray, view: int, count: int) -> list[int]:
    """The ``count`` other views that see the most centres of ``view``'s Gaussians inside
    their image (ties to the lower index) [V_i]: :func:`verification_views` from the counts
    ``seen[j, v]`` that the exclusion renders made; a negative count marks a view that
    cannot verify ``view`` (``leave_out``)."""
    others = [j for j in range(seen.shape[0]) if j != view and seen[j, view] >= 0]
    ranked = sorted((-int(seen[j, view]), j) for j in others)
    return [j for _, j in ranked[:count]]


def make_verifier(state):
    """The round's scorer against the input images, leaving out holes where ``verify_holes``
    asks."""
    config = state.config
    skip = (state.num_views <= 2 if config.verify_holes == "auto"
            else config.verify_holes == "skip")
    return state.backend.verifier(state.views, state.scene.images, epsilon=config.epsilon,
                                  hole_alpha=config.eta if skip else 0.0)


def exclusion_masks(proposals, rng: int, mode: str) -> list[np.ndarray]:
    """Q_j per view: M_j^1 for first-range candidates, M_j^1 | M_j^2 for second-range ones,
    plus the view's unreliable pixels where it has them (``mode="proposals+revealing"``); only
    the unreliable pixels with ``mode="revealing"``."""
    out = []
    for p in proposals:
        if mode == "revealing":
            out.append(p.unreliable)
            continue
        q = p.mask1 if rng == 1 else (p.mask1 | p.mask2)
        out.append(q if p.unreliable is None else (q | p.unreliable))
    return out


def range_masks(state, proposals) -> dict:
    """``{1: Q^1, 2: Q^2}``: the exclusion masks of each range (:func:`exclusion_masks`).
    Without refinement the proposal regions (the paper); with it also the pixels of each
    verifying view's Gaussians in front of the static reference (its own likely distractors),
    and from eight views on only those: there a proposal region of the verifying view is
    often the candidate itself, seen from nearly the same place (docs/method.md,
    "The verification mask")."""
    if state.config.refine == "none":
        mode = "proposals"
    else:
        mode = ("revealing" if state.num_views >= _REVEALING_MASK_MIN_VIEWS
                else "proposals+revealing")
    return {r: exclusion_masks(proposals, r, mode) for r in (1, 2)}


def passes(total: Partial, config, per_view: list | None = None) -> bool:
    """A test's verdict: a positive score and, where ``min_relative_score`` asks for
    it, a large enough share of the error it touches explained by the removal: with
    ``per_view`` (the terms of each verification view, the individual test) the median of the
    views' own shares (:func:`median_relative_score`), so that one view neither carries a
    candidate nor vetoes it; else the share of ``total``."""
    if not total.score > 0.0:
        return False
    if config.min_relative_score <= 0:
        return True
    if per_view is not None:
        return median_relative_score(per_view, pooled=total) > config.min_relative_score
    return total.relative_score > config.min_relative_score


#: The individual test's share is the median over the views whose change weight is at
#: least this share of the largest view's: a view where the removal changes a few pixels has
#: a share that says nothing of the candidate.
_MEDIAN_MIN_WEIGHT = 0.05


def median_relative_score(per_view: list, pooled: Partial | None = None) -> float:
    """The median of :attr:`Partial.relative_score` over the views whose terms carry weight:
    at least a twentieth of the weight (``den``) of the view that carries most. A median
    outvotes one view only among three or more: with one or two such views, the share pooled
    over every view (0 when none carries any weight). ``pooled``: the sum of ``per_view``
    where the caller has it (otherwise summed here)."""
    top = max((p.den for p in per_view), default=0.0)
    if not top > 0:
        return 0.0
    shares = [p.relative_score for p in per_view if p.den >= _MEDIAN_MIN_WEIGHT * top]
    if len(shares) < 3:
        if pooled is None:
            pooled = Partial()
            for p in per_view:
                pooled.add(p)
        return pooled.relative_score
    return float(np.median(shares))


def individual_tests(state, candidates: list, q: dict, verifier, renders) -> list:
    """Score every candidate alone on its verification views; return those that pass.

    Sets each candidate's ``verify_views``, ``scores["individual"]`` and ``reason``.
    ``q[r][j]`` is the exclusion mask of view j for candidates of range r; ``renders`` the
    round's :class:`~clearsplat.filter.exclusion.ExclusionRenders` (the bases).
    """
    config, views, own = state.config, state.views, state.own
    plan = state.plan
    if plan is not None and plan.verifiers is not None:
        views_of = dict(enumerate(plan.verifiers))     # never views left out (view_plan)
    else:
        # A view that leaves view i's Gaussians out of its base (itself, and with
        # ``leave_out`` its neighbours) cannot verify it.
        seen = np.where(state.left_out, -1, renders.seen)
        views_of = {i: top_views(seen, i, config.num_verify_views)
                    for i in range(state.num_views)}
    all_keep = np.ones(state.n, dtype=bool)
    # Every candidate's Gaussians: with the static base, those of the other views are left out
    # of each verifying view's base, so that their distractors do not hide the tested one's.
    proposed = (state.mask(*(c.gaussians for c in candidates))
                if config.verify_base == "static" else None)
    totals = {c.index: Partial() for c in candidates}
    per_view = {c.index: [] for c in candidates}     # each verification view's terms
    for c in candidates:
        c.verify_views = views_of[c.view]
    # Batch per verifying view: every candidate that view j verifies, in one call.
    for j in range(state.num_views):
        # Candidates that view j does not see score 0 there: left out (and the view with them).
        todo = [c for c in candidates if j in c.verify_views and c.gaussians.size
                and views.sees(j, c.gaussians)]
        if todo and proposed is not None:
            for c, p in _static_base_terms(state, j, todo, proposed, q, verifier, renders):
                totals[c.index].add(p)
                per_view[c.index].append(p)
        elif todo:
            if config.verify_base == "full":
                base_keep, base = all_keep, renders.full[j]
            else:
                base_keep, base = ~own[j], renders.excl[j]
            for rng in (1, 2):
                batch = [c for c in todo if c.range == rng]
                parts = verifier.score_view(j, base_keep, base, [c.gaussians for c in batch],
                                            q[rng][j])
                for c, p in zip(batch, parts):
                    totals[c.index].add(p)
                    per_view[c.index].append(p)
        state.report("individual", j + 1, state.num_views)
    for c in candidates:
        c.scores["individual"] = totals[c.index].score
        if c.gaussians.size == 0:
            c.reason = ("no Gaussians in region" if config.refine == "none"
                        else "no Gaussians left: none survived refinement")
        elif passes(totals[c.index], config, per_view[c.index]):
            c.reason = "passed individual test"
        else:
            c.reason = "rejected by individual test"
    return [c for c in candidates if c.reason == "passed individual test"]


def _static_base_terms(state, j: int, todo: list, proposed: np.ndarray, q: dict, verifier,
                       renders) -> list:
    """``(candidate, terms)`` of each candidate in ``todo`` on view j
    (``verify_base="static"``): its removal from R_j^-j without the candidates of every other
    view (``proposed``, every candidate's Gaussians). The candidates of one view share a base
    and are scored in one batch, as with the other bases."""
    pv, own = state.views[j], state.own[j]
    theirs = proposed & ~own        # every candidate R_j^-j holds
    by_view: dict = {}
    for c in todo:
        by_view.setdefault(c.view, []).append(c)
    out = []
    for i in sorted(by_view):
        mine = by_view[i]
        others = theirs.copy()
        others[state.index.members[i]] = False
        base_keep = ~(own | others)
        if verifier.incremental:
            # The scores read the base only in the tiles the candidates touch.
            base = renders.excl[j]
            tiles = np.intersect1d(pv.tiles_touched(others),
                                   pv.tiles_touched(np.concatenate([c.gaussians for c in mine])))
            if tiles.size:
                base = pv.rerender(base, keep=base_keep, tiles=tiles)
        else:
            base = pv.render(keep=base_keep)
        for rng in (1, 2):
            batch = [c for c in mine if c.range == rng]
            parts = verifier.score_view(j, base_keep, base, [c.gaussians for c in batch],
                                        q[rng][j])
            out += zip(batch, parts)
    return out


def second_range_tests(state, passed: list, q: list, verifier, renders) -> None:
    """Accept the first-range candidates in ``passed``; put the second-range ones through the
    additional test, then the survivors together through the joint test.

    ``passed`` are expanded candidates that passed their individual test; ``q[j]`` is view
    j's exclusion mask M_j^1 | M_j^2 (and its unreliable pixels).
    """
    first = [c for c in passed if c.range == 1]
    second = [c for c in passed if c.range == 2]
    for c in first:
        c.accepted, c.reason = True, "accepted (first range)"
    if not second:
        return
    survivors = _additional_tests(state, second, q, verifier, renders)
    if survivors:
        _joint_test(state, first, survivors, q, verifier, renders)


def _additional_tests(state, second: list, q: list, verifier, renders) -> list:
    """Each second-range candidate's expansion removed from R_j^-j; return those that pass."""
    views, own, v = state.views, state.own, state.num_views
    totals = {c.index: Partial() for c in second}
    for j in range(v):
        # Candidates that view j does not see score 0 there: left out (and the view with them).
        todo = [c for c in second if views.sees(j, c.expanded)]
        if todo:
            parts = verifier.score_view(j, ~own[j], renders.excl[j],
                                        [c.expanded for c in todo], q[j])
            for c, p in zip(todo, parts):
                totals[c.index].add(p)
        state.report("additional", j + 1, v)
    survivors = []
    for c in second:
        c.scores["additional"] = totals[c.index].score
        if passes(totals[c.index], state.config):
            survivors.append(c)
        else:
            c.reason = "rejected by additional test"
    return survivors


def _joint_test(state, first: list, survivors: list, q: list, verifier, renders) -> None:
    """All ``survivors`` removed at once, from each view's R_j^-j without the accepted first
    range (as the additional test: each view j without its own Gaussians)."""
    config, views, own, v = state.config, state.views, state.own, state.num_views
    removed_first = np.zeros(state.n, dtype=bool)
    for c in first:
        removed_first[c.expanded] = True
    joint = np.unique(np.concatenate([c.expanded for c in survivors]))
    jointly = state.mask(joint)
    total = Partial()
    for j in range(v):
        if not views.sees(j, joint):
            state.report("joint", j + 1, v)        # every term would be 0
            continue
        base_keep, start = ~(removed_first | own[j]), renders.excl[j]
        total.add(_joint_terms(verifier, views[j], j, base_keep, jointly, joint, start, q[j]))
        state.report("joint", j + 1, v)
    ok = passes(total, config)
    for c in survivors:
        c.scores["joint"] = total.score
        c.accepted = ok
        c.reason = "accepted (second range, joint test)" if ok else "rejected by joint test"


def _joint_terms(verifier, pv, j: int, base_keep, jointly, joint, start, q) -> Partial:
    """The joint removal's score terms on view j."""
    if verifier.incremental:
        # The score reads only the tiles the joint removal touches: composite the base and
        # the base without the joint removal there, in one pass.
        tiles = pv.tiles_touched(joint)
        base, after = pv.render_pair(first=base_keep, keep=base_keep & ~jointly,
                                     tiles=tiles, start=start)
        return verifier.score_tiles(j, base, after, tiles, q)
    base = pv.render(keep=base_keep)
    (p,) = verifier.score_view(j, base_keep, base, [joint], q)
    return p


def own_depth_map(scene: Scene, index: ViewIndex, view: int) -> np.ndarray:
    """(H*W,) float64: per pixel of ``view``, the camera depth of the nearest of its own
    Gaussians there (their ``pixel_id``, or the pixel their centre projects to); ``inf`` where
    it has none."""
    cam = scene.cameras[view]
    out = np.full(cam.height * cam.width, np.inf)
    if index.members[view].size:
        z, pix = index.depths[view], index.image_pixels[view]
        ok = (pix >= 0) & (z > 0)
        np.minimum.at(out, pix[ok], z[ok])
    return out


def seen_by_verifiers(state, candidates: list, margin: float,
                      view_margins: list | None = None) -> None:
    """Cut each candidate's hat C_k (``c.expanded``) to the Gaussians that one of its
    verifying views sees (``FilterConfig.verify_hidden``).

    A Gaussian is seen by view j when its centre projects inside j's image, in front of the
    camera, at most ``margin`` times the depth behind j's own surface there
    (:func:`own_depth_map`; a pixel where j has no Gaussian of its own counts as seen). With
    ``view_margins`` (per view, the margin of refinement's depth test, widened by the view's
    depth noise: :attr:`~clearsplat.filter.refine.Refinement.margins`; None for a view
    without one) the margin for a Gaussian and view j is the largest of ``margin``, its own
    view's and j's: where a view's depths are that noisy, the back of its distractor lies that
    far behind the others' surfaces.
    Candidates without verifying views or expansion are left as they are. Each cut candidate
    gets ``scores["hidden"]``: how many Gaussians it keeps for that reason.
    """
    scene = state.scene
    means = scene.gaussians.means
    # Per view, the margin its Gaussians and its surface are judged with.
    per_view = np.array([margin if m is None else max(margin, m)
                         for m in (view_margins or [None] * scene.num_views)] + [margin])
    own: dict = {}
    for c in candidates:
        if c.expanded is None or c.expanded.size == 0 or not c.verify_views:
            continue
        pts = means[c.expanded]
        theirs = per_view[scene.view_id[c.expanded]]     # a shared one's (-1): margin
        seen = np.zeros(c.expanded.size, dtype=bool)
        for j in c.verify_views:
            if j not in own:
                own[j] = own_depth_map(scene, state.index, j)
            pix, z = scene.cameras[j].flat_pixels(pts)
            inside = pix >= 0
            limit = 1.0 + np.maximum(theirs[inside], per_view[j])
            seen[inside] |= z[inside] <= limit * own[j][pix[inside]]
        hidden = int(np.count_nonzero(~seen))
        if hidden:
            c.expanded = c.expanded[seen]
            c.scores["hidden"] = hidden
