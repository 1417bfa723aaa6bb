"""Depth alignment (``FilterConfig.align_depths``): the per-view scales and the moved scene."""

import numpy as np
import pytest

from clearsplat import Camera, Gaussians, Scene
from clearsplat.filter import FilterConfig
from clearsplat.filter.align import aligned_scene, view_depth_alignment

H, W, DEPTH = 24, 32, 4.0


def _plane_scene(biases, *, loose_view=None):
    """Cameras looking down +z from z=0, side by side, each predicting the plane z=DEPTH with
    one Gaussian per pixel placed at ``bias`` times its true distance along the ray."""
    K = np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]])
    cams, means, view_id, pixel_id = [], [], [], []
    ys, xs = np.mgrid[0:H, 0:W]
    for v, bias in enumerate(biases):
        c2w = np.eye(4)
        c2w[:3, 3] = [0.15 * v, 0.05 * (v % 2), 0.0]
        cam = Camera(K=K, camera_to_world=c2w, width=W, height=H)
        rays = np.stack([(xs.ravel() + 0.5 - W / 2) / 30.0, (ys.ravel() + 0.5 - H / 2) / 30.0,
                         np.ones(H * W)], 1)
        means.append(cam.position + bias * DEPTH * rays)
        view_id.append(np.full(H * W, v))
        pid = np.arange(H * W)
        pixel_id.append(np.full(H * W, -1) if v == loose_view else pid)
        cams.append(cam)
    n = len(biases) * H * W
    rng = np.random.default_rng(0)
    g = Gaussians(np.concatenate(means), np.full((n, 3), 0.02), np.tile([1.0, 0, 0, 0], (n, 1)),
                  np.full(n, 0.9), rng.uniform(0, 1, (n, 1, 3)))
    return Scene(g, np.concatenate(view_id), np.concatenate(pixel_id), cams)


def test_alignment_recovers_each_views_depth_bias():
    biases = np.array([1.0, 1.04, 0.97, 1.02, 0.95])
    scales = view_depth_alignment(_plane_scene(biases))
    # Lateral cameras over a fronto-parallel plane: every ratio is exactly s_i / s_j.
    expected = biases / np.exp(np.log(biases).mean())
    np.testing.assert_allclose(scales, expected, rtol=1e-6)


def test_unbiased_views_and_views_without_pixel_ids_keep_their_scale():
    np.testing.assert_allclose(view_depth_alignment(_plane_scene([1.0, 1.0, 1.0])), 1.0,
                               rtol=1e-9)
    scales = view_depth_alignment(_plane_scene([1.0, 1.05, 0.95, 1.0], loose_view=1))
    assert scales[1] == 1.0
    expected = np.array([1.0, 0.95, 1.0])
    np.testing.assert_allclose(scales[[0, 2, 3]], expected / np.exp(np.log(expected).mean()),
                               rtol=1e-6)


def test_aligned_scene_moves_gaussians_along_their_own_rays():
    scene = _plane_scene([1.0, 1.1, 0.9])
    before = scene.gaussians.means.copy()
    scales = np.array([1.0, 1.1, 0.9])
    moved = aligned_scene(scene, scales)
    for v, cam in enumerate(scene.cameras):
        m = scene.view_id == v
        uv0, z0 = cam.project(scene.gaussians.means[m])
        uv1, z1 = cam.project(moved.gaussians.means[m])
        np.testing.assert_allclose(uv1, uv0, atol=1e-3)          # the same pixels
        np.testing.assert_allclose(z1, z0 / scales[v], rtol=1e-5)
        np.testing.assert_allclose(moved.gaussians.scales[m],
                                   scene.gaussians.scales[m] / scales[v], rtol=1e-6)
        np.testing.assert_allclose(z1, DEPTH, rtol=1e-5)          # back on the plane
    # The input is left as it was; everything but positions and sizes is the same.
    assert np.array_equal(scene.gaussians.means, before)
    assert moved.cameras == scene.cameras
    assert np.array_equal(moved.view_id, scene.view_id)
    assert np.array_equal(moved.pixel_id, scene.pixel_id)
    assert np.array_equal(moved.gaussians.sh, scene.gaussians.sh)


@pytest.mark.parametrize("preset", ["paper", "paper-local"])
def test_paper_presets_do_not_align(preset):
    assert FilterConfig.preset(preset).align_depths is False
    assert FilterConfig().align_depths is False


def test_filter_with_alignment_is_the_filter_on_the_aligned_scene():
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction

    world = make_world("object", num_views=4, seed=2, height=64, width=96)
    scene, _ = realistic_reconstruction(world, "depth", seed=2)
    scales = view_depth_alignment(scene)
    assert np.abs(np.log(scales)).max() > 0.01           # the stand-in's views do disagree
    extractor = get_extractor("local")
    before = scene.gaussians.means.copy()
    got = filter_distractors(scene, config=FilterConfig(align_depths=True), extractor=extractor)
    want = filter_distractors(aligned_scene(scene, scales), config=FilterConfig(),
                              extractor=extractor)
    assert np.array_equal(got.keep, want.keep)
    assert np.array_equal(scene.gaussians.means, before)   # the input is not moved
