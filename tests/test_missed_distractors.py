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
