"""Prepared views of the input cameras, kept within a memory budget.

The filter reads every input camera's :class:`~clearsplat.render.PreparedView` in a few passes
(exclusion renders, static reference, individual, additional and joint tests). Each holds about
60 bytes per Gaussian the camera sees, so dense captures (many views of many Gaussians) would
need the square of the view count in memory. :class:`PreparedViews` keeps the views it can
within ``budget`` bytes and prepares the others again when they are read: preparing is
deterministic, so the renders, and so the filter's output, do not depend on the budget.

A pass visits the views in order, so the views kept are those prepared first (the most
recently prepared one is dropped to make room): a pass over V views with room for K of them
then prepares V - K views, where dropping the least recently used would prepare all V.

Alongside, each view keeps a packed bit per Gaussian (1/8 byte, whether its camera sees it)
so that verification can skip the views that a removal cannot change without preparing them.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["PreparedViews"]


class PreparedViews:
    """Sequence-like access to one prepared view per camera, within a memory budget.

    Parameters
    ----------
    num_gaussians : int
    cameras : sequence of Camera
    make : callable(i) -> PreparedView
        Prepares view ``i`` (deterministic).
    budget : int or None
        Bytes the kept views may hold (None: no limit). One view is always kept, whatever
        its size.

    skip_unseen : bool
        :meth:`sees` leaves out the views a removal cannot change (False: every view is
        visited, the full-render reference path).

    Attributes
    ----------
    prepared : int
        Views prepared so far (counting preparations again after a view was dropped).
    peak_bytes : int
        Most bytes held at once by kept views.
    skipped : int
        (view, removal) pairs the filter left out because the view sees none of the removal's
        Gaussians.
    """

    def __init__(self, num_gaussians: int, cameras, make: Callable, *, budget: int | None,
                 skip_unseen: bool = True):
        self.num_gaussians = int(num_gaussians)
        self.skip_unseen = skip_unseen
        self.cameras = list(cameras)
        self._make = make
        self.budget = budget
        self._kept: dict = {}       # view -> PreparedView, in the order they were prepared
        self._seen: list = [None] * len(self.cameras)   # packed visibility bits per view
        self._counts: list = [None] * len(self.cameras)
        self.prepared = 0
        self.peak_bytes = 0
        self._largest = 0           # bytes of the largest view prepared so far
        self.skipped = 0

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getitem__(self, i: int):
        view = self._kept.get(i)
        if view is not None:
            return view
        if self._make is None:
            raise RuntimeError(f"view {i} is asked for after its view set was released")
        # Room first, for a view as large as the largest so far: the kept views and the new
        # one together stay within the budget (one view over it otherwise).
        self._fit(None, incoming=self._largest)
        view = self._make(i)
        self.prepared += 1
        self._largest = max(self._largest, view.memory_bytes)
        if self._seen[i] is None:
            self._seen[i] = self._bits(view)
        self._kept[i] = view
        self._fit(i)
        return view

    @property
    def held_bytes(self) -> int:
        """Bytes the views kept now hold."""
        return sum(v.memory_bytes for v in self._kept.values())

    def _fit(self, current: int | None, *, incoming: int = 0) -> None:
        """Drop the most recently prepared views other than ``current`` until they hold at most
        the budget less ``incoming`` bytes (a view about to be prepared)."""
        held = self.held_bytes
        self.peak_bytes = max(self.peak_bytes, held)
        if self.budget is None:
            return
        for j in reversed(list(self._kept)):
            if held + incoming <= self.budget:
                break
            if j != current:
                held -= self._kept.pop(j).memory_bytes

    def _bits(self, view) -> np.ndarray:
        seen = np.zeros(self.num_gaussians, dtype=bool)
        seen[view.visible] = True
        return np.packbits(seen)

    def make_room(self, nbytes: int) -> None:
        """Drop the most recently prepared views until those kept and ``nbytes`` more fit the
        budget."""
        self._fit(None, incoming=nbytes)

    def hand_on(self) -> None:
        """Keep the views held now for the next round to :meth:`take`, and drop what only this
        round reads: the visibility bits and what prepares a view (with the round state it
        holds)."""
        self._seen = [None] * len(self.cameras)
        self._make = None

    def take(self, i: int):
        """View ``i`` if it is held, no longer held here (None otherwise)."""
        return self._kept.pop(i, None)

    def release(self, *, bits: bool = False) -> None:
        """Drop every kept view; with ``bits`` also the visibility bits (N / 8 bytes per view)
        and what prepares a view (and the round state it holds), once nothing asks for a view
        or :meth:`sees` any more."""
        self._kept.clear()
        if bits:
            self.hand_on()      # nothing is left to hand on

    def sees(self, j: int, gaussians) -> bool:
        """Whether view ``j`` can be changed by removing ``gaussians`` (int indices or (N,)
        bool): False only when its camera sees none of them (then every score term there is 0
        and the view is left out without being prepared; counted in :attr:`skipped`). Always
        True without ``skip_unseen``."""
        if not self.skip_unseen:
            return True
        g = np.asarray(gaussians)
        if self.sees_any(j, np.flatnonzero(g) if g.dtype == np.bool_ else g):
            return True
        self.skipped += 1
        return False

    def stats(self, *, derived: int) -> dict:
        """The counters of :attr:`FilterResult.stats <clearsplat.filter.FilterResult.stats>`;
        ``derived``: views a later round took from the round before."""
        return {"views_prepared": self.prepared, "views_derived": derived,
                "views_peak_bytes": self.peak_bytes, "views_skipped": self.skipped}

    def sees_any(self, i: int, gaussians: np.ndarray) -> bool:
        """Whether camera ``i`` sees any of ``gaussians`` (int indices), without preparing it.

        Only for views prepared at least once (every view is, by the exclusion renders).
        """
        g = np.asarray(gaussians)
        if g.size == 0:
            return False
        bits = self._seen[i]
        if bits is None:
            raise RuntimeError(f"view {i} was never prepared or its visibility was released")
        return bool(((bits[g >> 3] >> (7 - (g & 7))) & 1).any())
