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

    def __init__(self, num_gaussians: int, cameras, make: Callable, *, budget: int | None):
        self.num_gaussians = int(num_gaussians)
        self.cameras = list(cameras)
        self._make = make
        self.budget = budget
        self._kept: dict = {}       # view -> PreparedView, in the order they were prepared
        self._seen: list = [None] * len(self.cameras)   # packed visibility bits per view
        self._counts: list = [None] * len(self.cameras)
        self.prepared = 0
        self.peak_bytes = 0
        self.skipped = 0

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getitem__(self, i: int):
        view = self._kept.get(i)
        if view is not None:
            return view
        view = self._make(i)
        self.prepared += 1
        if self._seen[i] is None:
            seen = np.zeros(self.num_gaussians, dtype=bool)
            seen[view.visible] = True
            self._seen[i] = np.packbits(seen)
        self._kept[i] = view
        self._fit(i)
        return view

    def _bytes(self) -> int:
        return sum(v.memory_bytes for v in self._kept.values())

    def _fit(self, current: int) -> None:
        """Drop the most recently prepared views other than ``current`` until within budget."""
        held = self._bytes()
        self.peak_bytes = max(self.peak_bytes, held)
        if self.budget is None:
            return
        for j in reversed(list(self._kept)):
            if held <= self.budget:
                break
            if j != current:
                held -= self._kept.pop(j).memory_bytes

    def release(self) -> None:
        """Drop every kept view (the visibility bits stay)."""
        self._kept.clear()

    def sees_any(self, i: int, gaussians: np.ndarray) -> bool:
        """Whether camera ``i`` sees any of ``gaussians`` (int indices), without preparing it.

        Only for views prepared at least once (every view is, by the exclusion renders).
        """
        g = np.asarray(gaussians)
        if g.size == 0:
            return False
        bits = self._seen[i]
        return bool(((bits[g >> 3] >> (7 - (g & 7))) & 1).any())
