"""The filter's options for real backbones (each view's depth noise, clearsplat.filter.robust;
its colour noise and misregistration, clearsplat.filter.explained; and where they plug in),
each against a slow reference or a closed form, and the paper presets untouched by them."""

import dataclasses

import numpy as np
import pytest

from clearsplat import ClearsplatError
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.association import ViewIndex
from clearsplat.filter.explained import tolerant_reference
from clearsplat.filter.refine import revealing_gaussians
from clearsplat.filter.robust import view_depth_scales
from clearsplat.filter.verify import Partial, change_weighted_terms
from clearsplat.synth import make_world
from clearsplat.synth.realism import realistic_reconstruction

NEW = dict(min_relative_score=0.3, rounds=2)


@pytest.fixture
def verify_removed_pixels(monkeypatch):
    """A later round verifies the pixels where the rounds before removed a view's own
    Gaussians as any other (a second run on the kept scene cannot know them)."""
    from clearsplat.filter import pipeline
    monkeypatch.setattr(pipeline, "removed_pixels", lambda scene, removed: None)


@pytest.fixture
def no_explained(monkeypatch):
    """Without the colour-explained verdict (``explained.explained_candidates``: none)."""
    from clearsplat.filter import explained
    monkeypatch.setattr(explained, "explained_candidates", lambda candidates, noise, **k: [])


def test_view_depth_scales_is_the_median_ratio():
    rng = np.random.default_rng(1)
    ref = rng.uniform(1, 5, 1000)
    z = 1.04 * ref * np.exp(0.005 * rng.standard_normal(1000))
    z[:100] = 0.5 * ref[:100]                                  # distractors in front
    ref2 = ref.copy()
    ref2[100:200] = 0                                          # nothing rendered there
    got = view_depth_scales([z, z, z[:10]], [ref, ref2, ref[:10]])
    assert got[0][0] == pytest.approx(1.04, rel=2e-3) and got[1][0] == pytest.approx(1.04, rel=2e-3)
    # spread: the log-normal noise's 0.005, not inflated by the 10 % in front
    assert 0.004 < got[0][1] < 0.0065
    assert got[2] == (1.0, 0.0)                                # too few pixels


def test_tolerant_reference_against_brute_force():
    rng = np.random.default_rng(2)
    depth = rng.uniform(1, 2, (9, 11))
    depth[3:5, 4:7] = 0
    depth[0, 0] = 0
    rgb = rng.uniform(0, 1, (9, 11, 3))
    rgb[6, 2] = np.nan
    r = 1
    (d,), (rlo,), (rhi,) = tolerant_reference([depth], [rgb], r)
    for y in range(9):
        for x in range(11):
            ys, xs = slice(max(y - r, 0), y + r + 1), slice(max(x - r, 0), x + r + 1)
            win = depth[ys, xs]
            assert d[y, x] == (win[win > 0].min() if (win > 0).any() else 0)
            if np.isnan(rgb[y, x]).any():
                assert np.isnan(rlo[y, x]).all() and np.isnan(rhi[y, x]).all()
            else:
                c = rgb[ys, xs].reshape(-1, 3)
                c = c[~np.isnan(c).any(1)]
                np.testing.assert_array_equal(rlo[y, x], c.min(0))
                np.testing.assert_array_equal(rhi[y, x], c.max(0))


def test_tolerant_reference_takes_its_own_depth_radius():
    rng = np.random.default_rng(5)
    depth = rng.uniform(1, 2, (8, 10))
    depth[2:4, 3:5] = 0
    rgb = rng.uniform(0, 1, (8, 10, 3))
    for r, rd in ((1, 2), (2, 0), (0, 1)):
        (d,), (lo,), (hi,) = tolerant_reference([depth], [rgb], r, depth_radius=rd)
        (d_ref,), _, _ = tolerant_reference([depth], [rgb], rd)
        _, (lo_ref,), (hi_ref,) = tolerant_reference([depth], [rgb], r)
        np.testing.assert_array_equal(d, d_ref)
        np.testing.assert_array_equal(lo, lo_ref)
        np.testing.assert_array_equal(hi, hi_ref)
    np.testing.assert_array_equal(tolerant_reference([depth], [rgb], 1, depth_radius=0)[0][0],
                                  depth)
    # one radius per view, for depth and colour apart
    two = tolerant_reference([depth, depth], [rgb, rgb], [0, 2], depth_radius=[1, 0])
    np.testing.assert_array_equal(two[0][1], depth)
    np.testing.assert_array_equal(two[0][0], tolerant_reference([depth], [rgb], 1)[0][0])
    np.testing.assert_array_equal(two[1][1], tolerant_reference([depth], [rgb], 2)[1][0])


def test_refinement_widens_the_colours_by_the_measured_radii_and_not_the_depths(monkeypatch):
    """Each pass's static reference: the colours within each view's measured misregistration
    (``explained.misregistration``), the depths as they are (a tolerant depth test drops small
    objects on sloping floors)."""
    from clearsplat.filter import explained, refine
    measured, calls = [], []
    real_misregistration, real_tolerant = explained.misregistration, explained.tolerant_reference

    def spy_misregistration(*args):
        measured.append(real_misregistration(*args))
        return measured[-1]

    def spy_tolerant(depths, rgbs, radius, *, depth_radius=None):
        out = real_tolerant(depths, rgbs, radius, depth_radius=depth_radius)
        calls.append((depths, rgbs, radius, depth_radius, out))
        return out
    monkeypatch.setattr(refine, "misregistration", spy_misregistration)
    monkeypatch.setattr(refine, "tolerant_reference", spy_tolerant)
    world = make_world("object", num_views=4, seed=1, height=96, width=160)
    scene, _ = realistic_reconstruction(world, "pose", seed=1)      # estimated poses
    filter_distractors(scene, config=FilterConfig(rounds=1), extractor=get_extractor("local"))
    assert len(calls) == refine.PASSES and len(measured) == scene.num_views
    assert any(r > 0 for r in measured)          # some view is out of register here
    for depths, rgbs, radius, depth_radius, (d, lo, hi) in calls:
        assert sorted(radius) == sorted(measured) and depth_radius == 0
        for v in range(scene.num_views):
            np.testing.assert_array_equal(d[v], depths[v])
            ref = tolerant_reference([depths[v]], [rgbs[v]], radius[v])
            np.testing.assert_array_equal(lo[v], ref[1][0])
            np.testing.assert_array_equal(hi[v], ref[2][0])


def test_a_depth_radius_keeps_a_static_edge_that_another_view_places_a_pixel_away():
    """Closed form: a near surface (depth 1) covers columns 0-9 of view 0 and only 0-8 of the
    other views' reference, which shows the far one (depth 2) from column 9 on. Column 9's
    Gaussians stand in front of the reference at their own pixel, not of the nearest surface
    it shows within one pixel; every other Gaussian is the same either way."""
    from clearsplat.synth import reconstruct
    h, w = 16, 20
    world = make_world("object", num_views=2, seed=0, height=h, width=w)
    cols = np.arange(w)[None, :] * np.ones((h, 1))
    own = np.where(cols < 10, 1.0, 2.0)
    ref = np.where(cols < 9, 1.0, 2.0)
    scene = reconstruct(world.cameras[:2], [np.full((h, w, 3), 0.5)] * 2, [own, own],
                        depth_blur=0.0, depth_noise=0.0)
    index = ViewIndex(scene)
    members = index.members[0]
    col = (scene.pixel_id[members] % w)
    rgb = np.full((h, w, 3), 0.5)
    for depth_radius, edge_in_front in ((0, True), (1, False)):
        near, _, _ = tolerant_reference([ref, ref], [rgb, rgb], 0, depth_radius=depth_radius)
        front = revealing_gaussians(scene, index, near, margin=0.02)[members]
        assert front[col == 9].all() == edge_in_front and not front[col != 9].any()


def test_depth_scale_alignment_against_a_slow_reference():
    """``align_scale``: each view's depths divided by their median ratio to the reference and
    its margin widened by the ratio's spread; a slow per-view reference of the same rule."""
    from clearsplat.filter.association import member_depths
    from clearsplat.filter.robust import _SPREAD_FACTOR
    world = make_world("object", num_views=3, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "depth", seed=0, clean=True)
    index = ViewIndex(scene)
    ref = [np.asarray(d, np.float64) for d in world.clean_depths]
    near, _, _ = tolerant_reference(ref, ref, 0, depth_radius=1)
    margins = [None] * scene.num_views      # each view's margin, as the test used it
    got = revealing_gaussians(scene, index, near, margin=0.02, align_scale=True,
                              margins=margins)
    depths, pixels = member_depths(scene, index)
    for v, members in enumerate(index.members):
        z, pix = depths[v], pixels[v]
        behind = near[v].ravel()[pix]
        scale, spread = view_depth_scales([z], [behind])[0]
        margin = max(0.02, 1.0 - np.exp(-_SPREAD_FACTOR * spread))
        expected = (behind > 0) & (z / scale < (1.0 - margin) * behind)
        np.testing.assert_array_equal(got[members], expected)
        assert margins[v] == margin
    assert max(margins) > 0.02                   # the depth scenario widens some
    fixed = [None] * scene.num_views
    revealing_gaussians(scene, index, near, margin=0.02, margins=fixed)
    assert fixed == [0.02] * scene.num_views     # without align_scale: the margin itself


def test_relative_score_is_the_share_of_the_error_removed():
    # One pixel: error 0.6 before, 0.15 after -> 75 % of it removed.
    base = np.array([[0.6, 0.0, 0.0]], np.float32)
    after = np.array([[0.15, 0.0, 0.0]], np.float32)
    img = np.zeros((1, 3), np.float32)
    p = change_weighted_terms(base, after, img, np.zeros(1, bool), 0.002)
    assert p.relative_score == pytest.approx(0.75, rel=1e-6)
    total = Partial()
    total.add(p)
    total.add(Partial(0.0, 1.0, 0.45))
    # w = 0.45: num 0.45 * 0.45, err 0.45 * 0.6 (+ 0.45 from the second part)
    assert total.relative_score == pytest.approx(0.2025 / 0.72, rel=1e-6)
    assert Partial().relative_score == 0.0


def test_median_pool_neither_carried_nor_vetoed_by_one_view():
    from clearsplat.filter.verify import median_relative_score, passes
    # Three verification views: two where the removal explains most of the error it touches
    # (shares 0.62 and 0.46), one heavy view where it trades one large error for another
    # (share -0.04 with most of the weight), and one view it does not change.
    views = [Partial(0.291 * 62, 62, 0.291 * 62 / 0.62),
             Partial(-0.029 * 142, 142, 0.029 * 142 / 0.04),
             Partial(0.115 * 8, 8, 0.115 * 8 / 0.46), Partial()]
    total = Partial()
    for p in views:
        total.add(p)
    assert total.score > 0 and total.relative_score < 0.2          # vetoed when pooled
    assert median_relative_score(views) == pytest.approx(0.46)     # the middle of 3 views
    median = FilterConfig()              # the individual test's terms: the median of the views
    assert not passes(total, median) and passes(total, median, views)
    # One view alone carrying a candidate that the others find no better: pooled it passes,
    # the median of the views' shares does not.
    carried = [Partial(30.0, 40.0, 40.0), Partial(0.1, 10.0, 20.0), Partial(0.05, 10.0, 20.0)]
    total = Partial()
    for p in carried:
        total.add(p)
    assert passes(total, median) and not passes(total, median, carried)
    # The score condition stays pooled; without min_relative_score the pool does not matter.
    assert not passes(Partial(-1.0, 2.0, 2.0), median, [Partial(3.0, 1.0, 3.0)] * 2)
    loose = FilterConfig(min_relative_score=0.0)
    assert passes(total, loose, [Partial(-1.0, 1.0, 1.0)] * 3)
    assert median_relative_score([]) == 0.0 and median_relative_score([Partial()]) == 0.0
    # Views where the removal changes a few pixels (under a twentieth of the weight of the view
    # it changes most) have shares that say nothing: they do not vote. A median outvotes one
    # view only among three: with fewer voters the share pooled over every view decides.
    heavy = Partial(0.7 * 30.0, 30.0, 30.0)                  # share 0.7 on most of the weight
    faint = [Partial(0.05 * 1.4, 1.4, 1.4), Partial(0.0, 0.3, 0.3)]   # shares 0.05 and 0
    pooled = (0.7 * 30.0 + 0.05 * 1.4) / (30.0 + 1.4 + 0.3)
    assert median_relative_score([heavy] + faint) == pytest.approx(pooled)
    total = Partial()
    for p in [heavy] + faint:
        total.add(p)
    assert passes(total, median, [heavy] + faint)
    # The caller's pooled terms (the same sum, in the same order) give the same share.
    assert median_relative_score([heavy] + faint, pooled=total) == \
        median_relative_score([heavy] + faint)
    # Two voters, one against (share -0.5 on a third of the weight): pooled, not their mean.
    against = Partial(-0.5 * 15.0, 15.0, 15.0)
    assert median_relative_score([heavy, against]) == pytest.approx((21.0 - 7.5) / 45.0)
    # At a twentieth of the heaviest weight a view votes: the median of 0.7, 0.05 and -0.5.
    counted = Partial(0.05 * 1.5, 1.5, 1.5)
    assert median_relative_score([heavy, counted, against]) == pytest.approx(0.05)


def test_depth_scale_alignment_undoes_a_view_scale_bias():
    world = make_world("object", num_views=3, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "plain", seed=0, clean=True)
    # Reference: the true depths; view 0 predicted 6 % too near (all of it "in front").
    means = scene.gaussians.means.copy()
    v0 = scene.view_id == 0
    cam = scene.cameras[0]
    means[v0] = cam.position + (means[v0] - cam.position) * 0.94
    scene.gaussians.means = means
    index = ViewIndex(scene)    # the Gaussians' depths in their cameras, read once
    ref = [np.asarray(d, np.float64) for d in world.clean_depths]
    plain = revealing_gaussians(scene, index, ref, margin=0.02)
    aligned = revealing_gaussians(scene, index, ref, margin=0.02, align_scale=True)
    assert plain[v0].mean() > 0.9
    # after alignment view 0 looks like the unbiased views (depth-edge Gaussians only)
    assert aligned[~v0].mean() < 0.1 and aligned[v0].mean() < aligned[~v0].mean() + 0.03


def test_options_are_validated_and_off_in_the_paper_presets():
    for name in ("paper", "paper-local"):
        cfg = FilterConfig.preset(name)
        assert cfg.refine == "none" and cfg.min_relative_score == 0.0 and cfg.rounds == 1
    for field, bad in (("min_relative_score", 1.0), ("min_relative_score", -0.1),
                       ("rounds", 0), ("rounds", 2.5), ("refine", "static")):
        with pytest.raises(ClearsplatError) as e:
            FilterConfig(**{field: bad})
        assert e.value.field == field


@pytest.fixture(scope="module")
def soft_scene():
    world = make_world("street", num_views=3, seed=1, height=48, width=80)
    return realistic_reconstruction(world, "all", seed=1)


def test_options_off_give_the_filter_without_them(soft_scene):
    scene, _ = soft_scene
    ex = get_extractor("local")
    off = dict(min_relative_score=0.0, rounds=1)
    a = filter_distractors(scene, config=FilterConfig.preset("paper-local"), extractor=ex)
    b = filter_distractors(scene, config=FilterConfig.preset("paper-local", **NEW).replace(**off),
                           extractor=ex)
    np.testing.assert_array_equal(a.keep, b.keep)
    assert [c.scores for c in a.candidates] == [c.scores for c in b.candidates]


@pytest.mark.slow
@pytest.mark.parametrize("option", sorted(NEW))
def test_each_option_runs_and_changes_only_through_its_stage(soft_scene, option):
    scene, _ = soft_scene
    ex = get_extractor("local")
    base = filter_distractors(scene, config=FilterConfig(min_relative_score=0.0, rounds=1),
                              extractor=ex)
    res = filter_distractors(scene, config=base.config.replace(**{option: NEW[option]}),
                             extractor=ex)
    assert res.keep.shape == base.keep.shape
    if option == "min_relative_score":
        # Stricter acceptance only: never removes anything the filter without it keeps...
        # (the joint test pools other candidates, so compare accepted sets of range 1).
        acc = {c.index for c in res.candidates if c.accepted and c.range == 1}
        acc0 = {c.index for c in base.candidates if c.accepted and c.range == 1}
        assert acc <= acc0
        # ... and the same proposals and individual scores.
        assert [c.scores.get("individual") for c in res.candidates] == \
            [c.scores.get("individual") for c in base.candidates]


def test_verification_mask_modes(soft_scene, monkeypatch):
    """``"revealing"`` leaves out exactly the verifying view's unreliable pixels; with
    refinement verification takes ``"revealing"`` from eight views on and
    ``"proposals+revealing"`` below, without it the proposal regions (the paper)."""
    from clearsplat.filter import verify
    from clearsplat.filter.verify import exclusion_masks as _exclusion_masks
    scene, _ = soft_scene
    ex = get_extractor("local")
    below = filter_distractors(scene, extractor=ex)
    monkeypatch.setattr(verify, "_REVEALING_MASK_MIN_VIEWS", 1)
    revealing = filter_distractors(scene, extractor=ex)
    props = revealing.proposals
    for rng in (1, 2):
        for p, q in zip(props, _exclusion_masks(props, rng, "revealing")):
            np.testing.assert_array_equal(q, p.unreliable)
        for p, q in zip(props, _exclusion_masks(props, rng, "proposals+revealing")):
            m = p.mask1 if rng == 1 else p.mask1 | p.mask2
            np.testing.assert_array_equal(q, m | p.unreliable)
    assert scene.num_views == 3
    # the masks differ, and with them some score
    assert [c.scores for c in revealing.candidates] != [c.scores for c in below.candidates]
    # with fewer views than the constant, the proposal regions stay out as well
    seen = []
    masks = verify.exclusion_masks
    monkeypatch.setattr(verify, "exclusion_masks",
                        lambda proposals, rng, mode: seen.append(mode) or masks(proposals,
                                                                                rng, mode))
    monkeypatch.setattr(verify, "_REVEALING_MASK_MIN_VIEWS", 8)
    again = filter_distractors(scene, extractor=ex)
    assert set(seen) == {"proposals+revealing"}
    assert [c.scores for c in again.candidates] == [c.scores for c in below.candidates]
    seen.clear()
    filter_distractors(scene, config=FilterConfig(refine="none"), extractor=ex)
    assert set(seen) == {"proposals"}


def test_config_specs_read_values_with_a_plus():
    from clearsplat.bench import parse_config
    cfg = parse_config("default+checkpoint=dino+v3+rounds=1")
    assert cfg.checkpoint == "dino+v3" and cfg.rounds == 1
    assert parse_config("paper-local") == FilterConfig.preset("paper-local")
    with pytest.raises(ClearsplatError):
        parse_config("default+revealing")


def _grow_connected(pixels, front, proposal, tau2):
    """What the expansion adds to a candidate's pixels: every group of ``front`` it touches."""
    from clearsplat.filter.expansion import growth_labels
    from clearsplat.filter.masks import touched_components
    return pixels | touched_components(growth_labels(front, proposal.similarity, tau2), pixels)


def test_grow_connected_adds_the_touched_in_front_groups_of_low_similarity():
    from types import SimpleNamespace
    from clearsplat import Camera, Gaussians, Scene
    h, w = 8, 8
    n = h * w
    cam = Camera(np.array([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]]), np.eye(4), w, h)
    g = Gaussians(means=np.zeros((n, 3), np.float32), scales=np.full((n, 3), 0.01, np.float32),
                  quats=np.tile(np.float32([1, 0, 0, 0]), (n, 1)),
                  opacities=np.full(n, 0.9, np.float32), sh=np.zeros((n, 1, 3), np.float32))
    scene = Scene(g, view_id=np.zeros(n, np.int32), pixel_id=np.arange(n), cameras=[cam],
                  images=[np.zeros((h, w, 3), np.float32)])
    index = ViewIndex(scene)
    front = np.zeros((h, w), bool)
    front[1:3, 1:6] = True          # a group touching the region
    front[6:8, 6:8] = True          # a group apart
    similarity = np.zeros((2, 2), np.float32)
    similarity[0, 1] = 0.9          # the top right cell is similar: no growth there
    proposal = SimpleNamespace(similarity=similarity)
    region = np.zeros((h, w), bool)
    region[2, 1] = True
    front_px = index.pixels_of(0, front.ravel())
    np.testing.assert_array_equal(front_px, front)     # pixel-aligned: Gaussian k at pixel k
    out = _grow_connected(region, front_px, proposal, 0.69)
    expected = region.copy()
    expected[1:3, 1:4] = True       # the touched group, cut at the similar cell
    np.testing.assert_array_equal(out, expected)
    # a region touching nothing in front stays as it is
    lone = np.zeros((h, w), bool)
    lone[5, 0] = True
    np.testing.assert_array_equal(_grow_connected(lone, front_px, proposal, 0.69), lone)


def test_expand_connected_only_adds_to_the_expansion(soft_scene, monkeypatch):
    from clearsplat.filter import expansion
    scene, _ = soft_scene
    ex = get_extractor("local")
    on = filter_distractors(scene, extractor=ex)
    monkeypatch.setattr(expansion, "touched_components",
                        lambda labels, pixels: np.zeros_like(pixels))
    off = filter_distractors(scene, extractor=ex)
    assert [c.scores.get("individual") for c in on.candidates] == \
        [c.scores.get("individual") for c in off.candidates]
    for a, b in zip(on.candidates, off.candidates):
        if b.expanded is not None:
            assert set(b.expanded) <= set(a.expanded)
    assert any(c.expanded is not None for c in off.candidates)


def test_revealing_by_depth_is_the_test_without_colours():
    """``by_depth=True`` also returns the Gaussians the depth test alone keeps: the same as
    the test without ``color_threshold``, within the full test's."""
    world = make_world("object", num_views=3, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "all", seed=0)
    index = ViewIndex(scene)
    ref = [np.asarray(d, np.float64) for d in world.clean_depths]
    rgb = [np.asarray(im, np.float64) for im in world.clean_images]
    near, lo, hi = tolerant_reference(ref, rgb, 1)
    kw = dict(margin=0.02, reference_rgbs=lo, reference_rgbs_hi=hi, color_threshold=0.3,
              align_scale=True)
    full, depth = revealing_gaussians(scene, index, near, by_depth=True, **kw)
    np.testing.assert_array_equal(full, revealing_gaussians(scene, index, near, **kw))
    np.testing.assert_array_equal(
        depth, revealing_gaussians(scene, index, near, **{**kw, "color_threshold": None}))
    assert not (depth & ~full).any() and (full & ~depth).any() and depth.any()


def test_expansion_colour_bound_lies_between_depth_only_and_every_colour(soft_scene,
                                                                       monkeypatch):
    """The expansion's colour reach (``explained.ColorNoise.beyond`` at ``explained.BEYOND``)
    decides every candidate's individual test as before and expands each to a set between the
    depth-only expansion (no Gaussian taken for its colour alone) and the one without a bound
    (every Gaussian kept for its colour alone is beyond), which holds the candidate's own
    Gaussians."""
    from clearsplat.filter import explained
    scene, _ = soft_scene
    ex = get_extractor("local")
    cfg = FilterConfig(rounds=1, verify_hidden=None)
    bounded = filter_distractors(scene, config=cfg, extractor=ex)
    assert explained.BEYOND == 0.99
    monkeypatch.setattr(explained.ColorNoise, "beyond",
                        lambda self, selected, quantile=None: selected.copy())
    every = filter_distractors(scene, config=cfg, extractor=ex)
    monkeypatch.setattr(explained.ColorNoise, "beyond",
                        lambda self, selected, quantile=None:
                        np.zeros(self.distances.shape, dtype=bool))
    runs = [filter_distractors(scene, config=cfg, extractor=ex), bounded, every]
    scores = [[c.scores.get("individual") for c in r.candidates] for r in runs]
    assert scores[0] == scores[1] == scores[2]
    below = above = 0
    for depth, bounded, every in zip(*(r.candidates for r in runs)):
        if bounded.expanded is None:
            continue
        assert set(depth.gaussians) <= set(depth.expanded) <= set(bounded.expanded) \
            <= set(every.expanded)
        below += len(every.expanded) - len(bounded.expanded)
        above += len(bounded.expanded) - len(depth.expanded)
    assert below > 0 and above > 0


def test_color_noise_beyond_matches_the_definition():
    from clearsplat.filter import explained
    from clearsplat.filter.explained import ColorNoise
    rng = np.random.default_rng(7)
    n = 600
    distances = rng.uniform(0, 1, n).astype(np.float32)
    distances[rng.uniform(size=n) < 0.1] = np.nan
    selected = rng.uniform(size=n) < 0.5
    unproposed = rng.uniform(size=n) < 0.6
    members = [np.flatnonzero(np.arange(n) % 3 == v) for v in range(3)]
    members.append(np.array([], dtype=np.int64))
    unproposed[members[2]] = False      # a view without static Gaussians: nothing beyond
    raw = [np.flatnonzero(~unproposed)[k::2] for k in range(2)]    # what the proposals cover
    noise = ColorNoise(distances, raw, members)
    static = unproposed & np.isfinite(distances)
    np.testing.assert_array_equal(noise.static, static)
    # Without a quantile: explained.BEYOND.
    np.testing.assert_array_equal(noise.beyond(selected),
                                  noise.beyond(selected, explained.BEYOND))
    for q in (0.0, 0.5, 0.99, 1.0):
        got = noise.beyond(selected, q)
        want = np.zeros(n, dtype=bool)
        for v, m in enumerate(members):
            ref = [float(distances[i]) for i in m if static[i]]
            if not ref:
                assert noise.bounds(q)[v] is None
                continue
            bound = float(np.quantile(np.array(ref), q))
            # The noise's bound: that quantile, taken in the distances' own precision.
            assert noise.bounds(q)[v] == float(np.quantile(np.array(ref, distances.dtype), q))
            for i in m:
                want[i] = bool(selected[i]) and float(distances[i]) > bound
        np.testing.assert_array_equal(got, want)
        assert not got[members[2]].any()
        if q == 1.0:    # closed form: beyond the largest static distance of the view
            for m in members[:2]:
                top = np.nanmax(np.where(static[m], distances[m], np.nan))
                np.testing.assert_array_equal(got[m], selected[m] & (distances[m] > top))


def test_a_depth_test_without_tolerance_keeps_a_superset():
    """Where the reference has no holes the nearest surface within the radius is never farther
    than the one at the pixel, so judging depth at the pixel (as the refinement does) keeps
    every Gaussian the tolerant depth test keeps, and more."""
    world = make_world("object", num_views=3, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "depth", seed=0, clean=True)
    index = ViewIndex(scene)
    ref = [np.asarray(d, np.float64) for d in world.clean_depths]
    assert all((d > 0).all() for d in ref)
    rgb = [np.asarray(im, np.float64) for im in world.clean_images]
    near, lo, hi = tolerant_reference(ref, rgb, 3)
    kw = dict(margin=0.02, reference_rgbs=lo, reference_rgbs_hi=hi, color_threshold=0.5)
    tol = revealing_gaussians(scene, index, near, **kw)
    own = revealing_gaussians(scene, index, ref, **kw)
    assert not (tol & ~own).any() and (own & ~tol).sum() > 0


def _two_runs(scene, one, ex):
    """The filter ``one`` (one round) run on ``scene``, then on what it kept: ``(first, kept,
    second, expect)``, ``expect`` the keep mask two rounds must give."""
    first = filter_distractors(scene, config=one, extractor=ex)
    kept = np.flatnonzero(first.keep)
    second = filter_distractors(scene.subset(kept), config=one, extractor=ex)
    expect = first.keep.copy()
    expect[kept[~second.keep]] = False
    return first, kept, second, expect


def _two_rounds_are_two_runs(scene, one, ex):
    """``one.replace(rounds=2)`` on ``scene`` against :func:`_two_runs` (with the pixels of
    what the rounds before removed verified as any other, which only a later round can leave
    out): the same keep mask,
    and the second round's candidates those of the second run, with their scores and reasons.
    Returns ``(first, second, both)``."""
    first, _, second, expect = _two_runs(scene, one, ex)
    both = filter_distractors(scene, config=one.replace(rounds=2), extractor=ex)
    np.testing.assert_array_equal(both.keep, expect)
    later = both.candidates[len(first.candidates):]
    assert all(c.round == 2 for c in later) and len(later) == len(second.candidates)
    for got, want in zip(later, second.candidates):
        assert got.scores == want.scores and got.reason == want.reason
    return first, second, both


def test_rounds_run_the_procedure_again_on_the_gaussians_kept(soft_scene, no_explained,
                                                              verify_removed_pixels):
    """``rounds=2`` is the filter run once, then run again on the scene without what it
    removed, the second run's removals and candidates mapped back to the whole scene."""
    scene, _ = soft_scene
    ex = get_extractor("local")
    # Without min_relative_score and the colour-explained verdict the first round leaves
    # something for the
    # second on this small scene. A later round also leaves out what the first removed from
    # verification, which a second run cannot know: not here (verify_removed_pixels).
    one = FilterConfig(rounds=1, min_relative_score=0.0)
    first, kept, second, expect = _two_runs(scene, one, ex)
    assert not second.keep.all(), "the scene should have something for a second round to find"
    stages = []
    res = filter_distractors(scene, config=one.replace(rounds=2), extractor=ex,
                             progress=lambda stage, done, total: stages.append(stage))
    assert "render" in stages and "render (round 2)" in stages
    np.testing.assert_array_equal(res.keep, expect)
    assert len(res.candidates) == len(first.candidates) + len(second.candidates)
    assert [c.index for c in res.candidates] == list(range(len(res.candidates)))
    later = res.candidates[len(first.candidates):]
    assert {c.round for c in res.candidates[:len(first.candidates)]} == {1}
    assert {c.round for c in later} == {2}
    for c, c2 in zip(later, second.candidates):
        np.testing.assert_array_equal(c.gaussians, kept[c2.gaussians])
        assert first.keep[c.gaussians].all()        # never one the first round removed
        if c.accepted:
            assert not res.keep[c.expanded].any()
    assert res.stats["views_prepared"] == 2 * scene.num_views
    # The second round took every view from the first (all within the view budget).
    assert res.stats["views_derived"] == scene.num_views
    assert res.timings["total"] == pytest.approx(res.timings["proposal"]
                                                 + res.timings["verification"])
    assert res.summary()["candidates"][-1]["round"] == 2
    # The filter never reads per-Gaussian extras (a later round leaves them out of its copy):
    # a scene that carries some gives the same rounds.
    g = scene.gaussians
    extras = {"normals": np.random.default_rng(0).normal(size=(len(g), 3)).astype(np.float32),
              "feature": np.arange(len(g), dtype=np.float64)}
    rich = dataclasses.replace(scene, gaussians=dataclasses.replace(g, extra=extras))
    again = filter_distractors(rich, config=one.replace(rounds=2), extractor=ex)
    np.testing.assert_array_equal(again.keep, res.keep)
    assert [c.record() for c in again.candidates] == [c.record() for c in res.candidates]


@pytest.fixture
def round_calls(monkeypatch):
    """The Gaussians each round of the filter removes, one entry per round run."""
    import clearsplat.filter.pipeline as pipeline
    calls = []
    run = pipeline.run_round

    def counted(sc, *args, **kwargs):
        out = run(sc, *args, **kwargs)
        calls.append(int((~out[0].keep).sum()))
        return out

    monkeypatch.setattr(pipeline, "run_round", counted)
    return calls


def test_rounds_stop_when_a_round_removes_nothing(soft_scene, round_calls):
    calls = round_calls
    scene, _ = soft_scene
    ex = get_extractor("local")
    res = filter_distractors(scene, config=FilterConfig(rounds=6), extractor=ex)
    assert 2 <= len(calls) <= 6
    assert calls[-1] == 0 or len(calls) == 6
    assert all(k > 0 for k in calls[:-1])
    assert int((~res.keep).sum()) == sum(calls)
    # A clean scene where the first round removes nothing: no second round.
    clean, _ = realistic_reconstruction(make_world("street", num_views=3, seed=2, height=48,
                                                   width=80), "plain", seed=2, clean=True)
    calls.clear()
    res = filter_distractors(clean, config=FilterConfig(rounds=6), extractor=ex)
    assert calls == [0] and res.keep.all()


def test_rounds_auto_runs_a_second_round_from_sixteen_views(round_calls):
    import clearsplat.filter.pipeline as pipeline
    calls = round_calls
    ex = get_extractor("local")
    for views, expect in ((pipeline._SECOND_ROUND_MIN_VIEWS - 1, 1),
                          (pipeline._SECOND_ROUND_MIN_VIEWS, 2)):
        world = make_world("object", num_views=views, seed=0, height=32, width=56)
        scene, _ = realistic_reconstruction(world, "plain", seed=0)
        calls.clear()
        filter_distractors(scene, config=FilterConfig(), extractor=ex)
        assert calls[0] > 0                         # the first round removes something
        assert len(calls) == expect
    assert FilterConfig().rounds == "auto" and FilterConfig(rounds="auto").rounds == "auto"


@pytest.mark.parametrize("seed", range(6))
def test_box_extreme_matches_scipy(seed):
    from scipy import ndimage
    from clearsplat.filter.explained import box_extreme
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 30, size=2)
    a = rng.normal(size=(h, w, 3)).astype(np.float32 if seed % 2 else np.float64)
    a[rng.random((h, w, 3)) < 0.1] = np.inf
    for r in (0, 1, 3, 7):
        size = (2 * r + 1, 2 * r + 1, 1)
        for op, want in ((np.minimum, ndimage.minimum_filter), (np.maximum, ndimage.maximum_filter)):
            got = box_extreme(a, r, op)
            assert got.dtype == a.dtype
            np.testing.assert_array_equal(got, want(a, size=size, mode="nearest"))
        np.testing.assert_array_equal(box_extreme(a[..., 0], r, np.minimum),
                                      ndimage.minimum_filter(a[..., 0], size=2 * r + 1,
                                                             mode="nearest"))


def test_three_rounds_equal_three_runs_on_what_each_kept(soft_scene, no_explained):
    """Each round takes its views and renders from the round before (restricted, not prepared
    again): the same as running the filter afresh on what the rounds before kept."""
    scene, _ = soft_scene
    ex = get_extractor("local")
    # Three rounds find something on this small scene without these two.
    one = FilterConfig(rounds=1, min_relative_score=0.0)
    kept = np.arange(len(scene))
    runs = 0
    for _ in range(3):
        r = filter_distractors(scene.subset(kept), config=one, extractor=ex)
        runs += 1
        if r.keep.all():
            break
        kept = kept[r.keep]
    assert runs == 3, "the scene should give three rounds something to find"
    res = filter_distractors(scene, config=one.replace(rounds=3), extractor=ex)
    expect = np.zeros(len(scene), bool)
    expect[kept] = True
    np.testing.assert_array_equal(res.keep, expect)
    assert {c.round for c in res.candidates} == {1, 2, 3}
    assert res.stats["views_derived"] == 2 * scene.num_views


def test_second_round_memory_check_counts_what_the_first_hands_on(soft_scene, monkeypatch):
    """The views and renders round 1 hands on become round 2's (or are dropped) as it goes:
    the check before round 2 counts them as available instead of needing them twice."""
    import clearsplat.filter.backend as backend
    scene, _ = soft_scene
    calls = []
    monkeypatch.setattr(backend, "check_memory",
                        lambda estimate, available=None: calls.append((estimate, available)))
    monkeypatch.setattr(backend, "available_memory", lambda: 10**6)
    res = filter_distractors(scene, config=FilterConfig(rounds=2),
                             extractor=get_extractor("local"))
    assert max(c.round for c in res.candidates) == 2
    (_, first), (_, second) = calls
    assert first is None                # round 1: the check reads the system itself
    held = res.stats["views_peak_bytes"]
    assert 10**6 < second and second - 10**6 >= 0.5 * held   # round 1's views, at least


def test_later_round_renders_on_images_not_a_multiple_of_the_tile(verify_removed_pixels):
    """The second round re-composites only the tiles the removals touched and takes the rest
    from the first round's renders; on a 50x71 image the last tiles are partial."""
    world = make_world("street", num_views=3, seed=1, height=50, width=71)
    scene, _ = realistic_reconstruction(world, "all", seed=1)
    ex = get_extractor("local")
    # Without min_relative_score the first round leaves something for the second on this
    # small scene.
    one = FilterConfig(rounds=1, min_relative_score=0.0)
    _, second, res = _two_rounds_are_two_runs(scene, one, ex)
    assert res.stats["views_derived"] == scene.num_views
    assert len(second.candidates) > 0


def test_rounds_with_color_explained_are_runs_on_what_each_kept(verify_removed_pixels,
                                                                monkeypatch):
    """The colour-explained verdict acts within each round, on that round's Gaussians."""
    from clearsplat.filter import explained
    # The verdict alone at a wider quantile than the default's (the silhouettes at
    # explained.EXPLAINED): the candidates reject_explained reads.
    verdict = explained.explained_candidates
    monkeypatch.setattr(explained, "explained_candidates",
                        lambda candidates, noise, **k: verdict(candidates, noise, quantile=0.9))
    world = make_world("street", num_views=8, seed=0, height=64, width=112)
    scene, _ = realistic_reconstruction(world, "pose", seed=0)
    ex = get_extractor("local")
    one = FilterConfig(rounds=1)
    first, second, _ = _two_rounds_are_two_runs(scene, one, ex)
    assert any(c.reason.startswith("explained") for c in first.candidates + second.candidates)


@pytest.mark.parametrize("seed", [0, 1])
def test_widened_band_qualifies_by_colour_within_the_views_depth_noise(seed):
    """``band_bounds`` (the refinement's: its colour noise at ``explained.BEYOND``): where the
    view's depth noise widens its margin, a Gaussian in front by more than ``margin`` but within
    the widened margin qualifies when its colour distance exceeds its view's bound; a slow
    per-view reference of the rule.
    Without a widened margin, or without a bound, nothing changes."""
    from clearsplat.filter.association import member_depths
    from clearsplat.filter.robust import _SPREAD_FACTOR
    world = make_world("object", num_views=3, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "depth", seed=seed, clean=True)
    index = ViewIndex(scene)
    ref = [np.asarray(d, np.float64) for d in world.clean_depths]
    rng = np.random.default_rng(seed)
    distance = rng.uniform(0, 1, len(scene)).astype(np.float32)
    distance[rng.random(len(scene)) < 0.1] = np.nan
    bounds = [0.5, None, 0.8]
    margins = [None] * scene.num_views
    kw = dict(margin=0.02, align_scale=True, color_distance=distance)
    got = revealing_gaussians(scene, index, ref, margins=margins, band_bounds=bounds, **kw)
    plain = revealing_gaussians(scene, index, ref, **kw)
    depths, pixels = member_depths(scene, index)
    for v, members in enumerate(index.members):
        z, pix = depths[v], pixels[v]
        scale, spread = view_depth_scales([z], [ref[v].ravel()[pix]])[0]
        margin = max(0.02, 1.0 - np.exp(-_SPREAD_FACTOR * spread))
        assert margins[v] == margin
        behind = ref[v].ravel()[pix]
        ratio = z / scale / behind
        expected = ratio < 1.0 - margin
        if bounds[v] is not None and margin > 0.02:
            d = distance[members]
            band = (ratio >= 1.0 - margin) & (ratio < 0.98)
            expected = expected | (band & ~np.isnan(d) & (np.nan_to_num(d) > bounds[v]))
        np.testing.assert_array_equal(got[members], expected)
        np.testing.assert_array_equal(plain[members], ratio < 1.0 - margin)
    assert max(margins) > 0.02 and (got & ~plain).any()       # the rule takes some
    assert not (plain & ~got).any()
    # Without align_scale the margin is never widened: the bounds change nothing.
    np.testing.assert_array_equal(
        revealing_gaussians(scene, index, ref, margin=0.02, color_distance=distance,
                            band_bounds=bounds),
        revealing_gaussians(scene, index, ref, margin=0.02, color_distance=distance))


def test_widened_band_color_finds_what_depth_noise_hides(monkeypatch):
    """The object world at 8 views with every artifact: within the views' widened margins
    lies part of a distractor that only its colour tells from the surface behind."""
    from clearsplat.features import get_extractor
    from clearsplat.filter import filter_distractors
    world = make_world("object", num_views=8, seed=0, height=128, width=224)
    scene, truth = realistic_reconstruction(world, "all", seed=0)
    extractor = get_extractor("local")
    from clearsplat.filter import refine
    on = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    # Without the band test: the refinement's revealing_gaussians without band_bounds.
    real = refine.revealing_gaussians
    monkeypatch.setattr(refine, "revealing_gaussians",
                        lambda *args, **kwargs: real(*args, **{**kwargs, "band_bounds": None}))
    off = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    recall = [(~r.keep & truth).sum() / truth.sum() for r in (off, on)]
    static = [(~r.keep & ~truth).sum() / (~truth).sum() for r in (off, on)]
    assert recall[1] > recall[0] + 0.03
    assert static[1] < static[0] + 0.001
