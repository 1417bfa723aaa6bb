"""benchmarks/missed_distractors.py: where a missed Gaussian lies against the static reference."""

from __future__ import annotations

import importlib.util
import os

import numpy as np

from clearsplat.filter.association import ViewIndex
from clearsplat.synth import make_world, reconstruct

SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                      "benchmarks", "missed_distractors.py")


def _script():
    spec = importlib.util.spec_from_file_location("missed_distractors", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_gaussians_moved_along_their_ray_are_placed_against_the_reference():
    world = make_world("object", num_views=3, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    cam = scene.cameras[0]
    g = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 24))[0]
    h = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 20))[0]
    centre = cam.camera_to_world[:3, 3]
    means = scene.gaussians.means
    means[g] = centre + 0.5 * (means[g] - centre)     # halfway to the camera: in front
    means[h] = centre + 3.0 * (means[h] - centre)     # three times as far: behind
    lost = np.zeros(len(scene), dtype=bool)
    lost[[g, h]] = True
    names = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02)
    got = dict(zip(np.flatnonzero(lost).tolist(), names))
    assert got[g] == "refined away: in front by more"
    assert got[h] == "refined away: behind the static reference"


def test_in_front_is_split_as_the_first_refinement_pass_judges_it():
    # View 0 predicts every depth at 0.9 of what it did, with 5 % noise: its scale against the
    # other views drops by a tenth and its margin widens. Three of its Gaussians are then put
    # at 0.99, in the middle of the widened margin, and at 0.60 of the reference at that scale.
    from clearsplat.filter.robust import view_depth_scales
    from clearsplat.render import render

    world = make_world("object", num_views=3, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    cam = scene.cameras[0]
    centre = cam.camera_to_world[:3, 3]
    means = scene.gaussians.means
    own = np.flatnonzero(scene.view_id == 0)
    rng = np.random.default_rng(1)
    means[own] = centre + 0.9 * np.exp(rng.normal(0.0, 0.05, own.size))[:, None] * (
        means[own] - centre)
    ref = render(scene, cam, keep=scene.view_id != 0).depth.ravel()[scene.pixel_id[own]]
    z = cam.to_camera(means[own])[:, 2]
    scale, spread = view_depth_scales([z], [ref])[0]
    widened = 1.0 - np.exp(-2.5 * spread)
    assert scale < 0.97 and widened > 0.08
    picks = {}
    for k, (row, f) in enumerate(((16, 0.99), (20, 1.0 - (0.02 + widened) / 2), (24, 0.60))):
        i = np.flatnonzero(scene.pixel_id[own] == row * 48 + 24)[0]
        assert ref[i] > 0
        means[own[i]] = centre + (f * scale * ref[i] / z[i]) * (means[own[i]] - centre)
        picks[own[i]] = k
    lost = np.zeros(len(scene), dtype=bool)
    lost[list(picks)] = True
    names = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02,
                                          align_scale=True)
    got = {picks[g]: name for g, name in zip(np.flatnonzero(lost).tolist(), names)}
    assert got == {0: "refined away: in front, not at its view's scale",
                   1: "refined away: within its view's widened margin",
                   2: "refined away: in front by more, all the same"}
    # Without the alignment all three are simply in front by more than the margin.
    plain = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02)
    assert set(plain) == {"refined away: in front by more"}
