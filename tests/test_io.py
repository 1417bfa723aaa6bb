"""File I/O: 3DGS PLY (exact round trip), cameras.json / transforms.json, images, bundles."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import clearsplat.io as cio
from clearsplat import Camera, ClearsplatError, Gaussians, Scene
from clearsplat.io.ply import RAW_PREFIX

# ------------------------------------------------------------------------------------------------
# an independent PLY writer / reader for the tests (numpy structured arrays, hand-made header)
# ------------------------------------------------------------------------------------------------
_CODE = {"float": "f4", "float32": "f4", "double": "f8", "float64": "f8", "uchar": "u1",
         "uint8": "u1", "char": "i1", "short": "i2", "int16": "i2", "ushort": "u2", "int": "i4",
         "int32": "i4", "uint": "u4"}


def make_ply(props, *, fmt="binary_little_endian", head="", tail_elements="", tail=b""):
    """PLY bytes from ``props = [(type, name, values), ...]`` (a vertex element).

    ``head``: header lines (elements) placed before the vertex element, with their body in
    ``head_body``; ``tail_elements`` / ``tail``: elements after the vertex and their body.
    """
    n = len(props[0][2])
    lines = ["ply", f"format {fmt} 1.0"]
    if head:
        lines.append(head[0])
    lines.append(f"element vertex {n}")
    lines += [f"property {t} {name}" for t, name, _ in props]
    if tail_elements:
        lines.append(tail_elements)
    lines.append("end_header")
    out = ("\n".join(lines) + "\n").encode()
    if head:
        out += head[1]
    if fmt == "ascii":
        rows = []
        for i in range(n):
            rows.append(" ".join(repr(float(v[i])) if _CODE[t][0] == "f" else str(int(v[i]))
                                 for t, _, v in props))
        out += ("\n".join(rows) + ("\n" if rows else "")).encode()
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        table = np.empty(n, dtype=[(name, order + _CODE[t]) for t, name, _ in props])
        for _, name, v in props:
            table[name] = v
        out += table.tobytes()
    return out + tail


def parse_ply(data: bytes) -> dict:
    """Columns of a binary little-endian vertex-only PLY (to inspect what the writer wrote)."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    fields = []
    for line in data[:end].decode().splitlines():
        w = line.split()
        if w[0] == "property":
            fields.append((w[2], "<" + _CODE.get(w[1], w[1].replace("int64", "i8"))))
    return {name: arr for name, arr in
            zip([f for f, _ in fields], _columns(np.frombuffer(data[end:], dtype=fields)))}


def _columns(table):
    return [table[name].copy() for name in table.dtype.names]


def reference_props(n=7, k=4, seed=0):
    """Raw columns in the original 3DGS order, plus view_id and pixel_id."""
    rng = np.random.default_rng(seed)
    f = lambda *s: rng.normal(size=s).astype(np.float32)  # noqa: E731
    props = [("float", c, f(n)) for c in ("x", "y", "z", "nx", "ny", "nz")]
    props += [("float", f"f_dc_{c}", f(n)) for c in range(3)]
    props += [("float", f"f_rest_{j}", f(n)) for j in range(3 * (k - 1))]
    props += [("float", "opacity", (4 * f(n)).astype(np.float32))]
    props += [("float", f"scale_{c}", (f(n) - 3).astype(np.float32)) for c in range(3)]
    props += [("float", f"rot_{c}", f(n)) for c in range(4)]
    props += [("int", "view_id", rng.integers(0, 3, n).astype(np.int32)),
              ("int", "pixel_id", rng.integers(-1, 48, n).astype(np.int32))]
    return props


def random_gaussians(n=9, k=16, seed=1) -> Gaussians:
    rng = np.random.default_rng(seed)
    op = rng.uniform(0, 1, n)
    op[:2] = [0.0, 1.0][:n]
    return Gaussians(rng.normal(size=(n, 3)), np.exp(rng.normal(size=(n, 3)) - 2),
                     rng.normal(size=(n, 4)), op, rng.normal(size=(n, k, 3)))


def sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def assert_same_gaussians(a: Gaussians, b: Gaussians):
    for name in ("means", "scales", "quats", "opacities", "sh"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), name
    pa = {k: v for k, v in a.extra.items() if not k.startswith(RAW_PREFIX)}
    pb = {k: v for k, v in b.extra.items() if not k.startswith(RAW_PREFIX)}
    assert list(pa) == list(pb)
    for k in pa:
        assert pa[k].dtype == pb[k].dtype and np.array_equal(pa[k], pb[k]), k


# ------------------------------------------------------------------------------------------------
# PLY
# ------------------------------------------------------------------------------------------------
def test_read_reference_3dgs_file(tmp_path):
    props = reference_props(n=7, k=4)
    raw = {name: v for _, name, v in props}
    path = tmp_path / "g.ply"
    path.write_bytes(make_ply(props))
    g, view_id, pixel_id = cio.read_ply(path)
    assert len(g) == 7 and g.sh.shape == (7, 4, 3)
    np.testing.assert_array_equal(g.means, np.stack([raw["x"], raw["y"], raw["z"]], 1))
    for i in range(7):
        # per-element closed forms with math (float64), rounded to float32
        assert g.opacities[i] == np.float32(1.0 / (1.0 + math.exp(-float(raw["opacity"][i]))))
        for c in range(3):
            assert g.scales[i, c] == np.float32(math.exp(float(raw[f"scale_{c}"][i])))
            assert g.sh[i, 0, c] == raw[f"f_dc_{c}"][i]
            for j in range(1, 4):   # channel-major: all red bands, then green, then blue
                assert g.sh[i, j, c] == raw[f"f_rest_{c * 3 + j - 1}"][i]
        for c in range(4):
            assert g.quats[i, c] == raw[f"rot_{c}"][i]
    assert list(k for k in g.extra if not k.startswith(RAW_PREFIX)) == ["nx", "ny", "nz"]
    np.testing.assert_array_equal(g.extra["ny"], raw["ny"])
    assert view_id.dtype == np.int32 and np.array_equal(view_id, raw["view_id"])
    assert pixel_id.dtype == np.int64 and np.array_equal(pixel_id, raw["pixel_id"])


def test_unchanged_3dgs_file_is_rewritten_byte_for_byte(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "out.ply"
    src.write_bytes(make_ply(reference_props(n=50, k=16, seed=3)))
    before = sha(src)
    g, view_id, pixel_id = cio.read_ply(src)
    cio.write_ply(out, g, view_id=view_id, pixel_id=pixel_id)
    assert out.read_bytes() == src.read_bytes()
    assert sha(src) == before                      # the input is never modified
    # a copy of the Gaussians (layout attribute lost) still writes the same values
    g2 = dataclasses.replace(g, opacities=g.opacities.copy())
    cio.write_ply(out, g2, view_id=view_id, pixel_id=pixel_id)
    a, b = parse_ply(src.read_bytes()), parse_ply(out.read_bytes())
    assert list(a) == list(b)
    for name in a:
        assert a[name].tobytes() == b[name].tobytes(), name


def test_memory_scene_load_save_load_is_identical(tmp_path):
    g = random_gaussians(n=40, k=16)
    view_id = np.arange(40) % 3
    p1, p2 = tmp_path / "a.ply", tmp_path / "b.ply"
    cio.write_ply(p1, g, view_id=view_id)
    g1, v1, px1 = cio.read_ply(p1)
    assert px1 is None and np.array_equal(v1, view_id)
    # reading back a fresh logit/log is accurate but not bit-exact; the file is
    np.testing.assert_allclose(g1.opacities[2:], g.opacities[2:], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(g1.scales, g.scales, rtol=1e-6)
    assert g1.opacities[0] < 1e-6 and g1.opacities[1] > 1 - 1e-6
    cio.write_ply(p2, g1, view_id=v1)
    assert p2.read_bytes() == p1.read_bytes()
    g2, v2, _ = cio.read_ply(p2)
    assert_same_gaussians(g1, g2)
    assert np.array_equal(v1, v2)


def test_written_values_are_logit_and_log(tmp_path):
    g = random_gaussians(n=12, k=4, seed=5)
    path = tmp_path / "g.ply"
    cio.write_ply(path, g, view_id=np.zeros(12, int), pixel_id=np.arange(12) - 1)
    cols = parse_ply(path.read_bytes())
    names = list(cols)
    assert names[:6] == ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[-2:] == ["view_id", "pixel_id"] and cols["pixel_id"][0] == -1
    for i in range(12):
        o = min(max(float(g.opacities[i]), 1e-7), 1 - 1e-7)
        assert cols["opacity"][i] == np.float32(math.log(o / (1 - o)))
        for c in range(3):
            assert cols[f"scale_{c}"][i] == np.float32(math.log(float(g.scales[i, c])))
            for j in range(1, 4):
                assert cols[f"f_rest_{c * 3 + j - 1}"][i] == g.sh[i, j, c]
    assert cols["opacity"][0] == np.float32(math.log(1e-7 / (1 - 1e-7)))
    assert cols["opacity"][1] == np.float32(math.log((1 - 1e-7) / 1e-7))


def test_zeroing_opacities_changes_only_those_values(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "out.ply"
    src.write_bytes(make_ply(reference_props(n=30, k=4, seed=7)))
    g, view_id, pixel_id = cio.read_ply(src)
    scene_like = dataclasses.replace(g, opacities=g.opacities.copy())  # as Scene.with_opacities
    zeroed = np.array([0, 5, 17])
    scene_like.opacities[zeroed] = 0.0
    scene_like.scales[3, 1] *= 2.0
    cio.write_ply(out, scene_like, view_id=view_id, pixel_id=pixel_id)
    a, b = parse_ply(src.read_bytes()), parse_ply(out.read_bytes())
    for name in a:
        assert a[name].dtype == b[name].dtype, name
        differ = np.flatnonzero((a[name].view(np.uint8).reshape(30, -1)
                                 != b[name].view(np.uint8).reshape(30, -1)).any(1))
        expect = {"opacity": zeroed, "scale_1": [3]}.get(name, [])
        assert list(differ) == list(expect), name
    assert (b["opacity"][zeroed] == np.float32(math.log(1e-7 / (1 - 1e-7)))).all()
    assert b["scale_1"][3] == np.float32(math.log(2.0 * math.exp(float(a["scale_1"][3]))))


def test_ascii_and_big_endian_read_like_little_endian(tmp_path):
    props = reference_props(n=6, k=9, seed=11)
    got = {}
    for fmt in ("binary_little_endian", "binary_big_endian", "ascii"):
        p = tmp_path / f"{fmt}.ply"
        p.write_bytes(make_ply(props, fmt=fmt))
        got[fmt] = cio.read_ply(p)
    ref = got["binary_little_endian"]
    for fmt in ("binary_big_endian", "ascii"):
        assert_same_gaussians(ref[0], got[fmt][0])
        assert np.array_equal(ref[1], got[fmt][1]) and np.array_equal(ref[2], got[fmt][2])
    # rewriting the ascii file gives the binary little-endian file
    out = tmp_path / "out.ply"
    cio.write_ply(out, got["ascii"][0], view_id=got["ascii"][1], pixel_id=got["ascii"][2])
    assert out.read_bytes() == (tmp_path / "binary_little_endian.ply").read_bytes()


def test_types_aliases_and_extras_keep_their_dtype(tmp_path):
    rng = np.random.default_rng(2)
    n = 5
    props = [("double", "x", rng.normal(size=n)), ("float32", "y", rng.normal(size=n)),
             ("float", "z", rng.normal(size=n)), ("short", "flags", rng.integers(-9, 9, n)),
             ("float64", "f_dc_0", rng.normal(size=n)), ("float", "f_dc_1", rng.normal(size=n)),
             ("float", "f_dc_2", rng.normal(size=n)), ("double", "opacity", rng.normal(size=n)),
             ("double", "scale_0", rng.normal(size=n)), ("float", "scale_1", rng.normal(size=n)),
             ("float", "scale_2", rng.normal(size=n)), ("float", "rot_0", 1 + rng.random(n)),
             ("int16", "rot_1", rng.integers(-3, 3, n)), ("float", "rot_2", rng.normal(size=n)),
             ("float", "rot_3", rng.normal(size=n)), ("uchar", "view_id", rng.integers(0, 4, n)),
             ("double", "confidence", rng.random(n)), ("uint8", "label", rng.integers(0, 255, n))]
    src, out = tmp_path / "in.ply", tmp_path / "out.ply"
    src.write_bytes(make_ply(props))
    g, view_id, pixel_id = cio.read_ply(src)
    assert pixel_id is None and view_id.dtype == np.int32
    assert g.extra["flags"].dtype == np.int16 and g.extra["confidence"].dtype == np.float64
    assert g.extra["label"].dtype == np.uint8
    np.testing.assert_array_equal(g.extra["confidence"], props[16][2])
    assert g.means.dtype == np.float32 and g.means[2, 0] == np.float32(props[0][2][2])
    cio.write_ply(out, g, view_id=view_id)
    assert out.read_bytes() == src.read_bytes()        # order, spellings and types kept
    g2, v2, _ = cio.read_ply(out)
    assert_same_gaussians(g, g2)
    # a copy loses the header layout but keeps each column's type and value
    cio.write_ply(out, g.subset(np.arange(n)), view_id=view_id)
    header = out.read_bytes().split(b"end_header")[0].decode()
    assert "property double x" in header and "property short rot_1" in header
    assert "property uchar view_id" in header and "property uchar label" in header
    g3, v3, _ = cio.read_ply(out)
    assert_same_gaussians(g, g3)
    assert np.array_equal(v3, view_id)


def test_other_elements_are_skipped(tmp_path):
    props = reference_props(n=4, k=1)
    face = b"".join(np.array([3], "u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes()
                    for _ in range(2))
    p = tmp_path / "faces.ply"
    p.write_bytes(make_ply(props, tail_elements="element face 2\nproperty list uchar int "
                           "vertex_indices", tail=face))
    g, v, _ = cio.read_ply(p)
    ref, _, _ = cio.read_ply(_write(tmp_path / "plain.ply", make_ply(props)))
    assert_same_gaussians(g, ref)
    # a fixed-size element before the vertices (binary) and ascii elements are skipped too
    head = ("element camera 1\nproperty float fx\nproperty uchar id",
            np.array([500.0], "<f4").tobytes() + b"\x07")
    g, _, _ = cio.read_ply(_write(tmp_path / "cam.ply", make_ply(props, head=head)))
    assert_same_gaussians(g, ref)
    head = ("element camera 1\nproperty float fx", b"500.0\n")
    g, _, _ = cio.read_ply(_write(tmp_path / "a.ply", make_ply(props, fmt="ascii", head=head,
                                  tail_elements="element face 1\nproperty list uchar int v",
                                  tail=b"3 0 1 2\n")))
    assert_same_gaussians(g, ref)


def _write(path, data):
    path.write_bytes(data)
    return path


def test_zero_gaussians_round_trip(tmp_path):
    g = random_gaussians(n=0, k=1)
    p = tmp_path / "empty.ply"
    cio.write_ply(p, g, view_id=np.zeros(0, int))
    g2, v, px = cio.read_ply(p)
    assert len(g2) == 0 and g2.sh.shape == (0, 1, 3) and v.shape == (0,) and px is None


# ------------------------------------------------------------------------------------------------
# cameras
# ------------------------------------------------------------------------------------------------
def _camera(seed=0, w=8, h=6) -> Camera:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = q, rng.normal(size=3)
    K = [[10.0 + seed, 0, w / 2 + 0.25], [0, 11.0, h / 2 - 0.5], [0, 0, 1]]
    return Camera(K=K, camera_to_world=c2w, width=w, height=h)


def test_cameras_json_round_trip_is_exact(tmp_path):
    cams = [_camera(0), _camera(1, w=5, h=9)]
    path = tmp_path / "cameras.json"
    cio.save_cameras(path, cams, ["images/a.png", None])
    got, images = cio.load_cameras(path)
    assert got == cams
    assert images == [tmp_path / "images/a.png", None]
    doc = json.loads(path.read_text())
    assert doc["frames"][0]["image"] == "images/a.png" and "image" not in doc["frames"][1]
    # the paths load_cameras returns are accepted back, and the folder form works
    cio.save_cameras(path, cams, images)
    assert cio.load_cameras(tmp_path) == (cams, images)


def test_transforms_json_gives_the_same_camera(tmp_path):
    cam = _camera(3)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "cameras.json").write_text(json.dumps({"frames": [{
        "image": "images/0.png", "width": cam.width, "height": cam.height,
        "K": cam.K.tolist(), "camera_to_world": cam.camera_to_world.tolist()}]}))
    gl = cam.camera_to_world.copy()
    gl[:, 1:3] *= -1                              # OpenCV -> OpenGL: flip the y and z axes
    (tmp_path / "b" / "transforms.json").write_text(json.dumps({
        "camera_model": "OPENCV", "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
        "w": cam.width, "h": cam.height, "k1": 0.0,
        "frames": [{"file_path": "images/0.png", "transform_matrix": gl.tolist()}]}))
    a, ia = cio.load_cameras(tmp_path / "a")
    b, ib = cio.load_cameras(tmp_path / "b")
    assert a == b == [cam]
    assert ia[0].relative_to(tmp_path / "a") == ib[0].relative_to(tmp_path / "b")
    # per-frame intrinsics win over the top level; written nerfstudio files read back
    doc = json.loads((tmp_path / "b" / "transforms.json").read_text())
    doc["frames"][0].update(fl_x=cam.fx, w=cam.width)
    doc["fl_x"], doc["w"] = 1.0, 3
    (tmp_path / "b" / "transforms.json").write_text(json.dumps(doc))
    assert cio.load_cameras(tmp_path / "b")[0] == [cam]
    out = tmp_path / "c" / "transforms.json"
    out.parent.mkdir()
    cio.save_cameras(out, [cam, _camera(4)], ["x.png", "y.png"])
    assert "transform_matrix" in out.read_text()
    assert cio.load_cameras(out)[0] == [cam, _camera(4)]


def test_transforms_json_defaults(tmp_path):
    gl = np.eye(4)
    p = tmp_path / "transforms.json"
    p.write_text(json.dumps({"camera_angle_x": 2 * math.atan(0.5), "w": 20, "h": 10,
                             "frames": [{"file_path": "./r_0", "transform_matrix": gl.tolist()}]}))
    (tmp_path / "r_0.png").write_bytes(b"")
    (cam,), (img,) = cio.load_cameras(p)
    assert cam.fx == cam.fy == pytest.approx(20.0) and (cam.cx, cam.cy) == (10.0, 5.0)
    assert img == tmp_path / "r_0.png"
    # OpenGL looks down -z: the OpenCV forward axis is world -z
    np.testing.assert_array_equal(cam.camera_to_world[:3, 2], [0, 0, -1])


# ------------------------------------------------------------------------------------------------
# images
# ------------------------------------------------------------------------------------------------
def test_image_modes(tmp_path):
    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    cases = {
        "rgb.png": (Image.fromarray(rgb), rgb / 255),
        "rgba.png": (Image.fromarray(np.dstack([rgb, rgb[..., :1]])), rgb / 255),
        "gray.png": (Image.fromarray(rgb[..., 0]), np.repeat(rgb[..., :1], 3, 2) / 255),
        "la.png": (Image.fromarray(rgb[..., 0]).convert("LA"),
                   np.repeat(rgb[..., :1], 3, 2) / 255),
        "pal.png": (Image.fromarray(rgb).quantize(8), None),
        "bits.png": (Image.fromarray(rgb[..., 0] > 127), np.repeat(rgb[..., :1] > 127, 3, 2)),
    }
    g16 = (rng.integers(0, 65536, (5, 7))).astype(np.uint16)
    cases["gray16.png"] = (Image.fromarray(g16), np.repeat(g16[..., None], 3, 2) / 65535)
    for name, (im, want) in cases.items():
        im.save(tmp_path / name)
        got = cio.read_image(tmp_path / name, expected_size=(7, 5))
        assert got.shape == (5, 7, 3) and got.dtype == np.float32, name
        if want is None:      # palette: the palette colours, in [0, 1]
            with Image.open(tmp_path / name) as pal:
                want = np.asarray(pal.convert("RGB")) / 255
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-7, err_msg=name)


def test_jpeg_and_png_round_trip(tmp_path):
    colour = np.full((16, 16, 3), [0.2, 0.6, 0.8], np.float32)
    Image.fromarray(np.round(colour * 255).astype(np.uint8)).save(tmp_path / "c.jpg", quality=95)
    got = cio.read_image(tmp_path / "c.jpg")
    assert np.abs(got - colour).max() < 3 / 255           # JPEG is lossy
    k = np.random.default_rng(0).integers(0, 256, (4, 3, 3))
    img = (k / 255).astype(np.float32)
    cio.write_image(tmp_path / "k.png", img)
    back = cio.read_image(tmp_path / "k.png")
    assert np.array_equal(back, img)                       # k / 255 reads back exactly
    with Image.open(tmp_path / "k.png") as im:
        assert im.mode == "RGB"


# ------------------------------------------------------------------------------------------------
# bundles
# ------------------------------------------------------------------------------------------------
def make_scene(n=20, views=2, with_pixels=True, seed=0) -> Scene:
    rng = np.random.default_rng(seed)
    cams = [_camera(i, w=8, h=6) for i in range(views)]
    images = [(rng.integers(0, 256, (6, 8, 3)) / 255).astype(np.float32) for _ in cams]
    view_id = rng.integers(0, views, n)
    pixel_id = rng.integers(0, 48, n) if with_pixels else None
    return Scene(random_gaussians(n, k=4, seed=seed), view_id, pixel_id, cams, images)


def assert_same_scene(a: Scene, b: Scene, *, exact_gaussians=False):
    assert a.cameras == b.cameras
    assert np.array_equal(a.view_id, b.view_id) and np.array_equal(a.pixel_id, b.pixel_id)
    if exact_gaussians:
        assert_same_gaussians(a.gaussians, b.gaussians)
    if a.images is None or b.images is None:
        assert a.images is None and b.images is None
    else:
        for x, y in zip(a.images, b.images):
            assert np.array_equal(x, y)


def test_scene_bundle_round_trip(tmp_path):
    scene = make_scene()
    cio.save_scene(scene, tmp_path / "b1")
    assert sorted(p.name for p in (tmp_path / "b1").iterdir()) == \
        ["cameras.json", "gaussians.ply", "images"]
    assert (tmp_path / "b1" / "images" / "001.png").is_file()
    s1 = cio.load_scene(tmp_path / "b1")
    assert_same_scene(scene, s1)
    np.testing.assert_allclose(s1.gaussians.opacities[2:], scene.gaussians.opacities[2:],
                               rtol=1e-5)
    hashes = {p: sha(p) for p in (tmp_path / "b1").rglob("*") if p.is_file()}
    s1.save(tmp_path / "b2")                                     # via Scene.save
    for p, h in hashes.items():                                  # input untouched ...
        assert sha(p) == h
        assert sha(tmp_path / "b2" / p.relative_to(tmp_path / "b1")) == h   # ... and copied
    s2 = cio.load_scene(tmp_path / "b2")
    assert_same_scene(s1, s2, exact_gaussians=True)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp left


def test_scene_without_pixels_or_images(tmp_path):
    scene = make_scene(with_pixels=False)
    scene.images = None
    cio.save_scene(scene, tmp_path / "b")
    assert b"pixel_id" not in (tmp_path / "b" / "gaussians.ply").read_bytes()[:2000]
    with pytest.raises(ClearsplatError, match=r"cameras\.json: frames\[0\]\.image: .*"
                                              r"require_images=False"):
        cio.load_scene(tmp_path / "b")
    s = cio.load_scene(tmp_path / "b", require_images=False)
    assert s.images is None and (s.pixel_id == -1).all()
    # images present on disk but not required: loaded
    cio.save_scene(make_scene(), tmp_path / "c")
    assert cio.load_scene(tmp_path / "c", require_images=False).images is not None


def test_zero_gaussian_scene_loads(tmp_path):
    scene = make_scene(n=0)
    cio.save_scene(scene, tmp_path / "b")
    s = cio.load_scene(tmp_path / "b")
    assert len(s) == 0 and s.num_views == 2


def test_save_scene_refuses_and_overwrites(tmp_path):
    scene = make_scene()
    dest = tmp_path / "out"
    dest.mkdir()
    cio.save_scene(scene, dest)                                   # an empty folder is fine
    with pytest.raises(ClearsplatError, match=r"out: bundle: .*overwrite=True"):
        cio.save_scene(scene, dest)
    (dest / "stale.txt").write_text("old")
    other = make_scene(views=3, seed=5)
    cio.save_scene(other, dest, overwrite=True)
    assert not (dest / "stale.txt").exists()
    assert_same_scene(other, cio.load_scene(dest))
    keep = tmp_path / "notabundle"
    keep.mkdir()
    (keep / "thesis.tex").write_text("precious")
    with pytest.raises(ClearsplatError, match=r"notabundle: bundle: refusing"):
        cio.save_scene(scene, keep, overwrite=True)
    assert (keep / "thesis.tex").read_text() == "precious"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ClearsplatError, match=r"file: bundle: exists and is not a folder"):
        cio.save_scene(scene, tmp_path / "file", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "notabundle", "out"]


def test_failed_save_leaves_nothing(tmp_path):
    scene = make_scene()
    scene.images[1] = scene.images[1][:, :, :2]        # invalid: caught before any write
    with pytest.raises(ClearsplatError, match=r"images\[1\]"):
        cio.save_scene(scene, tmp_path / "x")
    assert list(tmp_path.iterdir()) == []


def test_public_api():
    assert set(cio.__all__) >= {"load_scene", "save_scene", "load_cameras", "save_cameras",
                                "read_ply", "write_ply", "read_image", "write_image"}


@pytest.mark.parametrize("existing", ["missing", "empty folder", "folder", "file"])
def test_swap_into_place_replaces_what_is_there(tmp_path, existing):
    from clearsplat.io import swap_into_place
    src = tmp_path / ".new"
    src.mkdir()
    (src / "a.txt").write_text("new")
    dest = tmp_path / "out"
    if existing == "empty folder":
        dest.mkdir()
    elif existing == "folder":
        dest.mkdir()
        (dest / "old.txt").write_text("old")
    elif existing == "file":
        dest.write_text("old")
    swap_into_place(src, dest)
    assert sorted(p.name for p in dest.iterdir()) == ["a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]     # nothing left beside it
