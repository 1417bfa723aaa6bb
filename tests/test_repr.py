"""Short reprs: a Scene or a FilterResult prints on one line, whatever its size."""

from __future__ import annotations

import pytest

from clearsplat import FilterConfig, filter_distractors
from clearsplat.synth import make_world, reconstruct


@pytest.fixture(scope="module")
def scene():
    world = make_world("object", num_views=3, height=24, width=32)
    return reconstruct(world.cameras, world.images, world.depths, seed=0)


def test_scene_and_gaussians_repr(scene):
    text = repr(scene)
    assert text == ("Scene(2,304 Gaussians, SH degree 0; 3 views of 32x24; pixel-aligned; "
                    "with images)")
    assert repr(scene.gaussians) == "Gaussians(2,304, SH degree 0)"
    assert repr(scene.subset(scene.view_id == 0)).startswith("Scene(768 Gaussians")


def test_filter_result_repr(scene):
    result = filter_distractors(scene, config=FilterConfig(eta=0.3))
    text = repr(result)
    assert "\n" not in text and len(text) < 200, text
    accepted = sum(c.accepted for c in result.candidates)
    assert text.startswith(f"FilterResult(removed {int(result.removed.sum()):,} of 2,304 "
                           f"Gaussians; {accepted} of {len(result.candidates)} candidates")
    assert "preset 'default' with eta=0.3" in text
    for c in result.candidates:
        r = repr(c)
        assert "\n" not in r and len(r) < 200 and c.reason in r
    assert len(repr(result.candidates)) < 200 * len(result.candidates)
