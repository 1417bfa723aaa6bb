"""COLMAP sparse models: text and binary readers agree, and match cameras.json semantics."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clearsplat import Camera, ClearsplatError
from clearsplat.io.colmap import read_colmap

MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "OPENCV": 4,
             "OPENCV_FISHEYE": 5}


def _model(seed=0):
    """Cameras {id: (model, w, h, params)} and images [(id, qvec wxyz, tvec, cam, name)]."""
    rng = np.random.default_rng(seed)
    cams = {1: ("PINHOLE", 64, 48, [50.0, 52.0, 31.5, 24.25]),
            7: ("SIMPLE_PINHOLE", 40, 30, [33.0, 20.0, 15.0])}
    images = []
    for image_id, name, cam in [(3, "c.png", 1), (1, "b.png", 7), (2, "a.png", 1)]:
        q = Rotation.random(random_state=int(rng.integers(1 << 30))).as_quat()  # xyzw
        images.append((image_id, np.array([q[3], q[0], q[1], q[2]]), rng.normal(size=3), cam,
                       name))
    return cams, images


def _write_txt(folder, cams, images, *, points=True):
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:", "# CAMERA_ID, MODEL, ..."]
    for cid, (model, w, h, params) in cams.items():
        lines.append(" ".join([str(cid), model, str(w), str(h)] + [repr(p) for p in params]))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:"]
    for i, (image_id, q, t, cid, name) in enumerate(images):
        lines.append(" ".join([str(image_id)] + [repr(float(x)) for x in (*q, *t)]
                              + [str(cid), name]))
        lines.append("1.5 2.5 -1 3.0 4.0 17" if points and i % 2 == 0 else "")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")


def _write_bin(folder, cams, images):
    folder.mkdir(parents=True, exist_ok=True)
    out = struct.pack("<Q", len(cams))
    for cid, (model, w, h, params) in cams.items():
        out += struct.pack("<iiQQ", cid, MODEL_IDS[model], w, h)
        out += struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(out)
    out = struct.pack("<Q", len(images))
    for i, (image_id, q, t, cid, name) in enumerate(images):
        out += struct.pack("<i7di", image_id, *q, *t, cid) + name.encode() + b"\x00"
        out += struct.pack("<Q", i) + b"".join(struct.pack("<ddq", 1.0, 2.0, -1)
                                               for _ in range(i))
    (folder / "images.bin").write_bytes(out)


def test_text_and_binary_agree_and_sort_by_name(tmp_path):
    cams, images = _model()
    _write_txt(tmp_path / "txt", cams, images)
    _write_bin(tmp_path / "bin", cams, images)
    c_txt, n_txt = read_colmap(tmp_path / "txt")
    c_bin, n_bin = read_colmap(tmp_path / "bin")
    assert n_txt == n_bin == ["a.png", "b.png", "c.png"]
    for a, b in zip(c_txt, c_bin):
        assert (a.width, a.height) == (b.width, b.height)
        assert np.allclose(a.K, b.K, rtol=0, atol=1e-12)
        assert np.allclose(a.camera_to_world, b.camera_to_world, rtol=0, atol=1e-12)
    by_id, names = read_colmap(tmp_path / "bin", order="id")
    assert names == ["b.png", "a.png", "c.png"]


def test_projection_matches_colmap_and_cameras_json_semantics(tmp_path):
    cams, images = _model(seed=3)
    _write_txt(tmp_path, cams, images)
    cameras, names = read_colmap(tmp_path)
    rng = np.random.default_rng(4)
    for cam, name in zip(cameras, names):
        image_id, q, t, cid, _ = next(r for r in images if r[4] == name)
        model, w, h, p = cams[cid]
        fx, fy, cx, cy = (p[0], p[1], p[2], p[3]) if model == "PINHOLE" else (p[0], p[0], p[1],
                                                                               p[2])
        rot = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()   # world -> camera
        pc = rng.normal(size=(20, 3)) * [1, 1, 0.3] + [0, 0, 4]          # in front of it
        world = (pc - t) @ rot                                            # R^T (pc - t)
        uv, z = cam.project(world)
        expect = np.stack([fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy], 1)
        assert np.allclose(uv, expect, atol=1e-9) and np.allclose(z, pc[:, 2], atol=1e-12)
        # the same camera written as cameras.json would hold it
        same = Camera(K=[[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                      camera_to_world=np.linalg.inv(np.vstack([np.c_[rot, t], [0, 0, 0, 1]])),
                      width=w, height=h)
        assert np.allclose(same.project(world)[0], uv, atol=1e-9)
        assert np.allclose(same.camera_to_world, cam.camera_to_world, atol=1e-12)


def test_sparse_zero_folder_and_empty_point_lines(tmp_path):
    cams, images = _model()
    _write_txt(tmp_path / "sparse" / "0", cams, images, points=False)
    cameras, names = read_colmap(tmp_path)
    assert len(cameras) == 3 and names[0] == "a.png"


def test_distortion_refused_ignored_or_zero(tmp_path):
    cams, images = _model()
    cams[1] = ("OPENCV", 64, 48, [50.0, 52.0, 31.5, 24.25, 0.1, 0.0, 0.0, 0.0])
    _write_bin(tmp_path, cams, images)
    with pytest.raises(ClearsplatError, match="undistort") as e:
        read_colmap(tmp_path)
    assert e.value.field == "camera 1" and e.value.path.endswith("cameras.bin")
    with pytest.warns(UserWarning, match="ignoring OPENCV distortion"):
        cameras, _ = read_colmap(tmp_path, distortion="ignore")
    assert np.allclose(cameras[0].K, [[50, 0, 31.5], [0, 52, 24.25], [0, 0, 1]])
    cams[1] = ("SIMPLE_RADIAL", 64, 48, [50.0, 31.5, 24.25, 0.0])
    _write_bin(tmp_path, cams, images)
    assert read_colmap(tmp_path)[0][0].fx == 50.0           # zero distortion: a pinhole
    cams[1] = ("OPENCV_FISHEYE", 64, 48, [50.0, 52.0, 31.5, 24.25, 0, 0, 0, 0])
    _write_bin(tmp_path, cams, images)
    with pytest.raises(ClearsplatError, match="fisheye"):
        read_colmap(tmp_path, distortion="ignore")


def test_bad_input_names_file_and_field(tmp_path):
    cams, images = _model()
    with pytest.raises(ClearsplatError, match="no COLMAP model"):
        read_colmap(tmp_path)
    _write_txt(tmp_path, cams, images)
    text = (tmp_path / "images.txt").read_text().replace(" 7 b.png", " 9 b.png")
    (tmp_path / "images.txt").write_text(text)
    with pytest.raises(ClearsplatError, match="camera 9") as e:
        read_colmap(tmp_path)
    assert e.value.field == "CAMERA_ID" and e.value.path.endswith("images.txt")
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50.0 52.0 31.5\n")
    with pytest.raises(ClearsplatError, match="takes 4 parameters") as e:
        read_colmap(tmp_path)
    assert e.value.field == "line 1" and e.value.path.endswith("cameras.txt")
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 64 48 50.0 52.0 31.5 x\n")
    with pytest.raises(ClearsplatError, match="malformed"):
        read_colmap(tmp_path)
    _write_txt(tmp_path, cams, images)
    text = (tmp_path / "images.txt").read_text().splitlines()
    text[1] = " ".join(["4", "0", "0", "0", "0"] + text[1].split()[5:])
    (tmp_path / "images.txt").write_text("\n".join(text) + "\n")
    with pytest.raises(ClearsplatError, match="zero or non-finite pose"):
        read_colmap(tmp_path)
    folder = tmp_path / "bin"
    _write_bin(folder, cams, images)
    data = (folder / "images.bin").read_bytes()
    (folder / "images.bin").write_bytes(data[:-7])
    with pytest.raises(ClearsplatError, match="truncated") as e:
        read_colmap(folder)
    assert e.value.path.endswith("images.bin")
    with pytest.raises(ClearsplatError) as e:
        read_colmap(folder, order="size")
    assert e.value.field == "order"
