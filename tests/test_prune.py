"""Pruned prepared views: every render of a subset containing the floor is unchanged, bit for
bit. Subset views: the same arrays as preparing the subset scene. The filter's output does not
depend on the view budget."""

import numpy as np
import pytest

from clearsplat import RenderSettings, Scene
from clearsplat.errors import ClearsplatError
from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.association import ViewIndex
from clearsplat.render import prepare
from clearsplat.synth import make_world, reconstruct

from test_render import make_camera, random_gaussians


def _same(a, b):
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


@pytest.fixture(scope="module")
def street():
    w = make_world("street", num_views=8, seed=1, height=48, width=80)
    return reconstruct(w.cameras, w.images, w.depths, seed=1)


@pytest.fixture(scope="module")
def scattered():
    rng = np.random.default_rng(5)
    g = random_gaussians(rng, 4000, k=4, spread=0.8)
    g.scales[:] *= 0.4
    cams = [make_camera(70, 45, eye=(np.sin(a) * 3, 0.3, -np.cos(a) * 3)) for a in (0.0, 0.5)]
    return Scene(g, rng.integers(0, 2, 4000).astype(np.int32), None, cams)


def _cases(scene, view, rng):
    """A floor (all but the view's own Gaussians and a 'proposed' set) and its removable set."""
    n = len(scene)
    own = ViewIndex(scene).mask(view, n) if scene.pixel_id is not None else scene.view_id == view
    proposed = rng.uniform(size=n) < 0.04
    means = scene.gaussians.means
    centre = means[rng.integers(n)]
    proposed[np.argsort(np.linalg.norm(means - centre, axis=1))[:200]] = True   # a clump
    return own, proposed, ~(own | proposed)


@pytest.mark.parametrize("which", ["street", "scattered"])
def test_pruned_view_renders_every_superset_of_the_floor_identically(which, street, scattered):
    scene = street if which == "street" else scattered
    rng = np.random.default_rng(3)
    n = len(scene)
    for view in (0, 1):
        own, proposed, floor = _cases(scene, view, rng)
        full = prepare(scene, scene.cameras[view])
        small = full.pruned(floor)
        assert small.num_visible <= full.num_visible
        bg = (0.2, 0.5, 0.1)
        removable = np.flatnonzero(own | proposed)
        keeps = [None, ~own, floor, ~proposed, floor | (rng.uniform(size=n) < 0.5)]
        for keep in keeps:
            _same(small.render(keep=keep, background=bg), full.render(keep=keep, background=bg))
        for a, b in zip(small.render_pair(keep=floor, first=~own, background=bg),
                        full.render_pair(keep=floor, first=~own, background=bg)):
            _same(a, b)
        # Incremental re-renders of removals taken from outside the floor, with and without
        # the base render.
        base_keep = ~own
        base = full.render(keep=base_keep, background=bg)
        removals = [rng.choice(removable, size=k, replace=False) for k in (1, 10, 150)]
        removals.append(np.flatnonzero(proposed & ~own))
        for with_base in (None, base):
            got = small.rerender_tiles(keep=base_keep, removals=removals, background=bg,
                                       base=with_base)
            for removal, patch in zip(removals, got):
                k = base_keep.copy()
                k[removal] = False
                want = full.render(keep=k, background=bg)
                for a, f in zip(patch[1:], want):
                    np.testing.assert_array_equal(a, full.gather(f, patch.tiles))
                np.testing.assert_array_equal(small.scatter(patch, base).rgb, want.rgb)
        others = proposed & ~own
        tiles = small.tiles_touched(others)
        _same(small.rerender(base, keep=~(own | proposed), tiles=tiles, background=bg),
              full.render(keep=~(own | proposed), background=bg))
        everywhere = np.ones((scene.cameras[view].height, scene.cameras[view].width), bool)
        _same(small.contributions(everywhere), full.contributions(everywhere))


def test_pruning_drops_hidden_entries_and_guards_its_floor(street):
    rng = np.random.default_rng(0)
    own, proposed, floor = _cases(street, 0, rng)
    full = prepare(street, street.cameras[0])
    small = full.pruned(floor)
    # Eight views of one street: most of what a camera sees is hidden behind nearer layers.
    assert small._lists.size < 0.8 * full._lists.size
    assert small.memory_bytes < full.memory_bytes
    # A render that leaves out part of the floor, or removes part of it, is refused.
    outside = np.flatnonzero(floor)[:5]
    keep = np.ones(len(street), bool)
    keep[outside] = False
    with pytest.raises(ClearsplatError, match="pruned"):
        small.render(keep=keep)
    with pytest.raises(ClearsplatError, match="pruned"):
        small.rerender_tiles(keep=~own, removals=[outside])
    with pytest.raises(ClearsplatError, match="pruned"):
        small.contributions(np.ones((48, 80), bool), keep=own)
    # Layers: one layer holding the whole floor renders as before; any split is refused.
    everything = np.zeros(len(street), dtype=np.int8)
    _same(small.render_layers(everything)[0], full.render())
    _same(small.render_layers([np.ones(len(street), bool)])[0], full.render())
    for layers in (np.where(np.arange(len(street)) % 2 == 0, 0, 1), [floor, ~floor],
                   np.where(keep, 0, -1)):
        with pytest.raises(ClearsplatError, match="pruned"):
            small.render_layers(layers)
    # Floors add up: pruning again keeps the first floor too.
    again = small.pruned(floor | own)
    _same(again.render(keep=floor | own), full.render(keep=floor | own))
    with pytest.raises(ClearsplatError, match="pruned"):
        again.render(keep=floor)
    with pytest.raises(ClearsplatError, match="floor"):
        full.pruned(floor[:-1])


@pytest.mark.parametrize("preset", ["default", "paper-local"])
def test_filter_output_does_not_depend_on_the_view_budget(street, preset):
    ex = get_extractor("local")
    cfg = FilterConfig.preset(preset)
    a = filter_distractors(street, config=cfg, extractor=ex)
    c = filter_distractors(street, config=cfg.replace(view_memory=1e-6), extractor=ex)
    assert np.array_equal(a.keep, c.keep)
    assert [x.record() for x in a.candidates] == [x.record() for x in c.candidates]


_VIEW_ARRAYS = ("_splats", "_rects", "_index", "_offsets", "_lists")


@pytest.mark.parametrize("n, settings", [
    (4000, RenderSettings()), (4099, RenderSettings(antialiased=True, eps2d=0.1)),
    (3001, RenderSettings(sh_degree=2))])
def test_subset_view_equals_preparing_the_subset(n, settings):
    rng = np.random.default_rng(n)
    g = random_gaussians(rng, n, k=9, spread=0.8)
    g.scales[:] *= 0.4
    cam = make_camera(70, 45)
    scene = Scene(g, rng.integers(0, 3, n).astype(np.int32), None, [cam], None, settings)
    full = prepare(scene, cam, num_threads=2)
    assert full.num_visible > n // 3
    for share in (0.97, 0.5, 0.0):
        keep = rng.random(n) < share
        sub = scene.subset(np.flatnonzero(keep))
        got = full.subset(keep)
        assert got.num_gaussians == int(keep.sum())
        before = full.render()
        in_place = prepare(scene, cam, num_threads=2).restrict(keep)
        for threads in (1, 3):     # nor do the arrays depend on the threads that prepared them
            want = prepare(sub, cam, num_threads=threads)
            for name in _VIEW_ARRAYS:
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name),
                                              err_msg=name)
                np.testing.assert_array_equal(getattr(in_place, name), getattr(want, name),
                                              err_msg=name)
        _same(full.render(), before)        # the subset copied: this view is unchanged
        if keep.any():
            _same(got.render(background=(0.1, 0.2, 0.3)),
                  prepare(sub, cam).render(background=(0.1, 0.2, 0.3)))


def test_subset_view_needs_a_whole_view(street):
    full = prepare(street, street.cameras[0])
    keep = np.ones(len(street), bool)
    with pytest.raises(ClearsplatError, match="keep"):
        full.subset(keep[:-1])
    with pytest.raises(ClearsplatError, match="pruned"):
        full.pruned(keep).subset(keep)


def test_a_gaussians_record_does_not_depend_on_its_place_in_a_block():
    """Projection works in blocks of 64 Gaussians with eight-lane groups; a Gaussian in a short
    last group must get the very same record (its alpha box included) as one in a full group,
    or a subset view would differ from preparing the subset. 67 copies of one Gaussian (the
    last three in a short group), with the principal point bisected to where the box's right
    edge moves by a pixel: on both sides of that edge every copy has the same box."""
    from clearsplat import Gaussians
    n = 67
    g = Gaussians(means=np.zeros((n, 3)), scales=np.full((n, 3), 0.05),
                  quats=np.tile([1.0, 0, 0, 0], (n, 1)), opacities=np.full(n, 0.7),
                  sh=np.zeros((n, 1, 3)))

    def boxes(cx):
        view = prepare(g, make_camera(64, 48, c=(cx, 24.0)), num_threads=1)
        assert view.num_visible == n
        return view._splats.view(np.int16).reshape(n, -1)[:, -4:]   # bx0, bx1, by0, by1

    lo, hi = 32.0, 33.0
    assert boxes(lo)[0, 1] != boxes(hi)[0, 1]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if boxes(mid)[0, 1] == boxes(lo)[0, 1]:
            lo = mid
        else:
            hi = mid
    for cx in (lo, hi):
        b = boxes(cx)
        assert (b == b[0]).all(), cx
    assert boxes(lo)[0, 1] + 1 == boxes(hi)[0, 1]
