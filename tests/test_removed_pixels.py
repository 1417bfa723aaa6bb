"""Later rounds leave out of verification the pixels where earlier rounds removed a verifying
view's own Gaussians: its input image still shows the
removed distractor there."""

import numpy as np
import pytest

import clearsplat.filter.pipeline as pipeline
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.rounds import removed_pixels
from clearsplat.scene import Scene
from clearsplat.synth.realism import realistic_reconstruction
from clearsplat.synth.worlds import make_world


@pytest.fixture(scope="module")
def street():
    world = make_world("street", num_views=8, seed=3, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "plain", seed=3)
    return scene


@pytest.fixture(scope="module")
def extractor():
    return get_extractor("local")


def _removed_pixels_by_loop(scene, removed):
    """Slow reference: one Gaussian at a time, its pixel id, or its centre through the
    camera's pinhole model where it has none."""
    out = [np.zeros((c.height, c.width), dtype=bool) for c in scene.cameras]
    for g in np.flatnonzero(removed):
        v = int(scene.view_id[g])
        cam = scene.cameras[v]
        pid = int(scene.pixel_id[g])
        if pid >= 0:
            out[v].flat[pid] = True
            continue
        p = np.append(scene.gaussians.means[g].astype(np.float64), 1.0)
        x, y, z = (cam.world_to_camera @ p)[:3]
        if z <= 0:
            continue
        u, w = cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy
        if 0 <= u < cam.width and 0 <= w < cam.height:
            out[v][int(np.floor(w)), int(np.floor(u))] = True
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_removed_pixels_match_a_loop(street, seed):
    rng = np.random.default_rng(seed)
    scene = street
    pixel_id = scene.pixel_id.copy()
    loose = rng.random(len(scene)) < 0.3          # some Gaussians not pixel-aligned
    pixel_id[loose] = -1
    scene = Scene(scene.gaussians, scene.view_id, pixel_id, scene.cameras, scene.images,
                  scene.render_settings)
    removed = rng.random(len(scene)) < 0.05
    got = removed_pixels(scene, removed)
    want = _removed_pixels_by_loop(scene, removed)
    assert len(got) == scene.num_views
    assert any(m.any() for m in want)
    for g, w in zip(got, want):
        assert g.dtype == bool and g.shape == w.shape
        assert np.array_equal(g, w)
    assert not any(m.any() for m in removed_pixels(scene, np.zeros(len(scene), bool)))


def _rounds_seen(monkeypatch):
    """Record the ``removed`` masks each round of the filter is given."""
    seen = []
    run = pipeline.run_round

    def spy(*args, removed=None, **kwargs):
        seen.append(removed)
        return run(*args, removed=removed, **kwargs)
    monkeypatch.setattr(pipeline, "run_round", spy)
    return seen


def test_a_later_round_leaves_out_what_the_earlier_removed(street, extractor, monkeypatch):
    seen = _rounds_seen(monkeypatch)
    cfg = FilterConfig(rounds=2)
    out = filter_distractors(street, config=cfg, extractor=extractor)
    first = [c for c in out.candidates if c.round == 1 and c.accepted]
    assert first and len(seen) == 2 and seen[0] is None
    removed_first = np.ones(len(street), dtype=bool)
    for c in first:
        removed_first[c.expanded] = False
    want = _removed_pixels_by_loop(street, ~removed_first)
    for got, w in zip(seen[1], want):
        assert np.array_equal(got, w)


def test_one_round_is_unchanged(street, extractor, monkeypatch):
    """With one round there is nothing removed before: no round is given any pixels."""
    seen = _rounds_seen(monkeypatch)
    filter_distractors(street, config=FilterConfig(rounds=1), extractor=extractor)
    assert seen == [None]
