"""An accepted candidate removes only the Gaussians some verifying view sees
(``FilterConfig.verify_hidden``): :func:`clearsplat.filter.verify.own_depth_map` and
:func:`clearsplat.filter.verify.seen_by_verifiers` against loops one Gaussian at a time, a
closed case, and the option in a filter run."""

from types import SimpleNamespace

import numpy as np
import pytest

from clearsplat.cameras import Camera, look_at
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.association import ViewIndex
from clearsplat.filter.result import Candidate
from clearsplat.filter.verify import own_depth_map, seen_by_verifiers
from clearsplat.scene import Gaussians, Scene
from clearsplat.synth.realism import realistic_reconstruction
from clearsplat.synth.worlds import make_world


def _pinhole(cam, point):
    """(row, col, depth) of a world point in ``cam``, by the camera's matrices; None when
    behind it or outside the image."""
    x, y, z = (cam.world_to_camera @ np.append(np.asarray(point, np.float64), 1.0))[:3]
    if z <= 0:
        return None
    u, v = cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy
    if not (0 <= u < cam.width and 0 <= v < cam.height):
        return None
    return int(np.floor(v)), int(np.floor(u)), z


def _own_depth_by_loop(scene, view):
    cam = scene.cameras[view]
    out = np.full(cam.height * cam.width, np.inf)
    for g in np.flatnonzero(scene.view_id == view):
        z = cam.to_camera(scene.gaussians.means[g][None])[0, 2]
        pid = int(scene.pixel_id[g])
        if pid < 0:     # not pixel-aligned: the pixel its centre projects to
            hit = _pinhole(cam, scene.gaussians.means[g])
            if hit is None:
                continue
            pid = hit[0] * cam.width + hit[1]
        if z > 0:
            out[pid] = min(out[pid], z)
    return out


def _seen_by_loop(scene, expanded, verify_views, margin, view_margins=None):
    keep = []
    for g in expanded:
        for j in verify_views:
            hit = _pinhole(scene.cameras[j], scene.gaussians.means[g])
            if hit is None:
                continue
            row, col, z = hit
            surface = _own_depth_by_loop(scene, j)[row * scene.cameras[j].width + col]
            m = margin
            if view_margins is not None:    # the largest of the three
                for v in (int(scene.view_id[g]), j):
                    if view_margins[v] is not None:
                        m = max(m, view_margins[v])
            if z <= (1.0 + m) * surface:
                keep.append(g)
                break
    return np.array(keep, dtype=np.int64)


@pytest.fixture(scope="module")
def small():
    world = make_world("object", num_views=4, seed=1, height=24, width=40)
    scene, _ = realistic_reconstruction(world, "plain", seed=1)
    rng = np.random.default_rng(0)
    pixel_id = scene.pixel_id.copy()
    pixel_id[rng.random(len(scene)) < 0.3] = -1          # some Gaussians not pixel-aligned
    # Jitter the centres so that some fall behind, beside or out of the other cameras.
    g = scene.gaussians
    means = g.means + rng.normal(scale=0.15, size=g.means.shape).astype(g.means.dtype)
    gaussians = Gaussians(means, g.scales, g.quats, g.opacities, g.sh)
    return Scene(gaussians, scene.view_id, pixel_id, scene.cameras, scene.images,
                 scene.render_settings)


@pytest.mark.parametrize("view", range(4))
def test_own_depth_map_matches_a_loop(small, view):
    got = own_depth_map(small, ViewIndex(small), view)
    want = _own_depth_by_loop(small, view)
    assert np.isfinite(got).any()
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("widen", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_seen_by_verifiers_matches_a_loop(small, seed, widen):
    rng = np.random.default_rng(seed)
    state = SimpleNamespace(scene=small, index=ViewIndex(small))
    margin = float(rng.choice([0.0, 0.05, 0.3]))
    # Per view, refinement's margin (None: a view without one), some below ``margin``.
    view_margins = ([None if rng.random() < 0.25 else float(rng.uniform(0.0, 0.4))
                     for _ in range(4)] if widen else None)
    candidates, wants = [], []
    for k in range(5):
        view = int(rng.integers(4))
        members = np.flatnonzero(small.view_id == view)
        expanded = np.sort(rng.choice(members, size=60, replace=False)).astype(np.int64)
        verifiers = sorted(rng.choice([v for v in range(4) if v != view], size=2,
                                      replace=False).tolist())
        c = Candidate(k, view, 1, np.zeros((24, 40), bool), expanded[:10])
        c.expanded, c.verify_views = expanded.copy(), verifiers
        candidates.append(c)
        wants.append(_seen_by_loop(small, expanded, verifiers, margin, view_margins))
    seen_by_verifiers(state, candidates, margin, view_margins)
    cut = 0
    for c, want in zip(candidates, wants):
        assert np.array_equal(c.expanded, want)
        assert c.scores.get("hidden", 0) == 60 - want.size
        cut += want.size < 60
    assert cut > 0       # the jitter hides something from some verifier


def _wall_candidate(points) -> tuple:
    """View 1 looks at a wall at depth 2 (its own Gaussians); ``points`` are Gaussians of view
    0 (a camera 0.5 to the side), the expansion of one candidate that view 1 verifies.
    Returns ``(state, candidate)``."""
    K = np.array([[20.0, 0.0, 10.0], [0.0, 20.0, 10.0], [0.0, 0.0, 1.0]])
    cams = [Camera(K, look_at((x, 0.0, 0.0), (x, 0.0, 2.0), up=(0.0, -1.0, 0.0)), 20, 20)
            for x in (0.5, 0.0)]
    wall = np.array([[x, y, 2.0] for x in np.linspace(-0.4, 0.4, 9)
                     for y in np.linspace(-0.4, 0.4, 9)])
    means = np.concatenate([np.asarray(points, np.float64), wall]).astype(np.float32)
    n, k = len(means), len(points)
    gaussians = Gaussians(means, np.full((n, 3), 0.01, np.float32),
                          np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
                          np.full(n, 0.9, np.float32), np.zeros((n, 1, 3), np.float32))
    view_id = np.array([0] * k + [1] * len(wall), dtype=np.int64)
    scene = Scene(gaussians, view_id, np.full(n, -1, np.int64), cams)
    c = Candidate(0, 0, 1, np.zeros((20, 20), bool), np.arange(k))
    c.expanded, c.verify_views = np.arange(k), [1]
    return SimpleNamespace(scene=scene, index=ViewIndex(scene)), c


def test_a_surface_behind_the_verifying_views_own_stays():
    # On view 1's line of sight: one in front of the wall, one behind it; one beside the image.
    state, c = _wall_candidate([[0.0, 0.0, 1.5], [0.05, 0.0, 2.5], [3.0, 0.0, 1.0]])
    seen_by_verifiers(state, [c], 0.05)
    assert c.expanded.tolist() == [0]
    assert c.scores["hidden"] == 2


@pytest.mark.parametrize("own, verifier, kept", [
    (None, None, [0]),          # 0.05: 2.2 is 10 % behind the wall at 2
    (0.08, 0.02, [0]),          # neither view's margin reaches 10 %
    (0.12, 0.02, [0, 1]),       # the candidate's view is that noisy
    (0.02, 0.12, [0, 1]),       # the verifying view is
])
def test_a_noisy_view_widens_the_margin(own, verifier, kept):
    state, c = _wall_candidate([[0.0, 0.0, 1.5], [0.0, 0.0, 2.2]])
    seen_by_verifiers(state, [c], 0.05, None if own is None else [own, verifier])
    assert c.expanded.tolist() == kept


def test_paper_presets_remove_all_of_the_expansion():
    for name in ("paper", "paper-local"):
        assert FilterConfig.preset(name).verify_hidden is None
    assert FilterConfig().verify_hidden == 0.05


def _removes_less(a, b) -> list:
    """Results ``a`` and ``b`` of the same scene: the same verdicts, and every expansion and
    the removal of ``b`` a strict subset of ``a``'s. Returns the candidate pairs."""
    assert [c.accepted for c in a.candidates] == [c.accepted for c in b.candidates]
    assert not (b.removed & ~a.removed).any()
    for ca, cb in zip(a.candidates, b.candidates):
        assert set(cb.expanded.tolist()) <= set(ca.expanded.tolist())
    assert a.removed.sum() > b.removed.sum()
    return list(zip(a.candidates, b.candidates))


def test_widening_only_keeps_more(monkeypatch):
    # The object world with every artifact: view 2's depth test is widened to 9.6 % there,
    # and the back of its distractor lies up to that far behind the others' surfaces.
    from clearsplat.filter import pipeline
    world = make_world("object", num_views=4, seed=0, height=128, width=224)
    scene, _ = realistic_reconstruction(world, "all", seed=0)
    extractor = get_extractor("local")
    widened = filter_distractors(scene, extractor=extractor)

    def fixed(state, candidates, margin, view_margins):     # the fixed margin alone
        return seen_by_verifiers(state, candidates, margin, None)
    monkeypatch.setattr(pipeline, "seen_by_verifiers", fixed)
    _removes_less(widened, filter_distractors(scene, extractor=extractor))


def test_the_option_only_keeps_gaussians():
    # One round at four views; the clean twin keeps some Gaussians.
    world = make_world("object", num_views=4, seed=1, height=128, width=224)
    scene, _ = realistic_reconstruction(world, "plain", seed=1, clean=True)
    extractor = get_extractor("local")
    pairs = _removes_less(filter_distractors(scene, config=FilterConfig(verify_hidden=None),
                                             extractor=extractor),
                          filter_distractors(scene, extractor=extractor))
    for off, on in pairs:
        assert on.expanded.size + on.scores.get("hidden", 0) == off.expanded.size
