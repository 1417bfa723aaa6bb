"""Options of the distractor filter, with the paper's procedure as a preset.

Every departure from the paper is a named option here; ``docs/method.md`` gives the
ablation that justifies each default, and ``clearsplat bench --config`` reproduces it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np

from ..errors import ClearsplatError

__all__ = ["FilterConfig", "PRESETS", "FIELD_SPECS", "FieldSpec", "parse_value"]


@dataclass(frozen=True)
class FieldSpec:
    """What one :class:`FilterConfig` field accepts; :data:`FIELD_SPECS` holds one per field.

    Attributes
    ----------
    kind : {"number", "integer", "bool", "choice", "text"}
        ``"number"``: a finite real (stored as ``float``); ``"integer"``: an integer (not a bool);
        ``"bool"``: True or False; ``"choice"``: one of ``choices``; ``"text"``: a string (or
        path) that ``test`` accepts.
    low, high : float or None
        Bounds of a number or integer (None: unbounded); ``low_open`` / ``high_open`` exclude
        the bound itself.
    choices : tuple of str
        The allowed strings of a ``"choice"``.
    optional : bool
        None is allowed too.
    test : callable or None
        For ``"text"``: returns True for an allowed string; ``what`` describes those strings.
    also : tuple of str
        Strings allowed besides the values of ``kind`` (e.g. ``"auto"`` for an integer).
    """

    kind: Literal["number", "integer", "bool", "choice", "text"]
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple = ()
    optional: bool = False
    test: Callable[[str], bool] | None = None
    what: str = ""
    also: tuple = ()

    def allowed(self) -> str:
        """What the field accepts, in words (used in error messages and docs)."""
        if self.kind == "bool":
            text = "true or false"
        elif self.kind == "choice":
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        elif self.kind == "text":
            text = self.what or "a string"
        else:
            noun = "a number" if self.kind == "number" else "an integer"
            lo, hi = self.low, self.high
            if lo is not None and hi is not None:
                text = (f"{noun} in {'(' if self.low_open else '['}{_num(lo)}, "
                        f"{_num(hi)}{')' if self.high_open else ']'}")
            elif lo is not None:
                text = f"{noun} {'>' if self.low_open else '>='} {_num(lo)}"
            elif hi is not None:
                text = f"{noun} {'<' if self.high_open else '<='} {_num(hi)}"
            else:
                text = "a finite number" if self.kind == "number" else noun
        text += "".join(f" or {a!r}" for a in self.also)
        return text + (" or None" if self.optional else "")

    def check(self, name: str, value):
        """``value`` in its stored type (float for numbers, int for integers, str for text), or
        :class:`ClearsplatError` naming the field, the value and what is allowed."""
        if value is None and self.optional:
            return None
        if isinstance(value, str) and value in self.also:
            return value
        ok, out = False, value
        if self.kind == "bool":
            ok = isinstance(value, (bool, np.bool_))
            out = bool(value) if ok else value
        elif self.kind == "choice":
            ok = isinstance(value, str) and value in self.choices
        elif self.kind == "text":
            if isinstance(value, os.PathLike):
                out = os.fspath(value)
            ok = isinstance(out, str) and (self.test is None or self.test(out))
        elif not isinstance(value, (bool, np.bool_)):
            if self.kind == "integer" and isinstance(value, numbers.Integral):
                ok, out = True, int(value)
            elif self.kind == "number" and isinstance(value, numbers.Real):
                out = float(value)
                ok = math.isfinite(out)
            if ok:
                ok = ((self.low is None or (out > self.low if self.low_open else out >= self.low))
                      and (self.high is None
                           or (out < self.high if self.high_open else out <= self.high)))
        if not ok:
            raise ClearsplatError(f"got {value!r}; expected {self.allowed()}", field=name)
        return out


def _num(x: float) -> str:
    return f"{x:g}"


def _is_device(text: str) -> bool:
    return text in ("cpu", "cuda") or (text.startswith("cuda:") and text[5:].isdigit())


@dataclass(frozen=True)
class FilterConfig:
    """Options of :func:`clearsplat.filter_distractors`.

    Paper symbols in brackets. Thresholds left at ``None`` take the value calibrated
    for the chosen feature extractor. Every field is checked on construction against its entry
    in :data:`FIELD_SPECS` (type and range); a wrong value raises :class:`ClearsplatError`
    naming the field, the value and what is allowed.

    Attributes
    ----------
    features : str
        Feature extractor for the proposal similarity: ``"local"`` (weight-free, default),
        ``"rgb"`` (the paper's RGB-difference ablation), ``"dinov2"``, ``"dinov3"`` (the paper's
        choice; needs a local checkpoint).
    checkpoint : str or None
        Local checkpoint directory or cached model id for the DINO extractors.
    tau1, tau2 : float or None
        Similarity boundaries of the two proposal ranges [tau_1, tau_2]. None: the
        extractor's calibration (0.51 and 0.69 for ``"local"``, 0.63 and 0.80 for ``"rgb"``, the
        paper's 0.50 and 0.70 for DINO).
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
    verify_base : {"full", "exclude-own", "static"}
        What the individual test renders each verification view from. ``"full"`` is the paper:
        all Gaussians, so the verifying view's own Gaussians reproduce its image. ``"exclude-own"``
        removes the verifying view's own Gaussians first, as the paper's additional test does.
        ``"static"`` (the default) also removes the candidates of every other view than the
        tested candidate's, so that another view's distractor standing in front of it in the
        verifying view does not hide what its removal changes, as the static reference of
        ``refine`` leaves every proposal out (docs/method.md, "`verify_base="static"`").
    refine : {"static-depth", "depth", "none"}
        ``"static-depth"``: a candidate keeps only the Gaussians of its view that lie in front of
        the surface the other views render at their pixel once every proposed Gaussian (of any
        view) is left out too (falling back to R_i^-i where that leaves a hole) — the paper's
        depth condition applied per Gaussian instead of per patch, against a reference that other
        views' distractors cannot occlude.
        ``"depth"``: the same against the plain exclusion render R_i^-i.
        ``"none"``: every Gaussian of the region (the paper). With refinement, the default's
        departures that read it follow: each view's depths at its own scale and noise, a
        colour test within each view's measured misregistration, two passes of the static
        reference, candidates the other views' colours explain rejected, flying pixels at
        outlines kept, the pixels in front left out of verification and grown into by the
        expansion (the constants of :mod:`clearsplat.filter.refine`; docs/method.md).
    verify_holes : {"auto", "skip", "count"}
        Pixels where the render after a removal keeps accumulated opacity below ``eta`` show what
        no remaining Gaussian saw. ``"count"`` scores them against the empty background (the
        paper): with three or more views a hole is evidence that no third view supports the
        removal. ``"skip"`` leaves them out. ``"auto"`` counts them unless the scene has only two
        views, where every removal opens holes in the one verifying view (rendered without its
        own Gaussians) and counting them would forbid any removal.
    incremental : bool
        Verify by re-compositing only the tiles a candidate touches (exact); False re-renders whole
        images (slow reference path).
    num_threads : int or None
        Threads of the native rasterizer and of the per-view NumPy steps (feature pairs, the
        depth test) (None: all cores, at most ``OMP_NUM_THREADS``). Never changes the output.
    view_memory : float or None
        GB the prepared input views may hold at once on the CPU (about 60 bytes per Gaussian
        each camera sees); views beyond it are prepared again when read, which costs time but
        never changes the output. A later round (``rounds``) gives its views this less what
        stays held while it runs (the result of the rounds before, its copy of the kept
        Gaussians), so that it peaks about where the first does. None: no limit.
    min_relative_score : float
        Also require each test's removal to take away more than this share of the
        change-weighted error of the pixels it changes (``sum(w delta) / sum(w E)``, see
        :attr:`clearsplat.filter.verify.Partial.relative_score`). A distractor's removal
        explains most of the error where it changes the render; static content that the views
        merely place a little differently (pose error, depth scale) trades one error for another
        and scores a small share even when its score is positive. Default 0.2; 0: the paper.
    rounds : int or "auto"
        How often the whole procedure runs. Each later round runs it again on the Gaussians
        the earlier rounds kept, so that the distractors found so far no longer stand in the
        exclusion renders, the support condition and the static reference of the others:
        another view's distractor in front of a view's own hides it there (no farther
        surface is revealed, or the static reference is nearer), and one at nearly the same
        place (someone walking) lends it support. Stops early when a round removes nothing.
        ``"auto"``: two rounds from eight views on, one below (measured: the second round
        takes about half as long as the first at 16 views and two thirds at 8; it gains
        0.58 dB at 16 views, 0.18 dB at 8 and 0.02 dB at 4, and at 8 views it finds most of
        the passers-by that ``min_relative_score`` rejects in the first round, once the other
        views' passers-by that their removal uncovered are gone). 1: the paper (a single run).
    verify_hidden : float or None
        An accepted candidate removes only the Gaussians of hat C_k that at least one of its
        verifying views sees: whose centre, projected into that view, lies at most this share
        of the depth behind the view's own surface there (the nearest of its own Gaussians at
        that pixel; a pixel without any counts as seen). A Gaussian behind the surface of every
        verifying view is hidden from all of them; their images say nothing about it, so it
        stays (a surface only the candidate's view sees, such as the side of an object the
        other cameras face away from, goes with a candidate only where it shows). None: every
        Gaussian of hat C_k (the paper).
    leave_out : int
        Views on each side, in input order, whose Gaussians R_i^-i also leaves out with view
        i's own, and which do not verify view i. For video: a passer-by who stays for a few
        consecutive frames is in the neighbouring frames' predictions too, where R_i^-i would
        show him instead of the surface behind. 0: the paper (only view i's own).
    reveal_reference : {"composite", "quantile"}
        What the proposal (similarity and support) and refinement compare view i with.
        ``"quantile"`` (the default): the reveal reference (:mod:`clearsplat.filter.reveal`):
        the seven views that share the most of view i's field of view and see its scene from
        within 30 degrees, each rendered into camera i on its own, and per pixel the one at the
        0.75 quantile of their depths (where at least four of them cover it; R_i^-i
        elsewhere, so up to four input views, or where fewer views are that near, the output is
        the composite's; the constants of :mod:`clearsplat.filter.reveal`). Transients stand in
        front of the static surface, so the farther quantile still shows it where other views
        hold passers-by in front of it, as R_i^-i does not: several neighbouring frames of a
        video hold the same one, and every other view of a dense capture brings its own.
        ``"composite"``: the paper's R_i^-i. Verification keeps R_i^-i.
    verify_views : {"auto", "centres", "mutual"}
        How each view's verification views V_i are chosen. ``"auto"``: ``"mutual"`` where
        ``neighbours`` (as ``"auto"`` resolves it) bounds the neighbourhoods, ``"centres"``
        otherwise. ``"centres"``: the paper, the
        ``num_verify_views`` views that see the most centres of its Gaussians inside their
        image (ties to the lower index). ``"mutual"``: those that share the most of its field
        of view both ways (:func:`clearsplat.filter.neighbours.covisibility`, ``C[j, i] +
        C[i, j]``): in a capture that moves forward every camera behind view i sees all of
        its Gaussians, small and far, and the paper's count ties them and picks the first
        frames; the mutual share picks the nearest.
    neighbours : int or None
        Bounded neighbourhoods: each input camera's renders (R_i, R_i^-i, the static reference
        and verification's bases) hold only the Gaussians of the ``neighbours`` other views
        that share the most of its field of view, and of the views it verifies
        (:mod:`clearsplat.filter.neighbours`); the work then grows with views times
        ``neighbours`` instead of the square of the views. Exact (the same output as None)
        while the scene has at most ``neighbours + 1`` views. None: every view, the paper.
        ``"auto"``: 7 from 24 views on, every view below
        (:func:`clearsplat.filter.neighbours.dense_options`; measured in docs/method.md,
        "Dense captures").
    device : str
        ``"cpu"`` (the native rasterizer) or a CUDA device (``"cuda"``, ``"cuda:1"``...): every
        render then goes through gsplat on that GPU (``backend="auto"``; the torch backend on it
        with ``backend="torch"``) (needs PyTorch with CUDA and gsplat), and
        verification re-renders whole images (``incremental`` applies to the CPU only).
    backend : {"auto", "native", "gsplat", "torch"}
        The renderer behind the stages (:mod:`clearsplat.filter.backend`). ``"auto"``: the
        native rasterizer on ``"cpu"``, gsplat on a CUDA device. ``"native"``: the native CPU
        rasterizer (``device="cpu"`` only). ``"gsplat"``: gsplat (a CUDA device only).
        ``"torch"``: the native rasterizer's math in batched torch ops on ``device`` (CPU
        tensors on ``"cpu"``), incremental verification with every removal of a view in one
        batch (:mod:`clearsplat.render.torch_view`; needs ``pip install clearsplat[gpu]``).
        Renders agree with the native ones to float32 rounding, and so do the decisions but
        for threshold tests met within that rounding (``docs/method.md``, "The torch backend").
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
    verify_base: Literal["full", "exclude-own", "static"] = "static"
    refine: Literal["static-depth", "depth", "none"] = "static-depth"
    verify_holes: Literal["auto", "skip", "count"] = "auto"
    incremental: bool = True
    num_threads: int | None = None
    view_memory: float | None = 2.0
    device: str = "cpu"
    min_relative_score: float = 0.2
    rounds: int | str = "auto"
    neighbours: int | None | str = "auto"
    verify_views: Literal["auto", "centres", "mutual"] = "auto"
    verify_hidden: float | None = 0.05
    leave_out: int = 0
    reveal_reference: Literal["composite", "quantile"] = "quantile"
    backend: Literal["auto", "native", "gsplat", "torch"] = "auto"

    def __post_init__(self):
        for f in dataclasses.fields(self):
            spec = FIELD_SPECS.get(f.name)
            if spec is not None:        # tests/test_config.py requires a spec for every field
                object.__setattr__(self, f.name, spec.check(f.name, getattr(self, f.name)))
        if self.tau1 is not None and self.tau2 is not None and not self.tau1 < self.tau2:
            raise ClearsplatError(f"tau1 ({self.tau1}) must be below tau2 ({self.tau2})",
                                  field="tau1/tau2")
        if self.backend == "native" and self.device != "cpu":
            raise ClearsplatError(f"'native' renders on the CPU only, not on {self.device!r}; "
                                  "set device='cpu' or choose backend 'gsplat' or 'torch'",
                                  field="backend")
        if self.backend == "gsplat" and self.device == "cpu":
            raise ClearsplatError("'gsplat' renders on a CUDA device only; set device='cuda' or "
                                  "choose backend 'native' or 'torch' for the CPU",
                                  field="backend")

    @classmethod
    def preset(cls, name: str, **overrides) -> "FilterConfig":
        """A named configuration, optionally with some fields overridden.

        ``"default"`` is clearsplat's default; ``"paper"`` is the paper's procedure exactly
        (DINOv3 features, individual test from the full representation), which needs
        ``pip install "clearsplat[dino]"`` and a local checkpoint
        (``FilterConfig.preset("paper", checkpoint="/path/to/dinov3")``); ``"paper-local"`` is
        the paper's procedure with the weight-free ``"local"`` features. ``"exact"`` is the
        default without its approximations for dense captures (every view in every camera's
        renders); ``"video"`` is for the frames of a video (``leave_out=1``; ``docs/method.md``,
        "Video"); ``"fast"`` trades recall for time (one
        round, four neighbours per camera; ``docs/method.md``, "The fast preset").
        """
        if name not in PRESETS:
            raise ClearsplatError(f"unknown preset {name!r}; choose one of "
                                  f"{', '.join(repr(p) for p in PRESETS)}",
                                  field="preset")
        return dataclasses.replace(PRESETS[name], **overrides)

    def replace(self, **changes) -> "FilterConfig":
        """A copy with some fields changed."""
        names = {f.name for f in dataclasses.fields(self)}
        for k in changes:
            if k not in names:
                raise ClearsplatError(f"unknown option {k!r}; the options are "
                                      f"{', '.join(sorted(names))}", field=k)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def describe(self) -> str:
        """The preset this config equals (``"preset 'default'"``), or the nearest preset and
        the fields that differ from it (``"preset 'default' with eta=0.4"``)."""
        fields = [f.name for f in dataclasses.fields(self)]
        diff = {name: [k for k in fields if getattr(p, k) != getattr(self, k)]
                for name, p in PRESETS.items()}
        name = min(diff, key=lambda n: len(diff[n]))
        if not diff[name]:
            return f"preset {name!r}"
        return f"preset {name!r} with " + ", ".join(f"{k}={getattr(self, k)!r}"
                                                    for k in diff[name])


def _unit(**kw) -> FieldSpec:
    return FieldSpec("number", 0.0, 1.0, **kw)


#: What each :class:`FilterConfig` field accepts. Every field has an entry (a test checks it):
#: a new field needs its spec here.
FIELD_SPECS: dict[str, FieldSpec] = {
    "features": FieldSpec("choice", choices=("local", "rgb", "dinov2", "dinov3")),
    "checkpoint": FieldSpec("text", optional=True, test=bool,
                            what="a checkpoint directory or model id"),
    "tau1": FieldSpec("number", -1.0, 1.0, optional=True),
    "tau2": FieldSpec("number", -1.0, 1.0, optional=True),
    "eta": _unit(),
    "num_verify_views": FieldSpec("integer", 1),
    "epsilon": FieldSpec("number", 0.0, 3.0),           # L1 over RGB in [0, 1]: at most 3
    "dilation": FieldSpec("integer", 0),
    "second_range": FieldSpec("bool"),
    "single_threshold": FieldSpec("bool"),
    "verify": FieldSpec("bool"),
    "verify_base": FieldSpec("choice", choices=("full", "exclude-own", "static")),
    "refine": FieldSpec("choice", choices=("static-depth", "depth", "none")),
    "verify_holes": FieldSpec("choice", choices=("auto", "skip", "count")),
    "incremental": FieldSpec("bool"),
    "num_threads": FieldSpec("integer", 1, optional=True),
    "view_memory": FieldSpec("number", 0.0, low_open=True, optional=True),
    "device": FieldSpec("text", test=_is_device, what="'cpu', 'cuda' or 'cuda:N'"),
    "min_relative_score": FieldSpec("number", 0.0, 1.0, high_open=True),
    "rounds": FieldSpec("integer", 1, also=("auto",)),
    "neighbours": FieldSpec("integer", 1, optional=True, also=("auto",)),
    "verify_views": FieldSpec("choice", choices=("auto", "centres", "mutual")),
    "verify_hidden": FieldSpec("number", 0.0, optional=True),
    "leave_out": FieldSpec("integer", 0),
    "reveal_reference": FieldSpec("choice", choices=("composite", "quantile")),
    "backend": FieldSpec("choice", choices=("auto", "native", "gsplat", "torch")),
}


PRESETS = {
    # clearsplat's default (see docs/method.md for each departure and its ablation).
    "default": FilterConfig(),
    # The paper's procedure exactly (DINOv3 features need a local checkpoint).
    "paper": FilterConfig(features="dinov3", verify_base="full", refine="none",
                          verify_holes="count", min_relative_score=0.0, rounds=1,
                          neighbours=None, verify_views="centres", verify_hidden=None,
                          reveal_reference="composite"),
    # The paper's procedure with the weight-free features in place of DINOv3: what runs anywhere.
    "paper-local": FilterConfig(features="local", verify_base="full", refine="none",
                                verify_holes="count", min_relative_score=0.0, rounds=1,
                                neighbours=None, verify_views="centres", verify_hidden=None,
                                reveal_reference="composite"),
    # Today's default without the approximations that make it faster (bounded neighbourhoods
    # from 24 views on): the reference they are measured against (docs/method.md, "Dense
    # captures").
    "exact": FilterConfig(neighbours=None, verify_views="centres"),
    # The frames of a video: passers-by stay for several consecutive frames, so the frames
    # next to a view are also left out of its exclusion render, its reveal reference and its
    # verification (docs/method.md, "Video").
    "video": FilterConfig(leave_out=1),
    # Faster than the default, finding less: one round, and each camera's renders hold the
    # four views that share the most of its field of view (docs/method.md, "The fast preset").
    "fast": FilterConfig(rounds=1, neighbours=4),
}


def parse_value(text: str):
    """``"true"``/``"false"``, ``"null"`` (None), ints and floats from text; other text as is."""
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low == "null":
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text
