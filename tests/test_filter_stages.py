"""Each stage of the filter on small hand-built inputs (no rendering needed)."""

import numpy as np
import pytest

from clearsplat.features import upsample_nearest
from clearsplat.filter import FilterConfig
from clearsplat.filter.masks import dilate
from clearsplat.filter.proposal import (cell_index_map, connected_regions, patch_means,
                                        propose_view, proposal_ranges, support_condition)
from clearsplat.filter.verify import Partial, change_weighted_terms
from clearsplat import ClearsplatError, Scene


def test_cell_index_map_covers_every_cell_evenly():
    cells = cell_index_map((4, 7), 64, 112)
    assert cells.shape == (64, 112)
    counts = np.bincount(cells.ravel())
    assert counts.shape == (28,) and (counts == 256).all()
    assert cells[0, 0] == 0 and cells[63, 111] == 27 and cells[16, 0] == 7


def test_patch_means_against_loop():
    rng = np.random.default_rng(0)
    vals = rng.random((32, 48))
    valid = rng.random((32, 48)) > 0.3
    cells = cell_index_map((2, 3), 32, 48)
    mean, count = patch_means(vals, cells, 6, valid)
    for c in range(6):
        sel = (cells == c) & valid
        assert count[c] == sel.sum()
        assert mean[c] == pytest.approx(vals[sel].mean())


def test_support_needs_opacity_and_a_farther_surface():
    h, w = 32, 32
    alpha = np.ones((h, w), np.float32)
    z_full = np.full((h, w), 2.0, np.float32)
    z_excl = np.full((h, w), 5.0, np.float32)
    alpha[:16, :16] = 0.3            # cell (0,0): too transparent after exclusion
    z_excl[:16, 16:] = 1.0           # cell (0,1): exclusion reveals a nearer surface
    z_full[16:, :16] = 0.0           # cell (1,0): no valid depth before exclusion
    g = support_condition(alpha, z_full, z_excl, (2, 2), eta=0.5)
    assert g.tolist() == [[False, False], [False, True]]


def test_support_averages_over_pixels_valid_in_both():
    alpha = np.ones((16, 16), np.float32)
    z_full = np.full((16, 16), 3.0, np.float32)
    z_excl = np.full((16, 16), 2.0, np.float32)
    # Only the pixels valid in both count: there the full render is nearer.
    z_full[:8] = 1.0
    z_excl[8:] = 0.0
    assert support_condition(alpha, z_full, z_excl, (1, 1), eta=0.5)[0, 0]


def test_support_is_the_strict_comparison_of_the_patch_mean_depths():
    rng = np.random.default_rng(3)
    h, w = 48, 64                                  # a 3x4 grid of 16-px cells
    alpha = np.ones((h, w), np.float32)
    z_full = rng.uniform(1.0, 8.0, (h, w))
    cells = cell_index_map((3, 4), h, w)
    # Each cell's exclusion render is its full render scaled by 1 + r: the patch means keep the
    # ratio, so the closed form is r > 0.
    r = np.array([-1e-3, 0.0, 2e-7, 5e-5, 2e-4, 9e-4, 1.1e-3, 5e-3, 9e-3, 1.1e-2, 0.05, 0.3])
    z_excl = z_full * (1.0 + r[cells])
    g = support_condition(alpha, z_full, z_excl, (3, 4), eta=0.5)
    assert g.ravel().tolist() == (r > 0).tolist()
    # The strict comparison of the patch means, bit for bit.
    z_excl = z_full.copy()
    z_excl[:16, :16] = np.nextafter(z_full[:16, :16], np.inf)
    g = support_condition(alpha, z_full, z_excl, (3, 4), eta=0.5)
    assert g.ravel().tolist() == [True] + [False] * 11


def test_ranges_are_split_at_tau1_and_tau2():
    s = np.array([[0.1, 0.5, 0.69, 0.7, 0.9]], np.float32)
    sup = np.ones_like(s, bool)
    assert proposal_ranges(s, sup, tau1=0.5, tau2=0.7).tolist() == [[1, 2, 2, 0, 0]]
    assert proposal_ranges(s, sup, tau1=0.5, tau2=0.7, second_range=False).tolist() == \
        [[1, 0, 0, 0, 0]]
    assert proposal_ranges(s, sup, tau1=0.5, tau2=0.7, single_threshold=True).tolist() == \
        [[1, 1, 1, 0, 0]]
    sup[0, 0] = False
    assert proposal_ranges(s, sup, tau1=0.5, tau2=0.7)[0, 0] == 0


def test_components_are_eight_connected_and_ranges_never_merge():
    r = np.array([[1, 0, 0, 2],
                  [0, 1, 0, 2],
                  [0, 0, 0, 0],
                  [1, 1, 2, 0]], np.int8)
    ones = connected_regions(r, 1)
    twos = connected_regions(r, 2)
    assert len(ones) == 2           # the diagonal pair joins (8-connectivity)
    assert ones[0][0, 0] and ones[0][1, 1]
    assert len(twos) == 2           # (3,2) touches range-1 cells but stays apart
    assert sum(m.sum() for m in ones) == 4 and sum(m.sum() for m in twos) == 3


def test_propose_view_upsamples_components_to_pixels():
    sim = np.ones((2, 3), np.float32)
    sim[0, 1] = 0.2
    sim[1, 2] = 0.6
    alpha = np.ones((32, 48), np.float32)
    zf = np.ones((32, 48), np.float32)
    ze = np.full((32, 48), 2.0, np.float32)
    p = propose_view(0, sim, alpha, zf, ze, eta=0.5, tau1=0.5, tau2=0.7)
    assert [r.range for r in p.regions] == [1, 2]
    assert p.mask1.sum() == 256 and p.mask1[:16, 16:32].all()
    assert p.mask2.sum() == 256 and p.mask2[16:, 32:].all()
    assert not (p.mask1 & p.mask2).any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_regions_hold_cells_and_masks_are_their_union(seed):
    """Each region makes its pixels from its cells on each read (read-only), and the view's
    masks are the union of its regions' pixels, on an uneven grid (37x53 pixels, 5x7 cells)."""
    import pickle

    from clearsplat.filter.result import Candidate
    rng = np.random.default_rng(seed)
    sim = rng.random((5, 7)).astype(np.float32)
    h, w = 37, 53
    alpha = np.ones((h, w), np.float32)
    zf = np.ones((h, w), np.float32)
    ze = np.full((h, w), 2.0, np.float32)
    p = propose_view(0, sim, alpha, zf, ze, eta=0.5, tau1=0.3, tau2=0.6)
    assert p.regions
    union = {1: np.zeros((h, w), bool), 2: np.zeros((h, w), bool)}
    for r in p.regions:
        px = r.pixels
        assert px.shape == (h, w) and not px.flags.writeable
        np.testing.assert_array_equal(px, upsample_nearest(r.cells, h, w))
        union[r.range] |= px
    np.testing.assert_array_equal(p.mask1, union[1])
    np.testing.assert_array_equal(p.mask2, union[2])
    # A candidate made from a region reads the same pixels, also after pickling (Ray).
    c = Candidate(0, 0, p.regions[0].range, p.regions[0], np.zeros(0, np.int64))
    np.testing.assert_array_equal(c.pixels, p.regions[0].pixels)
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(c)).pixels, c.pixels)
    # One given as an array keeps that array.
    arr = np.zeros((h, w), bool)
    assert Candidate(1, 0, 1, arr, np.zeros(0, np.int64)).pixels is arr
    with pytest.raises(TypeError):
        Candidate(2, 0, 1)


def test_score_closed_form():
    # Two pixels: removing the candidate fixes one (error 0.6 -> 0) and harms another.
    image = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]], np.float32)
    base = np.array([[0.2, 0.2, 0.2], [0.5, 0.5, 0.5]], np.float32)
    after = np.array([[0.0, 0.0, 0.0], [0.6, 0.5, 0.5]], np.float32)
    p = change_weighted_terms(base, after, image, np.zeros(2, bool), 0.002)
    # w = [0.6, 0.1]; delta = [0.6, -0.1]
    assert p.num == pytest.approx(0.6 * 0.6 - 0.1 * 0.1)
    assert p.den == pytest.approx(0.7)
    assert p.score == pytest.approx((0.36 - 0.01) / 0.7)
    # Excluding the improved pixel leaves only harm: negative score.
    q = change_weighted_terms(base, after, image, np.array([True, False]), 0.002)
    assert q.score == pytest.approx(-0.1)


def test_score_ignores_changes_below_epsilon_and_is_zero_without_weight():
    image = np.zeros((3, 3), np.float32)
    base = np.full((3, 3), 0.1, np.float32)
    after = base + np.float32(0.0005)   # w = 0.0015 <= epsilon everywhere
    p = change_weighted_terms(base, after, image, np.zeros(3, bool), 0.002)
    assert p.den == 0 and p.score == 0.0
    assert Partial().score == 0.0
    pooled = Partial(1.0, 2.0)
    pooled.add(Partial(-3.0, 2.0))          # pooled over views: sums, then the ratio
    assert pooled.score == pytest.approx(-0.5)


def test_dilate_is_a_disk():
    m = np.zeros((41, 41), bool)
    m[20, 20] = True
    d = dilate(m, 9)
    yy, xx = np.mgrid[:41, :41]
    assert np.array_equal(d, (yy - 20) ** 2 + (xx - 20) ** 2 <= 81)
    assert np.array_equal(dilate(m, 0), m)


@pytest.mark.parametrize("seed", range(4))
def test_dilate_matches_full_image_dilation(seed):
    from scipy import ndimage
    rng = np.random.default_rng(seed)
    m = np.zeros((40, 56), bool)
    r0, c0 = rng.integers(0, 36), rng.integers(0, 52)   # regions may touch the border
    m[r0:r0 + rng.integers(1, 6), c0:c0 + rng.integers(1, 6)] = True
    yy, xx = np.mgrid[-9:10, -9:10]
    full = ndimage.binary_dilation(m, structure=(yy * yy + xx * xx) <= 81)
    assert np.array_equal(dilate(m, 9), full)


def test_config_presets_and_validation():
    paper = FilterConfig.preset("paper")
    assert (paper.tau1, paper.tau2) == (None, None) and paper.features == "dinov3"
    assert paper.verify_base == "full" and paper.num_verify_views == 3
    assert paper.eta == 0.5 and paper.epsilon == 0.002 and paper.dilation == 9
    assert FilterConfig.preset("paper", features="local").features == "local"
    with pytest.raises(ClearsplatError, match="preset"):
        FilterConfig.preset("nope")
    with pytest.raises(ClearsplatError, match="verify_base"):
        FilterConfig(verify_base="sometimes")
    with pytest.raises(ClearsplatError, match="unknown option"):
        FilterConfig().replace(colour="red")
    with pytest.raises(ClearsplatError, match="tau1"):
        FilterConfig(tau1=0.8, tau2=0.7)


def test_view_index_gathers_the_gaussians_of_a_region():
    from clearsplat import Camera, Gaussians, Scene
    from clearsplat.filter.association import ViewIndex, region_gaussians
    rng = np.random.default_rng(3)
    cams = [Camera(K=[[20.0, 0, 6], [0, 20.0, 4], [0, 0, 1]], camera_to_world=np.eye(4),
                   width=12, height=8) for _ in range(3)]
    n = 500
    view = rng.integers(0, 3, n)
    pixel = rng.integers(0, 96, n)            # several Gaussians per pixel, some pixels empty
    g = Gaussians(rng.normal(size=(n, 3)) + [0, 0, 5], np.full((n, 3), 0.1),
                  np.tile([1.0, 0, 0, 0], (n, 1)), np.full(n, 0.5), np.zeros((n, 1, 3)))
    scene = Scene(g, view, pixel, cams)
    index = ViewIndex(scene)
    for v in range(3):
        region = rng.random((8, 12)) < 0.3
        expected = np.flatnonzero((view == v) & region.ravel()[pixel])
        assert np.array_equal(region_gaussians(scene, v, region, index=index), expected)


@pytest.mark.parametrize("seed", [0, 1])
def test_region_map_equals_region_gaussians_for_gaussians_without_pixel(seed):
    """A round's RegionMap reads each view's whole-image contributions once; every region maps
    to exactly what region_gaussians composites for it alone, aligned and loose Gaussians mixed."""
    from types import SimpleNamespace

    from clearsplat.filter.association import RegionMap, ViewIndex, region_gaussians
    from clearsplat.render import prepare
    from clearsplat.synth import make_world
    from clearsplat.synth.realism import realistic_reconstruction
    world = make_world("object", num_views=3, seed=seed, height=48, width=80)
    scene, _ = realistic_reconstruction(world, "coarse", seed=seed)
    rng = np.random.default_rng(seed)
    pixel_id = scene.pixel_id.copy()
    pixel_id[rng.random(len(scene)) < 0.3] = -1      # some per-pixel ones lose their pixel too
    scene = Scene(scene.gaussians, scene.view_id, pixel_id, scene.cameras, scene.images,
                  scene.render_settings)
    index = ViewIndex(scene)
    views = [prepare(scene, cam) for cam in scene.cameras]
    region_map = RegionMap(SimpleNamespace(scene=scene, index=index, views=views))
    assert any(region_map.loose)
    for v in range(scene.num_views):
        for share in (0.0, 0.05, 0.4):
            region = rng.random((48, 80)) < share
            expected = region_gaussians(scene, v, region, index=index, prepared=views[v])
            got = region_map(v, region)
            assert got.dtype == np.int64 and np.array_equal(got, expected)
