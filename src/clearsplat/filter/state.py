"""What every stage of one round reads: the round's scene, options and views.

A round of the filter (:func:`clearsplat.filter.pipeline.run_round`) builds one
:class:`RoundState` and hands it to each stage beside that stage's own inputs; the stages
return their outputs (renders, proposals, masks, candidates) instead of storing them here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..scene import Scene
from .association import ViewIndex
from .backend import FilterBackend
from .config import FilterConfig

__all__ = ["RoundState", "Clock", "Progress"]

Progress = Callable[[str, int, int], None]


@dataclass(eq=False)
class RoundState:
    """The constants of one round of the procedure.

    Attributes
    ----------
    scene : Scene
        The round's Gaussians (the first round: the whole prediction; a later one: what the
        rounds before kept), the input cameras and images.
    config : FilterConfig
    backend : FilterBackend
        The renderer the stages go through.
    index : ViewIndex
        Per view, its Gaussians and their pixels.
    own : OwnMasks
        Per view i (``own[i]``), (N,) bool of the Gaussians left out of R_i^-i: those
        predicted from view i, and with ``leave_out`` those of the views up to that many places
        before and after it. Built when asked, read-only.
    left_out : (V, V) bool
        ``left_out[i, v]``: view v's Gaussians are in ``own[i]``.
    tau1, tau2 : float
        The similarity thresholds (the config's, else the extractor's calibration).
    views : view set
        One prepared view per input camera (:meth:`FilterBackend.prepare_views`).
    plan : ViewPlan or None
        The views each camera's renders hold and each view's verification views
        (``neighbours``, ``verify_views``; None: the paper's).
    report : callable(stage, done, total)
        Progress.
    clock : Clock
        Seconds per stage and sub-stage (``"proposal.features"``, ...), the ``"proposal"``
        stage timed from the state's making.
    """

    scene: Scene
    config: FilterConfig
    backend: FilterBackend
    index: ViewIndex
    own: "OwnMasks"
    tau1: float
    tau2: float
    report: Progress
    left_out: np.ndarray = None
    views: object = None
    plan: object = None
    clock: "Clock" = field(default_factory=lambda: Clock())

    @classmethod
    def begin(cls, scene: Scene, config: FilterConfig, backend: FilterBackend, extractor,
              report: Progress) -> "RoundState":
        """The state of a round on ``scene``, its ``"proposal"`` stage timed from now."""
        index = ViewIndex(scene)
        v = scene.num_views
        gap = np.abs(np.arange(v)[:, None] - np.arange(v)[None, :])
        left_out = gap <= config.leave_out
        return cls(scene, config, backend, index,
                   own=OwnMasks(index, left_out),
                   tau1=extractor.tau1 if config.tau1 is None else config.tau1,
                   tau2=extractor.tau2 if config.tau2 is None else config.tau2,
                   report=report, left_out=left_out)

    @property
    def n(self) -> int:
        """Gaussians in the round."""
        return len(self.scene)

    @property
    def num_views(self) -> int:
        return self.scene.num_views

    def lap(self, step: str) -> None:
        """Add the seconds since the last lap to ``timings["<stage>.<step>"]`` (:class:`Clock`)."""
        self.clock.lap(step)

    def mask(self, *gaussians) -> np.ndarray:
        """(N,) bool of the int indices in ``gaussians`` (one or more index arrays)."""
        out = np.zeros(self.n, dtype=bool)
        for g in gaussians:
            out[g] = True
        return out


class OwnMasks:
    """``own[i]``: (N,) bool of the Gaussians left out of view i's exclusion render.

    Built from the views' members when asked (time proportional to those Gaussians plus one
    (N,) fill) and read-only; the last one is kept, since a stage asks for the same view
    several times in a row. Holding all of them would cost V x N bytes: 0.47 GB at 64 views
    of 7.3 M Gaussians.
    """

    def __init__(self, index, left_out: np.ndarray):
        self._index, self._left_out, self._n = index, left_out, index.n
        self._last = (None, None)

    def __len__(self) -> int:
        return len(self._left_out)

    def __getitem__(self, i) -> np.ndarray:
        i = range(len(self))[i]                    # an int in range, or IndexError/TypeError
        if self._last[0] != i:
            mask = self._index.views_mask(self._left_out[i], self._n)
            mask.flags.writeable = False
            self._last = (i, mask)
        return self._last[1]


class Clock:
    """Seconds per stage (``timings["proposal"]``, ``timings["verification"]``) and per step
    of a stage (``timings["proposal.features"]``), from the making of the clock on."""

    def __init__(self):
        self.timings = {"proposal": 0.0, "verification": 0.0}
        self._stage = "proposal"
        self._start = self._last = time.perf_counter()

    def stage(self, name: str) -> None:
        """Start timing stage ``name`` (``"proposal"`` or ``"verification"``)."""
        self._stage = name
        self._start = self._last = time.perf_counter()

    def end_stage(self) -> None:
        """Record the seconds of the stage started last."""
        self.timings[self._stage] = time.perf_counter() - self._start

    def lap(self, step: str) -> None:
        """Add the seconds since the last lap to ``timings["<stage>.<step>"]``."""
        now = time.perf_counter()
        key = f"{self._stage}.{step}"
        self.timings[key] = self.timings.get(key, 0.0) + now - self._last
        self._last = now
