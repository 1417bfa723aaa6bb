"""Where the filter loses the distractor Gaussians it misses, view by view.

Usage::

    python benchmarks/missed_distractors.py --realism plain --family object --views 16
    python benchmarks/missed_distractors.py --views 16 --config default+rounds=1 --view 14
    python benchmarks/missed_distractors.py --family street --views 32 --occlusion high \
        --config default+neighbours=4
    python benchmarks/missed_distractors.py --family street --views 16 --transients video
    python benchmarks/missed_distractors.py --family street --views 8 --transients video \
        --config default+leave_out=1 --other

One scene of the realism stand-in (``clearsplat.synth.realism``; seed, resolution and config
as given) and its distractor ground truth. Every distractor Gaussian the filter keeps is put
in the first of these steps that lost it:

- *no region*: in none of the proposal regions of the first round (the patch similarity,
  the support condition or the ranges left its pixels out);
- *refined away*: in a region, but in no candidate: refinement found it not in front of the
  static reference (nor different in colour from it). Split by where the Gaussian lies against
  that reference (R_i^-i without every proposed Gaussian, rendered here from the first round's
  regions, and the reveal reference where it applies with ``reveal_reference="quantile"``,
  before the depth-scale alignment): *behind* it (another view's static content lies
  in front of the distractor at its pixel: misplaced by depth or pose error, or an occlusion
  edge), *within the margin* (in front by less than ``refine.MARGIN``: a distractor on or next
  to the surface behind it), *in front* (by more). With the refinement (the default)
  the last is split as the first refinement pass judges it, the view's depths divided by their
  median ratio to that reference: *not at its view's scale* (no longer in front by the
  margin), *within its view's widened margin* (in front by less than the margin widened to
  2.5 robust standard deviations of the view's depth ratio), *in front by more, all the same*
  (by more than that too: the second refinement pass, or the colour test's tolerance, dropped
  it);
- *rejected (...)*: in a candidate that a test rejected, by the reason it gives;
- *accepted: hidden from its verifying views*: in an accepted candidate, but behind the own
  surface of each of its verifying views (``verify_hidden``).

Prints the totals (and, with ``reveal_reference="quantile"``, the share of each view's pixels
where the reveal reference applies, averaged over the views), then per input view the
distractor Gaussians, those missed, the view's
depth scale and widened margin and their steps, and with ``--view`` every candidate of that
view with its round, scores, verification views and how many of its Gaussians are
distractors.

With ``--other``, also where the static Gaussians that the filter removes lie (the
benchmark's *other removed*: every removed Gaussian whose pixel shows the static scene in its
view's input image): along its own view's ray against the clean surface at its pixel (the first
surface of the scene without transients, ``World.clean_depths``), *in front* by more than 5 % of
its depth (a floater: depth between a transient and the surface behind it, as at a transient's
silhouette), *at* it (static content) or *behind* it; Gaussians without a pixel apart. Under the
``depth`` and ``all`` scenarios each view's depths are biased, which shifts that split.

Counts only: the same on any machine.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from clearsplat.bench import parse_config
from clearsplat.filter import filter_distractors
from clearsplat.filter import reveal as rv
from clearsplat.filter.association import MIN_WEIGHT, ViewIndex, member_pixels, region_gaussians
from clearsplat.filter.neighbours import dense_options, view_plan
from clearsplat.filter.refine import MARGIN
from clearsplat.filter.reveal import reveal_plan, reveal_reference
from clearsplat.filter.robust import view_depth_scales, widened_margin
from clearsplat.render import prepare, render
from clearsplat.synth import make_world, reconstruct
from clearsplat.synth.backbone import distractor_truth
from clearsplat.synth.realism import parse_realism, realistic_reconstruction


def _reveal_depths(scene, config):
    """Per view, the reveal reference's depth and where it applies, (H*W,) each, as the first
    round builds them (``reveal_reference="quantile"``); None for the composite."""
    if config.reveal_reference != "quantile":
        return None
    neighbours, verify_views = dense_options(scene.num_views, config.neighbours,
                                             config.verify_views)
    plan = view_plan(scene, neighbours=neighbours, verify_views=verify_views,
                     num_verify_views=config.num_verify_views, leave_out=config.leave_out)
    views = np.arange(scene.num_views)
    allowed = np.abs(views[:, None] - views[None]) > config.leave_out
    if plan is not None and plan.hoods is not None:
        allowed &= np.array(plan.hoods)
    neighbours_of = reveal_plan(scene, count=rv.VIEWS, max_angle=rv.MAX_ANGLE,
                                allowed=allowed, depths=ViewIndex(scene).depths)
    out = []
    for v, (cam, others) in enumerate(zip(scene.cameras, neighbours_of)):
        excl = render(scene, cam, keep=np.abs(scene.view_id - v) > config.leave_out)
        ref, valid = reveal_reference(prepare(scene, cam), [scene.view_id == j for j in others],
                                      excl, quantile=rv.QUANTILE, min_views=rv.MIN_VIEWS)
        out.append((ref.depth.ravel(), valid.ravel()))
    return out


def _against_reference(scene, index, lost: np.ndarray, proposed: np.ndarray,
                       margin: float, align_scale: bool = False,
                       margins: dict | None = None, reveal: list | None = None) -> np.ndarray:
    """For the ``lost`` Gaussians ((N,) bool), where each lies against the static reference of
    its view: R_i^-i without the ``proposed`` Gaussians, R_i^-i where that leaves a hole, and
    the reveal reference where it applies (``reveal``, from :func:`_reveal_depths`), as
    refinement builds it. Returns their step names, in the order of ``np.flatnonzero(lost)``.

    With ``align_scale`` (the refinement's) those in front by more than
    ``margin`` are split as the first refinement pass judges them: each view's depths divided
    by their median ratio to this reference, its margin widened by their spread; ``margins``
    (a dict) then receives each such view's ``(scale, widened margin)``."""
    names = np.empty(int(lost.sum()), dtype=object)
    where = np.flatnonzero(lost)
    own = scene.view_id
    for v in np.unique(own[where]):
        cam = scene.cameras[v]
        static = render(scene, cam, keep=(own != v) & ~proposed)
        excl = render(scene, cam, keep=own != v)
        ref = np.where(static.alpha > 0.1, static.depth, excl.depth).ravel()
        if reveal is not None:
            ref = np.where(reveal[v][1], reveal[v][0], ref)
        sel = own[where] == v
        g = where[sel]
        members = index.members[v]
        pos = np.searchsorted(members, g)
        pixels = member_pixels(scene, index, v)
        pix = pixels[pos]
        z = cam.to_camera(scene.gaussians.means[g])[:, 2]
        r = np.where(pix >= 0, ref[np.clip(pix, 0, None)], 0.0)
        front = "refined away: in front by more"
        if align_scale:     # as refinement's first pass: the view's scale and spread
            z_all = cam.to_camera(scene.gaussians.means[members])[:, 2]
            r_all = np.where(pixels >= 0, ref[np.clip(pixels, 0, None)], 0.0)
            scale, spread = view_depth_scales([z_all], [r_all])[0]
            widened = widened_margin(margin, spread)
            if margins is not None:
                margins[int(v)] = (scale, widened)
            za = z / scale
            front = np.where(za >= (1 - margin) * r,
                             "refined away: in front, not at its view's scale",
                             np.where(za >= (1 - widened) * r,
                                      "refined away: within its view's widened margin",
                                      "refined away: in front by more, all the same"))
        names[sel] = np.where(r <= 0, "refined away: reference empty",
                     np.where(z >= r, "refined away: behind the static reference",
                     np.where(z >= (1 - margin) * r, "refined away: within the margin", front)))
    return names


def _steps(scene, result, truth, min_weight: float, margin: float,
           align_scale: bool = False, margins: dict | None = None,
           reveal: list | None = None) -> np.ndarray:
    """(N,) object: the step that lost each missed distractor Gaussian ('' elsewhere)."""
    n = len(scene)
    index = ViewIndex(scene)
    in_region = np.zeros(n, dtype=bool)
    for prop in result.proposals:
        loose = bool((index.pixels[prop.view] < 0).any())
        prepared = prepare(scene, scene.cameras[prop.view]) if loose else None
        for region in prop.regions:
            in_region[region_gaussians(scene, prop.view, region.pixels, index=index,
                                       min_weight=min_weight, prepared=prepared)] = True
    step = np.full(n, "", dtype=object)
    missed = truth & result.keep
    step[missed & ~in_region] = "no region"
    step[missed & in_region] = _against_reference(scene, index, missed & in_region, in_region,
                                                  margin, align_scale, margins, reveal)
    for c in result.candidates:      # the latest test a candidate reached names the loss
        lost = c.gaussians[missed[c.gaussians]]
        if not c.accepted:
            step[lost] = c.reason.replace("rejected by ", "rejected (") + (
                ")" if c.reason.startswith("rejected by") else "")
        elif lost.size:     # accepted, but no verifying view sees them (verify_hidden)
            step[lost] = "accepted: hidden from its verifying views"
    return step


def split_by_clean_depth(scene, world, gaussians: np.ndarray, margin: float = 0.05) -> dict:
    """Counts of ``gaussians`` ((M,) int) in front of, at and behind the clean surface at
    their pixel of their own view, by more than ``margin`` of its depth; ``"no pixel"`` for
    those without ``pixel_id``."""
    ratio = np.full(gaussians.size, np.nan)
    for v, cam in enumerate(scene.cameras):
        sel = np.flatnonzero(scene.view_id[gaussians] == v)
        if sel.size == 0:
            continue
        g = gaussians[sel]
        pid = scene.pixel_id[g].astype(np.int64)
        ok = pid >= 0
        z = cam.to_camera(scene.gaussians.means[g[ok]])[:, 2]
        ratio[sel[ok]] = z / world.clean_depths[v].ravel()[pid[ok]]
    has = ~np.isnan(ratio)
    return {"in front": int((ratio[has] < 1.0 - margin).sum()),
            "at": int((np.abs(ratio[has] - 1.0) <= margin).sum()),
            "behind": int((ratio[has] > 1.0 + margin).sum()),
            "no pixel": int((~has).sum())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realism", default="plain")
    p.add_argument("--family", default="object")
    p.add_argument("--views", type=int, default=16)
    p.add_argument("--resolution", default="128x224", help="HxW")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--occlusion", default="medium", help="low, medium or high (make_world)")
    p.add_argument("--transients", default="shots",
                   help="shots or video (make_world: passers-by for several consecutive views)")
    p.add_argument("--config", default="default", help="PRESET[+key=value...]")
    p.add_argument("--view", type=int, action="append", default=[],
                   help="list this view's candidates (repeatable)")
    p.add_argument("--other", action="store_true",
                   help="also split the static Gaussians removed by the clean surface")
    args = p.parse_args(argv)
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    config = parse_config(args.config)
    world = make_world(args.family, num_views=args.views, seed=args.seed, height=h, width=w,
                       occlusion=args.occlusion, transients=args.transients)
    if parse_realism(args.realism):
        scene, truth = realistic_reconstruction(world, args.realism, seed=args.seed)
    else:       # the plain stand-in, as clearsplat bench builds it
        scene = reconstruct(world.cameras, world.images, world.depths, seed=args.seed)
        truth = distractor_truth(scene, world)
    result = filter_distractors(scene, config=config)
    margins: dict = {}
    reveal = _reveal_depths(scene, config)
    step = _steps(scene, result, truth, MIN_WEIGHT, MARGIN, config.refine == "static-depth",
                  margins,
                  reveal)
    missed = truth & result.keep
    print(f"{args.realism} {args.family}, {args.views} views at {w}x{h}, seed {args.seed}, "
          f"{args.config}: recall {1 - missed.sum() / max(truth.sum(), 1):.3f} "
          f"({int(missed.sum()):,} of {int(truth.sum()):,} distractor Gaussians missed)")
    if reveal is not None:
        print(f"  the reveal reference applies at {np.mean([v.mean() for _, v in reveal]):.2f} "
              f"of the pixels (mean over views, as the first round builds it)")
    for name, count in Counter(step[missed]).most_common():
        print(f"  {name:44s} {count:7,}")
    # scale, margin: the view's depth ratio to the static reference and its margin widened by
    # its depth noise, as the first refinement pass measures them (views with a distractor
    # Gaussian refined away, with depth_scale_align).
    print(f"\n{'view':>4} {'distractor':>10} {'missed':>7} {'scale':>6} {'margin':>7}  steps")
    for v in range(scene.num_views):
        own = scene.view_id == v
        if not (truth & own).any():
            continue
        steps = Counter(step[missed & own])
        scale, wide = ((f"{margins[v][0]:.3f}", f"{100 * margins[v][1]:.1f} %")
                       if v in margins else ("-", "-"))
        print(f"{v:>4} {int((truth & own).sum()):>10,} {int((missed & own).sum()):>7,} "
              f"{scale:>6} {wide:>7}  " + ", ".join(f"{k} {c:,}" for k, c in steps.most_common()))
    for v in args.view:
        print(f"\ncandidates of view {v}:")
        for c in result.candidates:
            if c.view != v:
                continue
            scores = ", ".join(f"{k} {s:+.3f}" for k, s in c.scores.items())
            print(f"  #{c.index} round {c.round}, range {c.range}: {c.gaussians.size:,} "
                  f"Gaussians, {int(truth[c.gaussians].sum()):,} distractor; {scores}; "
                  f"views {c.verify_views}; {c.reason}")
    if args.other:
        static = np.flatnonzero(~truth & ~result.keep)
        n_static = int((~truth).sum())
        print(f"\nother Gaussians removed: {static.size:,} "
              f"({100 * static.size / max(n_static, 1):.2f} % of {n_static:,} static), "
              "against the clean surface at their pixel:")
        for name, count in split_by_clean_depth(scene, world, static).items():
            print(f"  {name:10s} {count:7,}  ({100 * count / max(n_static, 1):.2f} % of the "
                  "static Gaussians)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
