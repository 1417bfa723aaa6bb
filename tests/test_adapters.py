"""Backbone adapters: layouts, covariance decomposition, SH rotation, PLY export options."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clearsplat import Camera, ClearsplatError
from clearsplat.cameras import look_at
from clearsplat.adapters import (covariance_to_scales_quats, from_anysplat, from_depthsplat,
                                 from_mvsplat, from_noposplat, from_pixel_aligned,
                                 from_resplat, from_yonosplat, rotate_sh,
                                 scales_quats_to_covariance, sh_basis)
from clearsplat.io.exports import read_export
from clearsplat.io.ply import read_ply
from clearsplat.metrics import psnr
from clearsplat.render import render
from clearsplat.scene import SH_C0, rgb_to_sh_dc

try:
    import torch
except ImportError:  # the adapters never need it; the tensor cases are skipped
    torch = None

H, W = 12, 16


def _cameras(v=2, h=H, w=W):
    K = np.array([[18.0, 0, w / 2], [0, 18.0, h / 2], [0, 0, 1]])
    return [Camera(K=K, camera_to_world=look_at(np.array([0.3 * i - 0.15, 0.05 * i, -3.0]),
                                                 [0, 0, 0], up=(0.0, -1.0, 0.0)), width=w, height=h)
            for i in range(v)]


def _native(cameras, *, spp=1, sh_degree=0, seed=0, frame=None):
    """The pixelSplat-family layout, built by unprojecting a known depth with known colours.

    Returns a dict of [1, G, ...] arrays, extrinsics [1, V, 4, 4], normalised intrinsics,
    images [1, V, 3, H, W] and the colours per view (V, H, W, 3).
    """
    rng = np.random.default_rng(seed)
    v = len(cameras)
    h, w = cameras[0].height, cameras[0].width
    rows, cols = np.mgrid[0:h, 0:w]
    images = np.stack([np.stack([0.5 + 0.4 * np.sin(0.15 * cols + i),
                                 0.5 + 0.4 * np.cos(0.2 * rows),
                                 np.full((h, w), 0.3 + 0.2 * i)], -1) for i in range(v)])
    means, covs, harm = [], [], []
    d_sh = (sh_degree + 1) ** 2
    for i, cam in enumerate(cameras):
        depth = 3.0 + 0.2 * np.sin(0.3 * cols) + 0.1 * rows / h
        pts = cam.unproject(depth)                                     # (H, W, 3)
        s = depth / cam.fx * 0.5
        local = np.zeros((h, w, 3, 3))
        local[..., 0, 0] = local[..., 1, 1] = s ** 2
        local[..., 2, 2] = (0.1 * s) ** 2
        rot = cam.camera_to_world[:3, :3]
        cov = np.einsum("ij,hwjk,lk->hwil", rot, local, rot)
        coeff = np.zeros((h, w, 3, d_sh))
        coeff[..., 0] = rgb_to_sh_dc(images[i])
        coeff[..., 1:] = 0.05 * rng.normal(size=(h, w, 3, d_sh - 1))
        means.append(np.repeat(pts[:, :, None], spp, axis=2))
        covs.append(np.repeat(cov[:, :, None], spp, axis=2))
        harm.append(np.repeat(coeff[:, :, None], spp, axis=2))
    g = {"means": np.stack(means).reshape(1, -1, 3),
         "covariances": np.stack(covs).reshape(1, -1, 3, 3),
         "harmonics": np.stack(harm).reshape(1, -1, 3, d_sh),
         "opacities": np.full((1, v * h * w * spp), 0.97 / spp)}
    ext = np.stack([c.camera_to_world for c in cameras])[None]
    intr = np.stack([np.diag([1 / w, 1 / h, 1.0]) @ c.K for c in cameras])[None]
    return g, ext, intr, np.moveaxis(images, -1, 1)[None], images


def _as_torch(x):
    if isinstance(x, dict):
        return {k: _as_torch(v) for k, v in x.items()}
    return torch.from_numpy(np.asarray(x, dtype=np.float32))


# ------------------------------------------------------------------------------------------------
# covariances
# ------------------------------------------------------------------------------------------------
def test_covariance_round_trip_random_spd():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(500, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(3)
    scales, quats = covariance_to_scales_quats(cov)
    assert scales.dtype == np.float32 and quats.dtype == np.float32
    assert np.all(scales[:, 0] >= scales[:, 1]) and np.all(scales[:, 1] >= scales[:, 2])
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-6)
    assert np.all(quats[:, 0] >= 0)
    back = scales_quats_to_covariance(scales, quats)
    err = np.abs(back - cov).max(axis=(1, 2)) / np.abs(cov).max(axis=(1, 2))
    assert err.max() < 2e-6


def test_covariance_round_trip_from_scales_and_rotations():
    rng = np.random.default_rng(2)
    s = np.exp(rng.normal(size=(200, 3)))
    q = Rotation.random(200, random_state=3).as_quat()[:, [3, 0, 1, 2]]
    cov = scales_quats_to_covariance(s, q)
    s2, q2 = covariance_to_scales_quats(cov)
    assert np.allclose(np.sort(s2, axis=1), np.sort(s, axis=1), rtol=1e-5)
    assert np.allclose(scales_quats_to_covariance(s2, q2), cov, rtol=1e-5, atol=1e-6)


def test_covariance_degenerate_gets_floor_and_negative_is_refused():
    flat = np.diag([4.0, 1.0, 0.0])[None]
    rounding = np.diag([4.0, 1.0, -1e-9])[None]
    for cov in (flat, rounding):
        s, _ = covariance_to_scales_quats(cov)
        assert np.allclose(s[0, :2], [2.0, 1.0]) and 0 < s[0, 2] <= 2e-5 * 2.0
    s, _ = covariance_to_scales_quats(np.zeros((1, 3, 3)))
    assert np.all(s > 0)
    with pytest.raises(ClearsplatError, match="positive semi-definite") as e:
        covariance_to_scales_quats(np.diag([1.0, 1.0, -0.1])[None])
    assert e.value.field == "covariances"


# ------------------------------------------------------------------------------------------------
# spherical harmonics
# ------------------------------------------------------------------------------------------------
def _sh_colour(sh, dirs):
    k = sh.shape[1]
    return np.einsum("mk,nkc->nmc", sh_basis(dirs, int(np.sqrt(k)) - 1), sh)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotate_sh_preserves_the_colour_function(degree):
    rng = np.random.default_rng(degree)
    sh = rng.normal(size=(6, (degree + 1) ** 2, 3))
    rot = Rotation.random(random_state=degree).as_matrix()
    dirs = rng.normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    out = rotate_sh(sh, rot)
    assert np.array_equal(out[:, 0], sh[:, 0].astype(np.float32))
    assert np.allclose(_sh_colour(out, dirs @ rot.T), _sh_colour(sh, dirs), atol=2e-5)
    # composition and per-Gaussian rotations
    r2 = Rotation.random(random_state=10 + degree).as_matrix()
    assert np.allclose(rotate_sh(rotate_sh(sh, rot), r2), rotate_sh(sh, r2 @ rot), atol=1e-5)
    per = np.stack([rot, r2] * 3)
    assert np.allclose(rotate_sh(sh, per)[1], rotate_sh(sh[1:2], r2)[0], atol=1e-6)


def test_rotate_sh_band1_closed_form():
    # Band 1 is -C1*y, C1*z, -C1*x: coefficients (a, b, c) are the vector C1*(-c, -a, b).
    rot = Rotation.from_euler("zyx", [30, -20, 75], degrees=True).as_matrix()
    sh = np.zeros((1, 4, 3))
    sh[0, 1:, 0] = [0.3, -0.2, 0.5]
    vec = np.array([-0.5, -0.3, -0.2])                 # the direction vector of the lobe
    new_vec = rot @ vec
    expect = np.array([-new_vec[1], new_vec[2], -new_vec[0]])
    assert np.allclose(rotate_sh(sh, rot)[0, 1:, 0], expect, atol=1e-6)


def test_rotate_sh_rejects_bad_rotation():
    with pytest.raises(ClearsplatError) as e:
        rotate_sh(np.zeros((1, 4, 3)), np.diag([1.0, 1.0, -1.0]))
    assert e.value.field == "rotation"


# ------------------------------------------------------------------------------------------------
# pixelSplat / MVSplat / DepthSplat layout
# ------------------------------------------------------------------------------------------------
def _index_layout(b, v, spp, d_sh=4):
    """Native arrays whose means encode (v, row, col, s) of their position in the layout."""
    vv, rr, cc, ss = np.meshgrid(np.arange(v), np.arange(H), np.arange(W), np.arange(spp),
                                 indexing="ij")
    means = np.stack([vv, rr, cc + 0.001 * ss], -1).reshape(1, -1, 3).astype(float)
    means = np.repeat(means, b, axis=0) + np.arange(b)[:, None, None] * 100.0
    g = means.shape[1]
    return {"means": means, "covariances": np.broadcast_to(0.01 * np.eye(3), (b, g, 3, 3)),
            "harmonics": np.zeros((b, g, 3, d_sh)), "opacities": np.full((b, g), 0.5)}


@pytest.mark.parametrize("use_torch", [False, True])
@pytest.mark.parametrize("spp", [1, 3])
def test_depthsplat_layout_assigns_view_and_pixel(spp, use_torch):
    if use_torch and torch is None:
        pytest.skip("torch not installed")
    b, v = 2, 3
    cams = _cameras(v)
    g = _index_layout(b, v, spp)
    ext = np.repeat(np.stack([c.camera_to_world for c in cams])[None], b, 0)
    intr = np.repeat(np.stack([np.diag([1 / W, 1 / H, 1.0]) @ c.K for c in cams])[None], b, 0)
    if use_torch:
        g, ext, intr = _as_torch(g), _as_torch(ext), _as_torch(intr)
    scene = from_depthsplat(g, ext, intr, height=H, width=W, batch=1)
    m = scene.gaussians.means - 100.0
    assert len(scene) == v * H * W * spp
    assert np.array_equal(scene.view_id, np.round(m[:, 0]).astype(int))
    assert np.array_equal(scene.pixel_id, np.round(m[:, 1]).astype(int) * W
                          + np.floor(m[:, 2] + 1e-6).astype(int))
    assert scene.is_pixel_aligned
    assert scene.gaussians.sh.shape == (len(scene), 4, 3)
    for c_in, c_out in zip(cams, scene.cameras):
        assert np.allclose(c_out.K, c_in.K) and np.allclose(c_out.camera_to_world,
                                                            c_in.camera_to_world, atol=1e-6)


def test_depthsplat_scene_renders_its_input_views():
    cams = _cameras(2)
    g, ext, intr, images_chw, images = _native(cams, sh_degree=0)
    scene = from_mvsplat(g, ext, intr, images_chw, height=H, width=W)
    for v in range(2):
        assert np.allclose(scene.images[v], images[v], atol=1e-6)
        out = render(scene, scene.cameras[v], keep=scene.view_mask(v))
        assert psnr(out.rgb, images[v]) > 25.0
        # Control: the other view's Gaussians do not reproduce this input.
        other = render(scene, scene.cameras[v], keep=scene.view_mask(1 - v))
        assert psnr(other.rgb, images[v]) < 20.0


def test_depthsplat_sh_channel_axis_and_higher_bands():
    cams = _cameras(1)
    g, ext, intr, _, _ = _native(cams, sh_degree=3)
    scene = from_depthsplat(g, ext, intr, height=H, width=W)
    # harmonics [.., 3, d_sh] -> sh [N, K, 3]
    assert np.allclose(scene.gaussians.sh, np.swapaxes(g["harmonics"][0], 1, 2), atol=1e-6)
    dc_only = from_depthsplat(g, ext, intr, height=H, width=W, max_sh_degree=0)
    assert dc_only.gaussians.sh.shape[1] == 1


def test_depthsplat_bad_input_names_the_field():
    cams = _cameras(2)
    g, ext, intr, images_chw, _ = _native(cams)
    logits = dict(g, opacities=np.full_like(g["opacities"], 2.0))
    with pytest.raises(ClearsplatError, match="logits") as e:
        from_depthsplat(logits, ext, intr, height=H, width=W)
    assert e.value.field == "opacities"
    trimmed = {k: a[:, :-5] for k, a in g.items()}
    with pytest.raises(ClearsplatError, match="trimmed") as e:
        from_depthsplat(trimmed, ext, intr, height=H, width=W)
    assert e.value.field == "gaussians"
    with pytest.raises(ClearsplatError, match="normalisation") as e:
        from_depthsplat(g, ext, intr, images_chw * 2 - 1, height=H, width=W)
    assert e.value.field == "images"
    bad_ext = ext.copy()
    bad_ext[0, 1, :3, :3] *= 2.0
    with pytest.raises(ClearsplatError) as e:
        from_depthsplat(g, bad_ext, intr, height=H, width=W)
    assert e.value.field == "extrinsics[1]"
    with pytest.raises(ClearsplatError) as e:
        from_depthsplat(g, ext, intr, height=H, width=W, spp=2)
    assert e.value.field == "spp"
    with pytest.raises(ClearsplatError) as e:
        from_depthsplat({k: a for k, a in g.items() if k != "harmonics"}, ext, intr,
                        height=H, width=W)
    assert e.value.field == "harmonics"


# ------------------------------------------------------------------------------------------------
# NoPoSplat / YoNoSplat: first-view frame
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("use_torch", [False, True])
def test_noposplat_moves_first_view_frame_to_world_with_sh(use_torch):
    if use_torch and torch is None:
        pytest.skip("torch not installed")
    world = _cameras(2)
    first = world[0].camera_to_world
    rel = [Camera(K=c.K, camera_to_world=np.linalg.inv(first) @ c.camera_to_world,
                  width=W, height=H) for c in world]
    # The model's output: Gaussians in the first view's frame, SH read in that frame.
    g, ext_rel, intr, _, _ = _native(rel, sh_degree=3, seed=4)
    g["harmonics"][..., 1:] *= 10.0                  # make the view dependence visible
    ext_world = np.stack([c.camera_to_world for c in world])[None]
    conv = _as_torch if use_torch else (lambda x: x)
    in_model_frame = from_noposplat(conv(g), conv(ext_rel), conv(intr), height=H, width=W)
    in_world = from_yonosplat(conv(g), conv(ext_world), conv(intr), height=H, width=W)
    assert np.allclose(in_model_frame.gaussians.means, g["means"][0], atol=1e-5)
    assert np.allclose(in_world.gaussians.means,
                       g["means"][0] @ first[:3, :3].T + first[:3, 3], atol=1e-4)
    assert np.array_equal(in_world.view_id, in_model_frame.view_id)
    for v in range(2):
        a = render(in_model_frame, in_model_frame.cameras[v])
        b = render(in_world, in_world.cameras[v])
        assert np.abs(a.rgb - b.rgb).max() < 2e-3
        assert np.abs(a.rgb - render(in_model_frame.gaussians, in_model_frame.cameras[1 - v]).rgb
                      ).max() > 0.05   # the comparison can fail


def test_yonosplat_downsampled_grid_is_not_pixel_aligned():
    cams = _cameras(2)
    g = _index_layout(1, 2, 1)
    keep = np.zeros((2, H, W), bool)
    keep[:, ::2, ::2] = True
    small = {k: a[:, keep.reshape(-1)] for k, a in g.items()}
    ext = np.stack([c.camera_to_world for c in cams])
    intr = np.stack([np.diag([1 / W, 1 / H, 1.0]) @ c.K for c in cams])
    scene = from_noposplat(small, ext, intr, height=H, width=W)
    assert np.array_equal(scene.view_id, np.repeat([0, 1], H * W // 4))
    assert (scene.pixel_id == -1).all()


# ------------------------------------------------------------------------------------------------
# ReSplat: latent grid
# ------------------------------------------------------------------------------------------------
def test_resplat_latent_grid():
    cams = _cameras(3)
    v, gh, gw = 3, H // 4, W // 4
    n = v * gh * gw
    g = {"means": np.zeros((1, n, 3)), "covariances": np.broadcast_to(np.eye(3), (1, n, 3, 3)),
         "harmonics": np.zeros((1, n, 3, 1)), "opacities": np.full((1, n), 0.5)}
    ext = np.stack([c.camera_to_world for c in cams])[None]
    intr = np.stack([np.diag([1 / W, 1 / H, 1.0]) @ c.K for c in cams])[None]
    scene = from_resplat(g, ext, intr, height=H, width=W)
    assert np.array_equal(scene.view_id, np.repeat(np.arange(v), gh * gw))
    assert (scene.pixel_id == -1).all() and not scene.is_pixel_aligned
    same = from_resplat(g, ext, intr, height=H, width=W, grid=(gh, gw))
    assert np.array_equal(same.view_id, scene.view_id)
    with pytest.raises(ClearsplatError) as e:
        from_resplat({k: a[:, :-1] for k, a in g.items()}, ext, intr, height=H, width=W)
    assert e.value.field == "gaussians"


# ------------------------------------------------------------------------------------------------
# AnySplat
# ------------------------------------------------------------------------------------------------
def _anysplat_inputs(n):
    cams = _cameras(2)
    ext = np.stack([c.camera_to_world for c in cams])[None]
    intr = np.stack([np.diag([1 / W, 1 / H, 1.0]) @ c.K for c in cams])[None]
    g = {"means": np.arange(n * 3, dtype=float).reshape(1, n, 3),
         "covariances": np.broadcast_to(np.eye(3), (1, n, 3, 3)),
         "harmonics": np.zeros((1, n, 3, 1)), "opacities": np.full((1, n), 0.5)}
    return g, ext, intr


def test_anysplat_voxels_go_to_the_majority_view():
    g, ext, intr = _anysplat_inputs(4)                   # 3 voxels + 1 padding row
    inv = np.full((2, H, W), 2)
    inv[0, 0, :3] = 0                                    # voxel 0: 3 pixels of view 0 ...
    inv[1, 5, 5] = 0                                     # ... and 1 of view 1
    inv[0, 1, 0] = 1                                     # voxel 1: 1 of view 0, 2 of view 1
    inv[1, 2, :2] = 1
    scene = from_anysplat(g, ext, intr, height=H, width=W, voxel_inverse=inv[None])
    assert len(scene) == 3
    assert scene.view_id.tolist() == [0, 1, 1]           # voxel 2: 190 vs 189 pixels
    assert (scene.pixel_id == -1).all()
    conf = np.zeros((2, H, W))
    conf[1, 5, 5] = 5.0                                  # view 1's pixel dominates the fusion
    weighted = from_anysplat(g, ext, intr, height=H, width=W, voxel_inverse=inv,
                             confidence=conf)
    assert weighted.view_id.tolist()[0] == 1
    kept = from_anysplat(g, ext, intr, height=H, width=W, voxel_inverse=inv,
                         kept=np.array([True, False, True]))
    assert kept.view_id.tolist() == [0, 1]


def test_anysplat_without_voxels_is_pixel_aligned():
    mask = np.zeros((2, H, W), bool)
    mask[0, 3, 4] = mask[1, 0, 1] = mask[1, 11, 15] = True
    g, ext, intr = _anysplat_inputs(3)
    scene = from_anysplat(g, ext, intr, height=H, width=W, valid_mask=mask[None])
    assert scene.view_id.tolist() == [0, 1, 1]
    assert scene.pixel_id.tolist() == [3 * W + 4, 1, 11 * W + 15]
    g_all, ext, intr = _anysplat_inputs(2 * H * W)
    assert from_anysplat(g_all, ext, intr, height=H, width=W).is_pixel_aligned
    with pytest.raises(ClearsplatError) as e:
        from_anysplat(g, ext, intr, height=H, width=W)   # 3 Gaussians for 384 pixels
    assert e.value.field == "gaussians"


# ------------------------------------------------------------------------------------------------
# generic
# ------------------------------------------------------------------------------------------------
def test_from_pixel_aligned_matches_the_native_adapter():
    cams = _cameras(2)
    g, ext, intr, _, images = _native(cams, spp=2, sh_degree=1)
    shape = (2, H, W, 2)
    native = from_depthsplat(g, ext, intr, height=H, width=W)
    generic = from_pixel_aligned(g["means"].reshape(shape + (3,)),
                                 covariances=g["covariances"].reshape(shape + (3, 3)),
                                 sh=g["harmonics"].reshape(shape + (3, 4)),
                                 opacities=g["opacities"].reshape(shape), cameras=cams,
                                 images=images)
    assert np.array_equal(generic.view_id, native.view_id)
    assert np.array_equal(generic.pixel_id, native.pixel_id)
    assert np.allclose(generic.gaussians.sh, native.gaussians.sh)
    xyzw = Rotation.from_quat(native.gaussians.quats[:, [1, 2, 3, 0]]).as_quat()
    from_sq = from_pixel_aligned(g["means"].reshape(shape + (3,)),
                                 scales=native.gaussians.scales.reshape(shape + (3,)),
                                 quats=xyzw.reshape(shape + (4,)), quat_order="xyzw",
                                 sh=native.gaussians.sh.reshape(shape + (4, 3)),
                                 opacities=g["opacities"].reshape(shape + (1,)), cameras=cams)
    assert np.allclose(scales_quats_to_covariance(from_sq.gaussians.scales,
                                                  from_sq.gaussians.quats),
                       g["covariances"][0], atol=1e-7)
    with pytest.raises(ClearsplatError) as e:
        from_pixel_aligned(g["means"].reshape(shape + (3,)), sh=np.zeros(shape + (1, 3)),
                           opacities=np.ones(shape), cameras=cams[:1],
                           covariances=g["covariances"].reshape(shape + (3, 3)))
    assert e.value.field == "cameras"


# ------------------------------------------------------------------------------------------------
# PLY exports
# ------------------------------------------------------------------------------------------------
def _write_export(path, means, dc, opacity, log_scales, quats_wxyz, rest=None):
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    cols = [means, np.zeros_like(means), dc]
    if rest is not None:
        names += [f"f_rest_{i}" for i in range(rest.shape[1])]
        cols.append(rest)
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    cols += [opacity[:, None], log_scales, quats_wxyz]
    table = np.concatenate(cols, axis=1).astype("<f4")
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(table)
    header += "".join(f"property float {n}\n" for n in names) + "end_header\n"
    path.write_bytes(header.encode() + table.tobytes())


def test_read_export_raw_opacity_presets(tmp_path):
    rng = np.random.default_rng(5)
    n = 40
    op = rng.uniform(0.05, 0.95, n)
    q = Rotation.random(n, random_state=6).as_quat()[:, [3, 0, 1, 2]]
    path = tmp_path / "mvsplat.ply"
    _write_export(path, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), op,
                  rng.normal(size=(n, 3)) - 3, q)
    g, view_id, pixel_id = read_export(path, preset="mvsplat")
    assert view_id is None and pixel_id is None
    assert np.allclose(g.opacities, op, atol=1e-7)
    as_3dgs, _, _ = read_ply(path)                       # the wrong reading
    assert np.abs(as_3dgs.opacities - op).max() > 0.1
    assert np.allclose(read_export(path, opacity="raw")[0].opacities, op, atol=1e-7)
    with pytest.raises(ClearsplatError, match="logit") as e:
        bad = tmp_path / "logit.ply"
        _write_export(bad, np.zeros((2, 3)), np.zeros((2, 3)), np.array([2.0, -1.0]),
                      np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)))
        read_export(bad, preset="anysplat")
    assert e.value.field == "opacity" and e.value.path == str(bad)
    with pytest.raises(ClearsplatError) as e:
        read_export(path, preset="nope")
    assert e.value.field == "preset"


def test_read_export_colour_options_and_to_world(tmp_path):
    rng = np.random.default_rng(7)
    n = 10
    rgb = rng.uniform(0, 1, (n, 3))
    rest = 0.1 * rng.normal(size=(n, 45))
    q = Rotation.random(n, random_state=8).as_quat()[:, [3, 0, 1, 2]]
    means, log_s = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) - 2
    path = tmp_path / "resplat.ply"
    _write_export(path, means, rgb, np.full(n, 1.5), log_s, q, rest)
    g, _, _ = read_export(path, preset="resplat")
    assert g.sh.shape == (n, 16, 3)
    assert np.allclose(g.opacities, 1 / (1 + np.exp(-1.5)), atol=1e-6)
    assert read_export(path, preset="resplat", color="dc")[0].sh.shape == (n, 1, 3)
    as_rgb = read_export(path, preset="resplat", color="rgb")[0]
    assert np.allclose(SH_C0 * as_rgb.sh[:, 0] + 0.5, rgb, atol=1e-6)
    # to_world: a similarity applied to centres, scales, rotations and SH
    rot = Rotation.from_euler("xyz", [10, 50, -30], degrees=True).as_matrix()
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = 2.0 * rot, [1.0, -2.0, 0.5]
    moved = read_export(path, preset="resplat", to_world=m)[0]
    assert np.allclose(moved.means, g.means @ (2 * rot).T + m[:3, 3], atol=1e-5)
    assert np.allclose(moved.scales, 2 * g.scales, rtol=1e-6)
    cov = scales_quats_to_covariance(g.scales, g.quats)
    assert np.allclose(scales_quats_to_covariance(moved.scales, moved.quats),
                       4 * rot @ cov @ rot.T, atol=1e-6)
    assert np.allclose(moved.sh, rotate_sh(g.sh, rot), atol=1e-6)
    with pytest.raises(ClearsplatError) as e:
        read_export(path, to_world=np.diag([1.0, 2.0, 1.0, 1.0]))
    assert e.value.field == "to_world"


# ------------------------------------------------------------------------------------------------
# SH degree 4 and the backbones' render settings
# ------------------------------------------------------------------------------------------------
def test_rotate_sh_degree_4_preserves_the_colour_function():
    rng = np.random.default_rng(4)
    sh = rng.normal(size=(6, 25, 3))
    rot = Rotation.random(random_state=4).as_matrix()
    dirs = rng.normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert np.allclose(_sh_colour(rotate_sh(sh, rot), dirs @ rot.T), _sh_colour(sh, dirs),
                       atol=5e-5)


def test_backbones_keep_the_bands_and_settings_of_their_renderer():
    from clearsplat import RenderSettings
    # AnySplat and ReSplat render with gsplat (band 4 evaluated); pixelSplat-style models and
    # NoPoSplat with the original 3DGS rasterizer (bands up to 3).
    g, ext, intr = _anysplat_inputs(2 * H * W)
    rng = np.random.default_rng(0)
    g["harmonics"] = rng.normal(size=(1, 2 * H * W, 3, 25))
    any_scene = from_anysplat(g, ext, intr, height=H, width=W)
    assert any_scene.gaussians.sh.shape[1] == 25
    assert any_scene.render_settings == RenderSettings(radius_clip=0.1)
    np.testing.assert_allclose(any_scene.gaussians.sh[:, 24], g["harmonics"][0, :, :, 24],
                               rtol=1e-6)
    res = from_resplat(g, ext, intr, height=H, width=W)
    assert res.gaussians.sh.shape[1] == 25
    assert res.render_settings == RenderSettings(antialiased=True, eps2d=0.1)
    dep = from_depthsplat(g, ext, intr, height=H, width=W)
    assert dep.gaussians.sh.shape[1] == 16 and dep.render_settings.is_classic
    assert from_depthsplat(g, ext, intr, height=H, width=W,
                           max_sh_degree=4).gaussians.sh.shape[1] == 25
