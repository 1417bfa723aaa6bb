"""FilterConfig: every field's type and range is checked, from one spec per field."""

from __future__ import annotations

import dataclasses
import math

import pytest

from clearsplat import ClearsplatError
from clearsplat.filter import PRESETS, FilterConfig
from clearsplat.filter.config import FIELD_SPECS, FieldSpec

FIELDS = [f.name for f in dataclasses.fields(FilterConfig)]


def test_every_field_has_a_spec():
    """A new FilterConfig field needs an entry in FIELD_SPECS (what it accepts)."""
    assert sorted(FIELD_SPECS) == sorted(FIELDS), (
        f"fields without a spec: {sorted(set(FIELDS) - set(FIELD_SPECS))}; specs without a "
        f"field: {sorted(set(FIELD_SPECS) - set(FIELDS))}")


@pytest.mark.parametrize("name", FIELDS)
def test_defaults_and_presets_pass_their_spec(name):
    for preset in PRESETS.values():
        value = getattr(preset, name)
        assert FIELD_SPECS[name].check(name, value) == value


def bad_values(spec: FieldSpec) -> list:
    """Values the spec must refuse: wrong types, non-finite numbers, just outside the range."""
    out = [] if spec.optional else [None]
    if spec.kind in ("number", "integer"):
        out += ["abc", True, [1]]
        out += [math.nan, math.inf] if spec.kind == "number" else [2.5, "3"]
        step = 1 if spec.kind == "integer" else 1e-6
        if spec.low is not None:
            out.append(spec.low if spec.low_open else spec.low - step)
        if spec.high is not None:
            out.append(spec.high if spec.high_open else spec.high + step)
    elif spec.kind == "bool":
        out += ["maybe", "true", 1, 0.0]
    elif spec.kind == "choice":
        out += ["nope", spec.choices[0].upper(), 1, True]
    else:
        out += [1, True, ""]
    return out


def good_values(spec: FieldSpec) -> list:
    """Values the spec must accept: its bounds, its choices, None when optional."""
    out = [None] if spec.optional else []
    if spec.kind in ("number", "integer"):
        step = 1 if spec.kind == "integer" else 1e-6
        if spec.low is not None:
            out.append(spec.low + step if spec.low_open else spec.low)
        if spec.high is not None:
            out.append(spec.high - step if spec.high_open else spec.high)
        if spec.low is None and spec.high is None:
            out += [-1e9, 0, 1e9]
    elif spec.kind == "bool":
        out += [True, False]
    elif spec.kind == "choice":
        out += list(spec.choices)
    return out


CASES = [(name, v) for name in FIELDS for v in bad_values(FIELD_SPECS[name])]


@pytest.mark.parametrize("name, value", CASES, ids=[f"{n}={v!r}" for n, v in CASES])
def test_bad_values_name_field_value_and_what_is_allowed(name, value):
    with pytest.raises(ClearsplatError) as e:
        FilterConfig(**{name: value})
    assert e.value.field == name
    message = str(e.value)
    assert message.startswith(f"{name}: got {value!r}; expected "), message
    assert FIELD_SPECS[name].allowed() in message
    with pytest.raises(ClearsplatError):
        FilterConfig().replace(**{name: value})
    with pytest.raises(ClearsplatError):
        FilterConfig.preset("paper", **{name: value})


@pytest.mark.parametrize("name", FIELDS)
def test_good_values_are_kept(name):
    spec = FIELD_SPECS[name]
    values = good_values(spec)
    if name in ("tau1", "tau2"):          # they must also stay ordered: tested below
        values = [None]
    for value in values:
        if name == "refine" and value == "none":
            cfg = FilterConfig(refine="none")
        elif name == "backend" and value == "gsplat":     # CUDA only: tested below
            cfg = FilterConfig(backend="gsplat", device="cuda")
        else:
            cfg = FilterConfig(**{name: value})
        got = getattr(cfg, name)
        assert got == value and type(got) is type(value if spec.kind != "number" or value is None
                                                  else float(value))


def test_numbers_are_stored_as_float_and_integers_as_int():
    import numpy as np
    cfg = FilterConfig(eta=1, num_verify_views=np.int64(4), epsilon=np.float32(0.5),
                       verify=np.bool_(False))
    assert type(cfg.eta) is float and cfg.eta == 1.0
    assert type(cfg.num_verify_views) is int and cfg.num_verify_views == 4
    assert type(cfg.epsilon) is float and type(cfg.verify) is bool
    import json
    json.dumps(cfg.to_dict())                  # summary.json can hold it


def test_cross_field_checks():
    FilterConfig(tau1=-1, tau2=1)
    with pytest.raises(ClearsplatError, match="tau1 .* must be below tau2"):
        FilterConfig(tau1=0.6, tau2=0.5)
    FilterConfig(refine="none")                 # the paper's mask follows without refinement
    FilterConfig(backend="torch", device="cuda")
    with pytest.raises(ClearsplatError, match="'native' renders on the CPU only") as e:
        FilterConfig(backend="native", device="cuda")
    assert e.value.field == "backend"
    with pytest.raises(ClearsplatError, match="'gsplat' renders on a CUDA device only"):
        FilterConfig(backend="gsplat")
    with pytest.raises(ClearsplatError, match="unknown option 'etaa'"):
        FilterConfig().replace(etaa=0.5)


def test_spec_descriptions():
    assert FIELD_SPECS["eta"].allowed() == "a number in [0, 1]"
    assert FIELD_SPECS["num_verify_views"].allowed() == "an integer >= 1"
    assert FIELD_SPECS["num_threads"].allowed() == "an integer >= 1 or None"
    assert FIELD_SPECS["verify"].allowed() == "true or false"
    assert FIELD_SPECS["refine"].allowed() == "one of 'static-depth', 'depth', 'none'"
    assert FieldSpec("number").allowed() == "a finite number"
    assert FieldSpec("number", 0.0, 1.0, low_open=True).allowed() == "a number in (0, 1]"


def test_paper_preset_without_dino_says_what_to_do_in_python(monkeypatch):
    """From Python, the error speaks of FilterConfig, not only of command-line options."""
    import sys

    from clearsplat import filter_distractors
    from clearsplat.synth import make_world, reconstruct
    monkeypatch.setitem(sys.modules, "transformers", None)
    world = make_world("object", num_views=2, height=16, width=24)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    with pytest.raises(ImportError) as e:
        filter_distractors(scene, config=FilterConfig.preset("paper"))
    message = str(e.value)
    for fragment in ('pip install "clearsplat[dino]"', "FilterConfig(features='dinov3', "
                     "checkpoint=", "FilterConfig.preset('paper-local')", "never downloads"):
        assert fragment in message, message
