"""The next round: what one round hands to the next, and how their results join.

From eight views on the default runs the procedure again on the Gaussians the first round
kept (``FilterConfig.rounds``): one view's distractor can hide another's in R_i^-i, and with
the first round's removals gone it shows. A later round on the CPU takes the round before's
prepared views, restricted to the kept Gaussians, and its renders, composited again only where
the removals touched (:class:`Carry`); both are exact, so a round equals a fresh run on what
the rounds before kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .result import FilterResult

__all__ = ["Carry", "in_round", "merge_round", "keep_changed_regions"]


@dataclass
class Carry:
    """What a round hands to the next: its prepared views (those still held; None where the
    backend does not hand them on), its renders R_i (empty then too) and R_i^-i, and which of
    its Gaussians it kept ((N,) bool). The next round, on the kept Gaussians, takes its views
    from these (``PreparedView.restrict``) and composites again only the tiles that the
    removed Gaussians touched; R_i^-i tells it where its own changed."""

    views: object
    full: list
    excl: list
    keep: np.ndarray

    def nbytes(self) -> int:
        """Bytes held: the views still kept and the renders not yet dropped."""
        renders = sum(a.nbytes for r in self.full + self.excl if r is not None for a in r)
        return (0 if self.views is None else self.views.held_bytes) + renders

    def release(self) -> None:
        if self.views is not None:
            self.views.release()
        self.full.clear()
        self.excl.clear()


def keep_changed_regions(proposals: list, changed: list) -> int:
    """Keep, in each view's proposal, only the regions a later round can decide otherwise.

    ``changed``: per view, the (H, W) bool pixels where R_i^-i differs from the round before's
    (:attr:`ExclusionRenders.changed <clearsplat.filter.exclusion.ExclusionRenders.changed>`;
    None: every pixel). Where the exclusion render did not change, the input, the render and
    so the similarity and the region are the round before's, which that round has decided; a
    region is kept when one of its cells, or a cell next to one (the similarity of a cell looks
    a little beyond it), holds a changed pixel (``FilterConfig.later_rounds="changed"``, off by
    default). The proposals' range masks stay whole. Returns how many regions were dropped.
    """
    from .proposal import cell_index_map
    dropped = 0
    for p, px in zip(proposals, changed):
        if px is None or not p.regions:
            continue
        grid = p.regions[0].cells.shape
        cells = cell_index_map(grid, *px.shape)
        hit = np.bincount(cells[px], minlength=grid[0] * grid[1]).reshape(grid) > 0
        pad = np.pad(hit, 1)
        hit = np.zeros_like(hit)
        for dy in range(3):             # with the 8 neighbours of each cell
            for dx in range(3):
                hit |= pad[dy:dy + grid[0], dx:dx + grid[1]]
        kept = [r for r in p.regions if (r.cells & hit).any()]
        dropped += len(p.regions) - len(kept)
        p.regions = kept
    return dropped


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
