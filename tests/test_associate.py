"""The association recovered from geometry and images (clearsplat.adapters.associate).

Exports are made from the stand-in per-pixel prediction by the generators of
benchmarks/association_quality.py: Depth Anything 3's ``gs_ply`` (border trim, per-view depth
percentile cut, sub-pixel offsets, (view, row, col) order) and AnySplat's voxel fusion; and,
for the pixel-centred association, the prediction itself (centres on their pixels' rays) in a
random order.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from clearsplat import Camera, ClearsplatError
from clearsplat.adapters import associate as assoc
from clearsplat.adapters.associate import (
    CENTRE_RATIO,
    CENTRE_TOLERANCE,
    Association,
    associate_centred,
    associate_fused,
    associate_ordered,
    normalised_frame,
)
from clearsplat.cameras import look_at
from clearsplat.synth import distractor_truth, make_world, reconstruct
from scripts import load_script

AQ = load_script("benchmarks/association_quality.py")


@pytest.fixture(scope="module", params=["street", "object"])
def prediction(request):
    world = make_world(request.param, num_views=8, height=96, width=160, seed=3)
    return world, reconstruct(world.cameras, world.images, world.depths, seed=3)


def _right(a: Association, view, pixel, width):
    """Shares of vertices with the right view, and with it a pixel within 1 px per axis."""
    return (float(np.mean(a.view_id == view)),
            float(np.mean(AQ.pixel_match(a.view_id, a.pixel_id, view, pixel, width))))


# ------------------------------------------------------------------------------------------------
# ordered exports
# ------------------------------------------------------------------------------------------------
def test_da3_style_export_gets_its_views_and_pixels(prediction):
    world, scene = prediction
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=0)
    assert 0.5 * len(scene) < len(export) < 0.95 * len(scene)      # trims and cuts happened
    a = associate_ordered(export.means, world.cameras)
    right_view, right_pixel = _right(a, view, pixel, world.width)
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)
    assert a.source == "geometry" and a.ambiguous.mean() < 0.01
    a.to_scene(export, world.cameras, world.images)                  # validates


@pytest.mark.parametrize("family", ["street", "object"])
def test_video_like_capture_is_cut_at_the_row_resets(family):
    # Consecutive cameras a few millimetres and 0.15 degrees apart: every camera sees every
    # view's vertices, and only the reset from one view's bottom row to the next view's top
    # row tells the runs apart.
    scene = AQ.video_capture(family, num_views=8, height=64, width=112, seed=1)
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=1)
    a = associate_ordered(export.means, scene.cameras)
    right_view, right_pixel = _right(a, view, pixel, 112)
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)


def test_identical_cameras_still_split_at_the_resets():
    scene = AQ.video_capture("street", num_views=5, height=64, width=112, seed=2, step=0.0,
                             turn_deg=0.0)
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=2)
    a = associate_ordered(export.means, scene.cameras)
    assert _right(a, view, pixel, 112) == (1.0, 1.0)


def test_every_kth_view_with_the_views_given(prediction):
    world, scene = prediction
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=4, interval=3)
    assert set(np.unique(view)) == {0, 3, 6}
    a = associate_ordered(export.means, world.cameras, views=range(0, 8, 3))
    right_view, right_pixel = _right(a, view, pixel, world.width)
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)


def test_every_kth_view_without_the_views_told_apart_by_stalls(prediction):
    # Views 1, 2, 4, 5, 7 are absent and not excluded: a camera close to a written one sees its
    # vertices in order; with offsets below half a pixel only the stalls (vertices packed
    # closer than a run of its own) tell the written camera apart.
    world, scene = prediction
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=4, interval=3)
    a = associate_ordered(export.means, world.cameras, max_offset=0.5)
    right_view, right_pixel = _right(a, view, pixel, world.width)
    assert right_view >= 0.99 and right_pixel >= 0.99, (right_view, right_pixel)


def test_offsets_up_to_a_pixel(prediction):
    world, scene = prediction
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=5, max_offset=1.0,
                                                 depth_error=0.05)
    a = associate_ordered(export.means, world.cameras)               # max_offset 1 px
    assert _right(a, view, pixel, world.width)[1] >= 0.99


def test_order_alone_decides_where_geometry_cannot():
    # Two views of one camera, each a full row-major grid on a plane: every vertex projects
    # inside both cameras, so only the reset between the views places the boundary.
    K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    cam = Camera(K=K, camera_to_world=np.eye(4), width=16, height=12)
    grid = cam.unproject(np.full((12, 16), 2.0)).reshape(-1, 3)
    keep = np.random.default_rng(0).random(2 * len(grid)) < 0.8
    means = np.concatenate([grid, grid])[keep]
    a = associate_ordered(means, [cam, cam])
    truth = np.repeat([0, 1], len(grid))[keep]
    assert np.array_equal(a.view_id, truth)
    assert np.array_equal(a.pixel_id, np.tile(np.arange(len(grid)), 2)[keep])


def test_normalised_frame_undoes_depth_anything_normalisation():
    world = make_world("object", num_views=5, height=64, width=112, seed=0)
    cams = world.cameras
    # The normalisation as DepthAnything3._normalize_extrinsics computes it.
    w2c = np.stack([c.world_to_camera for c in cams])
    ex = w2c @ cams[0].camera_to_world
    c2w = np.linalg.inv(ex)
    median = max(np.sort(np.linalg.norm(c2w[:, :3, 3], axis=1))[(len(cams) - 1) // 2], 0.1)
    ex[:, :3, 3] /= median
    norm_c2w = np.linalg.inv(ex)
    frame = normalised_frame(cams)
    assert np.allclose(frame.apply(norm_c2w[:, :3, 3]), [c.position for c in cams], atol=1e-9)
    for nc, c in zip(norm_c2w, cams):
        assert np.allclose(frame.rotation @ nc[:3, :3], c.camera_to_world[:3, :3], atol=1e-9)
    # An export in the normalised frame is associated once mapped back.
    scene = reconstruct(cams, world.images, world.depths, seed=0)
    export, view, pixel, _ = AQ.da3_style_export(scene, seed=0)
    normalised = (export.means - frame.translation) @ frame.rotation / frame.scale
    a = associate_ordered(frame.apply(normalised), cams)
    assert _right(a, view, pixel, world.width)[1] >= 0.99


def _brute_segment(outside, steps, weights):
    s_count, n = outside.shape
    best = np.inf
    for cut in itertools.combinations_with_replacement(range(n + 1), s_count - 1):
        bounds = (0, *cut, n)
        cost = 0.0
        for s in range(s_count):
            for k in range(bounds[s], bounds[s + 1]):
                cost += outside[s, k] + (weights[steps[s, k]] if k > bounds[s] else 0.0)
        best = min(best, cost)
    return best


def _cost(bounds, outside, steps, weights):
    return sum(outside[s, k] + (weights[steps[s, k]] if k > bounds[s] else 0.0)
               for s in range(outside.shape[0]) for k in range(bounds[s], bounds[s + 1]))


@pytest.mark.parametrize("seed", range(40))
def test_segmentation_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    s_count, n = int(rng.integers(1, 5)), int(rng.integers(0, 9))
    outside = rng.random((s_count, n)) < 0.3
    steps = rng.integers(0, 3, (s_count, n)).astype(np.uint8)
    weights = (0.0, float(rng.uniform(0, 0.5)), float(rng.uniform(0.5, 3)))
    bounds, cost = assoc._segment(outside, steps, weights)
    assert bounds[0] == 0 and bounds[-1] == n and np.all(np.diff(bounds) >= 0)
    assert cost == pytest.approx(_brute_segment(outside, steps, weights))
    assert _cost(bounds, outside, steps, weights) == pytest.approx(cost)


@pytest.mark.parametrize("max_offset", [0.5, 1.0, 1.7])
def test_order_steps_match_a_loop(max_offset):
    rng = np.random.default_rng(7)
    width = 9
    row, col = rng.integers(0, 6, 300), rng.integers(0, width, 300)
    ok = rng.random(300) < 0.9
    got = assoc._order_steps(row, col, ok, width, max_offset)
    # Per axis a floored centre lies within ceil(m - 1/2) below and ceil(m + 1/2) - 1 above
    # its pixel: d values apart.
    d = int(np.ceil(max_offset - 0.5) + np.ceil(max_offset + 0.5) - 1)
    for k in range(300):
        step = (row[k] - row[k - 1]) * width + col[k] - col[k - 1] if k else 0
        if k == 0 or not (ok[k] and ok[k - 1]):
            want = 0
        elif step < 1 - max(d, 1) * (width + 1):
            want = assoc.BREAK
        elif step < 1 - d * (width + 1):
            want = assoc.STALL
        else:
            want = 0
        assert got[k] == want, k


# ------------------------------------------------------------------------------------------------
# pixel-centred exports in no order
# ------------------------------------------------------------------------------------------------
def _shuffled(scene, share=0.4, seed=0):
    """A random subset of a per-pixel prediction in random order (a pruned or subsampled
    export): centres as float32, the true view and pixel of each."""
    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(scene))[:int(share * len(scene))]
    return scene.gaussians.means[idx], scene.view_id[idx], scene.pixel_id[idx]


def test_centred_export_in_no_order_gets_its_views_and_pixels(prediction):
    world, scene = prediction
    means, view, pixel = _shuffled(scene)
    a = associate_centred(means, world.cameras)
    right = a.view_id == view
    assert right.mean() >= 0.99 and (right & (a.pixel_id == pixel)).mean() >= 0.99
    assert a.source == "geometry" and a.ambiguous.mean() < 0.01
    assert right[~a.ambiguous].all()                   # the unambiguous ones are all right
    a.to_scene(scene.gaussians.subset(np.arange(len(means))), world.cameras)   # validates


@pytest.mark.parametrize("family", ["street", "object"])
def test_centred_video_like_capture(family):
    # Consecutive cameras a few millimetres and 0.15 degrees apart put a vertex near a pixel
    # centre only where their shift is close to a whole number of pixels.
    scene = AQ.video_capture(family, num_views=8, height=64, width=112, seed=1)
    means, view, pixel = _shuffled(scene, seed=1)
    a = associate_centred(means, scene.cameras)
    right = (a.view_id == view) & (a.pixel_id == pixel)
    assert right.mean() >= 0.99 and a.ambiguous.mean() < 0.01, (right.mean(), a.ambiguous.mean())


def test_identical_cameras_are_ambiguous():
    scene = AQ.video_capture("street", num_views=3, height=32, width=48, seed=2, step=0.0,
                             turn_deg=0.0)
    a = associate_centred(scene.gaussians.means, scene.cameras)
    assert a.ambiguous.all() and (a.view_id == 0).all()


def test_centres_off_their_pixel_centres_are_ambiguous(prediction):
    # Moved across the image by 0.1 to 0.4 px per axis (centres computed at a lower
    # precision): no camera puts them within the tolerance of a pixel centre.
    world, scene = prediction
    means, view, _ = _shuffled(scene, share=0.1)
    rng = np.random.default_rng(3)
    shift = rng.uniform(0.1, 0.4, (len(means), 2)) * rng.choice([-1, 1], (len(means), 2))
    moved = np.empty(means.shape)
    for v, cam in enumerate(world.cameras):
        sel = view == v
        pc = cam.to_camera(means[sel])
        pc[:, 0] += shift[sel, 0] * pc[:, 2] / cam.fx
        pc[:, 1] += shift[sel, 1] * pc[:, 2] / cam.fy
        moved[sel] = pc @ cam.camera_to_world[:3, :3].T + cam.camera_to_world[:3, 3]
    assert associate_centred(means, world.cameras).ambiguous.mean() < 0.01
    assert associate_centred(moved, world.cameras).ambiguous.mean() > 0.9


def _slow_centred(means, cameras, tolerance, ratio):
    """Per vertex and camera in plain Python: the offset from the centre of the pixel its
    projection falls in (larger axis), the nearest camera (first of equals), its pixel (-1
    off every pixel centre), and ambiguity; None for a vertex no camera sees."""
    uvz = [cam.project(means) for cam in cameras]
    out = []
    for k in range(len(means)):
        offs = []
        for v, cam in enumerate(cameras):
            (x, y), z = uvz[v][0][k], uvz[v][1][k]
            if not (z > 0 and 0 <= x < cam.width and 0 <= y < cam.height):
                continue
            col, row = int(np.floor(x)), int(np.floor(y))
            offs.append((max(abs(x - col - 0.5), abs(y - row - 0.5)), v, row * cam.width + col))
        if not offs:
            out.append(None)
            continue
        best = min(offs, key=lambda o: (o[0], o[1]))
        rest = [o[0] for o in offs if o is not best]
        second = min(rest) if rest else np.inf
        amb = best[0] > tolerance or second <= max(ratio * best[0], tolerance / ratio)
        out.append((best[1], best[2] if best[0] <= tolerance else -1, amb))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_centre_choice_matches_a_loop(seed):
    rng = np.random.default_rng(seed)
    cams = [Camera(K=np.array([[20.0, 0, 6], [0, 20.0, 5], [0, 0, 1]]),
                   camera_to_world=look_at(rng.normal(size=3) * 0.3 + (0, -3, 0), (0, 0, 0)),
                   width=12, height=10) for _ in range(int(rng.integers(2, 5)))]
    # Centres on pixel centres of random cameras, moved by 0 to 0.05 px (across the
    # tolerance), random points, and some behind every camera.
    v = rng.integers(0, len(cams), 60)
    rows, cols = rng.integers(0, 10, 60), rng.integers(0, 12, 60)
    centred = np.stack([cams[i].unproject(np.full((10, 12), d))[r, c] for i, r, c, d in
                        zip(v, rows, cols, rng.uniform(1, 5, 60))])
    centred += rng.normal(size=centred.shape) * rng.choice([0, 1e-4, 2e-3, 1e-2], (60, 1))
    means = np.concatenate([centred, rng.uniform(-1, 1, (40, 3)), [[0, -30.0, 0]]])
    a = associate_centred(means, cams, min_seen=0.0)
    want = _slow_centred(means, cams, CENTRE_TOLERANCE, CENTRE_RATIO)
    for k, w in enumerate(want):
        got = (int(a.view_id[k]), int(a.pixel_id[k]), bool(a.ambiguous[k]))
        if w is None:
            assert got[1:] == (-1, True), k
            assert got[0] == assoc._facing_view(means[k:k + 1], cams)[0], k
        else:
            assert got == w, k
    assert 0 < a.ambiguous.sum() < len(means)


# ------------------------------------------------------------------------------------------------
# fused Gaussians
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("family", ["object", "street"])
def test_fused_distractor_voxels_get_their_distractors_view(family):
    right = total = 0
    for seed in range(3):
        world = make_world(family, num_views=6, height=64, width=112, seed=seed)
        scene = reconstruct(world.cameras, world.images, world.depths, seed=seed)
        truth = distractor_truth(scene, world)
        fused, voxel, _ = AQ.voxel_fused_export(scene, seed=seed)
        k = len(fused)
        distractor = np.bincount(voxel, truth.astype(float), minlength=k) / np.bincount(voxel)
        distractor = distractor > 0.5
        its_view = AQ.majority_view(voxel, scene.view_id, 6, weights=truth.astype(float))
        a = associate_fused(fused, world.cameras, world.images)
        assert a.source == "images"
        assert a.view_id.min() >= -1 and a.view_id.max() < 6      # -1: shared static content
        # A voxel of one pixel is that pixel's Gaussian: its view and pixel (unless a second
        # camera puts it on a pixel centre too). A voxel given a pixel is one of its own pixels
        # (of one pixel, or near enough), but for those chance puts on a pixel centre ((2 x
        # 0.02)^2 per camera).
        one = np.bincount(voxel, minlength=k) == 1
        taken = a.pixel_id >= 0
        mine = np.zeros(k, dtype=bool)
        mine[voxel[taken[voxel] & (a.view_id[voxel] == scene.view_id)
                   & (a.pixel_id[voxel] == scene.pixel_id)]] = True
        assert one.mean() > 0.2 and mine[one].mean() > 0.999
        assert np.mean(taken & ~mine) < 2 * 6 * (2 * CENTRE_TOLERANCE) ** 2
        right += int(np.sum(a.view_id[distractor] == its_view[distractor]))
        total += int(distractor.sum())
    assert total > 100
    assert right / total >= 0.75, right / total


def test_voxel_fusion_follows_anysplat():
    world = make_world("object", num_views=3, height=32, width=48, seed=0)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    fused, voxel, size = AQ.voxel_fused_export(scene, seed=0)
    assert abs(len(scene) / len(fused) / 5.0 - 1) < 0.02
    keys = np.round(scene.gaussians.means.astype(np.float64) / size).astype(np.int64)
    # Voxels in torch.unique's order: lexicographic in the integer key; each is the weighted
    # mean of its pixels, so it lies within the voxel's bounds.
    first = np.stack([keys[voxel == k][0] for k in range(len(fused))])
    assert all(tuple(a) < tuple(b) for a, b in itertools.pairwise(first))
    for k in range(0, len(fused), 97):
        assert np.all(keys[voxel == k] == first[k])
        lo, hi = (first[k] - 0.5) * size, (first[k] + 0.5) * size
        assert np.all(fused.means[k] >= lo - 1e-5) and np.all(fused.means[k] <= hi + 1e-5)


def test_off_surface_measures_depth_from_the_true_surface():
    world = make_world("object", num_views=2, height=32, width=48, seed=0)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0, depth_blur=0.0,
                        depth_noise=0.0)
    g, views = scene.gaussians, scene.view_id
    assert not AQ.off_surface(g, views, world).any()          # every centre on its pixel's depth
    cam = world.cameras[1]
    centre = cam.camera_to_world[:3, 3]
    moved = g.means.astype(np.float64).copy()
    picked = np.flatnonzero(views == 1)[[5, 700, 1200]]
    # Along the ray through the pixel: 4 % nearer stays on, 6 % farther and 10 % nearer are off.
    for i, factor in zip(picked, (0.96, 1.06, 0.90)):
        moved[i] = centre + factor * (moved[i] - centre)
    g = dataclasses.replace(g, means=moved.astype(g.means.dtype))
    off = AQ.off_surface(g, views, world)
    assert np.flatnonzero(off).tolist() == sorted(picked[1:].tolist())
    shared = views.copy()
    shared[picked] = -1                                           # shared: never off the surface
    assert not AQ.off_surface(g, shared, world).any()


def _slow_choose(total, agreeing, agree_ratio, min_weight):
    views, ambiguous, unseen = [], [], []
    for w, a in zip(total.astype(float), agreeing.astype(float)):
        a = np.minimum(a, w)
        r = [a_v / w_v if w_v > 0 else 0.0 for a_v, w_v in zip(a, w)]
        scores = [a_v * r_v for a_v, r_v in zip(a, r)]
        best = scores.index(max(scores))
        seeing = [v for v in range(len(w)) if w[v] >= min_weight]
        agree = [v for v in seeing if r[best] > 0 and r[v] >= agree_ratio * r[best]]
        if len(agree) >= 2 and len(agree) > len(seeing) / 2:
            views.append(-1)
        elif len(agree) >= 2:
            views.append(max(agree, key=lambda v: (w[v], -v)))
        else:
            views.append(best if r[best] > 0 else int(np.argmax(w)))
        ambiguous.append(len(agree) == 0)
        unseen.append(max(w) <= 0)
    return views, ambiguous, unseen


@pytest.mark.parametrize("seed", range(5))
def test_view_choice_matches_a_loop(seed):
    rng = np.random.default_rng(seed)
    n, v = 200, 5
    total = (rng.random((n, v)) * (rng.random((n, v)) < 0.6) * 3).astype(np.float16)
    agreeing = (total * rng.random((n, v)) ** 3).astype(np.float16)
    total[:5] = 0
    got = assoc._choose_views(total, agreeing)
    want = _slow_choose(total, agreeing, assoc.AGREE_RATIO, assoc.SEEN_WEIGHT)
    for g, w in zip(got, want):
        assert np.array_equal(g, np.asarray(w))
    assert got[2][:5].all()
    assert (got[0] == -1).any() and (got[0] >= 0).any()


def _wall_and_cameras(distances):
    """A wall of one colour (9 x 11 Gaussians, one more beyond the nearest camera's image) and
    cameras facing it from ``distances``."""
    from clearsplat import Gaussians
    from clearsplat.scene import rgb_to_sh_dc

    xy = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 11), np.linspace(-0.4, 0.4, 9)),
                  -1).reshape(-1, 2)
    xy = np.concatenate([xy, [[1.6, 0.0]]])                # outside the near camera's view
    n = len(xy)
    wall = Gaussians(means=np.c_[xy, np.zeros(n)], scales=np.full((n, 3), 0.1),
                     quats=np.tile([1.0, 0, 0, 0], (n, 1)), opacities=np.full(n, 0.99),
                     sh=rgb_to_sh_dc(np.full((n, 1, 3), 0.6)))
    K = np.array([[40.0, 0, 24], [0, 40.0, 18], [0, 0, 1]])
    cams = [Camera(K=K, camera_to_world=look_at((0.0, 0.0, -d), (0.0, 0.0, 0.0),
                                                up=(0.0, -1.0, 0.0)), width=48, height=36)
            for d in distances]
    return wall, cams


def test_static_content_is_shared_by_the_views_that_see_it():
    # Two cameras, one twice as far, each image the wall's own render: both views see its
    # Gaussians agreeing (static content), and they are shared (-1). The Gaussian that only
    # the far camera sees (beyond the near one's image) goes to the far one.
    from clearsplat.render import render

    wall, cams = _wall_and_cameras((2.0, 4.0))
    images = [render(wall, cam).rgb for cam in cams]
    a = associate_fused(wall, cams, images)
    assert (a.view_id[:-1] == -1).mean() > 0.8 and a.view_id[-1] == 1
    assert a.summary().endswith(f"{np.sum(a.view_id == -1)} shared by several views, "
                                f"{np.sum(a.ambiguous)} ambiguous")
    # Each view's exclusion render keeps the shared wall: it differs from the view's image
    # only where the view's own (unshared) Gaussians are.
    scene = a.to_scene(wall, cams, images)
    for i, cam in enumerate(cams):
        excl = render(scene, cam, keep=scene.view_id != i).rgb
        own = render(scene, cam, keep=scene.view_id == i).alpha > 1e-3
        assert np.abs(excl - images[i])[~own].max() < 1e-5
        assert (~own).mean() > 0.5


def test_content_most_of_its_views_disagree_with_goes_to_the_view_that_sees_it_most():
    # Four cameras see the wall; the images of two show it, the other two a wall of another
    # colour there (as a transient two frames caught looks to the others). Two agreeing views
    # of four are not most of them: each Gaussian goes to the camera that sees it most, the
    # nearest. With three of four agreeing, the wall is shared.
    from clearsplat.render import render

    wall, cams = _wall_and_cameras((2.0, 2.5, 3.0, 3.5))
    shown = [render(wall, cam).rgb for cam in cams]
    other = [np.full_like(im, 0.1) for im in shown]
    two = associate_fused(wall, cams, shown[:2] + other[2:])
    seen_by_all = np.flatnonzero(np.abs(wall.means[:, 0]) < 1.0)
    assert (two.view_id[seen_by_all] == 0).mean() > 0.8
    three = associate_fused(wall, cams, shown[:3] + other[3:])
    assert (three.view_id[seen_by_all] == -1).mean() > 0.8


def test_the_filter_maps_no_region_to_shared_gaussians():
    # A fused export with its association recovered: shared Gaussians are in no candidate's
    # region (only expansion may take one with a distractor), and the filter still finds the
    # distractors.
    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors

    world = make_world("street", num_views=4, height=64, width=112, seed=0)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    truth = distractor_truth(scene, world)
    fused, voxel, _ = AQ.voxel_fused_export(scene, seed=0)
    distractor = np.bincount(voxel, truth.astype(float)) / np.bincount(voxel) > 0.5
    fs = associate_fused(fused, world.cameras, world.images).to_scene(
        fused, world.cameras, world.images)
    shared = fs.view_id == -1
    assert shared[fs.pixel_id < 0].mean() > 0.3           # of the voxels of several pixels
    res = filter_distractors(fs, config=FilterConfig(), extractor=get_extractor("local"))
    assert res.candidates and all(not shared[c.gaussians].any() for c in res.candidates)
    assert res.removed[distractor].mean() > 0.5
    assert res.removed[shared].mean() < 0.01


def _slow_unhidden(pixel, weight, depth, margin):
    out = []
    for i in range(len(weight)):
        pair = [j for j in range(len(weight)) if pixel[j] == pixel[i]]
        before = [j for j in pair if j < i]
        alpha = weight[i] / (1.0 - sum(weight[j] for j in before))
        t = 1.0
        for j in before:
            if depth[j] < (1.0 - margin) * depth[i]:
                t *= 1.0 - weight[j] / (1.0 - sum(weight[m] for m in before if m < j))
        out.append(alpha * t)
    return np.array(out)


@pytest.mark.parametrize("seed", range(4))
def test_unhidden_weights_match_a_loop(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    pixel = np.sort(rng.integers(0, 40, 300))
    depth = np.empty(300)
    weight = np.empty(300)
    for p in np.unique(pixel):
        at = np.flatnonzero(pixel == p)
        depth[at] = np.sort(rng.uniform(1.0, 1.3, len(at)))       # front to back
        alpha = rng.uniform(0.05, 0.99, len(at))
        weight[at] = alpha * np.concatenate([[1.0], np.cumprod(1.0 - alpha)[:-1]])
    got = assoc._unhidden_weights(pixel, weight.astype(np.float32), depth)
    want = _slow_unhidden(pixel, weight.astype(np.float32).astype(float), depth,
                          assoc.HIDDEN_DEPTH)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-9)
    # With no margin it is the render's own weight.
    monkeypatch.setattr(assoc, "HIDDEN_DEPTH", 0.0)
    same = assoc._unhidden_weights(pixel, weight.astype(np.float32), depth)
    np.testing.assert_allclose(same, weight, rtol=1e-4, atol=1e-7)


def test_a_surface_does_not_hide_its_own_gaussians():
    # Two Gaussians at one pixel, opacities 0.8 and 0.5: the second 3 % behind the first is of
    # the same surface (weight 0.5, its opacity); 10 % behind, the first hides it (0.5 x 0.2).
    weight = np.array([0.8, 0.5 * 0.2])
    for behind, want in ((1.03, 0.5), (1.10, 0.1)):
        got = assoc._unhidden_weights(np.array([7, 7]), weight, np.array([2.0, 2.0 * behind]))
        np.testing.assert_allclose(got, [0.8, want], rtol=1e-12)
    # Pixels do not hide each other.
    got = assoc._unhidden_weights(np.array([3, 4]), np.array([0.8, 0.5]), np.array([2.0, 9.0]))
    np.testing.assert_allclose(got, [0.8, 0.5])
    assert len(assoc._unhidden_weights(np.zeros(0, int), np.zeros(0), np.zeros(0))) == 0


def test_a_wall_right_behind_another_is_seen_by_the_view_that_shows_it():
    # A copy of a wall along the camera's rays, 1 % farther: each copy covers the same pixels
    # as its original, which hides it in the render (opacity 0.9), yet the view sees it as
    # much as the original. 20 % farther, the front wall hides it: its weight at each pixel is
    # its own opacity there times the front wall's transmittance.
    from clearsplat import Gaussians
    from clearsplat.render import prepare, render

    wall, cams = _wall_and_cameras((2.0,))
    wall = dataclasses.replace(wall, scales=np.full_like(wall.scales, 0.02),
                               opacities=np.full_like(wall.opacities, 0.9))
    eye = cams[0].position
    images = [np.full((36, 48, 3), 0.6)]
    n = len(wall)
    inside = np.flatnonzero(np.abs(wall.means[:, 0]) < 0.4)
    for gap in (0.01, 0.2):
        both = Gaussians(means=np.r_[wall.means, eye + (wall.means - eye) * (1 + gap)],
                         scales=np.r_[wall.scales, wall.scales * (1 + gap)],
                         **{f: np.r_[getattr(wall, f), getattr(wall, f)]
                            for f in ("quats", "opacities", "sh")})
        total, _ = assoc._view_sums(both, both.means.astype(np.float64), cams, images,
                                    settings=None, num_threads=1)
        front, behind = (total[inside, 0].astype(float), total[n + inside, 0].astype(float))
        if gap < assoc.HIDDEN_DEPTH:
            np.testing.assert_allclose(behind, front, rtol=2e-3)
        else:
            through = 1.0 - render(wall, cams[0]).alpha.ravel()
            for k, i in enumerate(inside[::9]):
                alone = prepare(both.subset([n + i]), cams[0]).contributions(
                    np.ones((36, 48), dtype=bool))
                want = np.sum(alone.weight * through[alone.pixel])
                np.testing.assert_allclose(behind[9 * k], want, rtol=2e-3)
            assert np.all(behind < 0.5 * front)


def test_one_pixel_gaussians_are_taken_only_where_real(prediction):
    # A per-pixel prediction with every other Gaussian moved off its pixel's ray (as a fusion
    # moves a voxel of several pixels): those on their ray get their view and pixel. A trained
    # scene's centres (every one moved) lie on pixel centres by chance only: none is taken.
    world, scene = prediction
    g = scene.gaussians
    rng = np.random.default_rng(0)
    means = g.means.astype(np.float64)
    # About 2 % of each one's distance from its camera: pixels off its ray.
    reach = 0.02 * np.linalg.norm(means - world.cameras[0].position, axis=1, keepdims=True)
    step = rng.normal(size=means.shape) * reach
    moved = means + step * (np.arange(len(g)) % 2 == 1)[:, None]
    hit, view, pixel = assoc._one_pixel_gaussians(moved, world.cameras)
    on_ray = np.arange(len(g)) % 2 == 0
    assert hit[on_ray].mean() > 0.99
    assert hit[~on_ray].mean() < 2 * 8 * (2 * CENTRE_TOLERANCE) ** 2
    assert np.array_equal(view[hit & on_ray], scene.view_id[hit & on_ray])
    assert np.array_equal(pixel[hit & on_ray], scene.pixel_id[hit & on_ray])
    everywhere = means + step
    hit, _, _ = assoc._one_pixel_gaussians(everywhere, world.cameras)
    assert not hit.any()
    _, _, best, _ = assoc._nearest_centres(everywhere, world.cameras)
    assert (best <= CENTRE_TOLERANCE).any()           # chance hits there were, none taken


def test_gaussians_no_camera_renders_face_a_camera():
    world = make_world("object", num_views=4, height=32, width=48, seed=0)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    g = scene.gaussians.subset(np.arange(0, len(scene), 7))
    cam = world.cameras[2]
    behind = cam.position - 30.0 * cam.camera_to_world[:3, 2]      # far behind every camera
    g.means[:3] = behind + np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]])
    local = [c.to_camera(g.means[:3]) for c in world.cameras]
    assert all((p[:, 2] < 0).all() for p in local)
    a = associate_fused(g, world.cameras, world.images)
    assert a.ambiguous[:3].all() and not a.ambiguous.all()
    # Behind every camera: the one whose optical axis points most towards it.
    cosine = np.stack([p[:, 2] / np.linalg.norm(p, axis=1) for p in local])
    assert np.array_equal(a.view_id[:3], np.argmax(cosine, axis=0))
    # In front of some: the one it projects nearest the image centre of.
    h = np.array([[0.05, 0.02, 0.3]])
    half = np.array([world.width / 2, world.height / 2])
    want = np.argmin([np.max(np.abs(c.project(h)[0][0] - half) / half)
                      if c.to_camera(h)[0, 2] > 0 else np.inf for c in world.cameras])
    assert assoc._facing_view(h, world.cameras)[0] == want


# ------------------------------------------------------------------------------------------------
# the association itself and bad input
# ------------------------------------------------------------------------------------------------
def test_summary_counts():
    a = Association(np.zeros(123_456, np.int64), np.full(123_456, -1, np.int64),
                    np.arange(123_456) < 3_455)
    assert a.summary() == ("associated 123,456 Gaussians from geometry: 120,001 got a view, "
                           "3,455 ambiguous")
    shared = Association(np.where(np.arange(123_456) < 100_000, -1, 0), np.full(123_456, -1),
                         np.zeros(123_456, bool), "images")
    assert shared.summary() == ("associated 123,456 Gaussians from images: 23,456 got a view, "
                                "100,000 shared by several views, 0 ambiguous")
    pixels = Association(shared.view_id, np.where(np.arange(123_456) >= 120_000, 5, -1),
                         shared.ambiguous, "images")
    assert pixels.summary() == ("associated 123,456 Gaussians from images: 23,456 got a view "
                                "(3,456 with their pixel), 100,000 shared by several views, "
                                "0 ambiguous")


def test_empty_export():
    world = make_world("object", num_views=2, height=32, width=48, seed=0)
    a = associate_ordered(np.zeros((0, 3)), world.cameras)
    assert len(a) == 0 and a.summary().startswith("associated 0 Gaussians")
    a = associate_centred(np.zeros((0, 3)), world.cameras)
    assert len(a) == 0 and a.pixel_id.dtype == np.int64


@pytest.fixture(scope="module")
def small():
    world = make_world("object", num_views=3, height=32, width=48, seed=1)
    return world, reconstruct(world.cameras, world.images, world.depths, seed=1)


def test_nan_means_are_refused(small):
    world, scene = small
    means = scene.gaussians.means.copy()
    means[5, 1] = np.nan
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(means, world.cameras)
    assert e.value.field == "means" and "vertex 5" in str(e.value)
    g = scene.gaussians.subset(np.arange(len(scene)))
    g.means[5, 1] = np.nan
    with pytest.raises(ClearsplatError) as e:
        associate_fused(g, world.cameras, world.images)
    assert e.value.field == "means"
    with pytest.raises(ClearsplatError) as e:
        associate_centred(means, world.cameras)
    assert e.value.field == "means" and "vertex 5" in str(e.value)


def test_cameras_that_see_none_of_the_vertices_are_refused(small):
    world, scene = small
    away = [Camera(K=c.K, camera_to_world=c.camera_to_world @ np.diag([-1.0, 1.0, -1.0, 1.0]),
                   width=c.width, height=c.height) for c in world.cameras]   # turned around
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(scene.gaussians.means, away)
    assert e.value.field == "cameras"
    with pytest.raises(ClearsplatError, match="0.0 % of the vertices") as e:
        associate_centred(scene.gaussians.means, away)
    assert e.value.field == "cameras"
    a = associate_centred(scene.gaussians.means, away, min_seen=0.0)
    assert a.ambiguous.all() and (a.pixel_id == -1).all()


def test_mismatched_images_are_refused(small):
    world, scene = small
    images = list(world.images)
    images[1] = images[1][:-1]
    with pytest.raises(ClearsplatError) as e:
        associate_fused(scene.gaussians, world.cameras, images)
    assert e.value.field == "images[1]"
    with pytest.raises(ClearsplatError) as e:
        associate_fused(scene.gaussians, world.cameras, world.images[:2])
    assert e.value.field == "images"
    with pytest.raises(ClearsplatError) as e:
        associate_fused(scene.gaussians, world.cameras, None)
    assert e.value.field == "images"


@pytest.mark.parametrize("views, message", [([0, 5], "distinct camera indices"),
                                            ([1, 1], "distinct camera indices"),
                                            ([], "non-empty"), ([0.5], "non-empty")])
def test_bad_views_are_refused(small, views, message):
    world, scene = small
    with pytest.raises(ClearsplatError, match=message) as e:
        associate_ordered(scene.gaussians.means, world.cameras, views=views)
    assert e.value.field == "views"


@pytest.mark.parametrize("kwargs, field", [({"max_offset": 0}, "max_offset"),
                                           ({"max_offset": -1.0}, "max_offset"),
                                           ({"max_offset": np.inf}, "max_offset"),
                                           ({"min_seen": 1.5}, "min_seen")])
def test_bad_options_are_refused(small, kwargs, field):
    world, scene = small
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(scene.gaussians.means, world.cameras, **kwargs)
    assert e.value.field == field


@pytest.mark.parametrize("kwargs, field", [({"min_seen": 1.5}, "min_seen"),
                                           ({"min_seen": -0.1}, "min_seen"),
                                           ({"min_seen": np.nan}, "min_seen")])
def test_bad_centred_options_are_refused(small, kwargs, field):
    world, scene = small
    with pytest.raises(ClearsplatError) as e:
        associate_centred(scene.gaussians.means, world.cameras, **kwargs)
    assert e.value.field == field


def test_bad_shapes_and_cameras_are_refused(small):
    world, scene = small
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(scene.gaussians.means[:, :2], world.cameras)
    assert e.value.field == "means"
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(scene.gaussians.means, [])
    assert e.value.field == "cameras"
    with pytest.raises(ClearsplatError) as e:
        associate_ordered(scene.gaussians.means, [world.cameras[0], "camera"])
    assert e.value.field == "cameras[1]"
    with pytest.raises(ClearsplatError) as e:
        associate_centred(scene.gaussians.means[:, :2], world.cameras)
    assert e.value.field == "means"
    with pytest.raises(ClearsplatError) as e:
        associate_centred(scene.gaussians.means, [])
    assert e.value.field == "cameras"
    with pytest.raises(ClearsplatError) as e:
        associate_fused(scene.gaussians.means, world.cameras, world.images)
    assert e.value.field == "gaussians"
    with pytest.raises(ClearsplatError) as e:
        Association(scene.view_id[:3], scene.pixel_id[:3], np.zeros(3, bool)).to_scene(
            scene.gaussians, world.cameras)
    assert e.value.field == "gaussians"


def test_view_choice_does_not_depend_on_the_chunk(monkeypatch):
    """The view choice works through the Gaussians a chunk of rows at a time: the same result
    whatever the chunk."""
    from clearsplat.adapters import associate as assoc
    rng = np.random.default_rng(7)
    total = rng.uniform(0, 2, (1000, 5)).astype(np.float16)
    total[rng.random(total.shape) < 0.3] = 0
    agreeing = (total * rng.uniform(0, 1, total.shape)).astype(np.float16)
    whole = assoc._choose_views(total, agreeing)
    monkeypatch.setattr(assoc, "_CHUNK", 7)
    chunked = assoc._choose_views(total, agreeing)
    for a, b in zip(whole, chunked):
        np.testing.assert_array_equal(a, b)
    assert (whole[0] == -1).any() and whole[1].any() and whole[2].any()


@pytest.mark.parametrize("call, option", [
    ("ordered", "max_offset"), ("ordered", "min_seen"), ("centred", "min_seen")])
@pytest.mark.parametrize("value", ["a lot", None, True, float("nan"), -1.0])
def test_options_that_are_not_numbers_in_range_are_one_line(call, option, value):
    from clearsplat.adapters import associate_centred, associate_ordered
    cam = Camera(K=np.array([[20.0, 0, 6], [0, 20.0, 5], [0, 0, 1]]),
                 camera_to_world=look_at(np.array([0.0, -3, 0]), (0, 0, 0)), width=12, height=10)
    means = np.zeros((3, 3))
    if call == "ordered":
        run = lambda: associate_ordered(means, [cam], **{option: value})   # noqa: E731
    else:
        run = lambda: associate_centred(means, [cam], **{option: value})   # noqa: E731
    with pytest.raises(ClearsplatError) as e:
        run()
    assert e.value.field == option


def test_the_benchmark_runs_on_the_messier_backbone(capsys):
    """``association_quality.py --realism``: both exports of a world from the messier stand-in
    backbone, in both tables, without the (plain) video-like capture."""
    def rows(realism):
        assert AQ.main(["--views", "3", "--families", "object", "--resolution", "48x64",
                        "--realism", realism]) == 0
        out = capsys.readouterr().out
        assert "other voxels removed on every scene" in out
        return [x for x in out.splitlines() if x.startswith("| object | 3 | 0 |")], out

    messy, out = rows("all")
    assert len(messy) == 2 and "| video |" not in out
    plain, out = rows("plain")
    assert len(plain) == 2 and "| video |" in out
    # Another prediction: the Depth Anything 3-style export keeps another number of vertices.
    assert messy[0].split("|")[4] != plain[0].split("|")[4], (messy[0], plain[0])
    with pytest.raises(SystemExit):
        AQ.main(["--realism", "multi"])          # not one Gaussian per pixel: refused


def test_the_fused_association_reports_its_progress():
    world = make_world("street", num_views=3, height=24, width=32, seed=1)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    calls = []
    a = associate_fused(scene.gaussians, world.cameras, world.images,
                        progress=lambda *c: calls.append(c))
    assert calls == [("associate", v, 3) for v in (1, 2, 3)]
    b = associate_fused(scene.gaussians, world.cameras, world.images)
    assert np.array_equal(a.view_id, b.view_id)
