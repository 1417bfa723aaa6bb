"""The next round: what one round hands to the next, and how their results join.

From eight views on the default runs the procedure again on the Gaussians the first round
kept (``FilterConfig.rounds``): one view's distractor can hide another's in R_i^-i, and with
the first round's removals gone it shows. A later round on the CPU takes the round before's
prepared views, restricted to the kept Gaussians, and its renders, composited again only where
the removals touched (:class:`Carry`); both are exact, so a round equals a fresh run on what
the rounds before kept, but for the pixels where the rounds before removed a verifying
view's own Gaussians: its input still shows what was removed there, so verification leaves
them out.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..scene import Gaussians, Scene
from .result import FilterResult

__all__ = ["Carry", "KeptGaussians", "held_bytes", "in_round", "kept_scene", "merge_round",
           "removed_pixels"]


@dataclass
class Carry:
    """What a round hands to the next: its prepared views (those still held), its renders
    R_i and R_i^-i, and which of its Gaussians it kept ((N,) bool). The next round, on the
    kept Gaussians, takes its views from these (``PreparedView.restrict``) and composites again
    only the tiles that the removed Gaussians touched. ``reveal``: per view, its reveal
    reference, where it applies and the neighbours it rendered (``(RenderResult, (H, W) bool,
    list)``; None without ``reveal_reference="quantile"``), made again in the same tiles.

    ``source``: the whole scene of the first round and the (N0,) bool mask of the Gaussians
    the next round runs on, where that round's scene is :func:`kept_scene` with ``light``: the
    native backend then projects the views it prepares afresh from the whole scene and
    restricts them (``PreparedView.restrict``), the same arrays bit for bit.

    ``reserve``: bytes that the rounds before hold besides what they hand on, for as long as
    the next round runs (:func:`held_bytes`); the next round's views leave room for them
    within ``FilterConfig.view_memory``."""

    views: object
    full: list
    excl: list
    keep: np.ndarray
    source: tuple | None = None
    reveal: list | None = None
    reserve: int = 0

    def nbytes(self) -> int:
        """Bytes held: the views still kept and the renders not yet dropped."""
        held = [r for r in self.full + self.excl if r is not None]
        held += [h[0] for h in self.reveal or () if h is not None]
        renders = sum(a.nbytes for r in held for a in r)
        return self.views.held_bytes + renders

    def release(self) -> None:
        """Drop everything held: the next round asks these views nothing more."""
        self.views.release(bits=True)
        self.full.clear()
        self.excl.clear()
        if self.reveal is not None:
            self.reveal.clear()


class KeptGaussians(Gaussians):
    """A later round's Gaussians: ``whole`` at the indices ``kept``, with ``means`` and
    ``opacities`` copied and ``scales``, ``quats`` and ``sh`` gathered from ``whole`` on each
    read. The native backend prepares a later round's views from the whole scene
    (:attr:`Carry.source`), so a round does not hold a second copy of what only projection
    reads: 28 bytes per Gaussian plus 12 per SH coefficient. ``extra`` is empty (the filter
    never reads it)."""

    def __init__(self, whole: Gaussians, kept: np.ndarray):
        self._whole, self._kept = whole, np.asarray(kept)
        self.means = whole.means[self._kept]
        self.opacities = whole.opacities[self._kept]
        self.extra = {}

    scales = property(lambda self: self._whole.scales[self._kept])
    quats = property(lambda self: self._whole.quats[self._kept])
    sh = property(lambda self: self._whole.sh[self._kept])

    @property
    def sh_degree(self) -> int:
        return self._whole.sh_degree


def kept_scene(scene: Scene, kept: np.ndarray, *, light: bool = False) -> Scene:
    """The scene a later round runs on: the Gaussians of ``scene`` at the indices ``kept``
    (ascending), without the per-Gaussian attributes the filter never reads
    (``Gaussians.extra``: a PLY's normals or features would be copied for nothing). With
    ``light`` its Gaussians are :class:`KeptGaussians`."""
    g = scene.gaussians
    gaussians = (KeptGaussians(g, kept) if light
                 else replace(g, extra={}).subset(kept))      # replace shares the arrays
    return Scene(gaussians, scene.view_id[kept], scene.pixel_id[kept], scene.cameras,
                 scene.images, scene.render_settings)


def held_bytes(result: FilterResult, scene: Scene, *others) -> int:
    """Bytes that stay held while a later round runs on ``scene`` besides its views and
    renders: the result of the rounds before (its keep mask, the arrays of its proposals and
    candidates), the arrays ``scene`` holds of its own (a kept scene's copies: not the shapes
    and colours :class:`KeptGaussians` gathers when read) and ``others`` (arrays, lists of
    arrays or None)."""
    g = scene.gaussians
    own = [g.means, g.opacities, scene.view_id, scene.pixel_id]
    if not isinstance(g, KeptGaussians):
        own += [g.scales, g.quats, g.sh]
    arrays = [result.keep, *own]
    for p in result.proposals:
        arrays += [a for a in vars(p).values() if isinstance(a, np.ndarray)]
    for c in result.candidates:
        arrays += [c.gaussians, c.expanded]
    for o in others:
        arrays += o if isinstance(o, list) else [o]
    return int(sum(a.nbytes for a in arrays if isinstance(a, np.ndarray)))


def in_round(report, round_: int):
    """``report`` with the stage names of a later round marked as such."""
    return lambda stage, done, total: report(f"{stage} (round {round_})", done, total)


def merge_round(result: FilterResult, later: FilterResult, kept: np.ndarray,
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
            p[loose] = cam.flat_pixels(scene.gaussians.means[where[sel][loose]])[0]
        mask[p[p >= 0]] = True
        out.append(mask.reshape(cam.height, cam.width))
    return out
