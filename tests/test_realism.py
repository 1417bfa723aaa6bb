"""The realistic stand-in backbone: each artifact does what it says, seeded, on the clean twin too."""

import numpy as np
import pytest

from clearsplat import ClearsplatError
from clearsplat.render import render
from clearsplat.synth import make_world
from clearsplat.synth.backbone import distractor_truth, reconstruct
from clearsplat.synth.realism import (ARTIFACTS, SCENARIOS, estimated_camera, parse_realism,
                                      realistic_reconstruction, reproduction_psnr)

H, W = 48, 80


@pytest.fixture(scope="module")
def world():
    return make_world("object", num_views=3, seed=2, height=H, width=W)


def test_parse_realism():
    assert parse_realism("plain") == ()
    assert parse_realism("all") == ("soft", "depth", "exposure", "pose")
    assert parse_realism("pose+soft") == ("soft", "pose")
    assert parse_realism(["coarse", "exposure"]) == ("exposure", "coarse")
    with pytest.raises(ClearsplatError, match="unknown realism"):
        parse_realism("blurry")
    with pytest.raises(ClearsplatError, match="layouts"):
        parse_realism("multi+coarse")
    assert set(SCENARIOS) == {"plain", "all", *ARTIFACTS}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_scenario_is_valid_seeded_and_its_truth_matches(world, scenario):
    s, truth = realistic_reconstruction(world, scenario, seed=5)
    s.validate()
    assert truth.shape == (len(s),) and truth.dtype == bool
    again, truth2 = realistic_reconstruction(world, scenario, seed=5)
    np.testing.assert_array_equal(s.gaussians.means, again.gaussians.means)
    np.testing.assert_array_equal(truth, truth2)
    other, _ = realistic_reconstruction(world, scenario, seed=6)
    if scenario != "plain" and scenario != "multi":
        assert not np.array_equal(s.gaussians.means, other.gaussians.means) or \
            not np.array_equal(s.images[0], other.images[0]) or \
            not np.array_equal(s.gaussians.opacities, other.gaussians.opacities)
    clean, clean_truth = realistic_reconstruction(world, scenario, seed=5, clean=True)
    assert len(clean) == len(s) and not clean_truth.any()
    if s.is_pixel_aligned:
        np.testing.assert_array_equal(truth, distractor_truth(s, world))
    # The clean twin shares every draw: same cameras, and identical Gaussians away from
    # transients (the depth blur and soft colours reach a few pixels around them).
    for a, b in zip(s.cameras, clean.cameras):
        np.testing.assert_array_equal(a.camera_to_world, b.camera_to_world)
    if s.is_pixel_aligned:
        near = np.stack([_grow(m) for m in world.transient_masks])
        far = ~near[s.view_id, s.pixel_id]
        np.testing.assert_allclose(s.gaussians.opacities[far], clean.gaussians.opacities[far],
                                   atol=1e-3)


def _grow(mask, r=8):
    from scipy import ndimage
    return ndimage.binary_dilation(mask, iterations=r).reshape(-1)


def test_plain_scenario_is_the_plain_backbone_layout(world):
    s, truth = realistic_reconstruction(world, "plain", seed=0)
    ref = reconstruct(world.cameras, world.images, world.depths, seed=0)
    np.testing.assert_allclose(s.gaussians.means, ref.gaussians.means, rtol=1e-6)
    np.testing.assert_array_equal(s.pixel_id, ref.pixel_id)


def test_soft_opacities_spread_and_lower_at_depth_edges(world):
    s, _ = realistic_reconstruction(world, "soft", seed=0)
    a = s.gaussians.opacities
    assert s.gaussians.sh_degree == 1 and np.abs(s.gaussians.sh[:, 1:]).max() > 0
    assert a.min() < 0.4 and a.max() > 0.9 and 0.6 < np.median(a) < 0.9
    d = np.log(world.depths[0])
    edge = (np.abs(np.diff(d, axis=1, append=d[:, -1:])) > 0.1).reshape(-1)
    a0 = a[s.view_id == 0]
    assert a0[edge].mean() < a0[~edge].mean() - 0.1


def test_depth_scale_bias_differs_per_view(world):
    s, _ = realistic_reconstruction(world, "depth", seed=0, clean=True)
    ratios = []
    for i, cam in enumerate(s.cameras):
        z = cam.to_camera(s.gaussians.means[s.view_id == i])[:, 2]
        ratios.append(np.median(z / world.clean_depths[i].reshape(-1)))
    assert np.ptp(ratios) > 0.01 and all(0.85 < r < 1.15 for r in ratios)


def test_multi_puts_three_gaussians_on_each_pixel_ray(world):
    s, truth = realistic_reconstruction(world, "multi", seed=0)
    assert len(s) == 3 * 3 * H * W
    v0 = np.flatnonzero(s.view_id == 0)
    cam = s.cameras[0]
    uv, z = cam.project(s.gaussians.means[v0])
    rows, cols = np.divmod(s.pixel_id[v0], W)
    np.testing.assert_allclose(uv, np.stack([cols + 0.5, rows + 0.5], 1), atol=1e-3)
    # three layers compound to the single Gaussian's opacity 0.9
    np.testing.assert_allclose(1 - (1 - s.gaussians.opacities[v0]) ** 3, 0.9, atol=1e-5)


def test_exposure_changes_the_inputs_per_view_and_channel(world):
    s, _ = realistic_reconstruction(world, "exposure", seed=0)
    gains = []
    for i in range(3):
        ok = (world.images[i] > 0.05) & (world.images[i] < 0.9)
        gains.append([np.median(s.images[i][..., c][ok[..., c]] / world.images[i][..., c][ok[..., c]])
                      for c in range(3)])
    gains = np.array(gains)
    assert np.abs(gains - 1).max() > 0.02 and np.ptp(gains[:, 0] / gains[:, 2]) > 0.005


def test_pose_error_is_small_and_the_model_follows_the_estimated_camera(world):
    s, _ = realistic_reconstruction(world, "pose", seed=0)
    for i, (cam, est) in enumerate(zip(world.cameras, s.cameras)):
        R = cam.camera_to_world[:3, :3].T @ est.camera_to_world[:3, :3]
        angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
        assert 0.01 < angle < 2.0
        shift = np.linalg.norm(cam.position - est.position) / np.median(world.depths[i])
        assert shift < 0.03
        # Gaussians sit on the estimated camera's pixel rays.
        uv, _ = est.project(s.gaussians.means[s.view_id == i])
        rows, cols = np.divmod(s.pixel_id[s.view_id == i], W)
        np.testing.assert_allclose(uv, np.stack([cols + 0.5, rows + 0.5], 1), atol=1e-3)
    np.testing.assert_array_equal(
        estimated_camera(world.cameras[0], world.depths[0], seed=3, view=0).camera_to_world,
        estimated_camera(world.cameras[0], world.depths[0], seed=3, view=0).camera_to_world)


def test_coarse_has_no_pixel_id_and_truth_from_mostly_transient_cells(world):
    s, truth = realistic_reconstruction(world, "coarse", seed=0)
    assert len(s) == 3 * (H // 2) * (W // 2) and not s.is_pixel_aligned
    m = world.transient_masks[0].reshape(H // 2, 2, W // 2, 2).mean(axis=(1, 3)) >= 0.5
    np.testing.assert_array_equal(truth[s.view_id == 0], m.reshape(-1))


def test_inputs_are_reproduced_by_their_own_gaussians(world):
    for scenario in ("plain", "all", "coarse"):
        s, _ = realistic_reconstruction(world, scenario, seed=0)
        p = reproduction_psnr(s)
        assert p.shape == (3,) and (p > 20).all()
    # the measure itself: a view's own render, not the whole scene's
    s, _ = realistic_reconstruction(world, "plain", seed=0)
    r = render(s, s.cameras[1], keep=s.view_id == 1)
    from clearsplat.metrics import psnr
    assert reproduction_psnr(s)[1] == pytest.approx(psnr(r.rgb, s.images[1]))


def test_bench_runs_a_realism_scenario_and_reports_the_exact_gain():
    from clearsplat.bench import format_tables, run_suite
    from clearsplat.filter import FilterConfig
    rows = run_suite(families=("street",), views=(3,), height=48, width=80,
                     configs={"default": FilterConfig()}, realism=("plain", "coarse"))
    assert [r["realism"] for r in rows] == ["plain", "coarse"]
    assert rows[1]["gaussians"] == 3 * 24 * 40
    # Removing exactly the distractors must change (and here improve) the test views: a wrong
    # truth (all False) would leave them as they are.
    for r in rows:
        assert r["distractor_gaussians"] > 0
        assert r["exact"]["psnr"] > r["baseline"]["psnr"]
    text = format_tables(rows)
    assert "scenario" in text and "coarse" in text and "of exact" in text
    with pytest.raises(ClearsplatError, match="unknown realism"):
        run_suite(families=("street",), views=(3,), height=48, width=80, realism=("fog",))


def test_bench_occlusion_reaches_the_worlds():
    from clearsplat.bench import run_suite
    from clearsplat.filter import FilterConfig
    from clearsplat.synth.worlds import make_world
    cfg = {"default": FilterConfig()}
    medium, high = (run_suite(families=("street",), views=(4,), height=48, width=80,
                              configs=cfg, occlusion=o)[0] for o in ("medium", "high"))
    assert medium["family"] == "street" and high["family"] == "street/high"
    # the rows count the transients of the world made at that level
    for row, level in ((medium, "medium"), (high, "high")):
        world = make_world("street", num_views=4, seed=0, height=48, width=80, occlusion=level)
        assert row["distractor_gaussians"] > 0
        assert sum(int(m.sum()) for m in world.transient_masks) > 0
    assert high["distractor_gaussians"] != medium["distractor_gaussians"]


def test_bench_video_transients_reach_the_worlds():
    from clearsplat.bench import run_suite
    from clearsplat.filter import FilterConfig
    (row,) = run_suite(families=("street",), views=(5,), height=48, width=80,
                       configs={"default": FilterConfig()}, transients="video")
    assert row["family"] == "street/video" and row["distractor_gaussians"] > 0
    with pytest.raises(ClearsplatError) as e:
        run_suite(families=("object",), views=(4,), height=48, width=80, transients="video")
    assert e.value.field == "transients"
