"""``clearsplat import`` end to end: a DepthSplat export of a synthetic scene with distractors
becomes a bundle that filters exactly as the exactly-inverted export does."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import upstream_exports as up
from clearsplat import Scene
from clearsplat.adapters._common import quats_to_matrices
from clearsplat.cli import main
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.io import load_scene, save_cameras, write_image
from clearsplat.synth.backbone import reconstruct
from clearsplat.synth.worlds import make_world

H, W, V = 96, 160, 4


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A DepthSplat ``save_gaussian_ply`` of a scene, its cameras and images on disk."""
    root = tmp_path_factory.mktemp("depthsplat")
    world = make_world("object", num_views=V, seed=1, height=H, width=W)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    g = scene.gaussians
    c2w = np.stack([c.camera_to_world[:3, :3] for c in scene.cameras])
    rot_cam = np.swapaxes(c2w[scene.view_id], 1, 2) @ quats_to_matrices(g.quats)
    pred = dict(means=g.means.astype(np.float64), scales=g.scales.astype(np.float64),
                rotations=Rotation.from_matrix(rot_cam).as_quat(),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64),
                opacities=g.opacities, extrinsics=np.stack([c.camera_to_world
                                                            for c in scene.cameras]))
    up.depthsplat_save_gaussian_ply(root / "gaussians.ply", pred, height=H, width=W)
    (root / "images").mkdir()
    names = [f"images/{i:03d}.png" for i in range(V)]
    for name, img in zip(names, scene.images):
        write_image(root / name, img)
    save_cameras(root / "cameras.json", scene.cameras, names)
    order = up._hwsv(np.arange(len(g)), V, H, W, 8)       # the export's vertex -> Gaussian
    return root, scene, order


def test_depthsplat_export_imports_and_filters_like_the_exact_inverse(exported, tmp_path):
    root, scene, order = exported
    bundle = tmp_path / "bundle"
    assert main(["import", "depthsplat", str(root / "gaussians.ply"), "--cameras",
                 str(root / "cameras.json"), "--images", str(root / "images"),
                 "--out", str(bundle)]) == 0
    imported = load_scene(bundle)
    n = len(order)
    assert len(imported) == n
    right_pixel = (imported.view_id == scene.view_id[order]) & \
                  (imported.pixel_id == scene.pixel_id[order])
    err = np.linalg.norm(imported.gaussians.means - scene.gaussians.means[order], axis=1)
    footprint = np.linalg.norm(scene.gaussians.means[order], axis=1) / scene.cameras[0].fx
    right_place = err < 1e-3 * footprint                       # a thousandth of a pixel
    assert right_pixel.mean() >= 0.999 and right_place.mean() >= 0.999
    report = json.loads((bundle / "import.json").read_text())
    assert report["inside_pixel"] == 1.0

    # filter the imported bundle with the CLI, and the exact inverse in memory
    filtered = tmp_path / "filtered"
    assert main(["filter", str(bundle), "--out", str(filtered)]) == 0
    removed = np.load(filtered / "removed.npy")
    exact = Scene(scene.gaussians.subset(order), view_id=scene.view_id[order],
                  pixel_id=scene.pixel_id[order], cameras=imported.cameras,
                  images=imported.images)
    expect = filter_distractors(exact, config=FilterConfig()).removed
    assert expect.sum() > 100                                  # there are distractors to find
    assert np.array_equal(removed, expect)


def test_import_refuses_to_overwrite_and_names_bad_views(exported, tmp_path, capsys):
    root, _, _ = exported
    args = ["import", "depthsplat", str(root / "gaussians.ply"), "--cameras",
            str(root / "cameras.json"), "--images", str(root / "images")]
    assert main(args + ["--out", str(root)]) == 2              # an input folder
    assert main(args + ["--out", str(tmp_path / "b"), "--views", "0,1,2,9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("clearsplat: error:") and "--views" in err[-1]
    assert main(args + ["--out", str(tmp_path / "c"), "--views", "0,1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "vertices" in err[0]
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


def test_import_with_colmap_cameras_views_by_name_and_scaled_cameras(exported, tmp_path):
    """A COLMAP model of the full-resolution capture (with a camera the model did not use),
    the context views picked by image name, images at half the cameras' resolution."""
    from clearsplat.io import read_image
    root, scene, order = exported
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    images = tmp_path / "ctx"
    images.mkdir()
    cams_lines, img_lines, names = [], [], []
    extra = scene.cameras[0].camera_to_world.copy()
    extra[:3, 3] += 0.3
    poses = [c.camera_to_world for c in scene.cameras] + [extra]
    for i, c2w in enumerate(poses):
        cam = scene.cameras[min(i, V - 1)]
        cams_lines.append(f"{i + 1} PINHOLE {2 * W} {2 * H} {2 * cam.fx} {2 * cam.fy} "
                          f"{2 * cam.cx} {2 * cam.cy}")
        r = c2w[:3, :3].T
        t = -r @ c2w[:3, 3]
        x, y, z, w = Rotation.from_matrix(r).as_quat()
        name = f"frame_{9 - i}.png"                   # sorted by name: reversed
        img_lines += [f"{i + 1} {w} {x} {y} {z} {t[0]} {t[1]} {t[2]} {i + 1} {name}", ""]
        names.append(name)
    (model / "cameras.txt").write_text("\n".join(cams_lines) + "\n")
    (model / "images.txt").write_text("\n".join(img_lines) + "\n")
    for i in range(V):
        write_image(images / names[i], read_image(root / f"images/{i:03d}.png"))
    bundle = tmp_path / "bundle"
    assert main(["import", "depthsplat", str(root / "gaussians.ply"), "--cameras",
                 str(tmp_path), "--images", str(images), "--views", ",".join(names[:V]),
                 "--out", str(bundle)]) == 0
    imported = load_scene(bundle)
    assert np.array_equal(imported.view_id, scene.view_id[order])
    assert np.array_equal(imported.pixel_id, scene.pixel_id[order])
    assert json.loads((bundle / "import.json").read_text())["inside_pixel"] == 1.0
    assert np.allclose(imported.cameras[1].K, scene.cameras[1].K)


@pytest.fixture(scope="module")
def every_export(exported, tmp_path_factory):
    """The fixture's scene written by every format's export (``export_matrix.py``)."""
    from export_matrix import write_every_export
    root, scene, _ = exported
    return write_every_export(tmp_path_factory.mktemp("every"), scene)


def test_wrong_format_is_refused_naming_the_format_that_fits(exported, every_export,
                                                            tmp_path, capsys):
    """An MVSplat export (viewer frame) imported as depthsplat: one line naming the file, the
    field and the command that imports it, exit 2, nothing written; --allow-misaligned keeps
    it with a warning; imported as mvsplat it fits."""
    from clearsplat.io.importers import MIN_NEAR_SHARE
    root, _, _ = exported
    ply = every_export["mvsplat"]
    args = ["--cameras", str(root / "cameras.json"), "--images", str(root / "images")]
    out = tmp_path / "b"
    assert main(["import", "depthsplat", str(ply), *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"clearsplat: error: {ply}: format: read as depthsplat "
                             "(first-rotation frame), only 0.")
    assert "the vertices fit mvsplat's viewer frame: clearsplat import mvsplat ... " in err[0]
    assert "--allow-misaligned" in err[0]
    assert not out.exists()

    assert main(["import", "depthsplat", str(ply), *args, "--out", str(out),
                 "--allow-misaligned"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clearsplat: warning: kept with "
                                               "--allow-misaligned")
    report = json.loads((out / "import.json").read_text())
    assert report["near_pixel"] < 0.01 and report["format"] == "depthsplat"
    assert len(load_scene(out)) == report["num_vertices"]

    right = tmp_path / "right"
    assert main(["import", "mvsplat", str(ply), *args, "--out", str(right)]) == 0
    assert capsys.readouterr().err == ""
    assert json.loads((right / "import.json").read_text())["near_pixel"] == 1.0 > MIN_NEAR_SHARE


def test_misaligned_import_without_a_fitting_format_names_the_cameras(exported, tmp_path,
                                                                    capsys):
    """The right format with the context views in the wrong order: no format fits, and the
    message says what else to check."""
    root, _, _ = exported
    out = tmp_path / "b"
    assert main(["import", "depthsplat", str(root / "gaussians.ply"), "--cameras",
                 str(root / "cameras.json"), "--images", str(root / "images"),
                 "--views", "1,0,2,3", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"clearsplat: error: {root / 'gaussians.ply'}: vertex: only ")
    assert "--views" in err[0] and "no other format's frame fits" in err[0]
    assert not out.exists()


def test_pixelsplat_figure_export_as_depthsplat_suggests_the_layout_flags(exported,
                                                                          tmp_path):
    """A suggestion keeps the layout the import was given when the other format's defaults
    differ (pixelSplat's figure script: trim 8, view fastest)."""
    from export_matrix import prediction

    from clearsplat.errors import ClearsplatError
    from clearsplat.io.importers import import_export
    _, scene, _ = exported
    path = tmp_path / "figure.ply"
    up.pixelsplat_figure_export(path, prediction(scene), height=H, width=W)
    cams = scene.cameras
    with pytest.raises(ClearsplatError) as e:
        import_export(path, "depthsplat", cams)
    assert e.value.field == "format" and "\n" not in str(e.value)
    assert "clearsplat import pixelsplat --order hwsv --trim 8 ..." in str(e.value)


@pytest.mark.slow
@pytest.mark.parametrize("pose", [0, 2])
def test_the_threshold_separates_right_and_wrong_formats(exported, tmp_path, pose):
    """Every format's export imported as every format: the right one puts at least
    MIN_NEAR_SHARE of the vertices near their pixel, also with cameras off by twice the
    realism pose error (0.5 degrees); every wrong one that passes the layout and opacity
    checks puts fewer than a tenth of it there (docs/backbones.md has the table)."""
    from export_matrix import SAME_FRAME, _measure

    from clearsplat.io.importers import MIN_NEAR_SHARE
    shares = _measure((H, W), pose, tmp_path)
    right = {k[0]: v for k, v in shares.items() if k[0] == k[1]}
    wrong = {k: v for k, v in shares.items() if k[0] != k[1] and frozenset(k) not in SAME_FRAME}
    assert len(right) == 8 and len(wrong) >= 15
    assert min(right.values()) >= MIN_NEAR_SHARE + 0.15, right
    assert max(wrong.values()) < MIN_NEAR_SHARE / 10, wrong
