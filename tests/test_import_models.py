"""Importing the exports whose vertex order no longer gives each vertex's view and pixel
(Depth Anything 3, AnySplat's voxels, WorldMirror v1 and 2.0, Long-LRM; VolSplat refused):
each written as the upstream code writes it (``tests/upstream_exports.py``) from a synthetic
prediction of known views and pixels, and imported with the association recovered."""

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import upstream_exports as up
from scripts import load_script
from clearsplat import Camera
from clearsplat.adapters import scales_quats_to_covariance
from clearsplat.adapters._common import quats_to_matrices
from clearsplat.cli import main
from clearsplat.errors import ClearsplatError
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.io import load_scene, read_export, save_cameras, write_image
from clearsplat.io.importers import MODEL_FORMATS, import_export, load_views, read_camera_params
from clearsplat.synth.backbone import distractor_truth, reconstruct
from clearsplat.synth.worlds import make_world

H, W, V = 64, 112, 4
#: A voxel about as large as a Gaussian's footprint here (0.025), as 0.002 is in the models'
#: own scenes: voxels hold one to a few pixels, some of several views.
VOXEL = 0.02


@pytest.fixture(scope="module")
def world():
    """A 4-view world with distractors, its pixel-aligned prediction, and which Gaussians
    come from transient pixels."""
    w = make_world("object", num_views=V, seed=1, height=H, width=W)
    scene = reconstruct(w.cameras, w.images, w.depths, seed=1)
    return w, scene, distractor_truth(scene, w)


@pytest.fixture(scope="module")
def other_world():
    return make_world("street", num_views=V, seed=5, height=H, width=W)


def _world_rotations(scene):
    return Rotation.from_matrix(quats_to_matrices(scene.gaussians.quats)).as_quat()


def _da3_prediction(scene, seed=0):
    """Depth Anything 3's per-pixel prediction of the scene: the distance of each centre
    along its pixel ray as the depth, sub-pixel xy offsets, a depth offset, head rotations."""
    rng = np.random.default_rng(seed)
    g = scene.gaussians
    c2w = np.stack([c.camera_to_world for c in scene.cameras])
    dist = np.linalg.norm(g.means - c2w[scene.view_id, :3, 3], axis=1)
    return dict(extrinsics=c2w, intrinsics=np.stack([c.K for c in scene.cameras]),
                depth=dist.reshape(V, H, W), offset_xy=rng.uniform(-0.45, 0.45, (len(g), 2)),
                offset_depth=rng.normal(scale=0.003, size=len(g)) * dist,
                scales=g.scales.astype(np.float64),
                rotations=Rotation.random(len(g), random_state=seed).as_quat(),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64),
                opacities=np.clip(g.opacities, 0.02, 0.98))


def _da3_world_means(pred):
    """Where Depth Anything 3 puts each pixel's centre, in the world."""
    ext, ks, off = pred["extrinsics"], pred["intrinsics"], pred["offset_xy"].reshape(V, H, W, 2)
    rows, cols = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    dist = pred["depth"] + pred["offset_depth"].reshape(V, H, W)
    out = [ext[v, :3, 3] + up._unit_rays(ks[v], ext[v, :3, :3], cols + 0.5 + off[v, ..., 0],
                                         rows + 0.5 + off[v, ..., 1]) * dist[v, ..., None]
           for v in range(V)]
    return np.stack(out).reshape(-1, 3)


def _voxel_prediction(scene, seed=0):
    """AnySplat's per-pixel raw channels for the scene (the adapter's activations undone)."""
    g = scene.gaussians
    return dict(means=g.means.astype(np.float64),
                opacity_logit=up._logit(np.clip(g.opacities, 0.02, 0.98)),
                scale_raw=np.log(np.expm1(g.scales.astype(np.float64) / 0.001)),
                rotations=_world_rotations(scene),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64),
                conf=np.random.default_rng(seed).normal(size=len(g)))


def _worldmirror_prediction(scene, seed=0):
    g = scene.gaussians
    w = 1 / (1 + np.exp(-np.random.default_rng(seed).normal(size=len(g))))
    return dict(means=g.means.astype(np.float64), scales=g.scales.astype(np.float64),
                rotations=_world_rotations(scene),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64), opacities=g.opacities,
                weights=w)


def _longlrm_prediction(scene, seed=0):
    g = scene.gaussians
    rng = np.random.default_rng(seed)
    return dict(extrinsics=np.stack([c.camera_to_world for c in scene.cameras]),
                means=g.means.astype(np.float64), scales=g.scales.astype(np.float64),
                rotations=_world_rotations(scene),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64),
                opacities=np.clip(g.opacities * rng.uniform(0.001, 1, len(g)), 1e-4, 0.98))


def _vggt_cameras(cameras):
    """The cameras as VGGT-style models state them: pixel ``(row, col)`` at ``(col, row)``,
    half a pixel before clearsplat's centres (the import moves them back)."""
    return [Camera(K=c.K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]),
                   camera_to_world=c.camera_to_world, width=c.width, height=c.height)
            for c in cameras]


def _majority(scene, source):
    """Each vertex's majority view among the pixels that made it (``source``: the vertex of
    every pixel, -1 where dropped), and its pixels' count per view."""
    keep = source >= 0
    k = source.max() + 1
    counts = np.zeros((k, V))
    np.add.at(counts, (source[keep], scene.view_id[keep]), 1)
    return counts.argmax(axis=1), counts


def _one_line(e):
    assert "\n" not in str(e.value)
    return str(e.value)


# ------------------------------------------------------------------------------------------------
# Depth Anything 3
# ------------------------------------------------------------------------------------------------
def _check_da3(scene, imported, report, kept, pred):
    """Right view for >= 99 %, pixel within 1 px for >= 99 %, centres within a twentieth of
    a pixel's footprint (the scale and shift are fitted to rays through pixel centres from
    centres up to 0.45 px off them)."""
    view, pix = kept // (H * W), kept % (H * W)
    assert (imported.view_id == view).mean() >= 0.99
    r, c = imported.pixel_id // W, imported.pixel_id % W
    near = (imported.pixel_id >= 0) & (np.abs(r - pix // W) <= 1) & (np.abs(c - pix % W) <= 1)
    assert near.mean() >= 0.99
    truth = _da3_world_means(pred)[kept]
    err = np.linalg.norm(imported.gaussians.means - truth, axis=1)
    centres = np.stack([c.position for c in scene.cameras])[view]
    footprint = np.linalg.norm(truth - centres, axis=1) / scene.cameras[0].fx
    assert np.median(err / footprint) < 0.02 and (err / footprint).max() < 0.05
    assert report.association.startswith(f"associated {len(kept):,} Gaussians from geometry")
    assert len(imported) == report.num_vertices == len(kept)


def test_da3_normalised_frame_of_given_poses(tmp_path, world):
    _, scene, _ = world
    pred = _da3_prediction(scene)
    path = tmp_path / "0000.ply"
    kept = up.da3_export_to_gs_ply(path, pred, poses_given=True)
    imported, report = import_export(path, "da3", scene.cameras, scene.images)
    _check_da3(scene, imported, report, kept, pred)
    s, _, _ = up.da3_normalisation(pred["extrinsics"])
    assert report.scale == pytest.approx(1 / s, rel=1e-3)
    assert "normalised frame" in report.notes[0] and "rescaled" not in report.notes[0]
    # opacities from logits, rotations as written (DA3 renders rot_0..3 as w x y z), turned by
    # camera 0, scales in the cameras' units
    g_file, _, _ = read_export(path, opacity="logit")
    assert np.allclose(imported.gaussians.opacities, pred["opacities"][kept], atol=2e-6)
    r0 = scene.cameras[0].camera_to_world[:3, :3]
    cov_file = scales_quats_to_covariance(g_file.scales, g_file.quats)
    expect = r0 @ cov_file @ r0.T * report.scale ** 2
    got = scales_quats_to_covariance(imported.gaussians.scales, imported.gaussians.quats)
    assert np.abs(got - expect).max() <= 1e-4 * np.abs(expect).max()


def test_da3_rescaled_frame_and_views_interval(tmp_path, world):
    """The model's rescaling off by 30 % and every second view written: the scale is found
    and the written views' runs recovered."""
    _, scene, _ = world
    pred = _da3_prediction(scene, seed=1)
    path = tmp_path / "0000.ply"
    kept = up.da3_export_to_gs_ply(path, pred, poses_given=True, pose_scale=1.3,
                                   gs_views_interval=2)
    assert set(np.unique(kept // (H * W))) == {0, 2}
    imported, report = import_export(path, "da3", scene.cameras, scene.images)
    _check_da3(scene, imported, report, kept, pred)
    assert "rescaled" in report.notes[0]


def test_da3_predicted_cameras_frame(tmp_path, world):
    """Without poses DA3 writes in the frame of its own cameras, which are the ones given."""
    _, scene, _ = world
    pred = _da3_prediction(scene, seed=2)
    path = tmp_path / "0000.ply"
    kept = up.da3_export_to_gs_ply(path, pred, poses_given=False)
    imported, report = import_export(path, "da3", scene.cameras, scene.images)
    _check_da3(scene, imported, report, kept, pred)
    assert "the cameras' frame" in report.notes[0]
    assert report.scale == pytest.approx(1.0, abs=1e-3)


def test_da3_border_trim_and_depth_cut_are_upstreams(tmp_path, world):
    """The written pixels: int(8/256 H) rows and int(8/256 W) columns off each border and the
    farthest tenth of each view (torch.quantile's linear interpolation)."""
    _, scene, _ = world
    pred = _da3_prediction(scene)
    kept = up.da3_export_to_gs_ply(tmp_path / "d.ply", pred)
    pix = kept % (H * W)
    assert (pix // W).min() == 2 and (pix // W).max() == H - 3       # int(8/256 * 64) = 2
    assert (pix % W).min() == 3 and (pix % W).max() == W - 4         # int(8/256 * 112) = 3
    g_file, _, _ = read_export(tmp_path / "d.ply", opacity="logit")
    assert (g_file.quats[:, 3] >= 0).all() and (g_file.quats[:, 0] < 0).any()   # x y z w
    for v in range(V):
        d = pred["depth"][v]
        inside = np.zeros((H, W), bool)
        inside[2:H - 2, 3:W - 3] = True
        expect = np.flatnonzero(inside & (d <= np.quantile(d, 0.9)))
        assert np.array_equal(pix[kept // (H * W) == v], expect)


def test_da3_cameras_that_do_not_fit_are_refused(tmp_path, world, other_world):
    _, scene, _ = world
    path = tmp_path / "0000.ply"
    up.da3_export_to_gs_ply(path, _da3_prediction(scene))
    with pytest.raises(ClearsplatError) as e:
        import_export(path, "da3", other_world.cameras, other_world.images)
    assert e.value.field == "cameras" and e.value.path == str(path)
    assert "fit neither" in _one_line(e)
    with pytest.raises(ClearsplatError) as e:
        import_export(path, "da3", scene.cameras[::-1], scene.images[::-1])
    assert e.value.field == "cameras"


# ------------------------------------------------------------------------------------------------
# voxels: AnySplat, WorldMirror
# ------------------------------------------------------------------------------------------------
def _check_voxels(scene, imported, source, transient, path, opacity):
    """The file's vertices in its order, the association
    :func:`~clearsplat.adapters.associate.associate_fused` gives the file's Gaussians with the
    scene's cameras, a voxel of one pixel that pixel's view and pixel and nearly every other
    no pixel, and the majority view (the view that saw it) for nearly every vertex made
    mostly of transient pixels. Returns which vertices those are."""
    from clearsplat.adapters.associate import CENTRE_TOLERANCE, associate_fused
    g_file, _, _ = read_export(path, opacity=opacity)
    assert np.array_equal(imported.gaussians.means, g_file.means)
    assert np.array_equal(imported.gaussians.opacities, g_file.opacities)
    direct = associate_fused(g_file, imported.cameras, scene.images,
                             settings=imported.render_settings)
    assert np.array_equal(imported.view_id, direct.view_id)
    assert np.array_equal(imported.pixel_id, direct.pixel_id)
    majority, counts = _majority(scene, source)
    k = len(imported)
    # A vertex given a pixel is one of its own pixels (a voxel of one pixel, or one whose
    # softmax weights all but make it one), but for those chance puts on a pixel centre.
    kept = np.flatnonzero(source >= 0)
    taken = imported.pixel_id >= 0
    mine = np.zeros(k, dtype=bool)
    hit = taken[source[kept]] & (imported.view_id[source[kept]] == scene.view_id[kept]) \
        & (imported.pixel_id[source[kept]] == scene.pixel_id[kept])
    mine[source[kept][hit]] = True
    one = counts.sum(axis=1) == 1
    assert one.sum() > 50 and mine[one].mean() >= 0.99
    chance = len(scene.cameras) * (2 * CENTRE_TOLERANCE) ** 2
    assert np.mean(taken & ~mine) < 2 * chance
    tr = np.bincount(source[source >= 0], transient[source >= 0], minlength=k) > \
        0.5 * counts.sum(axis=1)
    assert tr.sum() > 50 and (imported.view_id == majority)[tr].mean() >= 0.9
    return tr


def test_anysplat_voxels_are_associated_from_the_images(tmp_path, world):
    _, scene, transient = world
    path = tmp_path / "gaussians.ply"
    source = up.anysplat_voxel_export(path, _voxel_prediction(scene), voxel_size=VOXEL)
    cams = _vggt_cameras(scene.cameras)
    imported, report = import_export(path, "anysplat", cams, scene.images)
    assert len(imported) == source.max() + 1 < len(scene)
    tr = _check_voxels(scene, imported, source, transient, path, "raw")
    assert report.association.startswith(f"associated {len(imported):,} Gaussians from images")
    assert imported.cameras[0].cx == cams[0].cx + 0.5
    # the filter runs on the result: the voxels of transient pixels go far more often
    removed = filter_distractors(imported, config=FilterConfig()).removed
    assert len(removed) == len(imported)
    assert removed[tr].mean() > 5 * removed[~tr].mean()
    # the images are needed
    with pytest.raises(ClearsplatError) as e:
        import_export(path, "anysplat", cams)
    assert e.value.field == "images" and "needed" in _one_line(e)


def test_anysplat_voxel_export_fuses_raw_channels_before_activation(tmp_path, world):
    """Two pixels in one voxel: centre, opacity, scale, rotation of the softmax-weighted raw
    channels, as voxelizaton_with_fusion and UnifiedGaussianAdapter compute them."""
    pred = dict(means=np.array([[0.0101, 0.0, 0.0], [0.0109, 0.0, 0.0], [0.5, 0.0, 0.0]]),
                opacity_logit=np.array([2.0, -1.0, 0.0]),
                scale_raw=np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [0.0, 0.0, 0.0]]),
                rotations=np.array([[0, 0, 0, 2.0], [0, 0, 1.0, 1.0], [1.0, 0, 0, 0]]),
                harmonics=np.array([[[0.1]] * 3, [[0.3]] * 3, [[0.0]] * 3]),
                conf=np.array([0.0, np.log(3.0), 0.0]))
    path = tmp_path / "a.ply"
    source = up.anysplat_voxel_export(path, pred, voxel_size=0.002)
    assert source.tolist() == [0, 0, 1]
    g, _, _ = read_export(path, opacity="raw")
    wts = np.array([1.0, 3.0]) / (4.0 + 1e-6)
    assert np.allclose(g.means[0], wts @ pred["means"][:2], atol=1e-7)
    assert g.opacities[0] == pytest.approx(1 / (1 + np.exp(-(wts @ [2.0, -1.0]))), abs=1e-6)
    assert np.allclose(g.scales[0], 0.001 * np.log1p(np.exp(wts @ pred["scale_raw"][:2])))
    q = wts @ pred["rotations"][:2]
    q = q[[3, 0, 1, 2]] / np.linalg.norm(q)
    assert np.allclose(np.abs(g.quats[0] @ q), 1.0, atol=1e-6)


def test_anysplat_no_voxels_keeps_the_per_pixel_path(tmp_path, world):
    _, scene, _ = world
    pred = dict(_voxel_prediction(scene), scales=scene.gaussians.scales.astype(np.float64),
                opacities=np.clip(scene.gaussians.opacities, 0.02, 0.98))
    path = tmp_path / "gaussians.ply"
    up.anysplat_inference_export(path, pred)
    imported, report = import_export(path, "anysplat", _vggt_cameras(scene.cameras),
                                     voxelized=False)
    assert np.array_equal(imported.view_id, scene.view_id)
    assert np.array_equal(imported.pixel_id, scene.pixel_id)
    assert report.inside_pixel == 1.0 and report.association == ""


def test_worldmirror_v1_voxel_merge(tmp_path, world):
    _, scene, transient = world
    path = tmp_path / "gaussians.ply"
    pred = _worldmirror_prediction(scene)
    source = up.worldmirror_v1_save_gs_ply(path, pred, voxel_size=VOXEL)
    assert (source == -1).any()                              # the 95th percentile scale cut
    imported, report = import_export(path, "worldmirror", _vggt_cameras(scene.cameras),
                                     scene.images)
    _check_voxels(scene, imported, source, transient, path, "raw")
    assert "voxel order" in report.notes[0]
    # opacity written as the merge leaves it: sum w^2 / sum w, no logit
    keep = source >= 0
    w = pred["weights"][keep]
    expect = np.bincount(source[keep], w * w) / np.bincount(source[keep], w)
    assert np.allclose(imported.gaussians.opacities, expect, atol=1e-6)


def test_worldmirror2_pixel_voxel_and_subsampled_orders(tmp_path, world):
    """2.0 merges all or nothing: no voxel holding two splats leaves the masked pixels in
    pixel order (views and pixels recovered exactly); merged, voxel order; above the cap, a
    seeded subsample in no order, whose views and pixels the pixel centres give."""
    _, scene, transient = world
    pred = _worldmirror_prediction(scene, seed=3)
    keep = np.random.default_rng(4).uniform(size=(V, H, W)) > 0.05       # sky and edge masks
    cams = _vggt_cameras(scene.cameras)
    path = tmp_path / "gaussians.ply"
    source = up.worldmirror2_save_results(path, pred, keep=keep, voxel_size=1e-5)
    imported, report = import_export(path, "worldmirror", cams, scene.images)
    pixel = np.full(len(imported), -1)
    pixel[source[source >= 0]] = np.flatnonzero(source >= 0)
    assert np.array_equal(imported.view_id, scene.view_id[pixel])
    assert np.array_equal(imported.pixel_id, scene.pixel_id[pixel])
    assert "pixel order" in report.notes[0] and report.ambiguous == 0

    source = up.worldmirror2_save_results(path, pred, keep=keep, voxel_size=VOXEL)
    imported, report = import_export(path, "worldmirror", cams, scene.images)
    _check_voxels(scene, imported, source, transient, path, "raw")
    assert "voxel order" in report.notes[0]

    source = up.worldmirror2_save_results(path, pred, keep=keep, voxel_size=1e-5,
                                          max_points=15_000)
    imported, report = import_export(path, "worldmirror", cams, scene.images)
    assert len(imported) < 15_000
    assert "neither voxel nor pixel order" in report.notes[0] and "pixel centre" in \
        report.notes[0]
    pixel = np.full(len(imported), -1)
    pixel[source[source >= 0]] = np.flatnonzero(source >= 0)
    right_view, right_pixel = _right(imported, scene.view_id[pixel], scene.pixel_id[pixel])
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)
    # cameras already in clearsplat's convention, moved by another half pixel, put every
    # centre on a pixel's corner: the views from the images
    wrong = import_export(path, "worldmirror", scene.cameras, scene.images)[1]
    assert "from the images" in wrong.notes[0]


# ------------------------------------------------------------------------------------------------
# Long-LRM, VolSplat
# ------------------------------------------------------------------------------------------------
def test_longlrm_unpruned_in_its_normalised_frame(tmp_path, world):
    _, scene, _ = world
    pred = _longlrm_prediction(scene)
    path = tmp_path / "gaussians_001.ply"
    order = up.longlrm_save_gaussian_ply(path, pred)
    assert 0 < len(scene) - len(order) < 0.01 * len(scene)        # opacity <= 0.001 dropped
    imported, report = import_export(path, "longlrm", scene.cameras, scene.images)
    assert np.array_equal(imported.view_id, scene.view_id[order])
    assert np.array_equal(imported.pixel_id, scene.pixel_id[order])
    g = scene.gaussians
    assert np.abs(imported.gaussians.means - g.means[order]).max() < 1e-5
    assert np.allclose(imported.gaussians.opacities, pred["opacities"][order], atol=2e-6)
    cov = scales_quats_to_covariance(g.scales[order], g.quats[order])
    got = scales_quats_to_covariance(imported.gaussians.scales, imported.gaussians.quats)
    assert np.abs(got - cov).max() <= 1e-4 * np.abs(cov).max()
    assert imported.gaussians.sh.shape[1] == 16                   # 45 f_rest: degree 3
    assert "pixel order" in report.notes[0]
    header = path.read_bytes().split(b"end_header")[0].decode().splitlines()
    props = [line.split() for line in header if line.startswith("property")]
    assert len(props) == 62 and [p[1] for p in props[3:6]] == ["uchar"] * 3


def _right(imported, view, pixel):
    """Shares of vertices with the right view, and with it the right pixel."""
    right = imported.view_id == view
    return right.mean(), (right & (imported.pixel_id == pixel)).mean()


def test_longlrm_pruned_export_is_associated_from_pixel_centres(tmp_path, world,
                                                               other_world):
    """Ranked by opacity, then random picks: each centre lies on its pixel's ray, so its
    own camera puts it on that pixel's centre."""
    _, scene, _ = world
    pred = _longlrm_prediction(scene, seed=1)
    path = tmp_path / "gaussians_001.ply"
    order = up.longlrm_save_gaussian_ply(path, pred, prune_ratio=0.6, random_ratio=0.1)
    n = len(scene)
    assert len(order) <= int(n * 0.36) + int(n * 0.04)
    imported, report = import_export(path, "longlrm", scene.cameras, scene.images)
    assert "ranked by opacity" in report.notes[0] and "pixel centre" in report.notes[0]
    right_view, right_pixel = _right(imported, scene.view_id[order], scene.pixel_id[order])
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)
    assert report.association.startswith(f"associated {len(order):,} Gaussians from geometry")
    assert np.abs(imported.gaussians.means - scene.gaussians.means[order]).max() < 1e-5
    # the images are not needed for it; another world's cameras put no centre on a pixel
    # centre (each Gaussian's view then comes from the images)
    assert np.array_equal(import_export(path, "longlrm", scene.cameras)[0].view_id,
                          imported.view_id)
    other = import_export(path, "longlrm", other_world.cameras, other_world.images)[1]
    assert "from the images" in other.notes[0]


def test_longlrm_pruned_bfloat16_export_is_associated_from_the_images(tmp_path, world):
    """Computed under bfloat16 autocast (Long-LRM's configs) the centres miss their pixel
    centres: each Gaussian's view comes from the images."""
    _, scene, transient = world
    pred = _longlrm_prediction(scene, seed=1)
    path = tmp_path / "gaussians_001.ply"
    order = up.longlrm_save_gaussian_ply(path, pred, prune_ratio=0.6, random_ratio=0.1,
                                         bf16=True)
    moved = read_export(path, opacity="logit")[0].means
    exact = tmp_path / "exact.ply"
    up.longlrm_save_gaussian_ply(exact, pred, prune_ratio=0.6, random_ratio=0.1)
    off = np.abs(moved - read_export(exact, opacity="logit")[0].means).max(axis=1)
    assert np.median(off) > 1e-4                              # bfloat16 moved them
    imported, report = import_export(path, "longlrm", scene.cameras, scene.images)
    assert "ranked by opacity" in report.notes[0] and "from the images" in report.notes[0]
    assert (imported.pixel_id == -1).all()
    right = imported.view_id == scene.view_id[order]
    assert right[transient[order]].mean() >= 0.9


def _video_scene(family):
    aq = load_script("benchmarks/association_quality.py")
    return aq.video_capture(family, num_views=8, height=48, width=80, seed=1)


@pytest.mark.parametrize("family", ["street", "object"])
def test_pruned_and_subsampled_video_captures(tmp_path, family):
    """Consecutive cameras nearly identical: only each vertex's own camera puts it on a pixel
    centre (the others' shifts are rarely whole pixels)."""
    scene = _video_scene(family)
    path = tmp_path / "lrm.ply"
    order = up.longlrm_save_gaussian_ply(path, _longlrm_prediction(scene, seed=2),
                                         prune_ratio=0.6, random_ratio=0.1)
    imported, report = import_export(path, "longlrm", scene.cameras, scene.images)
    assert "ranked by opacity" in report.notes[0] and "pixel centre" in report.notes[0]
    right = _right(imported, scene.view_id[order], scene.pixel_id[order])
    assert min(right) >= 0.99, right
    path = tmp_path / "wm.ply"
    source = up.worldmirror2_save_results(path, _worldmirror_prediction(scene, seed=2),
                                          voxel_size=1e-6, max_points=len(scene) // 3)
    imported, report = import_export(path, "worldmirror", _vggt_cameras(scene.cameras),
                                     scene.images)
    assert "neither voxel nor pixel order" in report.notes[0]
    pixel = np.full(len(imported), -1)
    pixel[source[source >= 0]] = np.flatnonzero(source >= 0)
    right = _right(imported, scene.view_id[pixel], scene.pixel_id[pixel])
    assert min(right) >= 0.99, right


def test_volsplat_export_is_refused_in_one_line(tmp_path, world):
    _, scene, _ = world
    source = up.anysplat_voxel_export(tmp_path / "v.ply", _voxel_prediction(scene),
                                      voxel_size=VOXEL)
    g, _, _ = read_export(tmp_path / "v.ply", opacity="raw")
    pred = dict(means=g.means, harmonics=g.sh.transpose(0, 2, 1), opacities=g.opacities,
                extrinsics=np.stack([c.camera_to_world for c in scene.cameras]))
    assert source.max() + 1 < V * H * W                          # padded to V H W
    path = tmp_path / "scene.ply"
    up.volsplat_save_gaussian_ply(path, pred, height=H, width=W)
    assert len(read_export(path)[0]) == V * (H - 16) * (W - 16)
    with pytest.raises(ClearsplatError) as e:
        import_export(path, "volsplat", scene.cameras, scene.images)
    line = _one_line(e)
    assert e.value.path == str(path) and e.value.field == "scale_0"
    assert "every scale as 0.01" in line and "pads or truncates" in line
    assert "associate_fused" in line


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
def test_wrong_formats_and_options_are_one_line(tmp_path, world):
    _, scene, _ = world
    da3 = tmp_path / "da3.ply"
    up.da3_export_to_gs_ply(da3, _da3_prediction(scene))
    with pytest.raises(ClearsplatError) as e:                 # logits read as raw opacities
        import_export(da3, "worldmirror", scene.cameras, scene.images)
    assert e.value.field == "opacity"
    lrm = tmp_path / "lrm.ply"
    up.longlrm_save_gaussian_ply(lrm, _longlrm_prediction(scene))
    with pytest.raises(ClearsplatError) as e:
        import_export(lrm, "da3", scene.cameras)
    assert e.value.field == "f_rest" and "not da3's export" in _one_line(e)
    vox = tmp_path / "wm.ply"
    up.worldmirror_v1_save_gs_ply(vox, _worldmirror_prediction(scene), voxel_size=VOXEL)
    with pytest.raises(ClearsplatError) as e:                 # voxel order read as per-pixel
        import_export(vox, "da3", scene.cameras)
    assert e.value.field == "cameras" and "or the format" in _one_line(e)
    for option in (dict(trim=8), dict(order="hwsv"), dict(voxelized=False),
                   dict(align="scale")):
        with pytest.raises(ClearsplatError) as e:
            import_export(da3, "da3", scene.cameras, **option)
        assert e.value.field == next(iter(option)) and "does not apply" in _one_line(e)


def test_every_model_format_has_a_test():
    assert set(MODEL_FORMATS) == {"da3", "worldmirror", "longlrm", "volsplat"}


def test_camera_params_json_is_camera_to_world(tmp_path, world):
    _, scene, _ = world
    path = tmp_path / "camera_params.json"
    _write_camera_params(path, scene.cameras)
    ks, c2w = read_camera_params(path)
    assert np.allclose(c2w[2], scene.cameras[2].camera_to_world)
    assert np.allclose(ks[1], scene.cameras[1].K)
    # no image size in the file: the images give it, and must be the ones the model saw
    (tmp_path / "big").mkdir()
    for i, img in enumerate(scene.images):
        write_image(tmp_path / "big" / f"{i}.png", np.repeat(np.repeat(img, 2, 0), 2, 1))
    with pytest.raises(ClearsplatError) as e:
        load_views(path, tmp_path / "big")
    assert e.value.field == "size" and "processed" in _one_line(e)
    doc = json.loads(path.read_text())
    doc["intrinsics"][1]["camera_id"] = 0
    path.write_text(json.dumps(doc))
    with pytest.raises(ClearsplatError) as e:
        read_camera_params(path)
    assert e.value.field == "intrinsics" and "0..3" in _one_line(e)


# ------------------------------------------------------------------------------------------------
# the command line
# ------------------------------------------------------------------------------------------------
def _write_camera_params(path, cameras):
    """WorldMirror's save_camera_params: camera-to-world 'extrinsics', pixel intrinsics."""
    doc = {"num_cameras": len(cameras),
           "extrinsics": [{"camera_id": i, "matrix": c.camera_to_world.tolist()}
                          for i, c in enumerate(cameras)],
           "intrinsics": [{"camera_id": i, "matrix": c.K.tolist()}
                          for i, c in enumerate(cameras)]}
    path.write_text(json.dumps(doc, indent=2))


@pytest.fixture(scope="module")
def files(world, tmp_path_factory):
    """Each model's export of the world, its cameras (cameras.json, WorldMirror's
    camera_params.json) and images on disk."""
    _, scene, _ = world
    root = tmp_path_factory.mktemp("models")
    names = _write_views(root, scene.cameras, scene.images)
    save_cameras(root / "vggt.json", _vggt_cameras(scene.cameras), names)
    _write_camera_params(root / "camera_params.json", _vggt_cameras(scene.cameras))
    up.da3_export_to_gs_ply(root / "da3.ply", _da3_prediction(scene))
    up.anysplat_voxel_export(root / "anysplat.ply", _voxel_prediction(scene), voxel_size=VOXEL)
    up.worldmirror_v1_save_gs_ply(root / "worldmirror.ply", _worldmirror_prediction(scene),
                                  voxel_size=VOXEL)
    up.longlrm_save_gaussian_ply(root / "longlrm.ply", _longlrm_prediction(scene))
    g, _, _ = read_export(root / "anysplat.ply", opacity="raw")
    up.volsplat_save_gaussian_ply(root / "volsplat.ply", dict(
        means=g.means, harmonics=g.sh.transpose(0, 2, 1), opacities=g.opacities,
        extrinsics=np.stack([c.camera_to_world for c in scene.cameras])), height=H, width=W)
    return root


@pytest.fixture(scope="module")
def other(other_world, tmp_path_factory):
    """Cameras and images of another world."""
    root = tmp_path_factory.mktemp("other")
    _write_views(root, other_world.cameras, other_world.images)
    return root


def _write_views(root, cameras, images) -> list:
    """``images/NNN.png`` and ``cameras.json`` in ``root``; the image names."""
    (root / "images").mkdir()
    names = [f"images/{i:03d}.png" for i in range(len(images))]
    for name, img in zip(names, images):
        write_image(root / name, img)
    save_cameras(root / "cameras.json", cameras, names)
    return names


@pytest.mark.parametrize("format,cameras", [("da3", "cameras.json"),
                                            ("anysplat", "vggt.json"),
                                            ("worldmirror", "camera_params.json"),
                                            ("longlrm", "cameras.json")])
def test_import_command(files, world, tmp_path, capsys, monkeypatch, format, cameras):
    import clearsplat.cli.import_ as command
    _, scene, _ = world
    out = tmp_path / "bundle"
    told = []
    monkeypatch.setattr(command, "Bar", lambda: lambda *a: told.append(a))    # the progress bar
    assert main(["import", format, str(files / f"{format}.ply"), "--cameras",
                 str(files / cameras), "--images", str(files / "images"),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr()
    assert printed.err == ""
    line = printed.out.splitlines()[0]
    # Where the views come from the images (voxels: AnySplat's, WorldMirror v1's), the
    # association's progress, one camera at a time.
    v, fused = scene.num_views, " from images: " in line
    assert fused == (format in ("anysplat", "worldmirror")), line
    assert told == ([("associate", k, v) for k in range(1, v + 1)] if fused else []), told
    assert line.startswith(f"{format}: ") and " ambiguous" in line
    # From the images, the voxels of one pixel got theirs.
    assert re.search(r" got a view \([\d,]+ with their pixel\), " if fused else " got a view, ",
                     line), line
    bundle = load_scene(out)
    report = json.loads((out / "import.json").read_text())
    assert report["association"] in line and report["num_vertices"] == len(bundle)
    g_file, _, _ = read_export(files / f"{format}.ply",
                               opacity="logit" if format in ("da3", "longlrm") else "raw")
    assert len(bundle) == len(g_file)
    for got, cam in zip(bundle.cameras, scene.cameras):             # VGGT's half pixel undone
        assert np.allclose(got.K, cam.K) and np.allclose(got.camera_to_world,
                                                         cam.camera_to_world)


def test_filtered_voxel_bundle_indexes_the_file(files, tmp_path):
    bundle, filtered = tmp_path / "b", tmp_path / "f"
    args = ["--cameras", str(files / "vggt.json"), "--images", str(files / "images")]
    assert main(["import", "anysplat", str(files / "anysplat.ply"), *args,
                 "--out", str(bundle)]) == 0
    assert main(["filter", str(bundle), "--out", str(filtered)]) == 0
    removed = np.load(filtered / "removed.npy")
    assert len(removed) == len(read_export(files / "anysplat.ply", opacity="raw")[0])


def test_import_command_refuses_in_one_line(files, other, tmp_path, capsys):
    """VolSplat, cameras that do not fit, a wrong format, missing images, a layout option:
    exit 2, one line naming the file and field, nothing written."""
    (tmp_path / "empty").mkdir()
    cases = [
        (["volsplat", "volsplat.ply"], files / "cameras.json", files / "images",
         "scale_0: volsplat's save_gaussian_ply writes every scale as 0.01"),
        (["da3", "da3.ply"], other / "cameras.json", other / "images", "cameras: "),
        (["anysplat", "anysplat.ply"], other / "cameras.json", other / "images",
         "cameras: only "),
        (["longlrm", "longlrm.ply"], other / "cameras.json", other / "images", "cameras: "),
        (["worldmirror", "da3.ply"], files / "cameras.json", files / "images", "opacity: "),
        (["longlrm", "da3.ply"], files / "cameras.json", files / "images", "f_rest: "),
        (["da3", "da3.ply"], files / "cameras.json", tmp_path / "empty", "--images: "),
        (["da3", "da3.ply", "--trim", "8"], files / "cameras.json", files / "images",
         "trim: does not apply to da3"),
    ]
    for i, (head, cams, images, expect) in enumerate(cases):
        out = tmp_path / f"out{i}"
        argv = ["import", head[0], str(files / head[1]), *head[2:], "--cameras", str(cams),
                "--images", str(images), "--out", str(out)]
        assert main(argv) == 2, head
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("clearsplat: error: "), err
        assert expect in err[0], (expect, err[0])
        assert not out.exists()


def test_allow_misaligned_keeps_a_recovered_association_with_a_warning(files, other, tmp_path,
                                                                      capsys):
    out = tmp_path / "b"
    assert main(["import", "anysplat", str(files / "anysplat.ply"), "--cameras",
                 str(other / "cameras.json"), "--images", str(other / "images"),
                 "--out", str(out), "--allow-misaligned"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clearsplat: warning: kept with "
                                               "--allow-misaligned: only ")
    report = json.loads((out / "import.json").read_text())
    assert report["ambiguous"] > report["num_vertices"] / 2


@pytest.mark.parametrize("degrees", [0.5, 1.5])
def test_da3_predicted_cameras_near_the_normalised_frame(tmp_path, world, degrees):
    """DA3's own predicted cameras need not put camera 0 at the identity: a frame a little off
    the normalisation of their poses also fits the normalised frame, a little off. The
    cameras' own frame, where the pinned vertices lie nearest their pixels, is kept: every
    pixel exact (the offsets stay within the pixel)."""
    from clearsplat import Gaussians, Scene
    from clearsplat.adapters import normalised_frame
    _, scene, _ = world
    norm = normalised_frame(scene.cameras)
    turn = Rotation.from_euler("y", degrees, degrees=True).as_matrix() @ norm.rotation.T
    k = 1.03 / norm.scale       # median camera distance 1.03 after the move

    def move(x):
        return k * (np.asarray(x, np.float64) - norm.translation) @ turn.T
    cams = []
    for c in scene.cameras:
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = turn @ c.camera_to_world[:3, :3], move(c.position[None])[0]
        cams.append(Camera(K=c.K, camera_to_world=c2w, width=c.width, height=c.height))
    g = scene.gaussians
    moved = Scene(Gaussians(move(g.means).astype(np.float32), g.scales * k, g.quats,
                            g.opacities, g.sh), scene.view_id, scene.pixel_id, cams,
                  scene.images)
    pred = _da3_prediction(moved, seed=3)
    path = tmp_path / "0000.ply"
    kept = up.da3_export_to_gs_ply(path, pred, poses_given=False)
    imported, report = import_export(path, "da3", cams, scene.images)
    assert "the cameras' frame" in report.notes[0]
    assert (imported.pixel_id == kept % (H * W)).mean() >= 0.99
    _check_da3(moved, imported, report, kept, pred)


def test_da3_saturated_confidences_are_read_as_opacity_0_and_1(tmp_path, world):
    """Depth Anything 3 writes log(p / (1 - p)) unclamped: a confidence that saturated in
    float32 is an infinite logit, read as opacity 1 or 0 (a plain PLY read still refuses it)."""
    _, scene, _ = world
    pred = _da3_prediction(scene, seed=4)
    opac = pred["opacities"].copy()
    opac[::97], opac[5::97] = 1.0, 0.0
    pred["opacities"] = opac
    path = tmp_path / "0000.ply"
    with np.errstate(divide="ignore"):
        kept = up.da3_export_to_gs_ply(path, pred, poses_given=True)
    with pytest.raises(ClearsplatError, match="opacity: non-finite value -?inf"):   # as written
        read_export(path)
    imported, report = import_export(path, "da3", scene.cameras, scene.images)
    np.testing.assert_array_equal(imported.gaussians.opacities[opac[kept] == 1.0], 1.0)
    np.testing.assert_array_equal(imported.gaussians.opacities[opac[kept] == 0.0], 0.0)
    assert (opac[kept] == 1.0).any() and (opac[kept] == 0.0).any()
    _check_da3(scene, imported, report, kept, pred)
