"""How often a view's exclusion render reveals a farther surface behind its own Gaussians, and
how often its reveal reference (``reveal_reference="quantile"``) does.

Usage::

    python benchmarks/reference_reveal.py --views 16 --transients video
    python benchmarks/reference_reveal.py --views 8 --neighbours 7 --transients shots

The support condition and refinement ask whether removing view i's Gaussians reveals a
surface farther than their own. R_i^-i composites every other view front to back, so a
passer-by that other views also hold (the neighbouring frames of a video) stands in it and
reveals nothing. This compares, per Gaussian of view i, ``z < (1 - margin) * d`` for two
reference depths d at its pixel: R_i^-i's expected depth, and the reveal reference's
(:func:`clearsplat.filter.reveal.reveal_reference`: the ``--quantile`` of the depths of the
``--neighbours`` views that share most of view i's field of view, each rendered into camera i
on its own, where at least one covers the pixel), for the distractor Gaussians (which should
be revealed) and for a sample of the static ones (which should not); then per view, for its
distractor Gaussians. The plain stand-in (``clearsplat bench`` builds it so),
seed and resolution as given. Counts only: the same on any machine.
"""

from __future__ import annotations

import argparse

import numpy as np

from clearsplat.filter.neighbours import covisibility
from clearsplat.filter.reveal import reveal_reference
from clearsplat.render import RenderResult, prepare, render
from clearsplat.synth import make_world, reconstruct
from clearsplat.synth.backbone import distractor_truth


def covered_depth(result, min_alpha: float = 0.0) -> np.ndarray:
    """(H*W,) the render's expected depth where its accumulated opacity exceeds
    ``min_alpha``, NaN elsewhere."""
    return np.where(result.alpha.ravel() > min_alpha, result.depth.ravel(), np.nan)


def quantile_reference(scene, view: int, others, quantile: float) -> np.ndarray:
    """(H*W,) per pixel of ``view``, the depth of its reveal reference from the views
    ``others`` (:func:`clearsplat.filter.reveal.reveal_reference`, at least one covering
    view); NaN where none covers."""
    cam = scene.cameras[view]
    h, w = cam.height, cam.width
    nothing = RenderResult(np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32),
                           np.full((h, w), np.nan, np.float32))
    ref, _ = reveal_reference(prepare(scene, cam), [scene.view_id == j for j in others],
                              nothing, quantile=quantile, min_views=1)
    return ref.depth.ravel()


def revealed(scene, gaussians: np.ndarray, view: int, reference: np.ndarray,
             margin: float) -> np.ndarray:
    """(M,) bool: of ``gaussians`` (of ``view``, pixel-aligned), those in front of
    ``reference`` ((H*W,), NaN: nothing there) at their pixel by more than ``margin``."""
    z = scene.cameras[view].to_camera(scene.gaussians.means[gaussians])[:, 2]
    d = reference[scene.pixel_id[gaussians]]
    with np.errstate(invalid="ignore"):
        return np.nan_to_num(z < (1.0 - margin) * d, nan=False).astype(bool)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--family", default="street")
    p.add_argument("--views", type=int, default=16)
    p.add_argument("--resolution", default="128x224", help="HxW")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--transients", default="video", help="shots or video (make_world)")
    p.add_argument("--neighbours", type=int, default=7)
    p.add_argument("--quantile", type=float, default=0.75,
                   help="the reveal reference's rank among the covering depths")
    p.add_argument("--margin", type=float, default=0.05)
    p.add_argument("--static-sample", type=int, default=5000,
                   help="static Gaussians sampled per view")
    args = p.parse_args(argv)
    h, w = (int(x) for x in args.resolution.lower().split("x"))
    world = make_world(args.family, num_views=args.views, seed=args.seed, height=h, width=w,
                       transients=args.transients)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=args.seed)
    truth = distractor_truth(scene, world)
    shared = covisibility(scene)
    shared = shared + shared.T
    rng = np.random.default_rng(args.seed)
    counts = {("distractor", "excl"): 0, ("distractor", "quantile"): 0,
              ("static", "excl"): 0, ("static", "quantile"): 0}
    totals = {"distractor": 0, "static": 0}
    per_view = []
    for i in range(scene.num_views):
        own = scene.view_id == i
        others = [j for j in np.argsort(-shared[i], kind="stable") if j != i][:args.neighbours]
        excl = covered_depth(render(scene, scene.cameras[i], keep=~own))
        robust = quantile_reference(scene, i, others, args.quantile)
        static = np.flatnonzero(own & ~truth)
        static = rng.choice(static, size=min(args.static_sample, static.size), replace=False)
        for kind, ids in (("distractor", np.flatnonzero(own & truth)), ("static", static)):
            totals[kind] += ids.size
            counts[kind, "excl"] += int(revealed(scene, ids, i, excl, args.margin).sum())
            counts[kind, "quantile"] += int(revealed(scene, ids, i, robust, args.margin).sum())
        ids = np.flatnonzero(own & truth)
        if ids.size:
            per_view.append((i, ids.size, revealed(scene, ids, i, excl, args.margin).mean(),
                             revealed(scene, ids, i, robust, args.margin).mean()))
    print(f"{args.family}, {args.transients}, {args.views} views at {w}x{h}, seed {args.seed}; "
          f"a farther surface (by {args.margin:.0%}) revealed behind:")
    for kind in ("distractor", "static"):
        n = max(totals[kind], 1)
        print(f"  {kind:10s} Gaussians ({totals[kind]:,}): R_i^-i "
              f"{counts[kind, 'excl'] / n:.3f}, quantile {args.quantile} of {args.neighbours} "
              f"neighbours {counts[kind, 'quantile'] / n:.3f}")
    print(f"\n{'view':>4} {'distractor':>10} {'R_i^-i':>7} {'quantile':>8}")
    for i, n, a, b in per_view:
        print(f"{i:>4} {n:>10,} {a:>7.3f} {b:>8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
