"""Options of the distractor filter, with the paper's procedure as a preset.

Every departure from the paper is a named option here; ``docs/method.md`` gives the
ablation that justifies each default, and ``clearsplat bench --config`` reproduces it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from ..errors import ClearsplatError

__all__ = ["FilterConfig", "PRESETS"]


@dataclass(frozen=True)
class FilterConfig:
    """Options of :func:`clearsplat.filter_distractors`.

    Paper symbols in brackets. Thresholds left at ``None`` take the value calibrated
    for the chosen feature extractor.

    Attributes
    ----------
    features : str
        Feature extractor for the proposal similarity: ``"local"`` (weight-free, default),
        ``"rgb"`` (the paper's RGB-difference ablation), ``"dinov2"``, ``"dinov3"`` (the paper's
        choice; needs a local checkpoint).
    checkpoint : str or None
        Local checkpoint directory or cached model id for the DINO extractors.
    tau1, tau2 : float or None
        Similarity boundaries of the two proposal ranges [tau_1, tau_2].
    eta : float
        Support: minimum patch-mean accumulated opacity of the exclusion render [eta].
    num_verify_views : int
        Verification views per candidate [n_v].
    epsilon : float
        Pixels whose rendering change (L1 over RGB) is at most this are ignored [epsilon].
    dilation : int
        Radius in pixels of the dilation of accepted candidates before the final mapping.
    second_range : bool
        Propose from the second similarity range at all (False: single threshold below tau1).
    single_threshold : bool
        Merge both ranges into one below tau2, treated as first-range (the paper's
        "single threshold (< tau2)" ablation).
    verify : bool
        Run verification; False removes every proposal (the "without verification" ablation).
    verify_base : {"full", "exclude-own"}
        What the individual test renders each verification view from. ``"full"`` is the paper:
        all Gaussians, so the verifying view's own Gaussians reproduce its image. ``"exclude-own"``
        removes the verifying view's own Gaussians first, as the paper's additional test does.
    joint_base : {"exclude-own", "full"}
        What the joint test of the second-range candidates renders each view from (the paper says
        "the same error reduction" as the additional test; we read that as excluding each view's own
        Gaussians).
    refine : {"static-depth", "depth", "none"}
        ``"static-depth"``: a candidate keeps only the Gaussians of its view that lie in front of
        the surface the other views render at their pixel once every proposed Gaussian (of any
        view) is left out too (falling back to R_i^-i where that leaves a hole) — the paper's
        depth condition applied per Gaussian instead of per patch, against a reference that other
        views' distractors cannot occlude.
        ``"depth"``: the same against the plain exclusion render R_i^-i.
        ``"none"``: every Gaussian of the region (the paper).
    refine_margin : float
        Relative depth gap for ``refine="depth"``.
    refine_color : float or None
        With ``refine="static-depth"``: also keep Gaussians whose input colour differs from the
        static reference's colour by more than this (L1 over RGB) and that do not lie behind it
        (the parts of an object that touch the surface behind it). None: depth only.
    verify_mask : {"proposals+revealing", "proposals"}
        Pixels each verifying view leaves out. ``"proposals"``: its proposal regions (the paper).
        ``"proposals+revealing"``: also the pixels where its own Gaussians stand in front of the
        static reference (its own likely distractors, where the input does not show the static
        scene); needs ``refine`` other than ``"none"``.
    verify_holes : {"auto", "skip", "count"}
        Pixels where the render after a removal keeps accumulated opacity below ``eta`` show what
        no remaining Gaussian saw. ``"count"`` scores them against the empty background (the
        paper): with three or more views a hole is evidence that no third view supports the
        removal. ``"skip"`` leaves them out. ``"auto"`` counts them unless the scene has only two
        views, where every removal opens holes in the one verifying view (rendered without its
        own Gaussians) and counting them would forbid any removal.
    min_score : float
        Accept a test only when its score exceeds this (the paper: 0, i.e. positive).
    association_min_weight : float
        For scenes without ``pixel_id``: a Gaussian of the candidate's view belongs to a region when
        its blending weight (alpha * T) at some pixel of the region reaches this.
    incremental : bool
        Verify by re-compositing only the tiles a candidate touches (exact); False re-renders whole
        images (slow reference path).
    num_threads : int or None
        Threads of the native rasterizer (None: all cores).
    view_memory : float or None
        GB the prepared input views may hold at once on the CPU (about 60 bytes per Gaussian
        each camera sees); views beyond it are prepared again when read, which costs time but
        never changes the output. None: no limit.
    device : str
        ``"cpu"`` (the native rasterizer) or a CUDA device (``"cuda"``, ``"cuda:1"``...): every
        render then goes through gsplat on that GPU (needs PyTorch with CUDA and gsplat), and
        verification re-renders whole images (``incremental`` applies to the CPU only).
    """

    features: str = "local"
    checkpoint: str | None = None
    tau1: float | None = None
    tau2: float | None = None
    eta: float = 0.50
    num_verify_views: int = 3
    epsilon: float = 0.002
    dilation: int = 9
    second_range: bool = True
    single_threshold: bool = False
    verify: bool = True
    verify_base: Literal["full", "exclude-own"] = "exclude-own"
    joint_base: Literal["exclude-own", "full"] = "exclude-own"
    refine: Literal["static-depth", "depth", "none"] = "static-depth"
    refine_margin: float = 0.02
    refine_color: float | None = 0.5
    verify_mask: Literal["proposals+revealing", "proposals"] = "proposals+revealing"
    verify_holes: Literal["auto", "skip", "count"] = "auto"
    min_score: float = 0.0
    association_min_weight: float = 0.05
    incremental: bool = True
    num_threads: int | None = None
    view_memory: float | None = 2.0
    device: str = "cpu"

    def __post_init__(self):
        if not isinstance(self.device, str) or not (
                self.device == "cpu" or self.device == "cuda"
                or (self.device.startswith("cuda:") and self.device[5:].isdigit())):
            raise ClearsplatError(f"unknown device {self.device!r}; expected 'cpu', 'cuda' or "
                                  "'cuda:N'", field="device")
        if self.verify_base not in ("full", "exclude-own"):
            raise ClearsplatError(f"unknown value {self.verify_base!r}; expected 'full' or "
                                  "'exclude-own'", field="verify_base")
        if self.joint_base not in ("full", "exclude-own"):
            raise ClearsplatError(f"unknown value {self.joint_base!r}; expected 'full' or "
                                  "'exclude-own'", field="joint_base")
        if self.refine not in ("static-depth", "depth", "none"):
            raise ClearsplatError(f"unknown value {self.refine!r}; expected 'static-depth', "
                                  "'depth' or 'none'", field="refine")
        if self.verify_mask not in ("proposals+revealing", "proposals"):
            raise ClearsplatError(f"unknown value {self.verify_mask!r}; expected "
                                  "'proposals+revealing' or 'proposals'", field="verify_mask")
        if self.verify_mask == "proposals+revealing" and self.refine == "none":
            raise ClearsplatError("'proposals+revealing' needs refine other than 'none'",
                                  field="verify_mask")
        if self.verify_holes not in ("auto", "skip", "count"):
            raise ClearsplatError(f"unknown value {self.verify_holes!r}; expected 'auto', "
                                  "'skip' or 'count'", field="verify_holes")
        if self.view_memory is not None and not (
                isinstance(self.view_memory, (int, float)) and not isinstance(self.view_memory, bool)
                and self.view_memory > 0
                and self.view_memory < float("inf")):
            raise ClearsplatError(f"expected a positive number of GB or None, got "
                                  f"{self.view_memory!r}", field="view_memory")
        if self.num_verify_views < 1:
            raise ClearsplatError("must be at least 1", field="num_verify_views")
        if self.dilation < 0:
            raise ClearsplatError("must be >= 0", field="dilation")
        if self.tau1 is not None and self.tau2 is not None and not self.tau1 < self.tau2:
            raise ClearsplatError(f"tau1 ({self.tau1}) must be below tau2 ({self.tau2})",
                                  field="tau1/tau2")

    @classmethod
    def preset(cls, name: str, **overrides) -> "FilterConfig":
        """A named configuration, optionally with some fields overridden.

        ``"paper"`` is the paper's procedure exactly (DINOv3 features, individual test from the
        full representation); ``"default"`` is clearsplat's default.
        """
        if name not in PRESETS:
            raise ClearsplatError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}",
                                  field="preset")
        return dataclasses.replace(PRESETS[name], **overrides)

    def replace(self, **changes) -> "FilterConfig":
        """A copy with some fields changed."""
        names = {f.name for f in dataclasses.fields(self)}
        for k in changes:
            if k not in names:
                raise ClearsplatError(f"unknown option {k!r}", field=k)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


PRESETS = {
    # clearsplat's default (see docs/method.md for each departure and its ablation).
    "default": FilterConfig(),
    # The paper's procedure exactly (DINOv3 features need a local checkpoint).
    "paper": FilterConfig(features="dinov3", verify_base="full", joint_base="exclude-own",
                          refine="none", verify_mask="proposals", verify_holes="count",
                          min_score=0.0),
    # The paper's procedure with the weight-free features in place of DINOv3: what runs anywhere.
    "paper-local": FilterConfig(features="local", verify_base="full", joint_base="exclude-own",
                                refine="none", verify_mask="proposals", verify_holes="count",
                                min_score=0.0),
}
