"""The reveal reference: what lies behind view i's Gaussians, robust to the other views'
passers-by (``FilterConfig.reveal_reference="quantile"``).

The paper asks R_i^-i, every other view composited front to back, what surface removing view
i's Gaussians reveals. A passer-by held by any other view stands in front in that composite;
in a video the neighbouring frames hold the same person at nearly the same place, so
R_i^-i shows him instead of the wall behind and reveals nothing (docs/method.md, "Video").

Here each of the ``VIEWS`` (7) other views that share the most of view i's field of view
(:func:`clearsplat.filter.neighbours.covisibility`, ``C[i, j] + C[j, i]``) and see view i's
scene from within ``MAX_ANGLE`` (30 degrees; :func:`parallax_angles`; views farther round see past
the edges of what view i sees) is rendered into camera i on its own (every neighbour in one
pass over the view's tile lists, ``render_layers``, each equal to its own render bit for bit).
At each pixel the views that cover it (accumulated opacity above
0.5) give one expected depth each; transients only ever stand in front of the static surface, so
the reference is the view at rank ``floor(q (n - 1))`` of the n depths in ascending order
(``QUANTILE`` q): with q = 0.75 it still shows the surface when up to three quarters
of the covering views hold something in front, and is not fooled by a quarter that see past
an edge. Its colour, opacity and depth are that view's. Where fewer than
``MIN_VIEWS`` (4) views cover the pixel the evidence is too thin to outvote anything and
the reference is R_i^-i itself.

The proposal (similarity and support) and refinement read this
reference; verification keeps R_i^-i, whose incremental renders it needs. Refinement's static
reference is R_i^-i without the proposed Gaussians where the reference falls back to R_i^-i,
and the reference itself elsewhere: it outvotes the other views' passers-by already.
"""

from __future__ import annotations

import numpy as np

from ..render import RenderResult
from .neighbours import covisibility

__all__ = ["MAX_ANGLE", "MIN_ALPHA", "MIN_VIEWS", "QUANTILE", "VIEWS", "parallax_angles",
           "quantile_layers", "reveal_neighbours", "reveal_plan", "reveal_reference",
           "typical_depths"]

#: A neighbour covers a pixel where its own render's accumulated opacity exceeds this.
MIN_ALPHA = 0.5
#: Neighbours the reveal reference renders, among those that R_i^-i holds: the seven that
#: bounded neighbourhoods keep (docs/method.md, "The reveal reference").
VIEWS = 7
#: Degrees: only views whose camera centre lies within this angle of view i's, seen from view
#: i's scene point; views farther round see past the edges of what view i sees and outvote
#: its own surface there.
MAX_ANGLE = 30.0
#: Rank of the reference's depth among the covering neighbours' (0 the nearest, 1 the
#: farthest): the surface still shows where three quarters of them hold something in front.
QUANTILE = 0.75
#: Fewest covering neighbours for a pixel to take the reveal reference rather than R_i^-i:
#: so up to four input views the output is the composite's.
MIN_VIEWS = 4


def reveal_neighbours(shared: np.ndarray, view: int, *, count: int,
                      allowed: np.ndarray | None = None) -> list[int]:
    """The ``count`` views that share the most with ``view`` (``shared[view, j]``, ties to the
    lower index), among those ``allowed`` ((V,) bool; None: every view), never ``view``."""
    candidates = [j for j in range(shared.shape[0])
                  if j != view and (allowed is None or allowed[j])]
    candidates.sort(key=lambda j: (-shared[view, j], j))
    return candidates[:count]


def reveal_plan(scene, *, count: int, max_angle: float | None, allowed: np.ndarray,
                depths: list) -> list[list[int]]:
    """Per view i, the neighbours its reveal reference renders: the ``count`` views sharing
    the most of its field of view (:func:`~clearsplat.filter.neighbours.covisibility`, both
    ways), among those ``allowed[i]`` ((V, V) bool) allows and, unless ``max_angle`` is None,
    within ``max_angle`` degrees of parallax (:func:`parallax_angles` at the
    :func:`typical_depths` of ``depths``: per view, its Gaussians' camera depths,
    ``ViewIndex.depths``)."""
    c = covisibility(scene)
    shared = c + c.T
    if max_angle is not None:
        allowed = allowed & (parallax_angles(scene.cameras, typical_depths(depths))
                             <= max_angle)
    return [reveal_neighbours(shared, i, count=count, allowed=allowed[i])
            for i in range(scene.num_views)]


def parallax_angles(cameras: list, depths: list) -> np.ndarray:
    """(V, V) float, degrees: ``angles[i, j]`` is the angle at view i's scene point between the
    rays to camera i's centre and camera j's; the scene point lies on camera i's optical axis
    at ``depths[i]`` (its typical depth, e.g. the median camera depth of its Gaussians).
    0 on the diagonal; where ``depths[i]`` is not positive, row i is 0 (nothing to measure).
    """
    centres = np.array([c.camera_to_world[:3, 3] for c in cameras], dtype=np.float64)
    axes = np.array([c.camera_to_world[:3, 2] for c in cameras], dtype=np.float64)
    out = np.zeros((len(cameras), len(cameras)))
    for i, depth in enumerate(depths):
        if not depth > 0:
            continue
        point = centres[i] + axes[i] * depth
        to_i = centres[i] - point
        to_j = centres - point
        norms = np.linalg.norm(to_j, axis=1) * np.linalg.norm(to_i)
        cos = np.divide(to_j @ to_i, norms, out=np.ones(len(cameras)), where=norms > 0)
        out[i] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        out[i, i] = 0.0
    return out


def typical_depths(depths: list) -> list[float]:
    """Per view, the median camera depth of its own Gaussians in front of it (0 where it has
    none): the depth :func:`parallax_angles` measures at. ``depths``: per view, its Gaussians'
    camera depths ((M_v,) float, or None for a view without any: ``ViewIndex.depths``)."""
    out = []
    for z in depths:
        z = np.empty(0) if z is None else z[z > 0]
        out.append(float(np.median(z)) if z.size else 0.0)
    return out


def quantile_layers(depth: np.ndarray, alpha: np.ndarray, *, quantile: float,
                    min_views: int, min_alpha: float = MIN_ALPHA) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, which layer the reference takes.

    Parameters
    ----------
    depth, alpha : (K, H, W) float32
        The expected depth and accumulated opacity of K renders of the same camera (or of
        any set of their pixels: (K, ...)).
    quantile : float in [0, 1]
    min_views : int
        Fewest covering layers (``alpha > min_alpha``) for a pixel to take one.

    Returns
    -------
    layer : (H, W) int64
        The covering layer at rank ``floor(quantile * (n - 1))`` of the n covering layers'
        depths in ascending order (ties: the lower layer first).
    valid : (H, W) bool
        ``n >= min_views`` (and n >= 1): where ``layer`` applies.
    """
    covered = alpha > min_alpha
    n = covered.sum(axis=0)
    key = np.where(covered, depth, np.inf)
    order = np.argsort(key, axis=0, kind="stable")
    # The small epsilon keeps an exact product such as 0.75 * 4 = 3 from rounding down.
    rank = np.floor(quantile * np.maximum(n - 1, 0) + 1e-9).astype(np.int64)
    layer = np.take_along_axis(order, rank[None], axis=0)[0]
    return layer, n >= max(min_views, 1)


def reveal_reference(view, layers, fallback: RenderResult, *, quantile: float,
                     min_views: int, tiles: np.ndarray | None = None,
                     start: tuple | None = None) -> tuple[RenderResult, np.ndarray]:
    """View i's reveal reference: its prepared view ``view`` rendered with each of ``layers``
    (one neighbour's Gaussians each: a list of (N,) bool masks, or an (N,) int array of layer
    ids, -1 for none, as :meth:`~clearsplat.render.PreparedView.render_layers` takes them) on
    its own, the layer that :func:`quantile_layers` picks per pixel, and ``fallback``
    (R_i^-i) where it picks none.

    ``start``: a reference made earlier, ``(reference, valid)``, with the same layers but for
    Gaussians since removed in ``tiles`` (int tile ids) and a ``fallback`` that differs from
    the one given only there: the reference is then made again in those tiles alone, and
    equals the whole one bit for bit.

    Returns the reference and (H, W) bool, where it is not ``fallback``'s."""
    if start is None:
        renders = view.render_layers(layers)     # one pass over the tile lists, natively
        if not renders:
            return fallback, np.zeros(fallback.alpha.shape, dtype=bool)
        # R_i^-i, overwritten where a layer applies with that layer's own values.
        out = RenderResult(*(np.array(a, dtype=np.float32) for a in fallback))
        valid = np.zeros(fallback.alpha.shape, dtype=bool)
        pixels = slice(None)
    else:
        reference, valid = start
        # Copies: the round before's proposals keep its reference for their pictures.
        out = RenderResult(*(np.array(a, dtype=np.float32) for a in reference))
        valid = np.array(valid, dtype=bool)
        flat, inside = view.tile_pixels(tiles)
        pixels = flat[inside]
        if pixels.size == 0:
            return out, valid
        renders = view.render_layers(layers, tiles=tiles)
        for a, b in zip(out, fallback):     # R_i^-i there, as in the whole reference
            a.reshape(valid.size, -1)[pixels] = np.asarray(b).reshape(valid.size, -1)[pixels]
    # Each pixel on its own: the same bits whether every pixel is made or only these.
    n = valid.size
    if not renders:
        valid.reshape(-1)[pixels] = False
        return out, valid
    depth = np.stack([r.depth.reshape(-1)[pixels] for r in renders])
    alpha = np.stack([r.alpha.reshape(-1)[pixels] for r in renders])
    layer, applies = quantile_layers(depth, alpha, quantile=quantile, min_views=min_views)
    valid.reshape(-1)[pixels] = applies
    at = np.arange(n)[pixels]
    for k, r in enumerate(renders):
        take = at[applies & (layer == k)]
        for a, b in zip(out, r):
            a.reshape(n, -1)[take] = b.reshape(n, -1)[take]
    return out, valid
