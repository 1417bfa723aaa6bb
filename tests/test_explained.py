"""Candidates the other views explain (``explained.EXPLAINED``): the colour distances, each
view's colour noise (``explained.ColorNoise``) and the per-candidate test."""

import numpy as np
import pytest

from clearsplat import Camera, Gaussians, Scene
from clearsplat.filter import FilterConfig, explained
from clearsplat.filter.association import ViewIndex, member_pixels
from clearsplat.filter.explained import (ColorNoise, box_distance, color_distances,
                                         explained_candidates)
from clearsplat.filter.result import Candidate


def _slow_box_distance(image, lo, hi, pixels):
    out = []
    for p in pixels:
        d = 0.0
        for ch in range(3):
            x, a = float(image[p, ch]), float(lo[p, ch])
            b = a if hi is None else float(hi[p, ch])
            if np.isnan(a) or np.isnan(b):
                d = np.nan
                break
            d += max(a - x, 0.0) + max(x - b, 0.0) if hi is not None else abs(x - a)
        out.append(d)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_box_distance_matches_the_per_pixel_definition(seed):
    rng = np.random.default_rng(seed)
    n = 200
    image = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    a, b = rng.uniform(0, 1, (2, n, 3)).astype(np.float32)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    lo[rng.uniform(size=n) < 0.1] = np.nan
    pixels = rng.integers(0, n, 150)
    for box_hi in (hi, None):
        got = box_distance(image, lo, box_hi, pixels)
        want = _slow_box_distance(image, lo, box_hi, pixels)
        assert np.array_equal(np.isnan(got), np.isnan(want))
        ok = ~np.isnan(want)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-6, atol=1e-7)


def test_box_distance_closed_forms():
    image = np.array([[0.5, 0.5, 0.5], [0.0, 1.0, 0.2]], np.float32)
    lo = np.array([[0.4, 0.4, 0.4], [0.1, 0.5, 0.2]], np.float32)
    hi = np.array([[0.6, 0.6, 0.6], [0.3, 0.9, 0.2]], np.float32)
    # Inside the box: 0. Outside: the L1 distance to its nearest face per channel.
    np.testing.assert_allclose(box_distance(image, lo, hi, np.array([0, 1])), [0.0, 0.2],
                               atol=1e-7)
    # Without an upper bound the box is the colour ``lo``: the plain L1 difference.
    np.testing.assert_allclose(box_distance(image, lo, None, np.array([0, 1])), [0.3, 0.6],
                               atol=1e-6)


def _scene(num_views=2, h=6, w=8, loose=()):
    """One Gaussian per pixel and view; the views in ``loose`` without pixel ids."""
    K = np.array([[10.0, 0, w / 2], [0, 10.0, h / 2], [0, 0, 1]])
    cams, view_id, pixel_id = [], [], []
    for v in range(num_views):
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * v
        cams.append(Camera(K=K, camera_to_world=c2w, width=w, height=h))
        view_id.append(np.full(h * w, v))
        pixel_id.append(np.full(h * w, -1) if v in loose else np.arange(h * w))
    n = num_views * h * w
    rng = np.random.default_rng(3)
    means = np.concatenate([rng.uniform(-0.2, 0.2, (h * w, 3)) + [0, 0, 3] for _ in cams])
    g = Gaussians(means, np.full((n, 3), 0.02), np.tile([1.0, 0, 0, 0], (n, 1)),
                  np.full(n, 0.9), rng.uniform(0, 1, (n, 1, 3)))
    images = [rng.uniform(0, 1, (h, w, 3)).astype(np.float32) for _ in cams]
    return Scene(g, np.concatenate(view_id), np.concatenate(pixel_id), cams, images=images)


def test_color_distances_read_each_gaussians_own_pixel():
    scene = _scene(num_views=3)
    index = ViewIndex(scene)
    rng = np.random.default_rng(4)
    lo = [rng.uniform(0, 0.5, (6, 8, 3)).astype(np.float32) for _ in range(3)]
    hi = [a + 0.3 for a in lo]
    lo[1][2, 3] = np.nan                       # no reference colour at one pixel
    pixels = [member_pixels(scene, index, v) for v in range(3)]
    got = color_distances(scene, index, lo, scene.images, pixels, reference_rgbs_hi=hi)
    assert got.shape == (len(scene),) and got.dtype == np.float32
    for g in range(len(scene)):
        v, p = scene.view_id[g], scene.pixel_id[g]
        want = _slow_box_distance(scene.images[v].reshape(-1, 3), lo[v].reshape(-1, 3),
                                  hi[v].reshape(-1, 3), [p])[0]
        if np.isnan(want):
            assert np.isnan(got[g])
        else:
            assert got[g] == pytest.approx(want, rel=1e-5, abs=1e-6)
    assert np.isnan(got[(scene.view_id == 1) & (scene.pixel_id == 2 * 8 + 3)]).all()


def test_color_distances_without_a_pixel_are_nan():
    # Loose Gaussians take the pixel their centre projects to; one behind the camera has none.
    scene = _scene(num_views=2, loose=(1,))
    scene.gaussians.means[scene.view_id == 1] = [0.0, 0.0, -1.0]
    index = ViewIndex(scene)
    lo = [np.zeros((6, 8, 3), np.float32)] * 2
    pixels = [member_pixels(scene, index, v) for v in range(2)]
    got = color_distances(scene, index, lo, scene.images, pixels)
    assert np.isnan(got[scene.view_id == 1]).all()
    assert np.isfinite(got[scene.view_id == 0]).all()


def _members(view_id):
    return [np.flatnonzero(view_id == v) for v in range(int(view_id.max()) + 1)]


def _candidate(index, view, gaussians):
    return Candidate(index, view, 1, np.zeros((2, 2), bool), np.asarray(gaussians, np.int64))


def _noise(d, raw, view_id):
    return ColorNoise(d, raw, _members(view_id))


def _slow_bounds(d, raw, members, quantile):
    """Per view, the ``quantile`` of the distances of its Gaussians outside every proposal
    (``raw``) that have one, one Gaussian at a time; None where it has none."""
    proposed = {int(g) for r in raw for g in r}
    out = []
    for m in members:
        ref = [float(d[g]) for g in m if int(g) not in proposed and np.isfinite(d[g])]
        out.append(float(np.quantile(np.array(ref), quantile)) if ref else None)
    return out


def test_explained_candidates_compare_with_the_views_unproposed_gaussians(monkeypatch):
    view_id = np.repeat([0, 1], 100)
    d = np.empty(200)
    d[:100] = np.linspace(0.0, 0.99, 100)    # view 0: static distances 0 .. 0.99
    d[100:] = np.linspace(0.0, 0.099, 100)   # view 1: a view the others reproduce closely
    a = _candidate(0, 0, [0, 1, 2])          # view 0, distances 0.00-0.02: explained
    b = _candidate(1, 0, [97, 98, 99])       # view 0, 0.97-0.99: above its 0.9 quantile
    c = _candidate(2, 1, [150, 151])         # view 1, ~0.05: below 0.9 quantile of view 1
    raw = [np.array([0, 1, 2]), np.array([97, 98, 99]), np.array([150, 151])]
    got = explained_candidates([a, b, c], _noise(d, raw, view_id), quantile=0.9)
    assert got == [a, c]
    # The quantile is over the view's Gaussians outside every proposal: with its 60 lowest
    # distances proposed, view 1's 0.5 quantile rises from 0.0495 to 0.079 and the candidate
    # there (0.0505) is explained; counted with them it would not be.
    assert explained_candidates([c], _noise(d, raw, view_id), quantile=0.5) == []
    raw2 = raw + [np.arange(100, 160)]
    assert explained_candidates([c], _noise(d, raw2, view_id), quantile=0.5) == [c]
    assert c.scores["color"] == pytest.approx(0.0505)
    assert c.scores["color_bound"] == pytest.approx(np.quantile(d[160:200], 0.5))
    # A stricter quantile explains fewer.
    assert explained_candidates([a, b, c], _noise(d, raw, view_id), quantile=0.01) == [a]
    # The noise's bounds are the per-view quantiles of the static distances (a slow
    # reference), made once per quantile; a noise whose bounds were made already decides the
    # same as a fresh one.
    noise = _noise(d, raw, view_id)
    proposed = np.zeros(200, bool)
    proposed[np.concatenate(raw)] = True
    np.testing.assert_array_equal(noise.static, ~proposed & np.isfinite(d))
    for q in (0.01, 0.5, 0.9):
        made = noise.bounds(q)
        assert made == _slow_bounds(d, raw, _members(view_id), q)
        assert noise.bounds(q) is made
        assert [noise.bound(v, q) for v in range(2)] == made
        assert (explained_candidates([a, b, c], noise, quantile=q)
                == explained_candidates([a, b, c], _noise(d, raw, view_id), quantile=q))
    # The candidates are held against the noise's bounds (None: that view judges nothing).
    held = _noise(d, raw, view_id)
    monkeypatch.setattr(held, "bounds", lambda q: [1.0, 0.0])
    assert explained_candidates([a, b, c], held, quantile=0.9) == [a, b]
    monkeypatch.setattr(held, "bounds", lambda q: [None, 1.0])
    assert explained_candidates([a, b, c], held, quantile=0.9) == [c]
    # Without a quantile: ``explained.EXPLAINED``, read at call time.
    assert explained.EXPLAINED == 0.75
    assert (explained_candidates([a, b, c], noise)
            == explained_candidates([a, b, c], noise, quantile=0.75))
    monkeypatch.setattr(explained, "EXPLAINED", 0.01)
    assert explained_candidates([a, b, c], noise) == [a]


def test_a_candidate_is_judged_on_what_it_removes():
    # Its refined Gaussians look like the view's static content, but its expansion reaches
    # Gaussians the other views do not show: what accepting it would remove is not explained.
    view_id = np.zeros(100, int)
    d = np.linspace(0.0, 0.99, 100)
    c = _candidate(0, 0, [0, 1, 2])
    noise = _noise(d, [np.arange(3)], view_id)
    assert explained_candidates([c], noise, quantile=0.9) == [c]
    c.expanded = np.array([0, 1, 2, 95, 96, 97, 98, 99])
    assert explained_candidates([c], noise, quantile=0.9) == []


def test_the_bound_ignores_static_gaussians_without_a_reference_colour():
    view_id = np.zeros(100, int)
    d = np.linspace(0.0, 0.99, 100)
    d[50:] = np.nan                            # half the view has no reference colour
    c = _candidate(0, 0, [10, 11, 12])         # 0.10-0.12: above the 0.2 quantile of 0-0.49
    assert explained_candidates([c], _noise(d, [np.arange(10, 13)], view_id),
                                quantile=0.2) == []
    static = np.r_[d[:10], d[13:50]]          # unproposed, with a reference colour
    assert c.scores["color_bound"] == pytest.approx(np.quantile(static, 0.2))


def test_a_view_without_static_reference_colours_explains_nothing():
    view_id = np.repeat([0, 1], 10)
    d = np.zeros(20)
    d[10:] = np.nan                            # view 1: no reference colour anywhere...
    d[[15, 16]] = 0.0                          # ...but at its candidate's own Gaussians
    c = _candidate(0, 1, [15, 16])
    noise = _noise(d, [np.array([15, 16])], view_id)
    assert explained_candidates([c], noise, quantile=1.0) == []
    assert noise.bounds(1.0)[1] is None
    assert "color_bound" not in c.scores


def test_candidates_without_a_reference_colour_are_never_explained():
    view_id = np.zeros(10, int)
    d = np.full(10, np.nan)
    d[5:] = 0.0
    a = _candidate(0, 0, [0, 1])             # no finite distance: cannot be judged
    assert explained_candidates([a], _noise(d, [np.array([0, 1])], view_id),
                                quantile=1.0) == []
    empty = _candidate(1, 0, [])
    assert explained_candidates([empty], _noise(d, [np.array([], int)], view_id),
                                quantile=1.0) == []


@pytest.mark.parametrize("preset", ["paper", "paper-local"])
def test_paper_presets_remove_every_candidate_that_passes(preset):
    # No refinement, no static reference: nothing can be explained.
    assert FilterConfig.preset(preset).refine == "none"
    assert FilterConfig().refine == "static-depth" and explained.EXPLAINED == 0.75


def test_explained_candidates_are_rejected(monkeypatch):
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction

    world = make_world("object", num_views=4, seed=1, height=96, width=160)
    scene, _ = realistic_reconstruction(world, "pose", seed=1)
    extractor = get_extractor("local")
    import clearsplat.filter.explained as explained_module
    # The rule alone: without the silhouette rule (explained.explained_silhouettes), which
    # keeps the outlines of this scene's misplaced static content before any candidate is
    # judged.
    _no_silhouettes(monkeypatch)
    monkeypatch.setattr(explained_module, "EXPLAINED", 0.9)
    base = FilterConfig()
    verdict = explained_module.explained_candidates     # what reject_explained reads
    monkeypatch.setattr(explained_module, "explained_candidates",
                        lambda candidates, noise, **k: [])
    off = filter_distractors(scene, config=base, extractor=extractor)
    monkeypatch.setattr(explained_module, "explained_candidates", verdict)
    on = filter_distractors(scene, config=base, extractor=extractor)
    explained = [c for c in on.candidates if c.reason.startswith("explained")]
    assert explained                        # the estimated poses leave such candidates
    by_index = {c.index: c for c in off.candidates}
    for c in explained:
        # Each passed its individual test, as without the option: only its expansion's
        # colours, which the other views show, reject it.
        assert not c.accepted and c.scores["individual"] > 0
        assert c.scores["individual"] == by_index[c.index].scores["individual"]
        assert by_index[c.index].reason != "rejected by individual test"
        assert c.scores["color"] <= c.scores["color_bound"]
    for c in on.candidates:
        if c.accepted:
            assert c.scores["color"] > c.scores["color_bound"]
    # The same candidates are proposed, refined and expanded either way.
    assert [c.gaussians.tolist() for c in on.candidates] == \
        [c.gaussians.tolist() for c in off.candidates]
    assert [c.expanded.tolist() for c in on.candidates] == \
        [c.expanded.tolist() for c in off.candidates]
    assert not any(c.reason.startswith("explained") for c in off.candidates)
    removed = np.flatnonzero(~on.keep)
    for c in explained:                     # an explained candidate's own Gaussians stay
        only = np.setdiff1d(c.expanded, np.concatenate(
            [x.expanded for x in on.candidates if x.accepted] or [np.array([], int)]))
        assert not np.isin(only, removed).any()
    # With refine other than "static-depth" there is no static reference: nothing is explained.
    depth = filter_distractors(scene, config=base.replace(refine="depth"), extractor=extractor)
    assert not any(c.reason.startswith("explained") for c in depth.candidates)


def test_without_verification_nothing_is_explained(monkeypatch):
    # The "no verification" ablation removes every proposal, explained or not.
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction

    world = make_world("object", num_views=4, seed=1, height=96, width=160)
    scene, _ = realistic_reconstruction(world, "pose", seed=1)
    monkeypatch.setattr(explained, "EXPLAINED", 0.9)
    res = filter_distractors(scene, config=FilterConfig(verify=False),
                             extractor=get_extractor("local"))
    assert res.candidates and all(c.accepted for c in res.candidates)


def test_explained_second_range_candidates_skip_the_additional_and_joint_tests(monkeypatch):
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction

    world = make_world("object", num_views=4, seed=1, height=96, width=160)
    scene, _ = realistic_reconstruction(world, "pose", seed=1)
    chosen = []

    def every_second_range(candidates, noise, *, quantile=None):
        out = [c for c in candidates if c.range == 2]
        chosen.extend(out)
        return out
    monkeypatch.setattr(explained, "explained_candidates", every_second_range)
    res = filter_distractors(scene, config=FilterConfig(), extractor=get_extractor("local"))
    assert chosen                              # some second-range candidates passed
    for c in chosen:
        assert not c.accepted and c.reason.startswith("explained")
        assert "additional" not in c.scores and "joint" not in c.scores
    assert not any(c.accepted for c in res.candidates if c.range == 2)


# --- silhouettes (explained.explained_silhouettes at explained.EXPLAINED): flying pixels at a
# distractor's outline ---------------------------------------------------------------------

def _no_silhouettes(monkeypatch):
    """The refinement without the silhouette rule: no silhouette explained."""
    monkeypatch.setattr(explained, "explained_silhouettes",
                        lambda scene, index, revealing, noise, pixels, **k:
                        np.zeros(revealing.shape, bool))


def _slow_silhouettes(view_id, pixels, shapes, revealing, distances, raw, quantile):
    """Per Gaussian, by the definition: kept by the refinement, its pixel with an in-image
    8-neighbour holding Gaussians of its view but none of the kept ones, and a colour distance
    at most the view's quantile over its Gaussians outside every candidate (with a distance)."""
    proposed = np.zeros(view_id.size, bool)
    for g in raw:
        proposed[g] = True
    out = np.zeros(view_id.size, bool)
    for v, (h, w) in enumerate(shapes):
        own = np.flatnonzero(view_id == v)
        static = own[~proposed[own] & np.isfinite(distances[own])]
        if static.size == 0:
            continue
        bound = np.quantile(distances[static], quantile)
        held = {int(pixels[g]) for g in own if revealing[g] and pixels[g] >= 0}
        others = {int(pixels[g]) for g in own if pixels[g] >= 0} - held
        for g in own:
            p = int(pixels[g])
            if not revealing[g] or p < 0 or not distances[g] <= bound:
                continue
            y, x = divmod(p, w)
            edge = any(0 <= y + dy < h and 0 <= x + dx < w and (y + dy) * w + x + dx in others
                       for dy in (-1, 0, 1) for dx in (-1, 0, 1))
            out[g] = edge
    return out


@pytest.mark.parametrize("seed", range(6))
def test_explained_silhouettes_match_the_definition(seed):
    from types import SimpleNamespace

    from clearsplat.filter.explained import explained_silhouettes

    rng = np.random.default_rng(seed)
    shapes = [(int(rng.integers(3, 12)), int(rng.integers(3, 12))) for _ in range(3)]
    view_id, pixels = [], []
    for v, (h, w) in enumerate(shapes):
        count = int(rng.integers(h * w // 2, 2 * h * w))   # loose, doubled and empty pixels
        view_id.append(np.full(count, v))
        pixels.append(rng.integers(-1, h * w, count))
    view_id, flat = np.concatenate(view_id), np.concatenate(pixels)
    n = view_id.size
    revealing = rng.random(n) < rng.uniform(0.2, 0.8)
    distances = rng.uniform(0, 1, n).astype(np.float32)
    distances[rng.random(n) < 0.15] = np.nan
    raw = [rng.choice(n, int(rng.integers(1, n // 3)), replace=False) for _ in range(3)]
    members = _members(view_id)
    # A fourth view without Gaussians, as member_depths gives it: no pixels.
    scene = SimpleNamespace(cameras=[SimpleNamespace(height=h, width=w)
                                     for h, w in shapes + [(4, 4)]])
    per_view = [flat[m] for m in members] + [None]
    index = SimpleNamespace(members=members + [np.zeros(0, np.int64)],
                            pixels=per_view[:-1] + [np.zeros(0, np.int64)])
    noise = ColorNoise(distances, raw, index.members)
    proposed = np.zeros(n, bool)
    proposed[np.concatenate(raw)] = True
    np.testing.assert_array_equal(noise.static, ~proposed & np.isfinite(distances))
    for q in (0.25, 0.75, 1.0):
        got = explained_silhouettes(scene, index, revealing, noise, per_view, quantile=q)
        want = _slow_silhouettes(view_id, flat, shapes, revealing, distances, raw, q)
        assert np.array_equal(got, want)
        assert not (got & ~revealing).any()
        if q == explained.EXPLAINED:     # without a quantile: explained.EXPLAINED
            assert np.array_equal(
                explained_silhouettes(scene, index, revealing, noise, per_view), want)


def test_explained_silhouettes_closed_form():
    # One view, 5x5, one Gaussian per pixel; the refinement keeps a 3x3 block. Its outer ring
    # of eight pixels is the silhouette, the centre is not; of the ring, those within the
    # static bound are explained.
    from types import SimpleNamespace

    from clearsplat.filter.explained import explained_silhouettes

    h = w = 5
    pixels = np.arange(h * w)
    block = np.zeros((h, w), bool)
    block[1:4, 1:4] = True
    revealing = block.ravel().copy()
    distances = np.full(h * w, 0.1, np.float32)     # the 16 static Gaussians: bound 0.1
    distances[revealing] = 0.5
    distances[[6, 8]] = 0.05          # two corners of the ring show the static colour
    distances[12] = 0.0               # the centre too, but it is inside
    raw = [np.flatnonzero(revealing)]
    noise = ColorNoise(distances, raw, [pixels])
    got = explained_silhouettes(SimpleNamespace(cameras=[SimpleNamespace(height=h, width=w)]),
                                SimpleNamespace(members=[pixels], pixels=[pixels]), revealing,
                                noise, [pixels], quantile=0.75)
    assert np.flatnonzero(got).tolist() == [6, 8]
    # Placed by their centres (no pixel ids): the same pixels draw no outline.
    got = explained_silhouettes(SimpleNamespace(cameras=[SimpleNamespace(height=h, width=w)]),
                                SimpleNamespace(members=[pixels], pixels=[pixels * 0 - 1]),
                                revealing, noise, [pixels], quantile=0.75)
    assert not got.any()
    # The same block on a grid of 2x2 cells (Gaussians at every other pixel of a 10x10
    # image): no cell's pixel is an 8-neighbour of another's, so no outline is found.
    cells = (2 * (pixels // w)) * (2 * w) + 2 * (pixels % w)
    got = explained_silhouettes(SimpleNamespace(cameras=[SimpleNamespace(height=2 * h,
                                                                         width=2 * w)]),
                                SimpleNamespace(members=[pixels], pixels=[cells]), revealing,
                                noise, [cells], quantile=0.75)
    assert not got.any()


def test_silhouette_explained_keeps_flying_pixels_and_every_distractor(monkeypatch):
    # Video frames of the street: the stand-in backbone blurs depth across each passer-by's
    # outline, so the wall's pixels next to him float in front of the wall.
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world, reconstruct
    from clearsplat.synth.backbone import distractor_truth

    world = make_world("street", num_views=6, seed=0, height=96, width=160,
                       transients="video")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    truth = distractor_truth(scene, world)
    extractor = get_extractor("local")
    on = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    _no_silhouettes(monkeypatch)
    off = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    static_off = (~off.keep & ~truth).sum()
    static_on = (~on.keep & ~truth).sum()
    assert static_on < 0.8 * static_off
    assert (~on.keep & truth).sum() >= 0.99 * (~off.keep & truth).sum()
    # What it keeps is what stood in front: of the static Gaussians only the off run removes,
    # most lie in front of the clean surface at their pixel.
    kept = np.flatnonzero(~off.keep & on.keep & ~truth)
    z = np.empty(kept.size)
    for v, cam in enumerate(scene.cameras):
        sel = scene.view_id[kept] == v
        g = kept[sel]
        z[sel] = (cam.to_camera(scene.gaussians.means[g])[:, 2]
                  / world.clean_depths[v].ravel()[scene.pixel_id[g]])
    assert np.mean(z < 0.95) > 0.7


def test_kept_silhouettes_stay_unreliable_for_verification(monkeypatch):
    # The rule runs after the last refinement pass, on what that pass keeps: the pixels
    # verification leaves out are those of the run without the rule, bit for bit (a flying
    # pixel mixes the distractor's colour into the surface's and says nothing either way).
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    from clearsplat.synth import make_world, reconstruct

    world = make_world("street", num_views=6, seed=0, height=96, width=160,
                       transients="video")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    extractor = get_extractor("local")
    runs = {"on": filter_distractors(scene, config=FilterConfig(), extractor=extractor)}
    _no_silhouettes(monkeypatch)
    runs["none"] = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    assert all(len(r.proposals) == scene.num_views for r in runs.values())
    for none, on in zip(runs["none"].proposals, runs["on"].proposals):
        np.testing.assert_array_equal(on.unreliable, none.unreliable)
    assert (runs["on"].keep & ~runs["none"].keep).any()    # the rule kept some silhouettes


def test_the_colour_tests_take_quantiles_of_the_static_distances():
    # One colour-noise estimate per view, two levels: EXPLAINED (the verdict on a candidate
    # and the silhouette test), BEYOND (the band test and the expansion's reach).
    quantiles = (explained.EXPLAINED, explained.BEYOND)
    assert quantiles == (0.75, 0.99)
    assert all(0 < q <= 1 for q in quantiles)
