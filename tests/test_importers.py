"""Importing the models' PLY exports: each written exactly as the upstream function writes it
(``tests/upstream_exports.py``) from a known prediction, and read back to that prediction."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import upstream_exports as up
from clearsplat import Camera
from clearsplat.adapters import scales_quats_to_covariance
from clearsplat.errors import ClearsplatError
from clearsplat.io.importers import EXPORT_FORMATS, export_slots, import_export

H, W, V = 40, 48, 2


def _cameras(v=V, h=H, w=W, *, seed=0):
    """Cameras around the origin, the first one far from the identity (frames matter)."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(v):
        eye = np.array([4.0 * np.sin(0.3 * i + 0.4), 1.0 + 0.2 * i, -4.0 * np.cos(0.3 * i + 0.4)])
        eye += rng.normal(scale=0.05, size=3)
        z = -eye / np.linalg.norm(eye)
        x = np.cross(z, [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([x, y, z], axis=1)
        c2w[:3, 3] = eye + np.array([1.0, -2.0, 3.0])
        K = np.array([[50.0, 0, w / 2], [0, 52.0, h / 2], [0, 0, 1]])
        cams.append(Camera(K=K, camera_to_world=c2w, width=w, height=h))
    return cams


def _prediction(cams, *, grid=None, d_sh=1, seed=1, shift_px=0.0):
    """A per-pixel (or per-cell) prediction with known world values.

    Returns the native ``pred`` in the world frame with camera-frame rotations, and the truth
    ``(view_id, cell_id, means, world rotation matrices, scales, opacities, harmonics)`` in the
    model's order.
    """
    rng = np.random.default_rng(seed)
    gh, gw = grid or (cams[0].height, cams[0].width)
    f = cams[0].height // gh
    parts = {k: [] for k in ("view", "cell", "means", "rot_cam", "rot_world")}
    for v, cam in enumerate(cams):
        rows, cols = np.meshgrid(np.arange(gh), np.arange(gw), indexing="ij")
        # the centre of the cell, moved by less than half a pixel (the models' offsets)
        u = (cols * f + f / 2 + rng.uniform(-0.45, 0.45, cols.shape) - shift_px).reshape(-1)
        r = (rows * f + f / 2 + rng.uniform(-0.45, 0.45, rows.shape) - shift_px).reshape(-1)
        depth = 3.0 + 0.5 * np.sin(u / 7.0) + 0.3 * np.cos(r / 5.0)
        pc = np.stack([(u - cam.cx) / cam.fx, (r - cam.cy) / cam.fy, np.ones_like(u)], 1)
        means = (pc * depth[:, None]) @ cam.camera_to_world[:3, :3].T + cam.position
        rc = Rotation.random(len(u), random_state=seed + v)
        parts["view"].append(np.full(len(u), v))
        parts["cell"].append(np.arange(len(u)))
        parts["means"].append(means)
        parts["rot_cam"].append(rc.as_quat())
        parts["rot_world"].append(cam.camera_to_world[:3, :3] @ rc.as_matrix())
    t = {k: np.concatenate(p) for k, p in parts.items()}
    g = len(t["means"])
    t["scales"] = np.exp(rng.normal(-4, 0.5, (g, 3)))
    t["opacities"] = rng.uniform(0.02, 0.98, g).astype(np.float32).astype(np.float64)
    t["harmonics"] = rng.normal(scale=0.5, size=(g, 3, d_sh))
    ext = np.stack([c.camera_to_world for c in cams])
    pred = dict(means=t["means"], scales=t["scales"], rotations=t["rot_cam"],
                harmonics=t["harmonics"], opacities=t["opacities"], extrinsics=ext)
    return pred, t


def _to_first_view(pred, t, *, rotations):
    """The same prediction in the first camera's frame (pose-free models): relative poses,
    centres, and rotations either in that frame or left per view (``"local"``)."""
    e0 = pred["extrinsics"][0]
    inv = np.linalg.inv(e0)
    out = dict(pred)
    out["extrinsics"] = inv[None] @ pred["extrinsics"]
    out["means"] = t["means"] @ inv[:3, :3].T + inv[:3, 3]
    if rotations == "frame":
        out["rotations"] = Rotation.from_matrix(inv[:3, :3] @ t["rot_world"]).as_quat()
    return out


def _hwsv_truth(t, key, trim, keep=None):
    return up._hwsv(t[key], V, H, W, trim, keep)


def _check(scene, report, t, idx_fn, *, atol_means=2e-5, pixel=True, dc_only=True):
    """The imported scene equals the truth reordered by ``idx_fn``."""
    view = idx_fn("view")
    assert np.array_equal(scene.view_id, view)
    if pixel:
        assert np.array_equal(scene.pixel_id, idx_fn("cell"))
        assert report.inside_pixel == 1.0
    else:
        assert (scene.pixel_id == -1).all()
    g = scene.gaussians
    means = idx_fn("means")
    scale = np.abs(means).max()
    assert np.abs(g.means - means).max() <= atol_means * scale
    rot = idx_fn("rot_world")
    s = idx_fn("scales")
    cov = np.einsum("nij,nj,nkj->nik", rot, s ** 2, rot)
    got = scales_quats_to_covariance(g.scales, g.quats)
    assert np.abs(got - cov).max() <= max(2e-4, 2 * atol_means) * (s ** 2).max()
    assert np.allclose(g.opacities, idx_fn("opacities"), atol=2e-6)
    harm = idx_fn("harmonics")
    assert np.allclose(g.sh[:, 0], harm[..., 0], atol=1e-6)
    if dc_only:
        assert g.sh.shape[1] == 1


def _model_order(t):
    return lambda key: t[key]


@pytest.fixture
def cams():
    return _cameras()


def test_depthsplat_save_gaussian_ply(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "d.ply"
    up.depthsplat_save_gaussian_ply(path, pred, height=H, width=W)
    scene, report = import_export(path, "depthsplat", cams)
    _check(scene, report, t, lambda k: _hwsv_truth(t, k, 8))
    assert report.aligned == "none" and report.scale == 1.0


def test_mvsplat_figure_export_recovers_the_viewer_similarity(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "m.ply"
    up.mvsplat_figure_export(path, pred, height=H, width=W)
    scene, report = import_export(path, "mvsplat", cams)
    assert report.aligned == "scale-shift"
    # 0.45 px pixel offsets limit the fit: within a tenth of a pixel footprint
    _check(scene, report, t, lambda k: _hwsv_truth(t, k, 8), atol_means=3e-3)
    assert report.median_px < 0.4            # the offsets drawn: up to 0.45 px per axis


def test_pixelsplat_visualizer_export_camera_rotations(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "p.ply"
    up.pixelsplat_visualizer_export(path, pred)
    scene, report = import_export(path, "pixelsplat", cams)
    _check(scene, report, t, _model_order(t), atol_means=3e-3)


def test_pixelsplat_figure_script_export(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "p.ply"
    up.pixelsplat_figure_export(path, pred, height=H, width=W)
    scene, report = import_export(path, "pixelsplat", cams, trim=8, order="hwsv")
    _check(scene, report, t, lambda k: _hwsv_truth(t, k, 8), atol_means=3e-3)


def test_noposplat_first_view_frame(tmp_path, cams):
    pred, t = _prediction(cams, d_sh=4)
    rel = _to_first_view(pred, t, rotations="frame")
    path = tmp_path / "n.ply"
    up.noposplat_export_ply(path, rel["means"], rel["scales"], rel["rotations"],
                            rel["harmonics"], rel["opacities"])
    scene, report = import_export(path, "noposplat", cams)
    _check(scene, report, t, _model_order(t))
    # the model's own relative cameras give the scene in the first view's frame
    rel_cams = [Camera(K=c.K, camera_to_world=e, width=W, height=H)
                for c, e in zip(cams, rel["extrinsics"])]
    scene_rel, _ = import_export(path, "noposplat", rel_cams)
    assert np.allclose(scene_rel.gaussians.means, rel["means"], atol=1e-5)


def test_noposplat_higher_bands_turn_to_world(tmp_path, cams):
    from clearsplat.adapters import rotate_sh
    pred, t = _prediction(cams, d_sh=4)
    rel = _to_first_view(pred, t, rotations="frame")
    path = tmp_path / "n.ply"
    up.noposplat_export_ply(path, rel["means"], rel["scales"], rel["rotations"],
                            rel["harmonics"], rel["opacities"], save_sh_dc_only=False)
    scene, _ = import_export(path, "noposplat", cams)
    sh_file = np.swapaxes(rel["harmonics"], 1, 2).astype(np.float32)
    expect = rotate_sh(sh_file, cams[0].camera_to_world[:3, :3])
    assert np.allclose(scene.gaussians.sh, expect, atol=1e-5)


def test_noposplat_scale_is_fitted_when_cameras_are_metric(tmp_path, cams):
    pred, t = _prediction(cams)
    rel = _to_first_view(pred, t, rotations="frame")
    path = tmp_path / "n.ply"
    up.noposplat_export_ply(path, rel["means"] / 2.5, rel["scales"] / 2.5, rel["rotations"],
                            rel["harmonics"], rel["opacities"])
    scene, report = import_export(path, "noposplat", cams, align="scale")
    assert report.scale == pytest.approx(2.5, rel=2e-3)
    _check(scene, report, t, _model_order(t), atol_means=3e-3)


def test_yonosplat_test_step_export_local_rotations_and_opacity_cut(tmp_path, cams):
    pred, t = _prediction(cams)
    t["opacities"] = np.maximum(t["opacities"], 0.02)
    pred["opacities"] = t["opacities"]
    rel = _to_first_view(pred, t, rotations="local")
    path = tmp_path / "y.ply"
    up.yonosplat_test_step_export(path, rel, height=H, width=W)
    scene, report = import_export(path, "yonosplat", cams)
    _check(scene, report, t, lambda k: _hwsv_truth(t, k, 8))
    # a cut that dropped vertices: one line saying so, never a guess
    pred2 = dict(rel)
    op = t["opacities"].copy()
    op[20 * W + 24] = 0.005                  # inside the trimmed border
    pred2["opacities"] = op
    up.yonosplat_test_step_export(path, pred2, height=H, width=W)
    with pytest.raises(ClearsplatError, match="without recording which") as e:
        import_export(path, "yonosplat", cams)
    assert e.value.field == "vertex" and "\n" not in str(e.value)


def test_resplat_latent_grid_middle_view(tmp_path):
    cams = _cameras(3)
    pred, t = _prediction(cams, grid=(H // 4, W // 4), d_sh=4)
    path = tmp_path / "r.ply"
    up.resplat_save_gaussian_ply(path, pred)
    scene, report = import_export(path, "resplat", cams)
    assert report.grid == (H // 4, W // 4)
    _check(scene, report, t, _model_order(t), pixel=False, dc_only=False)
    # SH are written as the model renders them and stay so
    assert np.allclose(scene.gaussians.sh, np.swapaxes(t["harmonics"], 1, 2), atol=1e-6)


def test_anysplat_half_pixel_and_voxels(tmp_path, cams):
    # VGGT puts pixel (row, col) at (col, row): half a pixel before our centres
    pred, t = _prediction(cams, shift_px=0.5)
    rot = Rotation.from_matrix(t["rot_world"]).as_quat()
    pred = dict(pred, rotations=rot)         # in the frame of the predicted poses (the cameras)
    path = tmp_path / "a.ply"
    up.anysplat_inference_export(path, pred)
    with pytest.raises(ClearsplatError, match="images are needed") as e:
        import_export(path, "anysplat", cams)        # voxels (the default): from the images
    assert "\n" not in str(e.value) and e.value.field == "images"
    scene, report = import_export(path, "anysplat", cams, voxelized=False)
    _check(scene, report, t, _model_order(t))
    assert scene.cameras[0].cx == cams[0].cx + 0.5
    _, unshifted = import_export(path, "anysplat", cams, voxelized=False, half_pixel=False)
    assert unshifted.inside_pixel < 0.5


def test_3dgs_world_file(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "g.ply"
    rot = Rotation.from_matrix(t["rot_world"]).as_quat()
    up.write_vertex_ply(path, up._cols(t["means"], t["scales"], rot[:, [3, 0, 1, 2]],
                                       t["harmonics"][..., 0], None, up._logit(t["opacities"])))
    scene, report = import_export(path, "3dgs", cams)
    _check(scene, report, t, _model_order(t))


def test_wrong_layout_is_one_line_with_the_fitting_options(tmp_path, cams):
    pred, t = _prediction(cams)
    path = tmp_path / "p.ply"
    up.pixelsplat_visualizer_export(path, pred)
    with pytest.raises(ClearsplatError, match="trim=0 spp=1") as e:
        import_export(path, "depthsplat", cams)       # untrimmed, raw: not depthsplat's layout
    assert e.value.field == "vertex" and "\n" not in str(e.value)
    path2 = tmp_path / "d.ply"
    up.depthsplat_save_gaussian_ply(path2, pred, height=H, width=W)
    with pytest.raises(ClearsplatError) as e:
        import_export(path2, "mvsplat", cams)          # logits read as raw opacities
    assert e.value.field == "opacity"
    with pytest.raises(ClearsplatError) as e:
        import_export(path2, "nope", cams)
    assert e.value.field == "format"
    for option, value in (("opacity_cut", float("nan")), ("opacity_cut", -0.1),
                          ("opacity_cut", 1.0), ("trim", -1), ("spp", 0)):
        with pytest.raises(ClearsplatError) as e:
            import_export(path2, "depthsplat", cams, **{option: value})
        assert e.value.field == option


@pytest.mark.parametrize("order", ["vhws", "hwsv"])
def test_export_slots_against_a_loop(order):
    v, h, w, s, trim = 3, 7, 9, 2, 2
    expect = []
    if order == "vhws":
        for a in range(v):
            for r in range(trim, h - trim):
                for c in range(trim, w - trim):
                    expect += [(a, r * w + c)] * s
    else:
        for r in range(trim, h - trim):
            for c in range(trim, w - trim):
                for _ in range(s):
                    expect += [(a, r * w + c) for a in range(v)]
    view, cell = export_slots(v, h, w, order=order, trim=trim, spp=s)
    assert list(zip(view.tolist(), cell.tolist())) == expect


def test_every_format_has_a_round_trip_test():
    tested = {"depthsplat", "mvsplat", "pixelsplat", "noposplat", "yonosplat", "resplat",
              "anysplat", "3dgs"}
    assert set(EXPORT_FORMATS) == tested


def test_read_export_presets_agree_with_the_import_formats():
    from clearsplat.io.exports import EXPORT_PRESETS
    for name, fmt in EXPORT_FORMATS.items():
        assert EXPORT_PRESETS[name]["opacity"] == fmt.opacity, name


def test_noposplat_degree4_bands(tmp_path, cams):
    from clearsplat.adapters import rotate_sh
    pred, t = _prediction(cams, d_sh=25)
    rel = _to_first_view(pred, t, rotations="frame")
    path = tmp_path / "n4.ply"
    up.noposplat_export_ply(path, rel["means"], rel["scales"], rel["rotations"],
                            rel["harmonics"], rel["opacities"], save_sh_dc_only=False)
    rel_cams = [Camera(K=c.K, camera_to_world=e, width=W, height=H)
                for c, e in zip(cams, rel["extrinsics"])]
    scene, _ = import_export(path, "noposplat", rel_cams)      # nothing turns
    assert np.allclose(scene.gaussians.sh, np.swapaxes(rel["harmonics"], 1, 2), atol=1e-6)
    sh = np.swapaxes(rel["harmonics"], 1, 2).astype(np.float32)
    expect = rotate_sh(sh, cams[0].camera_to_world[:3, :3])
    scene, _ = import_export(path, "noposplat", cams)          # band 4 turned to the world
    assert scene.gaussians.sh.shape[1] == 25
    assert np.allclose(scene.gaussians.sh, expect, atol=1e-5)


def test_imported_scenes_carry_the_models_render_settings(tmp_path):
    from clearsplat.adapters.anysplat import RENDER_SETTINGS
    from clearsplat.adapters.pixelsplat import RESPLAT_RENDER_SETTINGS
    cams = _cameras(3)
    pred, _ = _prediction(cams, grid=(H // 4, W // 4))
    up.resplat_save_gaussian_ply(tmp_path / "r.ply", pred)
    scene, _ = import_export(tmp_path / "r.ply", "resplat", cams)
    assert scene.render_settings == RESPLAT_RENDER_SETTINGS
    pred, _ = _prediction(cams)
    up.anysplat_inference_export(tmp_path / "a.ply", pred)
    scene, _ = import_export(tmp_path / "a.ply", "anysplat", cams, voxelized=False)
    assert scene.render_settings == RENDER_SETTINGS
