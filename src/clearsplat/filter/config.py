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
        ``"none"``: every Gaussian of the region (the paper).
    refine_margin : float
        Relative depth gap that counts as "in front" of the reference in refinement
        (``refine="depth"`` and ``"static-depth"``): a Gaussian qualifies below
        ``(1 - refine_margin)`` times the reference depth at its pixel.
    refine_color : float or None
        With ``refine="static-depth"``: also keep Gaussians whose input colour differs from the
        static reference's colour by more than this (L1 over RGB) and that do not lie behind it
        (the parts of an object that touch the surface behind it). None: depth only.
    verify_mask : {"auto", "proposals+revealing", "proposals", "revealing"}
        Pixels each verifying view leaves out. ``"proposals"``: its proposal regions (the paper).
        ``"proposals+revealing"``: also the pixels where its own Gaussians stand in front of the
        static reference (its own likely distractors, where the input does not show the static
        scene). ``"revealing"``: only those: a proposal region of the verifying view is often
        caused by the candidate itself (another view's distractor standing in its exclusion
        render), and leaving it out leaves out the very pixels that would confirm the
        candidate. ``"auto"``: ``"revealing"`` with eight or more views, where neighbouring
        views see each distractor at nearly the same place; ``"proposals+revealing"`` with
        fewer, where the proposal regions also keep static candidates from passing on clean
        scenes.
        All but ``"proposals"`` need ``refine`` other than ``"none"``.
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
    depth_scale_align : bool
        Judge "in front of the static surface" (``refine``) in each view's own depth scale: its
        depths divided by their median ratio to the static reference first, and the margin
        widened to 2.5 robust standard deviations of that ratio where the view's depths are
        noisier. False: the paper.
    refine_tolerance : int or "auto"
        Radius in pixels of the misregistration the ``refine`` tests tolerate: a Gaussian is in
        front of the static reference only if it is in front of the nearest surface the other
        views render within this radius, and its colour differs only if it lies outside the range
        of their colours there (:func:`clearsplat.filter.robust.tolerant_reference`). 0: the
        tests at the Gaussian's own pixel. ``"auto"``: per view, the misregistration measured
        between its input and its exclusion render
        (:func:`clearsplat.filter.robust.misregistration`; 0 where the views agree).
    min_relative_score : float
        Also require each test's removal to take away more than this share of the
        change-weighted error of the pixels it changes (``sum(w delta) / sum(w E)``, see
        :attr:`clearsplat.filter.verify.Partial.relative_score`). A distractor's removal
        explains most of the error where it changes the render; static content that the views
        merely place a little differently (pose error, depth scale) trades one error for another
        and scores a small share even when its score is positive. Default 0.2; 0: the paper.
    color_explained : float or None
        Reject a candidate whose removal would take away only what the other views already show
        where its view shows it, within that view's misregistration: static content out of
        register (a pose or depth-scale error), not a transient. Per Gaussian, the colour
        distance is the L1 distance of its view's input colour to the range of the static
        reference's colours within the ``refine_tolerance`` radius
        (:func:`clearsplat.filter.refine.color_distances`); a candidate that passed its
        individual test is explained when the median over its expanded Gaussians [hat C_k] is at
        most this quantile of the same distance over its view's Gaussians outside every proposal
        region (how closely the other views reproduce that view's static content); both count
        only the Gaussians where the last refinement pass's static reference has a colour. An
        explained candidate is rejected; one of the second range then takes no part in the
        additional and joint tests. Applies with ``refine="static-depth"`` (whose reference it
        reads) and ``verify``, and is ignored otherwise. Default 0.75; None: the paper (every
        candidate that passes is removed).
    silhouette_explained : float or None
        Keep the flying pixels at a distractor's outline: a depth network blurs depth across
        the outline, so the Gaussians of the surface pixels next to a distractor float in front
        of that surface while showing its colour. Per view, a Gaussian that the refinement
        keeps is kept in the scene instead where its pixel has an 8-neighbour holding none of
        the view's kept Gaussians (the outline of what stands in front) and its colour
        distance (as for ``color_explained``) is at most this quantile of the distances of its
        view's Gaussians outside every proposal region. Applies with
        ``refine="static-depth"``. Default 0.75; None: off (the paper has no refinement).
    widened_band_color : float or None
        With ``depth_scale_align``: where a view's depth noise widens its refinement margin, a
        Gaussian in front of the static reference by more than ``refine_margin`` but less than
        the widened margin also qualifies when its colour distance (as for
        ``color_explained``) exceeds this quantile of the distances of its view's Gaussians
        outside every proposal region: within the view's depth noise, a colour the other views
        do not show there decides. Applies with ``refine="static-depth"``. Default 0.99;
        None: off (depth alone decides within the widened margin).
    refine_passes : int
        How often ``refine="static-depth"`` builds its static reference. The first pass renders
        each view without every proposed Gaussian of the others; a proposal region covers whole
        patches, so much static content goes with it and static surfaces "in front of" the
        hole it leaves qualify. Each later pass leaves out only the proposed Gaussians the
        previous pass kept. 1: a single pass (the paper does not refine at all).
    expand_connected : bool
        Also expand an accepted candidate [hat C_k] into every 8-connected group of its view's
        pixels that it touches whose Gaussians stand in front of the static reference
        (``refine``) within cells of similarity below tau2, whether or not the support
        condition holds there: the support is judged per patch, and a distractor's patches
        where the other views render little, or at a similar mean depth, drop out of the
        paper's expansion. False: the paper (dilation within the support only).
    expand_color_bound : float or None
        Beyond the candidate's own Gaussians, a Gaussian the refinement keeps for its colour
        alone joins the expansion only where its colour distance (as for
        ``color_explained``) exceeds this quantile of the distances of its view's Gaussians
        outside every proposal region. Around a distractor the dilation reaches static
        surfaces whose fine texture the other views render a pixel or two off (fences,
        spokes, print): their colours differ from the reference as much as the view's static
        content often does elsewhere, and colour alone says nothing there. Applies with
        ``refine="static-depth"``. Default 0.99; None: every Gaussian the refinement keeps.
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
    refine_margin: float = 0.02
    refine_color: float | None = 0.5
    verify_mask: Literal["auto", "proposals+revealing", "proposals", "revealing"] = "auto"
    verify_holes: Literal["auto", "skip", "count"] = "auto"
    incremental: bool = True
    num_threads: int | None = None
    view_memory: float | None = 2.0
    device: str = "cpu"
    depth_scale_align: bool = True
    refine_tolerance: int | str = "auto"
    min_relative_score: float = 0.2
    color_explained: float | None = 0.75
    silhouette_explained: float | None = 0.75
    widened_band_color: float | None = 0.99
    refine_passes: int = 2
    expand_connected: bool = True
    expand_color_bound: float | None = 0.99
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
        if self.verify_mask != "proposals" and self.refine == "none":
            raise ClearsplatError(f"{self.verify_mask!r} needs refine other than 'none' "
                                  "(or choose verify_mask='proposals')", field="verify_mask")
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
    "refine_margin": FieldSpec("number", 0.0),
    "refine_color": FieldSpec("number", 0.0, 3.0, optional=True),
    "verify_mask": FieldSpec("choice", choices=("auto", "proposals+revealing", "proposals",
                                                 "revealing")),
    "verify_holes": FieldSpec("choice", choices=("auto", "skip", "count")),
    "incremental": FieldSpec("bool"),
    "num_threads": FieldSpec("integer", 1, optional=True),
    "view_memory": FieldSpec("number", 0.0, low_open=True, optional=True),
    "device": FieldSpec("text", test=_is_device, what="'cpu', 'cuda' or 'cuda:N'"),
    "depth_scale_align": FieldSpec("bool"),
    "refine_tolerance": FieldSpec("integer", 0, also=("auto",)),
    "min_relative_score": FieldSpec("number", 0.0, 1.0, high_open=True),
    "color_explained": _unit(optional=True),
    "silhouette_explained": _unit(optional=True),
    "widened_band_color": _unit(optional=True),
    "refine_passes": FieldSpec("integer", 1),
    "expand_connected": FieldSpec("bool"),
    "expand_color_bound": _unit(optional=True),
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
                          verify_mask="proposals", verify_holes="count", depth_scale_align=False,
                          refine_tolerance=0, min_relative_score=0.0, color_explained=None,
                          silhouette_explained=None, widened_band_color=None,
                          expand_color_bound=None, refine_passes=1, expand_connected=False,
                          rounds=1, neighbours=None, verify_views="centres", verify_hidden=None,
                          reveal_reference="composite"),
    # The paper's procedure with the weight-free features in place of DINOv3: what runs anywhere.
    "paper-local": FilterConfig(features="local", verify_base="full", refine="none",
                                verify_mask="proposals", verify_holes="count",
                                depth_scale_align=False, refine_tolerance=0,
                                min_relative_score=0.0, color_explained=None,
                                silhouette_explained=None, widened_band_color=None,
                                expand_color_bound=None, refine_passes=1,
                                expand_connected=False, rounds=1, neighbours=None,
                                verify_views="centres", verify_hidden=None,
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
