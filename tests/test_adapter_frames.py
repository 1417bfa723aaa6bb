"""Adapters: frames and association that the models' code decides (train-mode batches,
YoNoSplat's two pose settings, AnySplat's pixel convention and voxel indices)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clearsplat import Camera, ClearsplatError
from clearsplat.adapters import (anysplat_voxel_inverse, from_anysplat, from_depthsplat,
                                 from_yonosplat)
from clearsplat.cameras import look_at
from clearsplat.io.importers import _residuals

try:
    import torch
except ImportError:
    torch = None

H, W = 12, 16


def _cameras(v=2):
    K = np.array([[18.0, 0, W / 2], [0, 18.0, H / 2], [0, 0, 1]])
    return [Camera(K=K, camera_to_world=look_at(np.array([0.4 * i + 1.0, 0.3, -3.0 + 0.2 * i]),
                                                 [0, 0, 0], up=(0.0, -1.0, 0.0)),
                   width=W, height=H) for i in range(v)]


def _per_pixel(cams, *, shift=0.5, frame=None):
    """One Gaussian per pixel at ``(col + shift, row + shift)``, in ``frame`` (4x4, world to
    the frame the model works in; default world)."""
    pts = []
    for cam in cams:
        rows, cols = np.mgrid[0:H, 0:W]
        x = (cols + shift - cam.cx) / cam.fx
        y = (rows + shift - cam.cy) / cam.fy
        d = 3.0 + 0.1 * np.sin(cols)
        pc = np.stack([x * d, y * d, d], -1).reshape(-1, 3)
        pts.append(pc @ cam.camera_to_world[:3, :3].T + cam.position)
    means = np.concatenate(pts)
    if frame is not None:
        means = means @ frame[:3, :3].T + frame[:3, 3]
    n = len(means)
    g = {"means": means[None], "covariances": np.broadcast_to(1e-4 * np.eye(3), (1, n, 3, 3)),
         "harmonics": np.zeros((1, n, 3, 1)), "opacities": np.full((1, n), 0.5)}
    return g


def _ext_intr(cams):
    ext = np.stack([c.camera_to_world for c in cams])[None]
    intr = np.stack([np.diag([1 / W, 1 / H, 1.0]) @ c.K for c in cams])[None]
    return ext, intr


def _offsets(scene):
    """Each Gaussian's projection minus its pixel centre, in pixels."""
    return _residuals(scene.gaussians.means.astype(np.float64), scene.cameras, scene.view_id,
                      scene.pixel_id)


def _inside(scene):
    return float((np.abs(_offsets(scene)) <= 0.5 + 1e-6).all(axis=1).mean())


def test_depthsplat_train_mode_batch_concat_is_refused():
    cams = _cameras()
    g = _per_pixel(cams)
    ext, intr = _ext_intr(cams)
    three = {k: np.concatenate([a] * 3) for k, a in g.items()}   # 2 intermediate + final
    with pytest.raises(ClearsplatError, match="eval") as e:
        from_depthsplat(three, ext, intr, height=H, width=W)
    assert e.value.field == "gaussians"
    last = {k: a[-1:] for k, a in three.items()}
    assert from_depthsplat(last, ext, intr, height=H, width=W).is_pixel_aligned


def test_yonosplat_relative_and_absolute_poses():
    world = _cameras()
    first = world[0].camera_to_world
    rel = [Camera(K=c.K, camera_to_world=np.linalg.inv(first) @ c.camera_to_world,
                  width=W, height=H) for c in world]
    ext_w, intr = _ext_intr(world)
    ext_r, _ = _ext_intr(rel)
    # pose_free: placed with the predicted relative poses -> first view's frame
    g_rel = _per_pixel(world, frame=np.linalg.inv(first))
    a = from_yonosplat(g_rel, ext_r, intr, height=H, width=W)
    b = from_yonosplat(g_rel, ext_w, intr, height=H, width=W)        # moved to the world
    assert _inside(a) == 1.0 and _inside(b) == 1.0
    # pose_free: false with absolute poses: already in the world
    g_abs = _per_pixel(world)
    c = from_yonosplat(g_abs, ext_w, intr, height=H, width=W, frame="extrinsics")
    assert _inside(c) == 1.0
    wrong = from_yonosplat(g_abs, ext_w, intr, height=H, width=W)    # moved twice
    assert _inside(wrong) < 0.1
    # with relative poses both settings agree
    d = from_yonosplat(g_rel, ext_r, intr, height=H, width=W, frame="extrinsics")
    assert np.array_equal(d.gaussians.means, a.gaussians.means)
    with pytest.raises(ClearsplatError) as e:
        from_yonosplat(g_rel, ext_r, intr, height=H, width=W, frame="world")
    assert e.value.field == "frame"


def test_anysplat_vggt_half_pixel():
    cams = _cameras()
    g = _per_pixel(cams, shift=0.0)            # VGGT: pixel (row, col) at (col, row)
    ext, intr = _ext_intr(cams)
    scene = from_anysplat(g, ext, intr, height=H, width=W)
    assert np.abs(_offsets(scene)).max() < 1e-4             # on the pixel centres
    assert scene.cameras[0].cx == cams[0].cx + 0.5
    plain = from_anysplat(g, ext, intr, height=H, width=W, vggt_pixels=False)
    assert np.allclose(_offsets(plain), -0.5, atol=1e-4)    # on the pixel corners


def _torch_voxel_inverse(enc, depth, voxel_size):
    """The encoder's computation, step by step in PyTorch (VGGT's pose decoding and
    unprojection, ``torch.unique(dim=0, return_inverse=True)``)."""
    t, q = enc[..., :3], enc[..., 3:7]
    i, j, k, r = torch.unbind(q, -1)
    two_s = 2.0 / (q * q).sum(-1)
    rot = torch.stack((1 - two_s * (j * j + k * k), two_s * (i * j - k * r),
                       two_s * (i * k + j * r), two_s * (i * j + k * r),
                       1 - two_s * (i * i + k * k), two_s * (j * k - i * r),
                       two_s * (i * k - j * r), two_s * (j * k + i * r),
                       1 - two_s * (i * i + j * j)), -1).reshape(q.shape[:-1] + (3, 3))
    b, v, h, w = depth.shape
    fy = (h / 2.0) / (torch.tan(enc[..., 7] / 2.0) + 1e-3)
    fx = (w / 2.0) / (torch.tan(enc[..., 8] / 2.0) + 1e-3)
    u = torch.arange(w)[None, None, :].expand(b * v, h, w)
    vv = torch.arange(h)[None, :, None].expand(b * v, h, w)
    dd = depth.flatten(0, 1)
    x = (u - w / 2) * dd / fx.flatten()[:, None, None]
    y = (vv - h / 2) * dd / fy.flatten()[:, None, None]
    cam = torch.stack((x, y, dd), -1)
    rt = rot.flatten(0, 1).transpose(1, 2)
    c2w = torch.eye(4)[None].repeat(b * v, 1, 1)
    c2w[:, :3, :3] = rt
    c2w[:, :3, 3:] = -torch.bmm(rt, t.flatten(0, 1)[..., None])
    homo = torch.cat((cam, torch.ones_like(cam[..., :1])), -1).flatten(1, 2)
    pts = torch.bmm(c2w, homo.transpose(1, 2)).transpose(1, 2)[:, :, :3].reshape(b, v, h, w, 3)
    idx = (pts[0].reshape(-1, 3) / voxel_size).round().int()
    return torch.unique(idx, dim=0, return_inverse=True)[1].numpy()


@pytest.mark.skipif(torch is None, reason="needs PyTorch for the reference")
def test_anysplat_voxel_inverse_matches_the_encoder_computation():
    rng = np.random.default_rng(3)
    v, h, w = 3, 24, 32
    quat = Rotation.random(v, random_state=4).as_quat()
    enc = np.concatenate([rng.normal(scale=0.3, size=(v, 3)), quat,
                          np.full((v, 2), 1.1)], axis=1)[None].astype(np.float32)
    depth = (1.0 + 0.5 * rng.random((1, v, h, w))).astype(np.float32)
    voxel = 0.05
    ref = _torch_voxel_inverse(torch.from_numpy(enc), torch.from_numpy(depth), voxel)
    got = anysplat_voxel_inverse(torch.from_numpy(enc), torch.from_numpy(depth),
                                 voxel_size=voxel)
    assert got.shape == (v * h * w,)
    # same voxels up to float32 round-off at boundaries (the docstring's caveat)
    assert (got == ref).mean() > 0.999
    count = int(ref.max()) + 1
    assert count < v * h * w                       # voxels do fuse pixels here
    same_count = anysplat_voxel_inverse(enc, depth, voxel_size=voxel)
    with pytest.raises(ClearsplatError) as e:
        anysplat_voxel_inverse(enc, depth, voxel_size=voxel, num_gaussians=same_count.max())
    assert e.value.field == "voxel_inverse"
    scene = from_anysplat({"means": np.zeros((1, count, 3)),
                           "covariances": np.broadcast_to(np.eye(3), (1, count, 3, 3)),
                           "harmonics": np.zeros((1, count, 3, 1)),
                           "opacities": np.full((1, count), 0.5)},
                          np.broadcast_to(np.eye(4), (1, v, 4, 4)),
                          np.broadcast_to(np.diag([1.0, 1.0, 1.0]), (1, v, 3, 3)),
                          height=h, width=w, voxel_inverse=got)
    assert len(scene) == count and (scene.pixel_id == -1).all()


def test_anysplat_example_dry_run(tmp_path):
    import runpy
    from pathlib import Path

    from clearsplat.io import load_scene

    path = Path(__file__).parent.parent / "examples" / "anysplat_inference.py"
    runpy.run_path(str(path), run_name="example")["main"](
        ["--dry-run", "--out", str(tmp_path / "out")])
    scene = load_scene(tmp_path / "out")
    assert len(scene) > 1000 and (scene.pixel_id == -1).all()
    assert set(np.unique(scene.view_id)) == {0, 1, 2}
