"""What the filter returns: each candidate with its verdict, and the result of a run.

:class:`Candidate` carries the paper's symbols of one candidate region (its view, range,
pixels M_k, Gaussians C_k and expanded Gaussians hat C_k, verification views V_i) and what
verification made of it; :class:`FilterResult` the keep mask, every candidate and proposal,
the timings and the statistics of a run.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene import Scene
from .config import FilterConfig

__all__ = ["Candidate", "FilterResult"]


class _Mask:
    """The descriptor of :attr:`Candidate.pixels`. It holds the (H, W) bool array it is given,
    or an object whose ``pixels`` property makes that array on each read (a proposal's
    :class:`~clearsplat.filter.proposal.Region`, from its feature-grid cells: 1/256 of the
    memory at 16-pixel cells, which a dense capture's hundreds of candidates need)."""

    def __set_name__(self, owner, name: str) -> None:
        self._slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:     # read on the class: a field without a default
            raise AttributeError(self._slot[1:])
        value = obj.__dict__[self._slot]
        return value if isinstance(value, np.ndarray) else value.pixels

    def __set__(self, obj, value) -> None:
        obj.__dict__[self._slot] = value


@dataclass(eq=False)
class Candidate:
    """One candidate region and what verification made of it.

    Attributes
    ----------
    index : int
    view : int
        Input view it was proposed in.
    range : int
        Similarity range, 1 or 2.
    pixels : (H, W) bool
        The region [M_k]. A filter run's candidates hold it as the proposal's grid cells and
        make the array on each read (read-only: a copy to change it).
    gaussians : (M,) int64
        Gaussians the region maps to [C_k].
    expanded : (M',) int64 or None
        Gaussians of the dilated region within the support [hat C_k]: what the candidate
        removes where accepted, and what accepting it would remove otherwise
        (``clearsplat edit``). Every candidate of a filter run has one; None only before
        expansion.
    verify_views : list of int
        The verification views [V_i].
    scores : dict of str to float
        ``"individual"``, ``"additional"`` and ``"joint"`` where run; ``"color"`` and
        ``"color_bound"`` where the colour-explained test judged it (explained when the first is at
        most the second).
    accepted : bool
    reason : str
        Why it was accepted or rejected.
    round : int
        The round of the procedure that found it (``FilterConfig.rounds``).
    """

    index: int
    view: int
    range: int
    pixels: np.ndarray = _Mask()
    gaussians: np.ndarray
    expanded: np.ndarray | None = None
    verify_views: list = field(default_factory=list)
    scores: dict = field(default_factory=dict)
    accepted: bool = False
    reason: str = "not verified"
    round: int = 1

    def __repr__(self) -> str:
        scores = ", ".join(f"{k} {v:+.4f}" for k, v in self.scores.items())
        return (f"Candidate({self.index}: view {self.view}, range {self.range}, "
                f"{int(self.pixels.sum()):,} pixels, {self.gaussians.size:,} Gaussians"
                f"{'; ' + scores if scores else ''}; {self.reason})")

    def record(self) -> dict:
        """A JSON-friendly summary."""
        return {
            "index": self.index, "view": self.view, "range": self.range,
            "pixels": int(self.pixels.sum()), "gaussians": int(self.gaussians.size),
            "expanded_gaussians": None if self.expanded is None else int(self.expanded.size),
            "verify_views": list(self.verify_views),
            "scores": {k: float(v) for k, v in self.scores.items()},
            "accepted": bool(self.accepted), "reason": self.reason, "round": self.round,
        }


@dataclass(eq=False)
class FilterResult:
    """What :func:`filter_distractors` found.

    Attributes
    ----------
    keep : (N,) bool
        False for the Gaussians to remove (set their opacity to zero).
    candidates : list of Candidate
    proposals : list of ViewProposal
        Per input view: similarity map, support, ranges, proposal masks (of the first round).
    timings : dict of str to float
        Seconds per stage.
    config : FilterConfig
    warnings : list of str
    stats : dict
        ``views_prepared``: camera preparations made (the number of views, plus those prepared
        again under ``config.view_memory``); ``views_derived``: those a later round took from
        the round before (restricted to the Gaussians it kept, not projected again);
        ``views_peak_bytes``: most bytes the prepared views held at once; ``views_skipped``:
        (view, removal) pairs left out because the view sees none of the removal's Gaussians.
        With several rounds (``config.rounds``) the counts and ``timings`` add up over the
        rounds and the byte figures are the largest of any round.
    """

    keep: np.ndarray
    candidates: list
    proposals: list
    timings: dict
    config: FilterConfig
    warnings: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)

    @classmethod
    def unchanged(cls, n: int, config: FilterConfig, message: str,
                  timings: dict) -> FilterResult:
        """Every one of ``n`` Gaussians kept, nothing proposed, and ``message`` (why) as the
        result's warning."""
        return cls(np.ones(n, bool), [], [], timings, config, [message])

    def __repr__(self) -> str:
        accepted = sum(c.accepted for c in self.candidates)
        warned = f"; {len(self.warnings)} warning(s)" if self.warnings else ""
        return (f"FilterResult(removed {int((~self.keep).sum()):,} of {self.keep.size:,} "
                f"Gaussians; {accepted} of {len(self.candidates)} candidates accepted; "
                f"{self.config.describe()}; {self.timings.get('total', 0.0):.2f} s{warned})")

    @property
    def removed(self) -> np.ndarray:
        """(N,) bool: the Gaussians removed."""
        return ~self.keep

    def keep_tensor(self, device="cpu"):
        """:attr:`keep` as an (N,) ``torch.bool`` tensor on ``device`` (a torch device or its
        name), for masking a prediction that stays on the GPU: ``opacities * keep``.

        Needs PyTorch (``pip install clearsplat[gpu]``).
        """
        from ..render.torch_view import import_torch
        torch = import_torch(device)
        return torch.from_numpy(np.ascontiguousarray(self.keep)).to(device)

    def apply(self, scene: Scene) -> Scene:
        """The filtered scene: removed Gaussians get opacity zero, nothing else changes."""
        return scene.with_opacities(np.where(self.keep, scene.gaussians.opacities, 0.0))

    def summary(self) -> dict:
        """A JSON-friendly summary: config, counts, candidates, timings."""
        return {
            "config": self.config.to_dict(),
            "gaussians": int(self.keep.size),
            "removed": int((~self.keep).sum()),
            "candidates": [c.record() for c in self.candidates],
            "accepted": int(sum(c.accepted for c in self.candidates)),
            "timings": {k: round(float(v), 4) for k, v in self.timings.items()},
            "warnings": list(self.warnings),
        }
