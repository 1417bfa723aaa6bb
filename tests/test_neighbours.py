"""Bounded neighbourhoods (``FilterConfig.neighbours``): which views each camera's renders
hold, that they hold exactly those, and that the filter is the exact one while every view is a
neighbour."""

import numpy as np
import pytest

from clearsplat.errors import ClearsplatError
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.neighbours import covisibility, view_plan


def neighbourhoods(scene, k, verify):
    """The views each camera holds with ``neighbours=k`` and the paper's verification views."""
    plan = view_plan(scene, neighbours=k, verify_views="centres", num_verify_views=verify)
    return None if plan is None else plan.hoods
from clearsplat.render import prepare, render
from clearsplat.synth.realism import realistic_reconstruction
from clearsplat.synth.worlds import make_world


@pytest.fixture(scope="module")
def street():
    world = make_world("street", num_views=8, seed=3, height=48, width=80)
    scene, truth = realistic_reconstruction(world, "plain", seed=3)
    return scene, truth


def _covisibility_by_loop(scene, samples):
    """Slow reference: every sampled centre of every view projected into every camera, one
    point at a time, through the camera's own pinhole model."""
    v_count = scene.num_views
    out = np.zeros((v_count, v_count))
    for v in range(v_count):
        members = np.flatnonzero(scene.view_id == v)
        if members.size == 0:
            continue
        pick = members[np.linspace(0, members.size - 1,
                                   min(samples, members.size)).astype(int)]
        for j, cam in enumerate(scene.cameras):
            hits = 0
            for g in pick:
                p = np.append(scene.gaussians.means[g].astype(np.float64), 1.0)
                x, y, z = (cam.world_to_camera @ p)[:3]
                if z <= 0:
                    continue
                u = cam.fx * x / z + cam.cx
                w = cam.fy * y / z + cam.cy
                hits += (0 <= u < cam.width) and (0 <= w < cam.height)
            out[j, v] = hits / pick.size
    return out


def test_covisibility_matches_a_loop_over_points(street):
    scene, _ = street
    np.testing.assert_allclose(covisibility(scene, samples=40), _covisibility_by_loop(scene, 40),
                               atol=1e-12)
    # A view without Gaussians: its column is 0, the others are as before.
    rest = scene.subset(np.flatnonzero(scene.view_id != 1))
    c = covisibility(rest, samples=40)
    assert not c[:, 1].any() and c[:, 0].any()
    np.testing.assert_allclose(c, _covisibility_by_loop(rest, 40), atol=1e-12)


def test_neighbourhoods_hold_the_most_covisible_views_and_the_verifiers(street):
    scene, _ = street
    v_count = scene.num_views
    c = covisibility(scene)
    shared = c + c.T
    for k in (1, 3, 5):
        hoods = neighbourhoods(scene, k, 3)
        assert len(hoods) == v_count
        for j, hood in enumerate(hoods):
            assert hood[j]
            # the k others sharing the most with j (ties to the lower index) are in
            ranked = sorted((-shared[j, i], i) for i in range(v_count) if i != j)
            for _, i in ranked[:k]:
                assert hood[i]
        for v in range(v_count):    # the three views seeing most of v hold v
            ranked = sorted((-c[j, v], j) for j in range(v_count) if j != v)
            for _, j in ranked[:3]:
                assert hoods[j][v]
        # nothing else: each camera holds itself, k neighbours and the views it verifies
        for j, hood in enumerate(hoods):
            verified = {v for v in range(v_count) if v != j and j in
                        [i for _, i in sorted((-c[i, v], i) for i in range(v_count)
                                              if i != v)[:3]]}
            near = {i for _, i in sorted((-shared[j, i], i) for i in range(v_count)
                                        if i != j)[:k]}
            assert set(np.flatnonzero(hood)) == {j} | near | verified
    assert neighbourhoods(scene, v_count - 1, 3) is None
    assert neighbourhoods(scene, None, 3) is None


def test_a_view_prepared_on_a_subset_renders_that_subset(street):
    scene, _ = street
    rng = np.random.default_rng(0)
    keep = rng.random(len(scene)) < 0.4
    cam = scene.cameras[2]
    view = prepare(scene, cam, keep=keep)
    want = render(scene, cam, keep=keep)
    got = view.render()
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    more = keep & (rng.random(len(scene)) < 0.5)     # a keep mask within the subset
    for a, b in zip(view.render(keep=more), render(scene, cam, keep=more)):
        np.testing.assert_array_equal(a, b)
    assert view.num_visible <= keep.sum()


def test_every_view_a_neighbour_is_the_exact_filter(street):
    scene, _ = street
    ex = get_extractor("local")
    exact = filter_distractors(scene, config=FilterConfig(), extractor=ex)
    same = filter_distractors(scene, config=FilterConfig(neighbours=scene.num_views - 1),
                              extractor=ex)
    np.testing.assert_array_equal(same.keep, exact.keep)
    assert [c.record() for c in same.candidates] == [c.record() for c in exact.candidates]


def test_bounded_neighbourhoods_run_and_change_only_what_the_renders_hold(street):
    scene, truth = street
    ex = get_extractor("local")
    res = filter_distractors(scene, config=FilterConfig(neighbours=3, verify_views="centres"),
                             extractor=ex)
    assert res.removed[truth].mean() > 0.5          # still finds most distractors
    assert res.removed[~truth].mean() < 0.02
    # each candidate's verifying views hold its view
    hoods = neighbourhoods(scene, 3, 3)
    for c in res.candidates:
        for j in c.verify_views:
            assert hoods[j][c.view] or c.scores.get("individual", 0.0) == 0.0


def test_neighbours_is_validated():
    for bad in (0, -1, 1.5, "all"):
        with pytest.raises(ClearsplatError) as e:
            FilterConfig(neighbours=bad)
        assert e.value.field == "neighbours"
    assert FilterConfig(neighbours=None).neighbours is None


def test_video_passers_by_stay_for_consecutive_views():
    world = make_world("street", num_views=10, seed=4, height=48, width=80, transients="video")
    names = [{p.name for p in prims} for prims in world.transients]
    people = set().union(*names)
    assert people
    for person in people:
        views = [i for i, n in enumerate(names) if person in n]
        # consecutive views, at most five, and each stays for two unless the capture ends
        assert views == list(range(views[0], views[-1] + 1)) and len(views) <= 5
        assert len(views) >= 2 or views[-1] == world.num_views - 1
    with pytest.raises(ClearsplatError) as e:
        make_world("object", num_views=4, height=48, width=80, transients="video")
    assert e.value.field == "transients"


def test_leave_out_renders_without_the_neighbouring_views_and_verifies_elsewhere():
    world = make_world("street", num_views=6, seed=4, height=48, width=80, transients="video")
    scene, truth = realistic_reconstruction(world, "plain", seed=4)
    ex = get_extractor("local")
    # The composite reference: the proposal's exclusion render is R_i^-i itself.
    base = FilterConfig(reveal_reference="composite", rounds=1, min_relative_score=0.0)
    res = filter_distractors(scene, config=base.replace(leave_out=1), extractor=ex)
    assert res.candidates
    for c in res.candidates:        # no verifying view next to the candidate's own
        assert all(abs(j - c.view) > 1 for j in c.verify_views)
    # R_i^-i without views i-1..i+1: the proposal's exclusion render equals a render of the
    # other views' Gaussians alone
    from clearsplat.render import render
    for p in res.proposals:
        far = np.abs(scene.view_id - p.view) > 1
        np.testing.assert_array_equal(p.exclusion, render(scene, scene.cameras[p.view],
                                                          keep=far).rgb)
    zero = filter_distractors(scene, config=base.replace(leave_out=0), extractor=ex)
    plain = filter_distractors(scene, config=base, extractor=ex)
    np.testing.assert_array_equal(zero.keep, plain.keep)
    assert res.removed[truth].mean() > zero.removed[truth].mean()


def test_neighbourhoods_skip_the_views_left_out():
    world = make_world("street", num_views=8, seed=4, height=48, width=80, transients="video")
    scene, _ = realistic_reconstruction(world, "plain", seed=4)
    plan = view_plan(scene, neighbours=2, verify_views="mutual", num_verify_views=3, leave_out=2)
    for v, vs in enumerate(plan.verifiers):
        assert len(vs) == 3 and all(abs(j - v) > 2 for j in vs)
    for j, hood in enumerate(plan.hoods):
        # no view left out of j's exclusion render is among its neighbours or verified by it
        assert not [k for k in np.flatnonzero(hood) if k != j and abs(k - j) <= 2]
        assert hood.sum() >= 3
    res = filter_distractors(scene, config=FilterConfig(neighbours=2, verify_views="mutual",
                                                         leave_out=2, rounds=1),
                             extractor=get_extractor("local"))
    assert res.candidates and all(len(c.verify_views) == 3 for c in res.candidates)


def test_dense_options_resolve_auto_by_view_count():
    from clearsplat.filter.neighbours import DENSE_MIN_VIEWS, DENSE_NEIGHBOURS, dense_options
    below, at = DENSE_MIN_VIEWS - 1, DENSE_MIN_VIEWS
    assert dense_options(below, "auto", "auto") == (None, "centres")
    assert dense_options(at, "auto", "auto") == (DENSE_NEIGHBOURS, "mutual")
    assert dense_options(at, "auto", "centres") == (DENSE_NEIGHBOURS, "centres")
    assert dense_options(below, 4, "auto") == (4, "mutual")       # explicit K: mutual V_i
    assert dense_options(at, None, "auto") == (None, "centres")   # explicit None: the paper's
    assert dense_options(at, 5, "centres") == (5, "centres")
    for preset in ("paper", "paper-local"):
        cfg = FilterConfig.preset(preset)
        assert dense_options(100, cfg.neighbours, cfg.verify_views) == (None, "centres")
    assert FilterConfig(neighbours="auto").neighbours == "auto"
    with pytest.raises(ClearsplatError) as e:
        FilterConfig(neighbours="many")
    assert e.value.field == "neighbours"


def test_auto_is_the_explicit_options_it_resolves_to(monkeypatch):
    from clearsplat.filter import neighbours as nb
    ex = get_extractor("local")
    world = make_world("street", num_views=6, seed=1, height=32, width=64)
    scene, _ = realistic_reconstruction(world, "plain", seed=1)
    auto = FilterConfig(neighbours="auto", verify_views="auto")
    # Below the threshold: the paper's views, bit for bit.
    a = filter_distractors(scene, config=auto, extractor=ex)
    b = filter_distractors(scene, config=FilterConfig(neighbours=None, verify_views="centres"),
                           extractor=ex)
    assert np.array_equal(a.keep, b.keep)
    assert [c.record() for c in a.candidates] == [c.record() for c in b.candidates]
    # From the threshold on (lowered to this scene's 6 views): 3 neighbours, mutual V_i.
    monkeypatch.setattr(nb, "DENSE_MIN_VIEWS", 6)
    monkeypatch.setattr(nb, "DENSE_NEIGHBOURS", 3)
    a = filter_distractors(scene, config=auto, extractor=ex)
    b = filter_distractors(scene, config=FilterConfig(neighbours=3, verify_views="mutual"),
                           extractor=ex)
    c = filter_distractors(scene, config=FilterConfig(neighbours=None, verify_views="centres"),
                           extractor=ex)
    assert np.array_equal(a.keep, b.keep)
    assert [x.record() for x in a.candidates] == [x.record() for x in b.candidates]
    assert [x.record() for x in a.candidates] != [x.record() for x in c.candidates]


def test_held_masks_through_the_view_index_equal_the_gather(street):
    # The masks a neighbourhood's prepared view and the own-view masks are built from each
    # view's members; they must equal hoods[j][view_id], also with views in shuffled order.
    from clearsplat.filter.association import ViewIndex
    from clearsplat.filter.backend import held_mask
    from clearsplat.scene import Scene
    scene, _ = street
    rng = np.random.default_rng(0)
    shuffled = scene.subset(rng.permutation(len(scene)))
    # Some Gaussians shared by the views (view id -1, a fused export): in no view's mask, and
    # held by every neighbourhood.
    shared = shuffled.view_id.copy()
    shared[rng.uniform(size=len(shared)) < 0.2] = -1
    shared = Scene(shuffled.gaussians, shared, np.where(shared < 0, -1, shuffled.pixel_id),
                   shuffled.cameras, shuffled.images)
    for s in (scene, shuffled, shared):
        index = ViewIndex(s)
        mine = s.view_id >= 0
        for _ in range(5):
            views = rng.uniform(size=s.num_views) < 0.4
            np.testing.assert_array_equal(index.views_mask(views, len(s)),
                                          mine & views[s.view_id])
        hoods = neighbourhoods(s, 3, 2)
        for j in range(s.num_views):
            want = ~mine | hoods[j][s.view_id]
            np.testing.assert_array_equal(held_mask(s, hoods, j, index), want)
            np.testing.assert_array_equal(held_mask(s, hoods, j), want)
        assert held_mask(s, None, 0, index) is None


def test_own_masks_are_built_when_asked_and_equal_the_gather(street):
    # RoundState.own builds each view's left-out mask on demand (with leave_out, the views
    # around it too); each must equal left_out[i][view_id], and none may be written to.
    from clearsplat.filter.association import ViewIndex
    from clearsplat.filter.state import OwnMasks
    scene, _ = street
    shuffled = scene.subset(np.random.default_rng(1).permutation(len(scene)))
    v = scene.num_views
    for s in (scene, shuffled):
        for leave_out in (0, 2):
            gap = np.abs(np.arange(v)[:, None] - np.arange(v)[None, :])
            left_out = gap <= leave_out
            own = OwnMasks(ViewIndex(s), left_out)
            assert len(own) == v
            for i in (0, 3, 3, v - 1, -1, 1):
                np.testing.assert_array_equal(own[i], left_out[i][s.view_id])
                with pytest.raises(ValueError):
                    own[i][0] = True
            with pytest.raises(IndexError):
                own[v]


def test_fast_preset_is_the_default_up_to_five_views():
    """``fast`` bounds each camera to four neighbours and one round: with five views every
    other view is a neighbour and the default runs one round there, so the output is the
    default's, bit for bit."""
    world = make_world("street", num_views=5, seed=4, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "plain", seed=4)
    ex = get_extractor("local")
    default = filter_distractors(scene, config=FilterConfig(), extractor=ex)
    fast = filter_distractors(scene, config=FilterConfig.preset("fast"), extractor=ex)
    assert default.candidates and default.removed.any()     # something to agree on
    np.testing.assert_array_equal(fast.keep, default.keep)
    assert [c.record() for c in fast.candidates] == [c.record() for c in default.candidates]


def test_fast_preset_runs_one_round_over_bounded_neighbourhoods(street):
    scene, truth = street
    ex = get_extractor("local")
    fast = FilterConfig.preset("fast")
    assert fast.describe() == "preset 'fast'"
    res = filter_distractors(scene, config=fast, extractor=ex)
    default = filter_distractors(scene, config=FilterConfig(), extractor=ex)
    assert {c.round for c in res.candidates} == {1}
    assert {c.round for c in default.candidates} == {1, 2}   # the default runs two here
    # the renders of a camera hold its four neighbours and the views it verifies, not all
    plan = view_plan(scene, neighbours=4, verify_views="mutual", num_verify_views=3)
    assert any(h.sum() < scene.num_views for h in plan.hoods)
    for c in res.candidates:
        assert c.verify_views == plan.verifiers[c.view]
        assert all(plan.hoods[j][c.view] for j in c.verify_views)
    assert res.removed[truth].mean() > 0.5
    assert res.removed[~truth].mean() < 0.02
