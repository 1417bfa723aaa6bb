"""The reveal reference (``FilterConfig.reveal_reference="quantile"``): the per-pixel rank
against a loop and closed cases, the renders it is made of, and the filter with it."""

from types import SimpleNamespace

import numpy as np
import pytest

from clearsplat.features import get_extractor
from clearsplat.filter import FilterConfig, filter_distractors
from clearsplat.filter.association import ViewIndex
from clearsplat.filter.neighbours import covisibility
from clearsplat.filter.refine import _tiles_of, static_reference
from clearsplat.filter.reveal import (MIN_ALPHA, parallax_angles, quantile_layers,
                                      reveal_neighbours, reveal_plan, reveal_reference,
                                      typical_depths)
from clearsplat.metrics import removal_stats
from clearsplat.render import RenderResult, prepare, render
from clearsplat.synth import distractor_truth, make_world, reconstruct


def _layers_by_loop(depth, alpha, quantile, min_views):
    """Slow reference: per pixel, the covering layers sorted by (depth, layer), and the one at
    rank floor(quantile (n - 1)), written out with integer arithmetic where it is exact."""
    k, h, w = depth.shape
    layer = np.zeros((h, w), np.int64)
    valid = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            cover = sorted((float(depth[l, y, x]), l) for l in range(k)
                           if alpha[l, y, x] > MIN_ALPHA)
            if not cover:
                continue
            rank = int(quantile * (len(cover) - 1) + 1e-9)
            layer[y, x] = cover[rank][1]
            valid[y, x] = len(cover) >= min_views
    return layer, valid


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("quantile,min_views", [(0.75, 4), (0.5, 1), (0.0, 2), (1.0, 3)])
def test_quantile_layers_match_a_loop(seed, quantile, min_views):
    rng = np.random.default_rng(seed)
    k, h, w = 7, 9, 11
    # Few distinct depths, so that ties occur and their order is tested too.
    depth = rng.integers(1, 6, size=(k, h, w)).astype(np.float32)
    # Each layer covers about a third of the pixels: 0 to 4-6 covering layers per pixel occur,
    # on both sides of every min_views tested (asserted below).
    alpha = (rng.uniform(0.0, 1.0, size=(k, h, w))
             * (rng.uniform(size=(k, h, w)) < 0.6)).astype(np.float32)
    layer, valid = quantile_layers(depth, alpha, quantile=quantile, min_views=min_views)
    ref_layer, ref_valid = _layers_by_loop(depth, alpha, quantile, min_views)
    np.testing.assert_array_equal(valid, ref_valid)
    assert valid.any() and (~valid).any()
    np.testing.assert_array_equal(layer[valid], ref_layer[valid])


def test_quantile_layers_closed_cases():
    # One pixel, four layers at depths 4, 1, 3, 2 (layers 0..3), all covering.
    depth = np.array([4, 1, 3, 2], np.float32).reshape(4, 1, 1)
    alpha = np.ones((4, 1, 1), np.float32)
    pick = lambda q, a=alpha, m=1: quantile_layers(depth, a, quantile=q, min_views=m)
    assert pick(0.0)[0][0, 0] == 1        # the nearest: depth 1
    assert pick(0.5)[0][0, 0] == 3        # rank floor(1.5) = 1: depth 2
    assert pick(0.75)[0][0, 0] == 2       # rank floor(2.25) = 2: depth 3
    assert pick(1.0)[0][0, 0] == 0        # the farthest: depth 4
    # The farthest layer does not cover: of 1, 2, 3 the 0.75 rank is floor(1.5) = 1, depth 2.
    partly = alpha.copy()
    partly[0] = MIN_ALPHA                 # not above the threshold
    assert pick(0.75, partly)[0][0, 0] == 3
    assert pick(0.75, partly, 3)[1][0, 0] and not pick(0.75, partly, 4)[1][0, 0]
    assert not pick(0.75, np.zeros_like(alpha))[1][0, 0]


def test_reveal_neighbours_rank_by_shared_view_and_respect_allowed():
    shared = np.array([[9, 5, 7, 5],
                       [5, 9, 1, 2],
                       [7, 1, 9, 3],
                       [5, 2, 3, 9]], float)
    assert reveal_neighbours(shared, 0, count=3) == [2, 1, 3]     # 1 and 3 tie: lower first
    assert reveal_neighbours(shared, 0, count=2) == [2, 1]
    allowed = np.array([True, False, True, True])
    assert reveal_neighbours(shared, 0, count=3, allowed=allowed) == [2, 3]
    assert reveal_neighbours(shared, 1, count=5) == [0, 3, 2]


@pytest.fixture(scope="module")
def video():
    world = make_world("street", num_views=8, seed=0, height=64, width=112,
                       transients="video")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    return scene, distractor_truth(scene, world)


def test_reveal_reference_takes_each_pixel_from_one_neighbours_own_render(video):
    scene, _ = video
    view = prepare(scene, scene.cameras[3])
    others = [2, 4, 1, 5, 6]
    layers = [scene.view_id == j for j in others]
    fallback = render(scene, scene.cameras[3], keep=scene.view_id != 3)
    out, valid = reveal_reference(view, layers, fallback, quantile=0.75, min_views=4)
    assert valid.any() and (~valid).any()
    singles = [render(scene, scene.cameras[3], keep=m) for m in layers]
    depth = np.stack([r.depth for r in singles])
    alpha = np.stack([r.alpha for r in singles])
    for y, x in np.ndindex(valid.shape):
        cover = sorted((depth[l, y, x], l) for l in range(len(others))
                       if alpha[l, y, x] > MIN_ALPHA)
        src = singles[cover[int(0.75 * (len(cover) - 1))][1]] if len(cover) >= 4 else fallback
        assert valid[y, x] == (len(cover) >= 4)
        for a, b in zip(out, src):
            np.testing.assert_array_equal(a[y, x], b[y, x])
    assert isinstance(out, RenderResult) and out.rgb.dtype == np.float32
    # The same neighbours as one array of layer ids: the same reference.
    ids = np.full(len(scene), -1, dtype=np.int8)
    for k, j in enumerate(others):
        ids[scene.view_id == j] = k
    by_id, valid_by_id = reveal_reference(view, ids, fallback, quantile=0.75, min_views=4)
    np.testing.assert_array_equal(valid_by_id, valid)
    for a, b in zip(by_id, out):
        np.testing.assert_array_equal(a, b)
    # Fewer neighbours than min_views: R_i^-i itself, every pixel.
    same, valid = reveal_reference(view, layers[:3], fallback, quantile=0.75, min_views=4)
    assert not valid.any()
    for a, b in zip(same, fallback):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_reveal_reference_made_again_in_tiles_equals_the_whole_one(video, seed):
    # A later round: some Gaussians removed (the top rows of one neighbour's, scattered ones
    # of every view among the same rows); the view restricted to the rest, R_i^-i composited
    # again in the tiles the removal touched, and the reveal reference made again there from
    # the earlier one equal the whole reference of the kept Gaussians, bit for bit.
    from clearsplat.filter.rounds import kept_scene
    scene, _ = video
    rng = np.random.default_rng(seed)
    i, others = 3, [2, 4, 1, 5, 6]
    top = scene.pixel_id < scene.cameras[0].width * 12
    removed = top & (rng.uniform(size=len(scene)) < 0.05)
    removed[top & (scene.view_id == others[seed % len(others)])] = True
    keep = ~removed
    ids = np.full(len(scene), -1, dtype=np.int8)
    for k, j in enumerate(others):
        ids[scene.view_id == j] = k
    view = prepare(scene, scene.cameras[i])
    first, first_valid = reveal_reference(view, ids, render(scene, scene.cameras[i],
                                                            keep=scene.view_id != i),
                                          quantile=0.75, min_views=3)
    tiles = view.tiles_touched(removed)
    assert 0 < tiles.size < view.num_tiles
    later = kept_scene(scene, np.flatnonzero(keep))
    fallback = render(later, later.cameras[i], keep=later.view_id != i)
    whole, valid = reveal_reference(prepare(later, later.cameras[i]), ids[keep], fallback,
                                    quantile=0.75, min_views=3)
    again, valid_again = reveal_reference(view.restrict(keep), ids[keep], fallback,
                                          quantile=0.75, min_views=3, tiles=tiles,
                                          start=(first, first_valid))
    np.testing.assert_array_equal(valid_again, valid)
    for a, b in zip(again, whole):
        np.testing.assert_array_equal(a, b)
    assert any((a != b).any() for a, b in zip(whole, first))     # the removal changed it
    assert first.rgb is not again.rgb and (first_valid is not valid_again)


def test_a_later_round_makes_the_reveal_reference_again_only_where_removals_touched(video,
                                                                                 monkeypatch):
    # The filter's second round takes each view's reveal reference from the first where the
    # neighbours are the same, and decides exactly as when it makes every reference whole.
    import clearsplat.filter.exclusion as exclusion
    scene, _ = video
    config = FilterConfig(rounds=2)
    extractor = get_extractor("local")
    made = []
    reveal = exclusion._reveal

    def counted(state, others, i, r_excl, start=None, tiles=None):
        made.append(start is not None)
        return reveal(state, others, i, r_excl, start, tiles)

    monkeypatch.setattr(exclusion, "_reveal", counted)
    again = filter_distractors(scene, config=config, extractor=extractor)
    assert any(made) and not all(made)
    monkeypatch.setattr(exclusion, "_held_reveal", lambda *args: None)
    whole = filter_distractors(scene, config=config, extractor=extractor)
    assert max(c.round for c in whole.candidates) == 2
    np.testing.assert_array_equal(again.keep, whole.keep)
    assert [c.scores for c in again.candidates] == [c.scores for c in whole.candidates]


def test_the_quantile_reference_shows_the_surface_behind_a_passer_by_held_by_neighbours(video):
    # In a video the passer-by of view i stands in his neighbouring frames too: R_i^-i shows
    # him, the quantile reference the street behind, farther than his Gaussians.
    scene, truth = video
    shared = covisibility(scene)
    shared = shared + shared.T
    revealed = {"composite": 0, "quantile": 0}
    total = 0
    for i in range(scene.num_views):
        ids = np.flatnonzero((scene.view_id == i) & truth)
        if ids.size == 0:
            continue
        total += ids.size
        cam = scene.cameras[i]
        excl = render(scene, cam, keep=scene.view_id != i)
        others = reveal_neighbours(shared, i, count=7)
        robust, _ = reveal_reference(prepare(scene, cam),
                                     [scene.view_id == j for j in others],
                                     excl, quantile=0.75, min_views=4)
        z = cam.to_camera(scene.gaussians.means[ids])[:, 2]
        for name, ref in (("composite", excl), ("quantile", robust)):
            d = ref.depth.ravel()[scene.pixel_id[ids]]
            revealed[name] += int(np.count_nonzero(z < 0.95 * d))
    assert total > 0
    assert revealed["quantile"] > 1.5 * revealed["composite"]


def test_the_reveal_reference_finds_the_passers_by_the_composite_misses(video):
    scene, truth = video
    extractor = get_extractor("local")
    composite = filter_distractors(scene, config=FilterConfig(reveal_reference="composite"),
                                   extractor=extractor)
    base = removal_stats(composite.removed, truth)
    for config in (FilterConfig(), FilterConfig.preset("video")):
        robust = filter_distractors(scene, config=config, extractor=extractor)
        stats = removal_stats(robust.removed, truth)
        assert stats["recall"] > base["recall"] + 0.3
        assert stats["static_removed"] < 0.03
        assert robust.timings["proposal.reveal"] > 0
    assert "proposal.reveal" not in composite.timings


def test_the_torch_backend_makes_the_native_decisions(video):
    pytest.importorskip("torch")
    scene, _ = video
    extractor = get_extractor("local")
    native = filter_distractors(scene, config=FilterConfig.preset("video"), extractor=extractor)
    config = FilterConfig.preset("video", backend="torch")
    result = filter_distractors(scene, config=config, extractor=extractor)
    assert native.removed.any()
    np.testing.assert_array_equal(result.removed, native.removed)
    assert ([(c.view, c.range, c.accepted, c.reason, c.gaussians.tolist())
             for c in result.candidates]
            == [(c.view, c.range, c.accepted, c.reason, c.gaussians.tolist())
                for c in native.candidates])


def test_below_min_views_neighbours_the_output_is_the_composite_one():
    # At four views each view has three others: with reveal.MIN_VIEWS = 4 no pixel takes the
    # reveal reference, and every decision is the composite's.
    world = make_world("object", num_views=4, seed=1, height=48, width=80)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    extractor = get_extractor("local")
    base = filter_distractors(scene, config=FilterConfig(reveal_reference="composite"),
                              extractor=extractor)
    same = filter_distractors(scene, extractor=extractor)
    assert base.removed.any()
    np.testing.assert_array_equal(same.keep, base.keep)
    assert ([(c.view, c.accepted, c.reason) for c in same.candidates]
            == [(c.view, c.accepted, c.reason) for c in base.candidates])


def test_views_beyond_the_parallax_limit_are_left_out_of_the_reveal_reference(monkeypatch):
    # Eight views on a 90-degree arc round the object: neighbours lie about 11, 21, 31...
    # degrees apart. A limit of 5 degrees leaves none near enough, so the decisions are the
    # composite's; without a limit the far views take part and decide otherwise.
    world = make_world("object", num_views=8, seed=0, height=48, width=80)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    extractor = get_extractor("local")

    def decisions(config):
        r = filter_distractors(scene, config=config, extractor=extractor)
        return r.keep, [(c.view, c.accepted, c.reason) for c in r.candidates], r.timings

    from clearsplat.filter import reveal
    base = decisions(FilterConfig(reveal_reference="composite"))
    monkeypatch.setattr(reveal, "MAX_ANGLE", 5.0)
    near = decisions(FilterConfig())
    np.testing.assert_array_equal(near[0], base[0])
    assert near[1] == base[1]
    monkeypatch.setattr(reveal, "MAX_ANGLE", None)
    unlimited = decisions(FilterConfig())
    assert unlimited[1] != base[1]


def test_parallax_angles_closed_form():
    # Cameras on a circle of radius 2 round the origin, looking at it: at view 0's scene
    # point (the origin, depth 2) the angle to camera j is its angle round the circle.
    from clearsplat.cameras import Camera, look_at
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    degrees = np.array([0.0, 10.0, 35.0, 90.0, 180.0])
    cams = [Camera(K, look_at([2 * np.sin(np.radians(a)), 0.0, 2 * np.cos(np.radians(a))],
                              [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]), 64, 48) for a in degrees]
    angles = parallax_angles(cams, [2.0, 2.0, 1.0, 0.0, 2.0])
    np.testing.assert_allclose(angles[0], degrees, atol=1e-9)
    np.testing.assert_allclose(angles[4], 180.0 - degrees, atol=1e-9)
    np.testing.assert_allclose(np.diag(angles), 0.0)
    assert not angles[3].any()                    # no depth: nothing measured
    # View 2's point lies halfway to the origin (O): in the triangle O, point P, camera 0
    # the sides are |OP| = 1, |OC0| = 2 with 35 degrees at O; camera 2 lies straight behind P
    # (away from O), so the angle at P is 180 degrees less the triangle's angle there.
    side = np.sqrt(1 + 4 - 4 * np.cos(np.radians(35.0)))
    inner = np.degrees(np.arccos((1 + side ** 2 - 4) / (2 * side)))
    assert angles[2, 0] == pytest.approx(180.0 - inner, abs=1e-9)
    assert angles[2, 0] > 35.0    # nearer the cameras, the same baseline subtends more


def test_the_paper_presets_compare_with_the_composite():
    for name in ("paper", "paper-local"):
        assert FilterConfig.preset(name).reveal_reference == "composite"
    for name in ("default", "exact", "fast", "video"):
        config = FilterConfig.preset(name)
        assert config.reveal_reference == "quantile"
    assert FilterConfig.preset("video").leave_out == 1


@pytest.mark.parametrize("seed", [0, 1])
def test_tiles_of_a_mask_match_a_loop(seed):
    rng = np.random.default_rng(seed)
    h, w = 37, 50                                  # not multiples of the tile size
    mask = rng.random((h, w)) > 0.995
    rows, cols = -(-h // 16), -(-w // 16)
    expected = [r * cols + c for r in range(rows) for c in range(cols)
                if mask[16 * r:16 * r + 16, 16 * c:16 * c + 16].any()]
    got = _tiles_of(mask, (rows, cols), 16)
    assert got.dtype == np.int32 and got.tolist() == expected
    assert _tiles_of(np.zeros((h, w), bool), (rows, cols), 16).size == 0


def test_the_static_reference_composites_only_the_tiles_it_is_read_in(video):
    # With ``needed``, the reference equals the full one in every tile holding a needed pixel
    # and is R_i^-i's in the others (the reveal reference replaces it there).
    scene, truth = video
    views = [prepare(scene, cam) for cam in scene.cameras]
    own = [scene.view_id == i for i in range(scene.num_views)]

    class Views(list):
        def sees(self, i, gaussians):
            return bool(gaussians.any())

    state = SimpleNamespace(views=Views(views), own=own, num_views=scene.num_views)
    excl = [v.render(keep=~o) for v, o in zip(views, own)]
    proposed = truth | (np.random.default_rng(0).random(len(scene)) < 0.05)
    rng = np.random.default_rng(1)
    needed = [np.zeros(e.alpha.shape, bool) for e in excl]
    for m in needed:
        m[rng.integers(0, m.shape[0], 3), rng.integers(0, m.shape[1], 3)] = True
    full_d, full_c = static_reference(state, excl, proposed)
    part_d, part_c = static_reference(state, excl, proposed, needed=needed)
    changed = 0
    for i, view in enumerate(views):
        tiles = _tiles_of(needed[i], view.grid, view.tile_size)
        inside = np.zeros(view.num_tiles, bool)
        inside[tiles] = True
        flat, exists = view.tile_pixels(np.arange(view.num_tiles))
        in_needed = np.zeros(excl[i].alpha.size, bool)
        in_needed[flat[exists]] = np.repeat(inside, view.tile_size ** 2)[exists]
        in_needed = in_needed.reshape(excl[i].alpha.shape)
        np.testing.assert_array_equal(part_d[i][in_needed], full_d[i][in_needed])
        np.testing.assert_array_equal(part_c[i][in_needed], full_c[i][in_needed])
        np.testing.assert_array_equal(part_d[i][~in_needed], excl[i].depth[~in_needed])
        changed += int((full_d[i][~in_needed] != part_d[i][~in_needed]).sum())
    assert changed > 0      # the skipped tiles did differ: the test can tell them apart


def test_reveal_plan_takes_the_most_shared_allowed_views_within_the_angle(video):
    scene, _ = video
    v = scene.num_views
    c = covisibility(scene)
    shared = c + c.T
    depths = ViewIndex(scene).depths
    typical = typical_depths(depths)
    for i, cam in enumerate(scene.cameras):    # the median depth of its Gaussians in front
        z = cam.to_camera(scene.gaussians.means[scene.view_id == i])[:, 2]
        assert typical[i] == float(np.median(z[z > 0]))
    angles = parallax_angles(scene.cameras, typical)
    allowed = ~np.eye(v, dtype=bool)
    allowed[:, 2] = False                          # view 2 may reveal nothing for anyone
    for max_angle in (None, float(np.median(angles[angles > 0]))):
        plan = reveal_plan(scene, count=3, max_angle=max_angle, allowed=allowed,
                           depths=depths)
        for i, others in enumerate(plan):
            ok = [j for j in range(v) if allowed[i, j]
                  and (max_angle is None or angles[i, j] <= max_angle)]
            ranked = sorted(ok, key=lambda j: (-shared[i, j], j))
            assert others == ranked[:3]
            assert 2 not in others and i not in others
    assert any(len(o) < 3 for o in plan)           # the angle did leave views out
