"""Prepared views within a memory budget, and verification limited to the views a removal can
change: the filter's output does not depend on either."""

import numpy as np
import pytest

from clearsplat.errors import ClearsplatError
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.views import PreparedViews
from clearsplat.render import prepare
from clearsplat.synth import make_world, reconstruct


@pytest.fixture(scope="module")
def street():
    # A street: cameras along it see only part of the scene, so some views see no Gaussian
    # of some candidates.
    w = make_world("street", num_views=8, seed=0, height=32, width=64)
    return reconstruct(w.cameras, w.images, w.depths, seed=0)


@pytest.fixture(scope="module")
def extractor():
    return get_extractor("local")


def _same(a, b):
    assert np.array_equal(a.keep, b.keep)
    assert [c.record() for c in a.candidates] == [c.record() for c in b.candidates]


#: A config whose tests leave out views on this scene (the default's candidates here are seen
#: by every view, and so are the paper's), and that tests a second range here.
_SKIPS = dict(refine="depth")


@pytest.mark.parametrize("preset,changes", [("default", {}), ("default", _SKIPS),
                                            ("paper-local", {})])
def test_views_left_out_change_no_score(street, extractor, preset, changes):
    """The incremental path leaves out views that see none of a removal's Gaussians; the
    full-render path visits every view: identical scores prove those views weigh nothing."""
    cfg = FilterConfig.preset(preset, **changes)
    a = filter_distractors(street, config=cfg, extractor=extractor)
    b = filter_distractors(street, config=cfg.replace(incremental=False), extractor=extractor)
    assert b.stats["views_skipped"] == 0
    if changes:
        assert a.stats["views_skipped"] > 0
    assert any("joint" in c.scores or "additional" in c.scores for c in a.candidates)
    _same(a, b)


@pytest.mark.parametrize("rounds", [1, 2])
def test_output_does_not_depend_on_the_view_budget(street, extractor, rounds):
    a = filter_distractors(street, config=FilterConfig(view_memory=None, rounds=rounds),
                           extractor=extractor)
    b = filter_distractors(street, config=FilterConfig(view_memory=1e-9, rounds=rounds),
                           extractor=extractor)
    _same(a, b)
    ran = max(c.round for c in a.candidates)
    assert ran == rounds            # the second round runs (and finds something) here
    assert a.stats["views_prepared"] == rounds * street.num_views
    assert b.stats["views_prepared"] > street.num_views
    assert b.stats["views_peak_bytes"] < a.stats["views_peak_bytes"]


def _fake_views(budget):
    """A view set of 4 cameras whose views hold 100 bytes each, and the list of the views it
    prepares, in order."""
    class Fake:
        memory_bytes = 100
        visible = np.arange(3)

    made = []

    def make(i):
        made.append(i)
        return Fake()

    return PreparedViews(8, [None] * 4, make, budget=budget), made


def test_prepared_views_make_room_before_preparing():
    """The kept views and the one being prepared stay within the budget together: room for a
    view as large as the largest so far is made first."""
    views, made = _fake_views(250)
    for _ in range(2):
        for i in range(4):
            views[i]
            assert views.held_bytes <= 250
    # Room for two views and the one being prepared: 0 stays, the second slot turns over.
    assert made == [0, 1, 2, 3, 1, 2, 3]
    assert views.peak_bytes == 200
    unlimited, _ = _fake_views(None)
    for i in range(4):
        unlimited[i]
    assert unlimited.peak_bytes == 400


def test_prepared_views_keep_the_first_within_budget(street):
    made = []

    def make(i):
        made.append(i)
        return prepare(street, street.cameras[i])

    one = prepare(street, street.cameras[0]).memory_bytes
    views = PreparedViews(len(street), street.cameras, make, budget=int(2.5 * one))
    for _ in range(2):
        for i in range(4):
            assert views[i].camera is street.cameras[i]
    # Room for two views: 0 stays, the last slot turns over (1, 2, 3, then 1, 2, 3 again).
    assert made == [0, 1, 2, 3, 1, 2, 3]
    assert views.peak_bytes <= int(2.5 * one) + max(v.memory_bytes for v in [views[3]])
    g = views[3].visible
    assert views.sees_any(3, g[:5])
    unseen = np.setdiff1d(np.arange(len(street)), g)
    if unseen.size:
        assert not views.sees_any(3, unseen)
    assert not views.sees_any(3, np.empty(0, np.int64))
    # release() drops the views and keeps the bits; release(bits=True) drops both.
    views.release()
    assert views.held_bytes == 0 and views.sees_any(3, g[:5])
    views.release(bits=True)
    with pytest.raises(RuntimeError, match="released"):
        views.sees_any(3, g[:5])
    # ... and what prepares a view, with all it holds (a round's Gaussian index, its scene):
    # nothing is prepared any more.
    for i in (0, 3):
        with pytest.raises(RuntimeError, match="released"):
            views[i]
    assert made == [0, 1, 2, 3, 1, 2, 3]


@pytest.mark.parametrize("bad", [0, -1.0, float("inf"), True, "2"])
def test_view_memory_must_be_positive(bad):
    with pytest.raises(ClearsplatError, match="view_memory"):
        FilterConfig(view_memory=bad)


def test_later_rounds_prepare_from_the_whole_scene(street, extractor, monkeypatch):
    """Under a budget that holds one view, the second round prepares its views afresh: from
    the whole scene, restricted to the kept Gaussians, with the output of views carried over."""
    import sys
    render = sys.modules["clearsplat.render"]   # the package (its name is also a function)
    sizes = []

    def counting(scene, *args, **kwargs):
        sizes.append(len(scene))
        return prepare(scene, *args, **kwargs)

    monkeypatch.setattr(render, "prepare", counting)
    a = filter_distractors(street, config=FilterConfig(view_memory=1e-9, rounds=2),
                           extractor=extractor)
    monkeypatch.undo()
    assert max(c.round for c in a.candidates) == 2
    assert len(sizes) > 2 * street.num_views and set(sizes) == {len(street)}
    _same(a, filter_distractors(street, config=FilterConfig(view_memory=None, rounds=2),
                                extractor=extractor))


def test_kept_gaussians_read_as_the_subset(street):
    from clearsplat.filter.rounds import KeptGaussians, kept_scene
    kept = np.flatnonzero(np.random.default_rng(0).random(len(street)) < 0.7)
    light, full = kept_scene(street, kept, light=True), kept_scene(street, kept)
    assert isinstance(light.gaussians, KeptGaussians) and len(light) == len(full) == kept.size
    for name in ("means", "scales", "quats", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(light.gaussians, name),
                                      getattr(full.gaussians, name))
    np.testing.assert_array_equal(light.view_id, full.view_id)
    np.testing.assert_array_equal(light.pixel_id, full.pixel_id)
    assert light.gaussians.sh_degree == full.gaussians.sh_degree and not light.gaussians.extra


def test_make_room_and_hand_on():
    views, made = _fake_views(400)
    for i in range(4):
        views[i]
    views.make_room(150)        # the most recently prepared go first: 3, then 2
    assert sorted(views._kept) == [0, 1] and views.held_bytes == 200
    views.hand_on()             # the views stay for the next round to take; nothing else
    assert views.take(1) is not None and views.take(3) is None
    with pytest.raises(RuntimeError, match="released"):
        views[3]
    with pytest.raises(RuntimeError, match="never prepared|released"):
        views.sees_any(0, np.arange(2))
    assert made == [0, 1, 2, 3]


def test_held_bytes_counts_what_a_later_round_keeps_alive(street, extractor):
    from clearsplat.filter.rounds import held_bytes, kept_scene
    r = filter_distractors(street, config=FilterConfig(rounds=1), extractor=extractor)
    kept = np.flatnonzero(r.keep)
    light, full = kept_scene(street, kept, light=True), kept_scene(street, kept)
    result = (r.keep.nbytes
              + sum(a.nbytes for p in r.proposals for a in vars(p).values()
                    if isinstance(a, np.ndarray))
              + sum(c.gaussians.nbytes + c.expanded.nbytes for c in r.candidates))
    ids = light.view_id.nbytes + light.pixel_id.nbytes
    g = light.gaussians
    assert held_bytes(r, light) == result + ids + g.means.nbytes + g.opacities.nbytes
    shapes = sum(getattr(full.gaussians, k).nbytes for k in ("scales", "quats", "sh"))
    assert held_bytes(r, full) == held_bytes(r, light) + shapes
    shown = [np.zeros((4, 5), bool), None]
    assert held_bytes(r, light, kept, shown, None) == held_bytes(r, light) + kept.nbytes + 20


def test_later_round_views_leave_room_for_what_stays_held(street, extractor, monkeypatch):
    """A later round's views get the budget less Carry.reserve, and the views handed on are
    trimmed to it first; the output stays that of an unlimited budget."""
    from clearsplat.filter import backend as backend_module
    from clearsplat.filter import pipeline
    budgets, reserves, rooms = [], [], []

    class Recording(PreparedViews):
        def __init__(self, *args, budget, **kwargs):
            budgets.append(budget)
            super().__init__(*args, budget=budget, **kwargs)

        def make_room(self, nbytes):
            rooms.append(nbytes)
            super().make_room(nbytes)

    held = pipeline.held_bytes

    def recording_held(*args):
        reserves.append(held(*args))
        return reserves[-1]

    monkeypatch.setattr(backend_module, "PreparedViews", Recording)
    monkeypatch.setattr(pipeline, "held_bytes", recording_held)
    budget = 3 * prepare(street, street.cameras[0]).memory_bytes
    cfg = FilterConfig(view_memory=budget / 1e9, rounds=2)
    a = filter_distractors(street, config=cfg, extractor=extractor)
    assert max(c.round for c in a.candidates) == 2
    assert len(reserves) == 1 and reserves[0] > 0 and rooms == reserves
    assert len(budgets) == 2 and abs(budgets[0] - budget) <= 1     # GB and back
    assert budgets[1] == max(budgets[0] - reserves[0], 0)
    monkeypatch.undo()
    _same(a, filter_distractors(street, config=cfg.replace(view_memory=None),
                                extractor=extractor))
