"""Bad input: every problem is a ClearsplatError naming the file and the field.

Each case matches ``<file>: <field>: <reason>`` (the ClearsplatError format) and checks that the
input files were not modified.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import clearsplat.io as cio
from clearsplat import Camera, ClearsplatError, Gaussians, Scene

_CODE = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "short": "i2"}
REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
            "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def props(n=4, seed=0, k=4):
    """Valid 3DGS columns [(type, name, values)] with view_id (3 views) and pixel_id (8x6)."""
    rng = np.random.default_rng(seed)
    f = lambda: rng.normal(size=n).astype(np.float32)  # noqa: E731
    out = [("float", c, f()) for c in ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1",
                                       "f_dc_2")]
    out += [("float", f"f_rest_{j}", f()) for j in range(3 * (k - 1))]
    out += [("float", c, f()) for c in ("opacity", "scale_0", "scale_1", "scale_2", "rot_0",
                                        "rot_1", "rot_2", "rot_3")]
    out += [("int", "view_id", rng.integers(0, 3, n)), ("int", "pixel_id", rng.integers(0, 48, n))]
    return out


def ply(columns, *, fmt="binary_little_endian", count=None):
    n = len(columns[0][2])
    head = ["ply", f"format {fmt} 1.0", f"element vertex {n if count is None else count}"]
    head += [f"property {t} {name}" for t, name, _ in columns] + ["end_header"]
    out = ("\n".join(head) + "\n").encode()
    if fmt == "ascii":
        return out + "".join(" ".join(repr(float(v[i])) if _CODE[t][0] == "f" else str(v[i])
                                      for t, _, v in columns) + "\n" for i in range(n)).encode()
    table = np.empty(n, dtype=[(name, "<" + _CODE[t]) for t, name, _ in columns])
    for _, name, v in columns:
        table[name] = v
    return out + table.tobytes()


def with_column(columns, name, values=None, *, drop=False, typ=None):
    out = []
    for t, nm, v in columns:
        if nm == name:
            if drop:
                continue
            v = np.array(v if values is None else values)
            t = typ or t
        out.append((t, nm, v))
    return out


def sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def raises(where: str, field: str, reason: str = ""):
    """``pytest.raises`` for a ClearsplatError naming ``where`` (file) and ``field``."""
    return pytest.raises(ClearsplatError,
                         match=re.escape(f"{where}: {field}: ") + ".*" + reason)


@pytest.fixture
def plyfile(tmp_path):
    """Write PLY bytes, yield the path, and check afterwards that reading left them alone."""
    written = {}

    def write(data: bytes, name="g.ply"):
        p = tmp_path / name
        p.write_bytes(data)
        written[p] = sha(p)
        return p

    yield write
    for p, h in written.items():
        assert sha(p) == h, f"{p} was modified"


# ------------------------------------------------------------------------------------------------
# PLY structure
# ------------------------------------------------------------------------------------------------
def test_garbage_bytes(plyfile):
    p = plyfile(np.random.default_rng(0).bytes(500))
    with raises(str(p), "header", "not a PLY file"):
        cio.read_ply(p)
    p = plyfile(b"ply\n" + np.random.default_rng(1).bytes(500).replace(b"end_header", b""))
    with raises(str(p), "header"):
        cio.read_ply(p)


def test_missing_file(tmp_path):
    with raises(str(tmp_path / "nope.ply"), "gaussians", "file not found"):
        cio.read_ply(tmp_path / "nope.ply")


def test_truncated_body(plyfile):
    p = plyfile(ply(props())[:-10])
    with raises(str(p), "vertex", "file too short: the header promises 4 vertices"):
        cio.read_ply(p)


def test_header_count_too_large_or_small(plyfile):
    p = plyfile(ply(props(), count=5))
    with raises(str(p), "vertex", "file too short"):
        cio.read_ply(p)
    p = plyfile(ply(props(), count=3), name="small.ply")
    with raises(str(p), "vertex", r"\d+ unexpected bytes after the 3 vertices"):
        cio.read_ply(p)


def test_ascii_body_errors(plyfile):
    good = ply(props(), fmt="ascii")
    lines = good.decode().splitlines(keepends=True)
    p = plyfile("".join(lines[:-1]).encode(), name="short.ply")
    with raises(str(p), "vertex", "file too short"):
        cio.read_ply(p)
    p = plyfile(good + lines[-1].encode(), name="long.ply")
    with raises(str(p), "vertex", "1 unexpected lines"):
        cio.read_ply(p)
    p = plyfile("".join(lines[:-1] + [lines[-1].replace(" ", " 7 ", 1)]).encode(),
                name="tokens.ply")
    with raises(str(p), "vertex", "vertex 3 has 29 values, the header declares 28"):
        cio.read_ply(p)
    p = plyfile(good.replace(lines[-1].encode(), b"abc" + lines[-1].encode()[1:]),
                name="word.ply")
    with raises(str(p), "x", "vertex 3: 'abc"):
        cio.read_ply(p)
    bad = with_column(props(), "view_id", [0, 1, 300, 2], typ="uchar")
    p = plyfile(ply(bad, fmt="ascii"), name="range.ply")
    with raises(str(p), "view_id", "vertex 2: 300 does not fit in uchar"):
        cio.read_ply(p)


@pytest.mark.parametrize("line, field, reason", [
    ("property float16 x", "x", "unknown property type 'float16'"),
    ("property float opacity", "opacity", "appears twice"),
    ("property list uchar int x", "x", "list properties are not supported"),
    ("bogus words", "header line 4", "unknown header keyword"),
])
def test_bad_header_lines(plyfile, line, field, reason):
    data = ply(props()).replace(b"property float x\n", line.encode() + b"\n", 1)
    p = plyfile(data)
    with raises(str(p), field, reason):
        cio.read_ply(p)


def test_bad_header_format(plyfile):
    p = plyfile(ply(props()).replace(b"binary_little_endian", b"binary_middle_endian"))
    with raises(str(p), "header line 2", "unsupported format"):
        cio.read_ply(p)
    p = plyfile(ply(props()).replace(b"element vertex 4", b"element vertex -4"), name="n.ply")
    with raises(str(p), "header line 3", "malformed element line"):
        cio.read_ply(p)
    p = plyfile(ply(props()).replace(b"element vertex", b"element point"), name="v.ply")
    with raises(str(p), "vertex", "expected exactly one 'vertex' element"):
        cio.read_ply(p)
    p = plyfile(ply(props()).replace(b"ply\n", b"ply\ncomment caf\xc3\xa9\n", 1), name="u.ply")
    with raises(str(p), "header", "header is not ASCII"):
        cio.read_ply(p)


def test_list_element_before_vertex_in_binary(plyfile):
    data = ply(props()).replace(b"element vertex", b"element face 1\nproperty list uchar int "
                                b"idx\nelement vertex", 1)
    end = data.index(b"end_header\n") + 11
    p = plyfile(data[:end] + b"\x03" + bytes(12) + data[end:])
    with raises(str(p), "face", "cannot skip element 'face' with list properties"):
        cio.read_ply(p)


# ------------------------------------------------------------------------------------------------
# PLY values
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", REQUIRED)
def test_missing_required_property(plyfile, name):
    p = plyfile(ply(with_column(props(), name, drop=True)))
    with raises(str(p), name, "required property is missing"):
        cio.read_ply(p)


@pytest.mark.parametrize("name", ["x", "f_dc_1", "f_rest_4", "opacity", "scale_2", "rot_3",
                                  "nx"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_values(plyfile, name, value):
    cols = props()
    v = dict((nm, val) for _, nm, val in cols)[name].copy()
    v[2] = value
    p = plyfile(ply(with_column(cols, name, v)))
    with raises(str(p), name, r"non-finite value -?(nan|inf) \(first at vertex 2\)"):
        cio.read_ply(p)


def test_non_finite_double_and_ascii(plyfile):
    cols = with_column(props(), "scale_1", [0.0, 1.0, 2.0, np.nan], typ="double")
    p = plyfile(ply(cols, fmt="ascii"))
    with raises(str(p), "scale_1", "non-finite value nan"):
        cio.read_ply(p)


@pytest.mark.parametrize("value", [200.0, -200.0])
def test_log_scale_outside_float32(plyfile, value):
    p = plyfile(ply(with_column(props(), "scale_0", [0.0, value, 0.0, 0.0])))
    with raises(str(p), "scale_0", "log scale .* gives a scale outside the float32 range"):
        cio.read_ply(p)


def test_zero_quaternion(plyfile):
    cols = props()
    for c in range(4):
        cols = with_column(cols, f"rot_{c}", [1.0, 0.0, 0.5, 0.5] if c == 0 else
                           [0.0, 0.0, 0.5, 0.5])
    p = plyfile(ply(cols))
    with raises(str(p), "rot_0..3", r"zero quaternion \(first at vertex 1\)"):
        cio.read_ply(p)


def test_bad_sh_rest_count(plyfile):
    p = plyfile(ply(with_column(props(), "f_rest_8", drop=True)))
    with raises(str(p), "f_rest_*", "expected f_rest_0"):
        cio.read_ply(p)


def test_non_integer_view_id(plyfile):
    p = plyfile(ply(with_column(props(), "view_id", [0, 1.5, 2, 0], typ="float")))
    with raises(str(p), "view_id", "must hold integers, got 1.5 at vertex 1"):
        cio.read_ply(p)
    p = plyfile(ply(with_column(props(), "view_id", [0, -2, 2, 0])), name="neg.ply")
    with raises(str(p), "view_id", "view id -2 at vertex 1 is below -1"):
        cio.read_ply(p)
    # -1: shared by several views (a fused export), read as it is
    p = plyfile(ply(with_column(props(), "view_id", [0, -1, 2, 0])), name="shared.ply")
    assert cio.read_ply(p)[1].tolist() == [0, -1, 2, 0]


def test_every_truncation_and_corruption_is_a_clear_error(tmp_path):
    """Fuzz: any prefix of a valid file, and random byte corruptions, never crash otherwise."""
    data = ply(props(n=3, k=1))
    rng = np.random.default_rng(0)
    p = tmp_path / "fuzz.ply"
    outcomes = {"ok": 0, "error": 0}
    cases = [data[:i] for i in range(len(data))]
    for _ in range(300):
        b = bytearray(data)
        for i in rng.integers(0, len(b), rng.integers(1, 4)):
            b[i] = int(rng.integers(0, 256))
        cases.append(bytes(b))
    for case in cases:
        p.write_bytes(case)
        try:
            cio.read_ply(p)
            outcomes["ok"] += 1
        except ClearsplatError as e:
            assert e.path == str(p) and e.field
            outcomes["error"] += 1
    assert outcomes["error"] >= len(data)        # every proper prefix is refused
    assert outcomes["ok"] > 0                    # some corruptions only change values


# ------------------------------------------------------------------------------------------------
# in-memory Gaussians on writing
# ------------------------------------------------------------------------------------------------
def _gaussians(n=4):
    rng = np.random.default_rng(0)
    return Gaussians(rng.normal(size=(n, 3)), np.full((n, 3), 0.1), rng.normal(size=(n, 4)),
                     np.full(n, 0.5), rng.normal(size=(n, 1, 3)))


@pytest.mark.parametrize("attr, index, value, field, reason", [
    ("scales", (1, 2), 0.0, "scales", "scales must be positive"),
    ("scales", (1, 2), -1.0, "scales", "scales must be positive"),
    ("means", (3, 0), np.nan, "means", "non-finite value"),
    ("sh", (0, 0, 1), np.inf, "sh", "non-finite value"),
    ("opacities", (2,), 1.5, "opacities", "opacity outside"),
    ("quats", (2, slice(None)), 0.0, "quats", "zero quaternion"),
])
def test_write_refuses_invalid_memory(tmp_path, attr, index, value, field, reason):
    g = _gaussians()
    getattr(g, attr)[index] = value
    out = tmp_path / "out.ply"
    with raises(str(out), field, reason):
        cio.write_ply(out, g)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("key, value, reason", [
    ("opacity", np.zeros(4, np.float32), "may not reuse the name"),
    ("f_rest_0", np.zeros(4, np.float32), "may not reuse the name"),
    ("two words", np.zeros(4, np.float32), "non-empty ASCII"),
    ("normal", np.zeros((4, 3), np.float32), r"must be an \(4,\) array"),
    ("flag", np.zeros(4, bool), r"must be an \(4,\) array"),
])
def test_write_refuses_bad_extra(tmp_path, key, value, reason):
    g = _gaussians()
    g.extra[key] = value
    with pytest.raises(ClearsplatError, match=re.escape(str(tmp_path / "o.ply")) + ".*" + reason):
        cio.write_ply(tmp_path / "o.ply", g)


def test_write_refuses_bad_index_columns(tmp_path):
    g, out = _gaussians(), tmp_path / "o.ply"
    with raises(str(out), "view_id", "expected 4 values"):
        cio.write_ply(out, g, view_id=[0, 1])
    with raises(str(out), "view_id", "values must be >= -1"):
        cio.write_ply(out, g, view_id=[0, 1, -2, 0])
    with raises(str(out), "pixel_id", "values must be >= -1"):
        cio.write_ply(out, g, pixel_id=[0, 1, -2, 0])
    with raises(str(out), "pixel_id", "must hold integers"):
        cio.write_ply(out, g, pixel_id=[0, 1, 0.5, 0])


# ------------------------------------------------------------------------------------------------
# bundles
# ------------------------------------------------------------------------------------------------
def frame(i=0, w=8, h=6):
    return {"image": f"images/{i:03d}.png", "width": w, "height": h,
            "K": [[10.0, 0.0, 4.0], [0.0, 10.0, 3.0], [0.0, 0.0, 1.0]],
            "camera_to_world": [[1.0, 0, 0, i], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]}


@pytest.fixture
def bundle(tmp_path):
    """A valid 3-view bundle written by hand; checks afterwards that loading left it alone."""
    root = tmp_path / "bundle"
    (root / "images").mkdir(parents=True)
    (root / "cameras.json").write_text(json.dumps({"frames": [frame(i) for i in range(3)]}))
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray(rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)).save(
            root / "images" / f"{i:03d}.png")
    (root / "gaussians.ply").write_bytes(ply(props()))
    assert len(cio.load_scene(root)) == 4            # the fixture itself is valid
    snapshot(root)
    yield root
    after = {p: sha(p) for p in root.rglob("*") if p.is_file()}
    assert after == _SNAPSHOTS.pop(root), "loading modified the bundle"


_SNAPSHOTS: dict = {}


def snapshot(root):
    """Record the bundle's files after a test edited them (checked again at teardown)."""
    _SNAPSHOTS[root] = {p: sha(p) for p in root.rglob("*") if p.is_file()}


def edit_cameras(root, fn, *, name="cameras.json"):
    doc = json.loads((root / "cameras.json").read_text())
    fn(doc)
    (root / "cameras.json").unlink()
    (root / name).write_text(json.dumps(doc))
    snapshot(root)


def test_view_id_out_of_range(bundle):
    (bundle / "gaussians.ply").write_bytes(ply(with_column(props(), "view_id", [0, 1, 3, 2])))
    snapshot(bundle)
    with raises(str(bundle / "gaussians.ply"), "view_id", "view id 3 at vertex 2 is out of "
                r"range: the bundle has 3 cameras \(0..2\)"):
        cio.load_scene(bundle)


@pytest.mark.parametrize("value", [48, -2])
def test_pixel_id_out_of_range(bundle, value):
    (bundle / "gaussians.ply").write_bytes(ply(with_column(props(), "pixel_id",
                                                           [0, value, 3, 2])))
    snapshot(bundle)
    with raises(str(bundle / "gaussians.ply"), "pixel_id",
                f"pixel id {value} at vertex 1 is out of range"):
        cio.load_scene(bundle)


def test_missing_view_id_or_gaussians(bundle):
    (bundle / "gaussians.ply").write_bytes(ply(with_column(props(), "view_id", drop=True)))
    snapshot(bundle)
    with raises(str(bundle / "gaussians.ply"), "view_id", "property 'view_id' is missing"):
        cio.load_scene(bundle)
    (bundle / "gaussians.ply").unlink()
    snapshot(bundle)
    with raises(str(bundle / "gaussians.ply"), "gaussians", "Gaussians file not found"):
        cio.load_scene(bundle)


def test_missing_image(bundle):
    (bundle / "images" / "001.png").unlink()
    snapshot(bundle)
    with raises(str(bundle / "images" / "001.png"), "frames[1].image",
                r"frame 1 image file not found \(1 of 3 missing\)"):
        cio.load_scene(bundle)
    assert cio.load_scene(bundle, require_images=False).images is None


def test_image_of_the_wrong_size(bundle):
    Image.new("RGB", (8, 5)).save(bundle / "images" / "002.png")
    snapshot(bundle)
    with raises(str(bundle / "images" / "002.png"), "frames[2].height",
                r"image is 8x5 \(width x height\) but the camera says 8x6"):
        cio.load_scene(bundle)


def test_unreadable_images(bundle):
    (bundle / "images" / "000.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(40))
    snapshot(bundle)
    with raises(str(bundle / "images" / "000.png"), "image"):
        cio.load_scene(bundle)
    Image.new("RGB", (8, 6)).save(bundle / "images" / "000.png", format="BMP")
    snapshot(bundle)
    with raises(str(bundle / "images" / "000.png"), "image", "unsupported image format BMP"):
        cio.load_scene(bundle)
    good = (bundle / "images" / "001.png").read_bytes()
    (bundle / "images" / "000.png").write_bytes(good[:len(good) // 2])     # truncated PNG
    snapshot(bundle)
    with raises(str(bundle / "images" / "000.png"), "image", "cannot decode the image"):
        cio.load_scene(bundle)


def test_image_format_or_mode_refused(tmp_path, monkeypatch):
    Image.new("F", (4, 3)).save(tmp_path / "f.tiff")
    with raises(str(tmp_path / "f.tiff"), "image", "unsupported image format TIFF"):
        cio.read_image(tmp_path / "f.tiff")
    # Pillow opens PNG/JPEG in modes the reader handles; fake the others it refuses
    import PIL.Image

    def fake_open(mode, value):
        def open_(path):
            im = PIL.Image.new(mode, (4, 3), value)
            im.format = "PNG"
            return im
        return open_
    (tmp_path / "x.png").write_bytes(b"")
    monkeypatch.setattr(PIL.Image, "open", fake_open("F", 0.5))
    with raises(str(tmp_path / "x.png"), "image", "unsupported image mode 'F'"):
        cio.read_image(tmp_path / "x.png")
    monkeypatch.setattr(PIL.Image, "open", fake_open("I", 70000))
    with raises(str(tmp_path / "x.png"), "image", "values outside 0..65535"):
        cio.read_image(tmp_path / "x.png")


def test_malformed_json(bundle):
    (bundle / "cameras.json").write_text('{"frames": [ {"width": 8,, } ]}')
    snapshot(bundle)
    with raises(str(bundle / "cameras.json"), "line 1 column 26", "malformed JSON"):
        cio.load_scene(bundle)
    (bundle / "cameras.json").write_bytes(b'{"frames": "\xff"}')
    snapshot(bundle)
    with raises(str(bundle / "cameras.json"), "cameras", "not UTF-8"):
        cio.load_scene(bundle)


def test_every_truncated_cameras_json_is_a_clear_error(tmp_path):
    text = json.dumps({"frames": [frame(0), frame(1)]})
    p = tmp_path / "cameras.json"
    for i in range(len(text)):
        p.write_text(text[:i])
        with pytest.raises(ClearsplatError, match=re.escape(str(p))):
            cio.load_cameras(p)


@pytest.mark.parametrize("edit, field, reason", [
    (lambda d: d.pop("frames"), "frames", "expected an object with a 'frames' list"),
    (lambda d: d.update(frames=[]), "frames", "no frames"),
    (lambda d: d["frames"].__setitem__(1, 3), r"frames\[1\]", "expected an object"),
    (lambda d: d["frames"][1].pop("K"), r"frames\[1\]\.K", "missing key 'K'"),
    (lambda d: d["frames"][0].pop("width"), r"frames\[0\]\.width", "missing key"),
    (lambda d: d["frames"][2].pop("camera_to_world"), r"frames\[2\]\.camera_to_world",
     "missing key"),
    (lambda d: d["frames"][0].update(width=8.5), r"frames\[0\]\.width", "whole number"),
    (lambda d: d["frames"][0].update(height=0), r"frames\[0\]\.height", "must be positive"),
    (lambda d: d["frames"][0].update(height="6"), r"frames\[0\]\.height", "expected a number"),
    (lambda d: d["frames"][0]["K"][0].__setitem__(2, float("nan")), r"frames\[0\]\.K\[0\]\[2\]",
     "non-finite value nan"),
    (lambda d: d["frames"][1]["camera_to_world"][2].__setitem__(3, float("inf")),
     r"frames\[1\]\.camera_to_world\[2\]\[3\]", "non-finite value inf"),
    (lambda d: d["frames"][0].update(K=[[10.0, 0, 4], [0, 10.0, 3]]), r"frames\[0\]\.K",
     "expected a 3x3"),
    (lambda d: d["frames"][0]["K"][0].__setitem__(1, 0.5), r"frames\[0\]\.K", "no skew"),
    (lambda d: d["frames"][0]["K"][1].__setitem__(1, -10.0), r"frames\[0\]\.K",
     "focal lengths must be positive"),
    (lambda d: d["frames"][1].update(camera_to_world=[[0.0] * 4] * 3 + [[0, 0, 0, 1.0]]),
     r"frames\[1\]\.camera_to_world", "singular, scaled or mirrored"),
    (lambda d: d["frames"][1]["camera_to_world"][0].__setitem__(0, -1.0),
     r"frames\[1\]\.camera_to_world", "singular, scaled or mirrored"),
    (lambda d: d["frames"][1]["camera_to_world"][3].__setitem__(0, 1.0),
     r"frames\[1\]\.camera_to_world", "last row must be"),
    (lambda d: d["frames"][2].update(image="../../etc/passwd"), r"frames\[2\]\.image",
     "leaves the bundle"),
    (lambda d: d["frames"][2].update(image="/tmp/x.png"), r"frames\[2\]\.image",
     "absolute path"),
    (lambda d: d["frames"][2].update(image=7), r"frames\[2\]\.image", "expected a non-empty"),
])
def test_bad_cameras_json(bundle, edit, field, reason):
    edit_cameras(bundle, edit)
    with pytest.raises(ClearsplatError, match=re.escape(str(bundle / "cameras.json")) + ": "
                       + field + ": .*" + reason):
        cio.load_scene(bundle)


def nerf(i=0):
    return {"file_path": f"images/{i:03d}.png",
            "transform_matrix": [[1.0, 0, 0, i], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]}


@pytest.mark.parametrize("edit, field, reason", [
    (lambda d: d.update(camera_model="OPENCV_FISHEYE"), "camera_model", "not supported"),
    (lambda d: d.update(k1=0.1), "k1", "lens distortion is not supported"),
    (lambda d: d["frames"][1].update(p2=0.1), r"frames\[1\]\.p2", "lens distortion"),
    (lambda d: d.pop("w"), r"frames\[0\]\.w", "missing key 'w'"),
    (lambda d: d.pop("fl_x"), r"frames\[0\]\.fl_x", "missing key 'fl_x'"),
    (lambda d: d.update(fl_y=float("-inf")), "fl_y", "non-finite"),
    (lambda d: d["frames"][2].pop("transform_matrix"), r"frames\[2\]\.transform_matrix",
     "missing key"),
    (lambda d: d["frames"][0]["transform_matrix"][1].__setitem__(1, 2.0),
     r"frames\[0\]\.camera_to_world", "singular, scaled or mirrored"),
    (lambda d: d["frames"][0].update(file_path="../x.png"), r"frames\[0\]\.file_path",
     "leaves the bundle"),
])
def test_bad_transforms_json(bundle, edit, field, reason):
    (bundle / "cameras.json").unlink()
    doc = {"camera_model": "OPENCV", "fl_x": 10.0, "fl_y": 10.0, "cx": 4.0, "cy": 3.0,
           "w": 8, "h": 6, "frames": [nerf(i) for i in range(3)]}
    (bundle / "transforms.json").write_text(json.dumps(doc))
    snapshot(bundle)
    assert len(cio.load_scene(bundle).cameras) == 3
    edit(doc)
    (bundle / "transforms.json").write_text(json.dumps(doc))
    snapshot(bundle)
    with pytest.raises(ClearsplatError, match=re.escape(str(bundle / "transforms.json")) + ": "
                       + field + ": .*" + reason):
        cio.load_scene(bundle)


def test_not_a_bundle(tmp_path):
    with raises(str(tmp_path / "none"), "bundle", "expected a bundle folder"):
        cio.load_scene(tmp_path / "none")
    (tmp_path / "empty").mkdir()
    with raises(str(tmp_path / "empty"), "cameras", "no cameras.json or transforms.json"):
        cio.load_scene(tmp_path / "empty")


def test_save_refuses_invalid_scene(tmp_path):
    cam = Camera(K=[[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]], camera_to_world=np.eye(4), width=8,
                 height=6)
    g = _gaussians()
    scene = Scene(g, [0, 0, 1, 0], None, [cam])
    with raises(str(tmp_path / "b"), "view_id", "view id 1 out of range"):
        cio.save_scene(scene, tmp_path / "b")
    scene = Scene(g, [0, 0, 0, 0], None, [cam], [np.zeros((6, 8, 3), np.float32) + np.nan])
    with raises(str(tmp_path / "b"), "images[0]", "non-finite"):
        cio.save_scene(scene, tmp_path / "b")
    assert list(tmp_path.iterdir()) == []


def test_write_image_refuses(tmp_path):
    with raises(str(tmp_path / "a.png"), "image", r"expected an \(H, W, 3\) image"):
        cio.write_image(tmp_path / "a.png", np.zeros((4, 4)))
    with raises(str(tmp_path / "a.png"), "image", "non-finite"):
        cio.write_image(tmp_path / "a.png", np.full((4, 4, 3), np.nan))
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# hardening: symbolic links, 16-bit colour, values beyond float32, memory
# ------------------------------------------------------------------------------------------------
def test_symlink_out_of_the_bundle_is_refused(bundle, tmp_path):
    import os
    outside = tmp_path / "outside.png"
    (bundle / "images" / "001.png").rename(outside)
    os.symlink(outside, bundle / "images" / "001.png")
    snapshot(bundle)
    with raises(str(bundle / "cameras.json"), "frames[1].image",
                "leads out of the bundle through a symbolic link"):
        cio.load_scene(bundle)
    # a linked folder that leads out is refused too; links that stay inside are followed
    (bundle / "images" / "001.png").unlink()
    outside.rename(bundle / "images" / "001.png")
    (bundle / "images").rename(tmp_path / "images_elsewhere")
    os.symlink(tmp_path / "images_elsewhere", bundle / "images")
    snapshot(bundle)
    with raises(str(bundle / "cameras.json"), "frames[0].image", "symbolic link"):
        cio.load_scene(bundle)
    (bundle / "images").unlink()
    (tmp_path / "images_elsewhere").rename(bundle / "pictures")
    os.symlink("pictures", bundle / "images")
    snapshot(bundle)
    assert len(cio.load_scene(bundle).images) == 3


_ADAM7 = ((0, 0, 8, 8), (0, 4, 8, 8), (4, 0, 8, 4), (0, 2, 4, 4), (2, 0, 4, 2), (0, 1, 2, 2),
          (1, 0, 2, 1))   # (first row, first column, row step, column step) of each pass


def png16(path, samples, color_type, *, interlace=False, sub_filter=False):
    """A 16-bit PNG written from the specification (Pillow cannot write 16-bit colour)."""
    import struct
    import zlib

    arr = np.asarray(samples, dtype=">u2")
    if arr.ndim == 2:
        arr = arr[:, :, None]
    bpp = 2 * arr.shape[2]

    def rows(a):
        out = b""
        for row in a:
            raw = np.frombuffer(row.tobytes(), np.uint8).astype(np.int16)
            if sub_filter:      # filter type 1: each byte minus the one a pixel to the left
                raw[bpp:] = (raw[bpp:] - raw[:-bpp]) % 256
            out += bytes([int(sub_filter)]) + raw.astype(np.uint8).tobytes()
        return out
    passes = [arr[r::dr, c::dc] for r, c, dr, dc in _ADAM7] if interlace else [arr]
    data = b"".join(rows(p) for p in passes if p.size)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", arr.shape[1], arr.shape[0], 16, color_type, 0, 0,
                       int(interlace))
    Path(path).write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                           + chunk(b"IDAT", zlib.compress(data)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("interlace", [False, True])
@pytest.mark.parametrize("sub_filter", [False, True])
@pytest.mark.parametrize("color_type, channels", [(2, 3), (6, 4), (4, 2)])
def test_16bit_colour_png_keeps_full_precision(tmp_path, color_type, channels, interlace,
                                               sub_filter):
    rng = np.random.default_rng(color_type)
    samples = rng.integers(0, 65536, (13, 19, channels)).astype(np.uint16)
    samples[0, 0] = 257 * 7 + 1          # a low byte that 8-bit precision would lose
    png16(tmp_path / "x.png", samples, color_type, interlace=interlace, sub_filter=sub_filter)
    got = cio.read_image(tmp_path / "x.png", expected_size=(19, 13))
    colour = samples[..., :3] if channels >= 3 else np.repeat(samples[..., :1], 3, axis=2)
    expected = colour.astype(np.float32) / np.float32(65535.0)
    assert got.dtype == np.float32 and got.shape == (13, 19, 3)
    np.testing.assert_array_equal(got, expected)


def test_16bit_png_of_the_wrong_size_or_damaged(tmp_path):
    png16(tmp_path / "x.png", np.zeros((4, 5, 3), np.uint16), 2)
    with raises(str(tmp_path / "x.png"), "width", "camera says 6x4"):
        cio.read_image(tmp_path / "x.png", expected_size=(6, 4))
    data = (tmp_path / "x.png").read_bytes()
    (tmp_path / "x.png").write_bytes(data[:45])
    with raises(str(tmp_path / "x.png"), "image", "cannot"):
        cio.read_image(tmp_path / "x.png")


def test_values_beyond_float32_are_refused(plyfile):
    cols = with_column(props(), "x", [0.0, 1e300, 0.0, 0.0], typ="double")
    p = plyfile(ply(cols))
    with raises(str(p), "x", r"value 1e\+300 \(vertex 1\) is outside the float32 range"):
        cio.read_ply(p)
    cols = with_column(props(), "rot_2", [0.0, 0.0, 0.0, 1e40])
    p = plyfile(ply(cols, fmt="ascii"), name="a.ply")
    with raises(str(p), "rot_2", "vertex 3: '1e\\+40' does not fit in float"):
        cio.read_ply(p)


@pytest.mark.parametrize("value, reason", [(10**400, "non-finite"),
                                           (1e300, "outside the float32 range")])
def test_cameras_beyond_float32_are_refused(bundle, value, reason):
    edit_cameras(bundle, lambda d: d["frames"][1]["camera_to_world"][0].__setitem__(3, value))
    with raises(str(bundle / "cameras.json"), "frames[1].camera_to_world[0][3]", reason):
        cio.load_scene(bundle)


def test_memory_estimate_and_check(monkeypatch):
    from clearsplat import _memory as m
    cam = Camera(K=[[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]], camera_to_world=np.eye(4), width=8,
                 height=6)
    # closed form: V views x N x (60 + 4 t + 4) held + V x N x 1.125 + 100 N + 381 per pixel
    rest = 3 * 1000 * 1.125 + 100 * 1000 + 381 * 144
    assert m.estimate_filter_memory(1000, [cam] * 3) == int(3 * 1000 * 72 + rest)
    assert m.estimate_filter_memory(1000, [cam] * 3, tiles_per_gaussian=4.0,
                                    visible_fraction=0.5) == \
        int(3 * 1000 * (0.5 * 76 + 4) + rest)
    # a budget bounds the held views at the budget plus the views being read and prepared
    assert m.estimate_filter_memory(1000, [cam] * 3, view_budget=50_000) == \
        int(50_000 + 2 * 72_000 + rest)
    assert m.estimate_filter_memory(1000, [cam] * 3, view_budget=10**9) == \
        int(3 * 1000 * 72 + rest)
    assert m.estimate_read_memory(10**6) == 5 * 10**6
    assert m.estimate_read_memory(10**6, ascii=True) == 20 * 10**6
    m.check_memory(10**9, available=2 * 10**9)
    with pytest.raises(ClearsplatError, match=r"^memory: the filter needs about 3\.0 GB, 2\.0 GB "
                       "available"):
        m.check_memory(3 * 10**9, available=2 * 10**9)
    with pytest.raises(ClearsplatError, match=r"^a\.ply: gaussians: reading needs about "
                       r"0\.5 GB, 0\.1 GB available: buy more"):
        m.check_memory(5 * 10**8, available=10**8, what="reading", path="a.ply",
                       field="gaussians", advice="buy more")
    monkeypatch.setenv("CLEARSPLAT_MEMORY_CHECK", "0")
    m.check_memory(3 * 10**9, available=2 * 10**9)
    monkeypatch.delenv("CLEARSPLAT_MEMORY_CHECK")
    monkeypatch.setattr(m, "available_memory", lambda: None)     # unknown: nothing checked
    m.check_memory(10**15)


def test_available_memory_reads_the_system_and_cgroup_limits(monkeypatch):
    from clearsplat import _memory as m
    avail = m.available_memory()
    assert avail is None or avail > 0
    files = {"/sys/fs/cgroup/memory.max": 8 * 2**30, "/sys/fs/cgroup/memory.current": 7 * 2**30}
    monkeypatch.setattr(m, "_read_int", lambda p: files.get(p))
    monkeypatch.setattr(m, "_stat_value", lambda p, k: 2**29 if k == "inactive_file" else 0)
    assert m._cgroup_available() == 8 * 2**30 - (7 * 2**30 - 2**29)
    files["/sys/fs/cgroup/memory.max"] = None                   # "max": no limit
    assert m._cgroup_available() is None


def test_read_ply_refuses_a_file_too_large_for_memory(plyfile, monkeypatch):
    from clearsplat import _memory as m
    import clearsplat.io.ply as ply_module
    p = plyfile(ply(props()))
    monkeypatch.setattr(ply_module, "_CHECK_ABOVE", 0)
    monkeypatch.setattr(m, "available_memory", lambda: 100)
    with raises(str(p), "gaussians", "reading this file needs about"):
        cio.read_ply(p)
    monkeypatch.setattr(m, "available_memory", lambda: 10**9)
    assert len(cio.read_ply(p)[0]) == 4
