"""The diagnostic scripts of benchmarks/: missed_distractors.py (where a missed Gaussian lies
against the static reference, and where removed static Gaussians lie against the clean surface),
real_image_removals.py (what the real-image check removes beside the pasted object) and
reference_reveal.py (what R_i^-i and a median over neighbours reveal behind a view's own)."""

from __future__ import annotations

import importlib.util
import os
import warnings

import numpy as np
import pytest

from clearsplat.filter import FilterConfig
from clearsplat.filter.association import ViewIndex
from clearsplat.synth import make_world, reconstruct
from clearsplat.synth.stereo import real_image_check

BENCHMARKS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                          "benchmarks")


def _script(name: str = "missed_distractors"):
    spec = importlib.util.spec_from_file_location(name, os.path.join(BENCHMARKS, name + ".py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_gaussians_moved_along_their_ray_are_placed_against_the_reference():
    world = make_world("object", num_views=3, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    cam = scene.cameras[0]
    g = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 24))[0]
    h = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 20))[0]
    centre = cam.camera_to_world[:3, 3]
    means = scene.gaussians.means
    means[g] = centre + 0.5 * (means[g] - centre)     # halfway to the camera: in front
    means[h] = centre + 3.0 * (means[h] - centre)     # three times as far: behind
    lost = np.zeros(len(scene), dtype=bool)
    lost[[g, h]] = True
    names = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02)
    got = dict(zip(np.flatnonzero(lost).tolist(), names))
    assert got[g] == "refined away: in front by more"
    assert got[h] == "refined away: behind the static reference"
    # Where the reveal reference applies it is the reference: a reveal depth far beyond both
    # puts both in front, one at the camera puts both behind; where it does not, as before.
    pixels = scene.cameras[0].height * scene.cameras[0].width
    for depth, where, expect in ((1e6, True, ("in front by more", "in front by more")),
                                 (1e-6, True, ("behind the static reference",) * 2),
                                 (1e-6, False, ("in front by more",
                                                "behind the static reference"))):
        reveal = [(np.full(pixels, depth), np.full(pixels, where))] * scene.num_views
        names = _script()._against_reference(scene, ViewIndex(scene), lost,
                                              np.zeros(len(scene), dtype=bool), 0.02,
                                              reveal=reveal)
        got = dict(zip(np.flatnonzero(lost).tolist(), names))
        assert (got[g], got[h]) == tuple("refined away: " + e for e in expect)


def _assert_reveal_depths(scene, out, allowed, min_views):
    """``out`` (the script's ``_reveal_depths``) equals the library's reveal reference of each
    view from its ``reveal_neighbours`` among ``allowed`` ((V, V) bool; None: every view)."""
    from clearsplat.filter.neighbours import covisibility
    from clearsplat.filter.reveal import reveal_neighbours, reveal_reference
    from clearsplat.render import prepare, render

    c = covisibility(scene)
    hoods = []
    for v, (depth, valid) in enumerate(out):
        others = reveal_neighbours(c + c.T, v, count=7,
                                   allowed=None if allowed is None else allowed[v])
        hoods.append(others)
        cam = scene.cameras[v]
        ref, where = reveal_reference(prepare(scene, cam), [scene.view_id == j for j in others],
                                      render(scene, cam, keep=scene.view_id != v),
                                      quantile=0.75, min_views=min_views)
        np.testing.assert_array_equal(valid, where.ravel())
        np.testing.assert_array_equal(depth, ref.depth.ravel())
    return hoods


def test_reveal_depths_are_the_filters_reveal_references():
    world = make_world("street", num_views=6, seed=1, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    mod = _script()
    assert mod._reveal_depths(scene, FilterConfig(reveal_reference="composite")) is None
    out = mod._reveal_depths(scene, FilterConfig())
    hoods = _assert_reveal_depths(scene, out, None, 4)
    assert all(len(others) == 5 for others in hoods)
    assert any(valid.any() for _, valid in out)


def test_reveal_depths_leave_out_the_views_beyond_the_parallax_limit(monkeypatch):
    # Six views on a 90-degree arc round the object, about 15 degrees apart: a 20-degree limit
    # leaves each view its one or two adjacent views.
    from clearsplat.filter import reveal
    from clearsplat.filter.reveal import parallax_angles, typical_depths

    world = make_world("object", num_views=6, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    monkeypatch.setattr(reveal, "MAX_ANGLE", 20.0)
    monkeypatch.setattr(reveal, "MIN_VIEWS", 1)
    out = _script()._reveal_depths(scene, FilterConfig())
    near = parallax_angles(scene.cameras, typical_depths(ViewIndex(scene).depths)) <= 20.0
    hoods = _assert_reveal_depths(scene, out, near, 1)
    for v, others in enumerate(hoods):
        assert sorted(others) == [j for j in (v - 1, v + 1) if 0 <= j < scene.num_views]


def test_in_front_is_split_as_the_first_refinement_pass_judges_it():
    # View 0 predicts every depth at 0.9 of what it did, with 5 % noise: its scale against the
    # other views drops by a tenth and its margin widens. Three of its Gaussians are then put
    # at 0.99, in the middle of the widened margin, and at 0.60 of the reference at that scale.
    from clearsplat.filter.robust import view_depth_scales
    from clearsplat.render import render

    world = make_world("object", num_views=3, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=0)
    cam = scene.cameras[0]
    centre = cam.camera_to_world[:3, 3]
    means = scene.gaussians.means
    own = np.flatnonzero(scene.view_id == 0)
    rng = np.random.default_rng(1)
    means[own] = centre + 0.9 * np.exp(rng.normal(0.0, 0.05, own.size))[:, None] * (
        means[own] - centre)
    ref = render(scene, cam, keep=scene.view_id != 0).depth.ravel()[scene.pixel_id[own]]
    z = cam.to_camera(means[own])[:, 2]
    scale, spread = view_depth_scales([z], [ref])[0]
    widened = 1.0 - np.exp(-2.5 * spread)
    assert scale < 0.97 and widened > 0.08
    picks = {}
    for k, (row, f) in enumerate(((16, 0.99), (20, 1.0 - (0.02 + widened) / 2), (24, 0.60))):
        i = np.flatnonzero(scene.pixel_id[own] == row * 48 + 24)[0]
        assert ref[i] > 0
        means[own[i]] = centre + (f * scale * ref[i] / z[i]) * (means[own[i]] - centre)
        picks[own[i]] = k
    lost = np.zeros(len(scene), dtype=bool)
    lost[list(picks)] = True
    margins = {}
    names = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02,
                                          align_scale=True, margins=margins)
    # The view's scale and margin as measured with the three moved Gaussians among its own.
    s_after, after = view_depth_scales([cam.to_camera(means[own])[:, 2]], [ref])[0]
    assert margins == {0: (pytest.approx(s_after), pytest.approx(1.0 - np.exp(-2.5 * after)))}
    got = {picks[g]: name for g, name in zip(np.flatnonzero(lost).tolist(), names)}
    assert got == {0: "refined away: in front, not at its view's scale",
                   1: "refined away: within its view's widened margin",
                   2: "refined away: in front by more, all the same"}
    # Without the alignment all three are simply in front by more than the margin.
    plain = _script()._against_reference(scene, ViewIndex(scene), lost,
                                          np.zeros(len(scene), dtype=bool), 0.02)
    assert set(plain) == {"refined away: in front by more"}


def test_bands_count_every_other_removed_pixel_by_its_distance_to_the_paste():
    check = real_image_check(FilterConfig(), height=96)
    mask = check["info"]["mask"]
    extra = check["removed_pixels"] & ~mask
    bands = _script("real_image_removals").removals_beside(check)
    assert sum(b["count"] for b in bands) == int(extra.sum()) > 0
    # The distance of each such pixel to the nearest pasted pixel, by brute force.
    rows, cols = np.nonzero(extra)
    pr, pc = np.nonzero(mask)
    d = np.sqrt(((rows[:, None] - pr[None]) ** 2 + (cols[:, None] - pc[None]) ** 2).min(1))
    for b in bands:
        assert b["count"] == int(((d > b["from"]) & (d <= b["to"])).sum())
        assert b["count"] == 0 or 0.0 < b["ratio"] < 2.0


def test_removed_static_gaussians_are_split_by_the_clean_surface():
    # On the clutter-free twin every Gaussian lies at the clean surface (the stand-in puts it
    # at its pixel's depth); moved along its ray it lies in front of or behind it.
    world = make_world("object", num_views=3, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.clean_images, world.clean_depths, seed=0)
    split = _script().split_by_clean_depth
    rng = np.random.default_rng(0)
    picked = np.sort(rng.choice(len(scene), size=60, replace=False))
    means = scene.gaussians.means
    factors = np.ones(picked.size)
    factors[:20], factors[20:35] = 0.8, 1.2       # 20 % nearer, 20 % farther, the rest as is
    for g, f in zip(picked, factors):
        centre = scene.cameras[int(scene.view_id[g])].camera_to_world[:3, 3]
        means[g] = centre + f * (means[g] - centre)
    scene.pixel_id[picked[-5:]] = -1                # five without a pixel
    got = split(scene, world, picked, 0.05)
    assert got == {"in front": 20, "at": 20, "behind": 15, "no pixel": 5}


def test_reference_reveal_reads_both_references_at_each_gaussians_pixel():
    from clearsplat.render import render
    world = make_world("object", num_views=4, seed=0, height=32, width=48)
    scene = reconstruct(world.cameras, world.clean_images, world.clean_depths, seed=0,
                        depth_blur=0.0, depth_noise=0.0)
    mod = _script("reference_reveal")
    cam = scene.cameras[0]
    g = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 24))[0]
    h = np.flatnonzero((scene.view_id == 0) & (scene.pixel_id == 16 * 48 + 20))[0]
    centre = cam.camera_to_world[:3, 3]
    scene.gaussians.means[g] = centre + 0.5 * (scene.gaussians.means[g] - centre)
    excl = mod.covered_depth(render(scene, cam, keep=scene.view_id != 0))
    robust = mod.quantile_reference(scene, 0, [1, 2, 3], 0.75)
    for reference in (excl, robust):    # halfway to the camera: revealed; on the surface: not
        assert mod.revealed(scene, np.array([g, h]), 0, reference, 0.05).tolist() == [True,
                                                                                      False]
    # One neighbour: its own expected depth (the render's depth, already divided by its
    # opacity) wherever it covers the pixel by more than half, at any quantile.
    one = render(scene, cam, keep=scene.view_id == 2)
    want = np.where(one.alpha.ravel() > 0.5, one.depth.ravel(), np.nan)
    for q in (0.0, 0.75):
        np.testing.assert_array_equal(mod.quantile_reference(scene, 0, [2], q), want)
    # Two neighbours: where both cover, the nearer below the quantile 1 and the farther at it;
    # where one covers, that one.
    other = render(scene, cam, keep=scene.view_id == 3)
    both = np.vstack([want, np.where(other.alpha.ravel() > 0.5, other.depth.ravel(), np.nan)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # pixels neither covers: NaN
        near, far = np.nanmin(both, axis=0), np.nanmax(both, axis=0)
    assert (near < far).any()
    np.testing.assert_array_equal(mod.quantile_reference(scene, 0, [2, 3], 0.75), near)
    np.testing.assert_array_equal(mod.quantile_reference(scene, 0, [2, 3], 1.0), far)
    assert np.isnan(mod.quantile_reference(scene, 0, [], 0.75)).all()
