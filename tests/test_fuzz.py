"""Property-based fuzzing of the readers: only ClearsplatError ever escapes.

Each reader gets damaged versions of valid files (byte flips, truncations, insertions, header
tokens that lie, JSON values swapped for arbitrary ones) and arbitrary input. Whatever it is
given, it either returns something valid or raises :class:`ClearsplatError` naming the file and
a field; any other exception (or warning: warnings are errors here) fails the test.

CI runs a few hundred inputs in all (deterministic: ``derandomize=True``). The longer run::

    CLEARSPLAT_FUZZ_EXAMPLES=20000 python -m pytest tests/test_fuzz.py -s

runs that many examples per test and prints how many inputs each reader was given.
"""

from __future__ import annotations

import io
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from PIL import Image

import clearsplat.io as cio
from clearsplat import Camera, ClearsplatError, Gaussians

EXAMPLES = int(os.environ.get("CLEARSPLAT_FUZZ_EXAMPLES", "0")) or None
FUZZ = settings(max_examples=EXAMPLES or 120, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])
COUNTS: dict = {}


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """A folder for the fuzzed files, and a report of the inputs tried when the module ends."""
    start = time.perf_counter()
    yield tmp_path_factory.mktemp("fuzz")
    if EXAMPLES:
        total = sum(v for k, v in COUNTS.items() if " " not in k)
        print(f"\nfuzz: {total} inputs in {time.perf_counter() - start:.0f} s: "
              + ", ".join(f"{k} {v}" for k, v in sorted(COUNTS.items())))


def _count(name: str) -> None:
    COUNTS[name] = COUNTS.get(name, 0) + 1


def _expect_clear(fn, path: Path, name: str):
    """Call ``fn(path)``: its result, or None after a ClearsplatError naming ``path``."""
    _count(name)
    try:
        result = fn(path)
    except ClearsplatError as e:
        assert e.path is not None and Path(e.path).name == path.name, str(e)
        assert e.field, str(e)
        assert "\n" not in str(e)
        _count(f"{name} refused")
        return None
    _count(f"{name} read")
    return result


# ------------------------------------------------------------------------------------------------
# PLY
# ------------------------------------------------------------------------------------------------
_CODES = {"float": "f4", "double": "f8", "int": "i4", "uchar": "u1", "short": "i2"}
_TYPE_WORDS = ["float", "double", "int", "uint", "uchar", "char", "short", "ushort", "int8",
               "float32", "float64", "int64", "uint64", "list", "float16", "", "x"]


def _valid_ply(fmt: str, n: int = 3, k: int = 1, seed: int = 0, double: bool = False) -> bytes:
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{j}" for j in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    wide = ("x", "f_dc_2", "opacity", "scale_1", "rot_0", "f_rest_3") if double else ()
    cols = [("double" if c in wide else "float", c, rng.normal(size=n)) for c in names]
    cols += [("int", "view_id", rng.integers(0, 3, n)), ("int", "pixel_id",
                                                          rng.integers(-1, 48, n))]
    head = ["ply", f"format {fmt} 1.0", "comment fuzz", f"element vertex {n}"]
    head += [f"property {t} {c}" for t, c, _ in cols] + ["end_header"]
    out = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        return out + "".join(" ".join(repr(float(v[i])) if t != "int" else str(v[i])
                                      for t, _, v in cols) + "\n" for i in range(n)).encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    table = np.empty(n, dtype=[(c, order + _CODES[t]) for t, c, _ in cols])
    for _, c, v in cols:
        table[c] = v
    return out + table.tobytes()


_BASES = [_valid_ply(f, n=n, k=k, double=d) for f in ("binary_little_endian",
                                                     "binary_big_endian", "ascii")
          for n, k, d in ((3, 1, False), (2, 4, True), (0, 1, False))]
_SPECIAL_WORDS = ["1e40", "-1e400", "nan", "inf", "-inf", "1e-50", "99999999999999999999", "-0",
                  "0", "1.5", "-1", "4294967296", "0x10", ""]
_SPECIAL_VALUES = [1e300, -1e300, np.nan, np.inf, -np.inf, 1e-300, 3.5e38, 0.0, -0.0, 2.0**40]


@st.composite
def damaged_ply(draw) -> bytes:
    data = bytearray(draw(st.sampled_from(_BASES)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "truncate", "insert", "delete", "token", "swap",
                                   "value", "value"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        end = bytes(data).find(b"end_header\n") + len(b"end_header\n")
        if op == "value" and end > len(b"end_header\n") - 1:
            if bytes(data).startswith(b"ply\nformat ascii"):       # a body word
                words = bytes(data[end:]).split(b" ")
                i = draw(st.integers(0, max(len(words) - 1, 0)))
                words[i] = draw(st.sampled_from(_SPECIAL_WORDS)).encode()
                data[end:] = b" ".join(words)
            else:                                                   # a float or double
                value = draw(st.sampled_from(_SPECIAL_VALUES))
                code = draw(st.sampled_from(["<f8", ">f8", "<f4", ">f4"]))
                with np.errstate(over="ignore"):
                    raw = np.array([value], dtype=code).tobytes()
                at = end + draw(st.integers(0, max(len(data) - end - len(raw), 0)))
                data[at:at + len(raw)] = raw
        elif op == "flip" and data:
            data[at] = draw(st.integers(0, 255))
        elif op == "truncate":
            del data[at:]
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete":
            del data[at:at + draw(st.integers(1, 16))]
        elif op == "swap":                 # move one header line elsewhere
            lines = bytes(data).split(b"\n")
            head = lines.index(b"end_header") if b"end_header" in lines else len(lines) - 1
            if head > 1:
                i, j = draw(st.integers(0, head - 1)), draw(st.integers(0, head - 1))
                lines.insert(j, lines.pop(i))
                data = bytearray(b"\n".join(lines))
        else:                              # a header word replaced by a lie
            words = bytes(data).split(b" ")
            i = draw(st.integers(0, max(len(words) - 1, 0)))
            word = draw(st.sampled_from(_TYPE_WORDS) | st.integers(-5, 10**12).map(str)
                        | st.sampled_from(["ascii", "binary_big_endian", "vertex", "face"]))
            words[i] = word.encode()
            data = bytearray(b" ".join(words))
    return bytes(data)


@st.composite
def generated_ply(draw) -> bytes:
    """A header built from random elements, properties and types, then random body bytes."""
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian"]))
    head = ["ply", f"format {fmt} 1.0"]
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "view_id", "pixel_id", "nx",
             "f_rest_0", "extra"]
    for element in draw(st.lists(st.sampled_from(["vertex", "face", "edge"]), min_size=1,
                                 max_size=3)):
        head.append(f"element {element} {draw(st.integers(0, 6))}")
        for name in draw(st.lists(st.sampled_from(names), max_size=20)):
            if draw(st.integers(0, 9)) == 0:
                head.append(f"property list uchar int {name}")
            else:
                head.append(f"property {draw(st.sampled_from(_TYPE_WORDS[:13]))} {name}")
    head.append("end_header")
    if fmt == "ascii":
        body = "\n".join(" ".join(draw(st.lists(
            st.sampled_from(["0", "1", "-1", "0.5", "nan", "inf", "1e40", "x", "300"]),
            max_size=25))) for _ in range(draw(st.integers(0, 8))))
        return ("\n".join(head) + "\n" + body).encode()
    return ("\n".join(head) + "\n").encode() + draw(st.binary(max_size=600))


def _check_ply(path: Path):
    result = _expect_clear(cio.read_ply, path, "ply")
    if result is not None:
        g, view_id, pixel_id = result
        assert isinstance(g, Gaussians)
        g.validate()
        for ids in (view_id, pixel_id):
            assert ids is None or ids.shape == (len(g),)


@FUZZ
@given(data=damaged_ply() | generated_ply()
       | st.binary(max_size=400).map(lambda b: b"ply\n" + b))
def test_fuzz_ply_reader(scratch, data):
    path = scratch / "g.ply"
    path.write_bytes(data)
    _check_ply(path)


def test_fuzz_bases_are_valid(scratch):
    """The damaged files start from valid ones (else the fuzzing only tests the first check)."""
    for data in _BASES:
        (scratch / "base.ply").write_bytes(data)
        cio.read_ply(scratch / "base.ply")


# ------------------------------------------------------------------------------------------------
# cameras.json and transforms.json
# ------------------------------------------------------------------------------------------------
def _frame(i: int) -> dict:
    return {"image": f"images/{i:03d}.png", "width": 8, "height": 6,
            "K": [[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]],
            "camera_to_world": [[1.0, 0, 0, i], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]}


def _nerf(i: int) -> dict:
    return {"file_path": f"images/{i:03d}", "fl_x": 10.0, "w": 8, "h": 6,
            "transform_matrix": [[1.0, 0, 0, i], [0, 1.0, 0, 0], [0, 0, 1.0, 0],
                                 [0, 0, 0, 1.0]]}


_DOCS = [{"frames": [_frame(0), _frame(1)]},
         {"camera_model": "OPENCV", "fl_y": 10.0, "cx": 4.0, "cy": 3.0,
          "frames": [_nerf(0), _nerf(1)]},
         {"camera_angle_x": 0.8, "w": 8, "h": 6,
          "frames": [{"file_path": "./images/000.png",
                      "transform_matrix": _nerf(0)["transform_matrix"]}]}]

_NUMBERS = st.sampled_from([float("nan"), float("inf"), -float("inf"), 0, -1, 0.5, -0.0, 1e308,
                            -1e300, 3.5e38, 1e-320, 10**400, -10**400, 2**63, 2**31, 7])
_SCALARS = (st.none() | st.booleans() | st.integers() | st.floats()
            | st.sampled_from([10**400, -10**400, 2**63, 1e308, -0.0, 1e-320, "", "..",
                               "../x.png", "/abs.png", "images/000.png", "C:\\x.png", "\x00"])
            | st.text(max_size=8))
_JSON = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=5)
                     | st.dictionaries(st.text(max_size=8) | st.sampled_from(
                         ["frames", "K", "width", "height", "camera_to_world", "image",
                          "transform_matrix", "fl_x", "w", "h", "k1", "camera_model"]),
                         inner, max_size=5), max_leaves=20)


def _paths(value, prefix=()):
    """Every (container path) in a JSON document."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, prefix + (i,))


@st.composite
def damaged_doc(draw):
    doc = json.loads(json.dumps(draw(st.sampled_from(_DOCS))))
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        how = draw(st.sampled_from(["number", "scalar", "json", "delete"]))
        if how == "number":
            parent[path[-1]] = draw(_NUMBERS)
        elif how == "scalar":
            parent[path[-1]] = draw(_SCALARS)
        elif how == "json":
            parent[path[-1]] = draw(_JSON)
        elif isinstance(parent, dict):
            del parent[path[-1]]
        else:
            parent.pop(path[-1])
    return doc


def _check_cameras(path: Path):
    result = _expect_clear(cio.load_cameras, path, "cameras")
    if result is not None:
        cameras, images = result
        assert len(cameras) == len(images) > 0
        for cam in cameras:
            assert isinstance(cam, Camera)
            assert np.isfinite(cam.K).all() and np.isfinite(cam.world_to_camera).all()
            assert cam.width > 0 and cam.height > 0


_IDENTITY = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]


@FUZZ
@given(doc=damaged_doc() | _JSON, name=st.sampled_from(["cameras.json", "transforms.json"]))
# found by the fuzzer: an integer beyond the float range; a subnormal that made det() warn
@example(doc={"fl_y": 10**400, "w": 8, "h": 6, "fl_x": 1.0,
              "frames": [{"transform_matrix": _IDENTITY}]}, name="cameras.json")
@example(doc={"camera_angle_x": 0.8, "w": 8, "h": 6, "frames": [{
    "transform_matrix": [[0, 1.0, 0, 0], [0, 0, 1.0, 0], [1e-320, 0, 0, 1.0]]}]},
    name="transforms.json")
@example(doc={"frames": [{**_frame(0), "image": "a\x00.png"}]}, name="cameras.json")
def test_fuzz_cameras_reader(scratch, doc, name):
    folder = scratch / "cams"
    folder.mkdir(exist_ok=True)
    path = folder / name
    path.write_text(json.dumps(doc))
    _check_cameras(path)


@FUZZ
@given(text=st.sampled_from([json.dumps(d) for d in _DOCS]), cut=st.integers(0, 400),
       junk=st.binary(max_size=8))
def test_fuzz_cameras_bytes(scratch, text, cut, junk):
    folder = scratch / "cams_bytes"
    folder.mkdir(exist_ok=True)
    path = folder / "cameras.json"
    data = text.encode()
    path.write_bytes(data[:cut] + junk + data[cut:])
    _check_cameras(path)


# ------------------------------------------------------------------------------------------------
# images
# ------------------------------------------------------------------------------------------------
def _encoded(fmt: str, mode: str) -> bytes:
    rng = np.random.default_rng(0)
    arr = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    im = Image.fromarray(arr).convert(mode)
    buf = io.BytesIO()
    im.save(buf, format=fmt)
    return buf.getvalue()


_IMAGES = [_encoded("PNG", m) for m in ("RGB", "RGBA", "L", "P")] + [_encoded("JPEG", "RGB")]


@FUZZ
@given(base=st.sampled_from(_IMAGES), edits=st.lists(st.tuples(
    st.integers(0, 2000), st.integers(0, 255), st.sampled_from(["flip", "cut", "insert"])),
    min_size=1, max_size=3))
def test_fuzz_image_reader(scratch, base, edits):
    data = bytearray(base)
    for at, value, op in edits:
        at %= max(len(data), 1)
        if op == "flip" and data:
            data[at] = value
        elif op == "cut":
            del data[at:]
        else:
            data[at:at] = bytes([value]) * 3
    path = scratch / "im.png"
    path.write_bytes(bytes(data))
    result = _expect_clear(lambda p: cio.read_image(p, expected_size=(8, 6)), path, "image")
    if result is not None:
        assert result.shape == (6, 8, 3) and result.dtype == np.float32
        assert np.isfinite(result).all() and result.min() >= 0 and result.max() <= 1
