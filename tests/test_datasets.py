"""RobustNeRF and NeRF On-the-go readers, the paper's view configurations, ``prepare`` / ``eval``.

The miniature datasets are built here from a synthetic world, in the published layouts:
RobustNeRF ``images/`` + COLMAP ``sparse/0`` (text or binary; ``*clutter*`` training and
``*extra*`` test images) and On-the-go ``images/`` + ``transforms.json`` + ``split.json``.
Sparse points are back-projected pixels; a view observes a point when it projects inside the
image at the depth of the view's depth map.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clearsplat import ClearsplatError
from clearsplat.evaluate import (evaluate_prediction, format_table, view_configurations,
                                 write_configurations)
from clearsplat.io.datasets import (read_colmap_points, read_dataset, read_onthego,
                                    read_robustnerf)

H, W = 32, 48


# ------------------------------------------------------------------------------------------------
# miniature datasets
# ------------------------------------------------------------------------------------------------
def _quat(R):
    """wxyz quaternion of a rotation matrix (COLMAP's QW QX QY QZ)."""
    w = np.sqrt(max(1.0 + np.trace(R), 1e-12)) / 2
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                     (R[1, 0] - R[0, 1]) / (4 * w)])


def _observes(cam, depth, pts):
    """(P,) bool and pixel coordinates: points in front, inside, at the depth map's depth."""
    w2c = np.linalg.inv(cam.camera_to_world)
    pc = pts @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    uv = (pc[:, :2] / np.maximum(z, 1e-9)[:, None]) @ cam.K[:2, :2].T + cam.K[:2, 2]
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
    ok = np.zeros(len(pts), bool)
    d = depth[row[inside], col[inside]]
    ok[inside] = np.abs(d - z[inside]) < 0.02 * z[inside]
    return ok, uv


@pytest.fixture(scope="module")
def world():
    from clearsplat.synth import make_world
    return make_world("object", num_views=10, height=H, width=W, num_test_views=4, seed=0)


def _views(world):
    """All views in capture order: input i, then test i (between inputs i and i+1)."""
    out = []
    for i in range(len(world.cameras)):
        out.append(("clutter", i, world.cameras[i], world.images[i], world.depths[i]))
        if i < len(world.test_cameras):
            out.append(("extra", i, world.test_cameras[i], world.test_images[i],
                        world.test_depths[i]))
    return out


def _sparse(world, rng):
    views = _views(world)
    pts = []
    for _, _, cam, _, depth in views:
        rows, cols = np.mgrid[2:H:6, 2:W:6]
        rows, cols = rows.ravel(), cols.ravel()
        z = depth[rows, cols]
        keep = np.isfinite(z) & (z > 0)
        uv1 = np.stack([cols[keep] + 0.5, rows[keep] + 0.5, np.ones(keep.sum())], 1)
        pc = (uv1 @ np.linalg.inv(cam.K).T) * z[keep, None]
        pts.append(pc @ cam.camera_to_world[:3, :3].T + cam.camera_to_world[:3, 3])
    pts = np.concatenate(pts)
    pts = pts[rng.permutation(len(pts))[:400]]
    seen = [_observes(cam, depth, pts) for _, _, cam, _, depth in views]
    return views, pts, seen


def write_robustnerf(root: Path, world, *, binary=False, seed=0) -> dict:
    """RobustNeRF layout; returns the expected visibility per image name."""
    views, pts, seen = _sparse(world, np.random.default_rng(seed))
    (root / "images").mkdir(parents=True)
    model = root / "sparse" / "0"
    model.mkdir(parents=True)
    names, images, tracks = [], [], {p: [] for p in range(len(pts))}
    for k, (kind, i, cam, img, _) in enumerate(views):
        name = f"{1 + (kind == 'extra')}{kind}{i:03d}.png"
        names.append(name)
        Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)).save(
            root / "images" / name)
        w2c = np.linalg.inv(cam.camera_to_world)
        ok, uv = seen[k]
        obs = [(float(uv[p, 0]), float(uv[p, 1]), int(p) + 1) for p in np.flatnonzero(ok)]
        for j, (_, _, pid) in enumerate(obs):
            tracks[pid - 1].append((k + 10, j))          # image ids 10, 11, ...
        images.append((k + 10, _quat(w2c[:3, :3]), w2c[:3, 3], k + 1, name, obs, cam))
    if binary:
        out = struct.pack("<Q", len(images))
        for (_, _, _, cid, _, _, cam) in images:
            K = cam.K
            out += struct.pack("<iiQQ", cid, 1, cam.width, cam.height)
            out += struct.pack("<4d", K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        (model / "cameras.bin").write_bytes(out)
        out = struct.pack("<Q", len(images))
        for (iid, q, t, cid, name, obs, _) in images:
            out += struct.pack("<i7di", iid, *q, *t, cid) + name.encode() + b"\x00"
            out += struct.pack("<Q", len(obs)) + b"".join(struct.pack("<ddq", *o) for o in obs)
        (model / "images.bin").write_bytes(out)
        out = struct.pack("<Q", len(pts))
        for p in range(len(pts)):
            out += struct.pack("<Q3d3Bd", p + 1, *pts[p], 128, 128, 128, 0.5)
            out += struct.pack("<Q", len(tracks[p])) + b"".join(
                struct.pack("<ii", *t) for t in tracks[p])
        (model / "points3D.bin").write_bytes(out)
    else:
        lines = []
        for (_, _, _, cid, _, _, cam) in images:
            K = cam.K
            lines.append(f"{cid} PINHOLE {cam.width} {cam.height} {float(K[0, 0])!r} {float(K[1, 1])!r} "
                         f"{float(K[0, 2])!r} {float(K[1, 2])!r}")
        (model / "cameras.txt").write_text("# cameras\n" + "\n".join(lines) + "\n")
        lines = ["# images"]
        for (iid, q, t, cid, name, obs, _) in images:
            lines.append(" ".join([str(iid)] + [repr(float(x)) for x in (*q, *t)]
                                  + [str(cid), name]))
            lines.append(" ".join(f"{x!r} {y!r} {pid}" for x, y, pid in obs))
        (model / "images.txt").write_text("\n".join(lines) + "\n")
        lines = ["# points"]
        for p in range(len(pts)):
            lines.append(" ".join([str(p + 1)] + [repr(float(x)) for x in pts[p]]
                                  + ["128", "128", "128", "0.5"]
                                  + [f"{i} {j}" for i, j in tracks[p]]))
        (model / "points3D.txt").write_text("\n".join(lines) + "\n")
    return {name: np.flatnonzero(seen[k][0]) + 1 for k, name in enumerate(names)}


def write_onthego(root: Path, world, *, seed=0) -> list:
    """On-the-go layout (frames shuffled: split indices refer to sorted names); returns the
    (kind, index) of each image in name order."""
    write_robustnerf(root, world, seed=seed)            # images and sparse/0 first
    order = []
    frames = []
    for k, (kind, i, cam, _, _) in enumerate(_views(world)):
        old = root / "images" / f"{1 + (kind == 'extra')}{kind}{i:03d}.png"
        new = f"IMG_{k:04d}.png"
        old.rename(root / "images" / new)
        order.append((kind, i))
        gl = cam.camera_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"images/{new}", "transform_matrix": gl.tolist(),
                       "fl_x": cam.K[0, 0], "fl_y": cam.K[1, 1], "cx": cam.K[0, 2],
                       "cy": cam.K[1, 2], "w": cam.width, "h": cam.height})
    # COLMAP names follow the renamed files
    txt = (root / "sparse" / "0" / "images.txt").read_text()
    for k, (kind, i) in enumerate(order):
        txt = txt.replace(f" {1 + (kind == 'extra')}{kind}{i:03d}.png", f" IMG_{k:04d}.png")
    (root / "sparse" / "0" / "images.txt").write_text(txt)
    rng = np.random.default_rng(seed)
    frames = [frames[j] for j in rng.permutation(len(frames))]
    (root / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV",
                                                      "frames": frames}))
    (root / "split.json").write_text(json.dumps({
        "clutter": [k for k, (kind, _) in enumerate(order) if kind == "clutter"],
        "extra": [k for k, (kind, _) in enumerate(order) if kind == "extra"]}))
    return order


# ------------------------------------------------------------------------------------------------
# readers
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("binary", [False, True])
def test_robustnerf_reader(world, tmp_path, binary):
    expected = write_robustnerf(tmp_path / "statue", world, binary=binary)
    d = read_robustnerf(tmp_path / "statue")
    assert (d.kind, d.name) == ("robustnerf", "statue")
    assert d.names == sorted(expected)
    assert [d.names[i] for i in d.train] == [f"1clutter{i:03d}.png" for i in range(10)]
    assert [d.names[i] for i in d.test] == [f"2extra{i:03d}.png" for i in range(4)]
    for name, cam, vis in zip(d.names, d.cameras, d.visibility):
        kind, i = ("extra", int(name[6:9])) if "extra" in name else ("clutter", int(name[8:11]))
        truth = world.test_cameras[i] if kind == "extra" else world.cameras[i]
        np.testing.assert_allclose(cam.camera_to_world, truth.camera_to_world, atol=1e-9)
        np.testing.assert_allclose(cam.K, truth.K)
        np.testing.assert_array_equal(vis, expected[name])
    assert sum(len(v) for v in d.visibility) > 400       # points seen from several views
    ids, tracks = read_colmap_points(tmp_path / "statue" / "sparse" / "0")
    assert len(ids) == 400 and all(t.dtype == np.int64 for t in tracks)
    assert read_dataset(tmp_path / "statue").names == d.names


def test_onthego_reader(world, tmp_path):
    order = write_onthego(tmp_path / "patio", world)
    d = read_onthego(tmp_path / "patio")
    assert (d.kind, d.name) == ("onthego", "patio")
    assert d.names == [f"IMG_{k:04d}.png" for k in range(len(order))]
    assert [order[i] for i in d.train] == [("clutter", i) for i in range(10)]
    assert [order[i] for i in d.test] == [("extra", i) for i in range(4)]
    for (kind, i), cam in zip(order, d.cameras):
        truth = world.test_cameras[i] if kind == "extra" else world.cameras[i]
        np.testing.assert_allclose(cam.camera_to_world, truth.camera_to_world, atol=1e-9)
    r = read_robustnerf(tmp_path / "patio") if False else None   # names differ: not RobustNeRF
    assert r is None
    assert read_dataset(tmp_path / "patio").kind == "onthego"
    assert all(len(v) for v in d.visibility)


def test_downscaled_images_scale_the_cameras(world, tmp_path):
    write_robustnerf(tmp_path / "s", world)
    (tmp_path / "s" / "images_2").mkdir()
    for p in (tmp_path / "s" / "images").iterdir():
        Image.open(p).resize((W // 2, H // 2)).save(tmp_path / "s" / "images_2" / p.name)
    full, half = read_dataset(tmp_path / "s"), read_dataset(tmp_path / "s", images="images_2")
    for a, b in zip(full.cameras, half.cameras):
        assert (b.width, b.height) == (W // 2, H // 2)
        np.testing.assert_allclose(b.K[:2], a.K[:2] / 2)
        np.testing.assert_allclose(b.camera_to_world, a.camera_to_world)


def test_bad_layouts_name_file_and_field(world, tmp_path):
    root = tmp_path / "g"
    write_onthego(root, world)
    split = json.loads((root / "split.json").read_text())
    for bad, fragment in (({"clutter": split["clutter"]}, "extra"),
                          ({**split, "extra": [99]}, "out of range"),
                          ({**split, "extra": [split["clutter"][0]]}, "both")):
        (root / "split.json").write_text(json.dumps(bad))
        with pytest.raises(ClearsplatError, match=fragment) as e:
            read_onthego(root)
        assert e.value.path.endswith("split.json")
    (root / "split.json").write_text("{")
    with pytest.raises(ClearsplatError, match="split.json"):
        read_onthego(root)

    root = tmp_path / "r"
    write_robustnerf(root, world)
    next((root / "images").glob("2extra000.png")).unlink()
    with pytest.raises(ClearsplatError, match="missing.*2extra000.png"):
        read_robustnerf(root)
    for p in (root / "images").glob("2extra*"):
        p.unlink()
    txt = root / "sparse" / "0" / "images.txt"
    lines = txt.read_text().splitlines()
    keep = [i for i in range(1, len(lines), 2) if "extra" not in lines[i]]
    txt.write_text("\n".join(["# images"] + [x for i in keep for x in lines[i:i + 2]]) + "\n")
    with pytest.raises(ClearsplatError, match="no 'extra' image"):
        read_robustnerf(root)
    with pytest.raises(ClearsplatError, match="not a RobustNeRF scene"):
        read_dataset(tmp_path)
    (root / "sparse" / "0" / "points3D.txt").write_text("1 0 0 0 1 2 3 0.5 10\n")
    with pytest.raises(ClearsplatError, match="line 1"):
        read_colmap_points(root / "sparse" / "0")


# ------------------------------------------------------------------------------------------------
# view configurations, against a reference written with Python sets
# ------------------------------------------------------------------------------------------------
def _reference(d, n, count, num_test):
    P = [set(v.tolist()) for v in d.visibility]

    def joint(ins, tests):
        return len(set().union(*(P[i] for i in ins)) & set().union(*(P[t] for t in tests)))

    pairs = sorted(((-len(P[i] & P[t]), i, t) for i in d.train for t in d.test))
    seeds, used_i, used_t = [], set(), set()
    for _, i, t in pairs:
        if i not in used_i and t not in used_t and len(seeds) < count:
            seeds.append((i, t))
            used_i.add(i)
            used_t.add(t)
    out = []
    for i0, t0 in seeds:
        ins, tests = [i0], [t0]
        while len(ins) < n or len(tests) < min(num_test, len(d.test)):
            if len(ins) < n:
                other = set().union(*(P[t] for t in tests))
                ins.append(min((c for c in d.train if c not in ins), key=lambda c: (
                    -(joint(ins + [c], tests) - joint(ins, tests)), -len(P[c] & other), c)))
            if len(tests) < min(num_test, len(d.test)):
                other = set().union(*(P[i] for i in ins))
                tests.append(min((c for c in d.test if c not in tests), key=lambda c: (
                    -(joint(ins, tests + [c]) - joint(ins, tests)), -len(P[c] & other), c)))
        out.append((ins, tests, joint(ins, tests)))
    return out


@pytest.mark.parametrize("n", [1, 4, 8])
def test_view_configurations_follow_the_rule(world, tmp_path, n):
    write_robustnerf(tmp_path / "s", world, seed=n)
    d = read_dataset(tmp_path / "s")
    configs = view_configurations(d, n, count=4, num_test=2)
    assert [(c.inputs, c.test, c.covisibility) for c in configs] == _reference(d, n, 4, 2)
    assert [c.index for c in configs] == [0, 1, 2, 3]
    assert len({c.inputs[0] for c in configs}) == 4 and len({c.test[0] for c in configs}) == 4
    for c in configs:
        assert len(c.inputs) == len(set(c.inputs)) == n and set(c.inputs) <= set(d.train)
        assert len(c.test) == len(set(c.test)) == 2 and set(c.test) <= set(d.test)
        assert c.covisibility > 0
    # the first configuration starts from the pair sharing the most points
    best = max(len(np.intersect1d(d.visibility[i], d.visibility[t]))
               for i in d.train for t in d.test)
    assert len(np.intersect1d(d.visibility[configs[0].inputs[0]],
                              d.visibility[configs[0].test[0]])) == best
    with pytest.raises(ClearsplatError, match="11 input views asked for"):
        view_configurations(d, 11)


# ------------------------------------------------------------------------------------------------
# prepare -> backbone -> filter -> eval
# ------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_prepare_filter_eval(world, tmp_path, capsys):
    from clearsplat.batch import filter_scene
    from clearsplat.cli import main
    from clearsplat.io import load_cameras, read_image, read_ply
    from clearsplat.metrics import lpips_available, psnr, ssim
    from clearsplat.render import render_batch
    from clearsplat.synth import reconstruct

    write_robustnerf(tmp_path / "data" / "statue", world)
    write_onthego(tmp_path / "data" / "patio", world, seed=1)
    code = main(["prepare", str(tmp_path / "data" / "statue"), str(tmp_path / "data" / "patio"),
                 "--out", str(tmp_path / "prep"), "--views", "4,8", "--configs", "2",
                 "--test-views", "2"])
    out = capsys.readouterr()
    assert code == 0, out.err
    bundles = sorted((tmp_path / "prep").glob("*/*"))
    assert [b.parent.name for b in bundles].count("robustnerf") == 4
    assert {b.name for b in bundles if b.parent.name == "onthego"} == {
        f"patio-{n}v-c{k}" for n in (4, 8) for k in range(2)}

    depth_of = {}                   # the "backbone": depth maps of the world's input views
    for i, cam in enumerate(world.cameras):
        depth_of[f"1clutter{i:03d}.png"] = world.depths[i]
    onthego = read_dataset(tmp_path / "data" / "patio")
    order = write_onthego(tmp_path / "again", world, seed=1)
    for name, (kind, i) in zip(onthego.names, order):
        if kind == "clutter":
            depth_of[name] = world.depths[i]
    for b in bundles:
        meta = json.loads((b / "view_config.json").read_text())
        cams, paths = load_cameras(b)
        assert [p.name for p in paths] == meta["input_images"]
        imgs = [read_image(p) for p in paths]
        scene = reconstruct(cams, imgs, [depth_of[p.name] for p in paths], seed=0)
        scene.save(b / "pred")
        (b / "pred" / "gaussians.ply").rename(b / "gaussians.ply")
        filter_scene(b, tmp_path / "filtered" / b.name)

    code = main(["eval", str(tmp_path / "prep" / "*" / "*"), "--filtered",
                 str(tmp_path / "filtered"), "--label", "Backbone", "--json",
                 str(tmp_path / "scores.json")])
    out = capsys.readouterr()
    assert code == 0, out.err
    lines = out.out.splitlines()
    assert "4 views" in lines[0] and "8 views" in lines[0]
    assert lines[1].split() == ["Method"] + ["PSNR", "SSIM", "LPIPS"] * 2
    assert lines[2] == "RobustNeRF dataset (1 scene)"
    assert lines[3].startswith("Backbone") and lines[4].startswith("+ filter")
    assert lines[5] == "NeRF On-the-go dataset (1 scene)"
    rows = json.loads((tmp_path / "scores.json").read_text())
    assert len(rows) == 8

    # one bundle scored by hand: render, PSNR / SSIM against the test images
    b = bundles[0]
    cams, paths = load_cameras(b / "test")
    truth = [read_image(p) for p in paths]
    by_hand = {}
    for part, folder in (("prediction", b), ("filtered", tmp_path / "filtered" / b.name)):
        g, _, _ = read_ply(folder / "gaussians.ply")
        r = [x.rgb for x in render_batch(g, cams)]
        by_hand[part] = (np.mean([psnr(x, y) for x, y in zip(r, truth)]),
                         np.mean([ssim(x, y) for x, y in zip(r, truth)]))
    row = evaluate_prediction(b, tmp_path / "filtered" / b.name)
    for part in ("prediction", "filtered"):
        assert row[part]["psnr"] == pytest.approx(by_hand[part][0], rel=1e-12)
        assert row[part]["ssim"] == pytest.approx(by_hand[part][1], rel=1e-12)
        if not lpips_available():
            assert row[part]["lpips"] is None
    # the table's cells: mean over configurations of the scene (one scene per dataset)
    agg = [r for r in rows if r["dataset"] == "robustnerf" and r["views"] == 4]
    cell = np.mean([r["filtered"]["psnr"] for r in agg])
    assert f"{cell:8.2f}" in lines[4][:22 + 8]
    if not lpips_available():
        assert "n/a" in lines[3] and lines[-2].startswith("LPIPS n/a")


def test_eval_without_filtered_output_and_table_shape(tmp_path):
    rows = [{"dataset": "onthego", "scene": s, "views": v, "config": c,
             "prediction": {"psnr": p, "ssim": 0.5, "lpips": None}, "filtered": None}
            for s, p0 in (("a", 10.0), ("b", 20.0)) for v in (4,) for c, p in
            ((0, p0), (1, p0 + 2), (2, p0 + 4))]
    table = format_table(rows).splitlines()
    assert table[2] == "NeRF On-the-go dataset (2 scenes)"
    assert table[3].split() == ["Prediction", "17.00", "0.500", "n/a"]   # (12 + 22) / 2
    assert "+ filter" not in "\n".join(table)
    with pytest.raises(ClearsplatError, match="view_config.json"):
        evaluate_prediction(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ClearsplatError, match="clearsplat did not write it"):
        write_configurations([], tmp_path)
    assert (tmp_path / "notes.txt").read_text() == "mine"
