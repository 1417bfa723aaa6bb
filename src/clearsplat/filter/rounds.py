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

__all__ = ["Carry", "in_round", "merge_round"]


@dataclass
class Carry:
    """What a round hands to the next: its prepared views (those still held), its renders
    R_i and R_i^-i, and which of its Gaussians it kept ((N,) bool). The next round, on the
    kept Gaussians, takes its views from these (``PreparedView.restrict``) and composites again
    only the tiles that the removed Gaussians touched."""

    views: object
    full: list
    excl: list
    keep: np.ndarray

    def nbytes(self) -> int:
        """Bytes held: the views still kept and the renders not yet dropped."""
        renders = sum(a.nbytes for r in self.full + self.excl if r is not None for a in r)
        return self.views.held_bytes + renders

    def release(self) -> None:
        """Drop everything held: the next round asks these views nothing more."""
        self.views.release(bits=True)
        self.full.clear()
        self.excl.clear()


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
