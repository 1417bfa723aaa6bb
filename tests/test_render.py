"""The native rasterizer against the NumPy reference, closed forms, and its exactness contracts."""

from __future__ import annotations

import numpy as np
import pytest

import reference_rasterizer as ref
from clearsplat import Camera, ClearsplatError, Gaussians, RenderSettings, Scene
from clearsplat.cameras import look_at
from clearsplat.render import (Contributions, PreparedView, RenderResult, TilePatch,
                               contributions, prepare, render, render_batch)
from clearsplat.render.base import _TiledView
from clearsplat.scene import rgb_to_sh_dc

# Native float32 vs float64 reference.
ATOL = 1e-4


def make_camera(width, height, *, eye=(0.3, 0.2, -3.0), target=(0.0, 0.0, 0.0), f=(50.0, 55.0),
                c=None) -> Camera:
    cx, cy = c if c is not None else (width / 2 + 0.3, height / 2 - 0.2)
    return Camera(K=[[f[0], 0, cx], [0, f[1], cy], [0, 0, 1]],
                  camera_to_world=look_at(eye, target, up=(0.0, -1.0, 0.0)), width=width, height=height)


def random_gaussians(rng, n, *, k=16, spread=1.2) -> Gaussians:
    """Anisotropic Gaussians around the origin; with the default camera some are behind it
    (z < -3) and many beside the frustum."""
    means = rng.normal(size=(n, 3)) * spread
    means[: n // 10, 2] = rng.uniform(-6.0, -3.05, n // 10)  # behind the camera at z = -3
    opac = rng.uniform(0, 1, n)
    opac[:3] = (0.0, 1.0, 0.999)
    return Gaussians(means=means, scales=np.exp(rng.uniform(np.log(0.01), np.log(0.4), (n, 3))),
                     quats=rng.normal(size=(n, 4)), opacities=opac,
                     sh=rng.normal(size=(n, k, 3)) * 0.4)


def lone_gaussian(mean, scale, opacity, colour=(1.0, 0.5, 0.25)) -> Gaussians:
    return Gaussians(means=[mean], scales=[[scale] * 3], quats=[[1.0, 0, 0, 0]],
                     opacities=[opacity], sh=rgb_to_sh_dc(np.array([[colour]])))


def assert_matches_reference(g, cam, *, keep=None, background=(0.0, 0.0, 0.0), settings=None):
    out = render(g, cam, keep=keep, background=background, settings=settings)
    rgb, alpha, depth, _ = ref.render(g, cam, keep=keep, background=background,
                                      settings=settings)
    assert out.rgb.dtype == np.float32 and out.rgb.shape == (cam.height, cam.width, 3)
    assert out.alpha.shape == out.depth.shape == (cam.height, cam.width)
    np.testing.assert_allclose(out.rgb, rgb, atol=ATOL, rtol=0)
    np.testing.assert_allclose(out.alpha, alpha, atol=ATOL, rtol=0)
    # depth = D / alpha amplifies float32 rounding where alpha is tiny: compare D itself.
    np.testing.assert_allclose(out.depth * out.alpha, depth * alpha, atol=ATOL, rtol=0)
    np.testing.assert_allclose(out.depth[alpha > 0.05], depth[alpha > 0.05], atol=ATOL, rtol=1e-5)
    assert alpha.max() > 0.9 and alpha.min() < 0.5  # not a trivial image
    return out


# -- against the reference -------------------------------------------------------------------
@pytest.mark.parametrize("width,height,k,seed", [(40, 24, 1, 0), (64, 48, 4, 1), (33, 17, 9, 2),
                                                 (64, 48, 16, 3), (17, 40, 16, 4)])
def test_matches_reference(width, height, k, seed):
    rng = np.random.default_rng(seed)
    g = random_gaussians(rng, 250, k=k)
    cam = make_camera(width, height, f=(0.8 * width, 0.9 * width))
    assert_matches_reference(g, cam, background=(0.1, 0.2, 0.3))


AA = RenderSettings(antialiased=True, eps2d=0.1)


@pytest.mark.parametrize("width,height,k,seed,settings", [
    (40, 24, 1, 10, AA), (33, 17, 4, 11, AA), (24, 40, 9, 12, AA), (48, 32, 16, 13, AA),
    (40, 24, 25, 14, AA), (31, 45, 25, 15, RenderSettings()),
    (40, 24, 25, 20, RenderSettings(antialiased=True, eps2d=0.3, radius_clip=2.0)),
    (33, 21, 25, 17, RenderSettings(eps2d=0.1, sh_degree=2)),
    (40, 24, 16, 18, RenderSettings(antialiased=True, sh_degree=0))])
def test_settings_match_reference(width, height, k, seed, settings):
    # Many sub-pixel Gaussians, where antialiasing matters most (a feed-forward model's case).
    rng = np.random.default_rng(seed)
    g = random_gaussians(rng, 300, k=k)
    g.scales[::2] *= 0.05
    cam = make_camera(width, height, f=(0.8 * width, 0.9 * width))
    out = assert_matches_reference(g, cam, background=(0.1, 0.2, 0.3), settings=settings)
    if settings.antialiased or settings.eps2d != 0.3:
        classic = render(g, cam, background=(0.1, 0.2, 0.3))
        assert np.abs(classic.rgb - out.rgb).max() > 1e-2    # the settings change the image


def test_render_uses_the_scene_settings_and_settings_override_them():
    rng = np.random.default_rng(19)
    g = random_gaussians(rng, 200, k=25)
    g.scales[:] *= 0.1
    cam = make_camera(40, 24)
    scene = Scene(g, np.zeros(200, np.int32), None, [cam], render_settings=AA)
    aa = render(g, cam, settings=AA)
    for a, b in zip(render(scene, cam), aa):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(prepare(scene, cam).render(), aa):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(render_batch(scene, [cam])[0], aa):
        np.testing.assert_array_equal(a, b)
    classic = render(g, cam)
    for a, b in zip(render(scene, cam, settings=RenderSettings()), classic):
        np.testing.assert_array_equal(a, b)
    mask = np.ones((24, 40), bool)
    c = contributions(scene, cam, mask)
    np.testing.assert_array_equal(c.weight, contributions(g, cam, mask, settings=AA).weight)
    # SH degree 4 cut to 3 equals the degree-3 Gaussians.
    cut = Gaussians(g.means, g.scales, g.quats, g.opacities, g.sh[:, :16])
    for a, b in zip(render(g, cam, settings=RenderSettings(sh_degree=3)), render(cut, cam)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ClearsplatError) as e:
        render(g, cam, settings={"antialiased": True})
    assert e.value.field == "settings"


def test_classic_renders_bit_identical_to_the_saved_ones():
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent / "data"))
    try:
        import classic_renders
    finally:
        sys.path.pop(0)
    saved = np.load(classic_renders.FILE)
    for name, g, cam, keep, bg in classic_renders.cases():
        out = render(g, cam, keep=keep, background=bg)
        assert out.alpha.max() > 0.5
        for field in ("rgb", "alpha", "depth"):
            a, b = getattr(out, field), saved[f"{name}_{field}"]
            assert a.dtype == b.dtype and a.shape == b.shape
            assert a.tobytes() == b.tobytes(), (name, field)


def test_matches_reference_with_keep_and_near_camera_gaussians():
    rng = np.random.default_rng(5)
    g = random_gaussians(rng, 200, k=9)
    # Gaussians just past the near plane and across the image border.
    g.means[:20] = np.array([0.3, 0.2, -3.0]) + rng.normal(size=(20, 3)) * [0.3, 0.3, 0.02] \
        + [0, 0, 0.2]
    cam = make_camera(48, 32)
    keep = rng.uniform(size=200) < 0.7
    assert_matches_reference(g, cam, keep=keep)


def test_contributions_match_reference():
    rng = np.random.default_rng(6)
    g = random_gaussians(rng, 200, k=4)
    cam = make_camera(40, 24)
    mask = rng.uniform(size=(24, 40)) < 0.3
    keep = rng.uniform(size=200) < 0.8
    got = contributions(g, cam, mask, keep=keep)
    assert isinstance(got, Contributions)
    assert got.pixel.dtype == np.int64 and got.gaussian.dtype == np.int64
    assert got.weight.dtype == np.float32
    *_, expected = ref.render(g, cam, keep=keep, mask=mask)
    assert len(expected) > 200
    np.testing.assert_array_equal(got.pixel, [e[0] for e in expected])
    np.testing.assert_array_equal(got.gaussian, [e[1] for e in expected])
    np.testing.assert_allclose(got.weight, [e[2] for e in expected], atol=1e-5, rtol=0)
    # Weights reproduce the render at the masked pixels.
    out = render(g, cam, keep=keep)
    p = ref.project(g, cam)
    recon = np.zeros((24 * 40, 3))
    np.add.at(recon, got.pixel, p["colour"][got.gaussian] * got.weight[:, None])
    np.testing.assert_allclose(recon[mask.ravel()], out.rgb.reshape(-1, 3)[mask.ravel()],
                               atol=ATOL)
    assert set(np.unique(got.pixel)) <= set(np.flatnonzero(mask))


# -- closed forms ----------------------------------------------------------------------------
@pytest.mark.parametrize("opacity,scale,z", [(0.3, 0.02, 2.0), (0.35, 0.005, 1.0)])
def test_lone_isotropic_gaussian_profile(opacity, scale, z):
    # On the optical axis J J^T = (f / z)^2 I, so Sigma2D = (s^2 f^2 / z^2 + 0.3) I. With
    # o < exp(4.5) / 255 alpha drops below 1/255 inside the 3-sigma radius: no tile cut-off.
    f, (w, h), (cx, cy) = 60.0, (40, 30), (17.3, 13.8)
    cam = Camera(K=[[f, 0, cx], [0, f, cy], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=w, height=h)
    out = render(lone_gaussian([0, 0, z], scale, opacity), cam, background=(0.0, 0.0, 1.0))
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    r2 = (cols - cx) ** 2 + (rows - cy) ** 2
    expected = np.minimum(0.99, opacity * np.exp(-r2 / (2 * (scale**2 * f**2 / z**2 + 0.3))))
    expected[expected < 1 / 255] = 0
    np.testing.assert_allclose(out.alpha, expected, atol=1e-6, rtol=1e-5)
    np.testing.assert_allclose(out.rgb[..., 0], expected, atol=1e-6, rtol=1e-5)
    np.testing.assert_allclose(out.rgb[..., 2], 0.25 * expected + (1 - expected), atol=1e-6)
    # depth = D / (1 - T): 1 - (1 - a) in float32 loses up to eps / a relative, a >= 1/255.
    np.testing.assert_allclose(out.depth[expected > 0], z, rtol=2e-5)
    assert (out.depth[expected == 0] == 0).all()


@pytest.mark.parametrize("eps2d", [0.1, 0.3])
def test_antialiased_lone_isotropic_gaussian_closed_form(eps2d):
    # On the optical axis Sigma2D = (s^2 f^2 / z^2) I = sigma^2 I; antialiased, the footprint is
    # o * sigma^2 / (sigma^2 + eps) * exp(-r^2 / (2 (sigma^2 + eps))): the compensation
    # sqrt(det / det_blur) = sigma^2 / (sigma^2 + eps) keeps the integral o * 2 pi sigma^2.
    f, (w, h), (cx, cy), z, opacity = 60.0, (40, 30), (17.3, 13.8), 2.0, 0.8
    cam = Camera(K=[[f, 0, cx], [0, f, cy], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=w, height=h)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    r2 = (cols - cx) ** 2 + (rows - cy) ** 2
    settings = RenderSettings(antialiased=True, eps2d=eps2d)
    for scale in (0.004, 0.02, 0.05):
        var = scale**2 * f**2 / z**2
        out = render(lone_gaussian([0, 0, z], scale, opacity), cam, settings=settings)
        peak = opacity * var / (var + eps2d)
        expected = np.minimum(0.99, peak * np.exp(-r2 / (2 * (var + eps2d))))
        expected[expected < 1 / 255] = 0
        np.testing.assert_allclose(out.alpha, expected, atol=1e-6, rtol=1e-5)
        # The energy is the unblurred Gaussian's, o 2 pi sigma^2, less the tail beyond the
        # 1/255 cut-off (a fraction 1 / (255 peak) of it); the pixel grid adds a few percent.
        energy = opacity * 2 * np.pi * var * (1 - 1 / (255 * peak))
        assert out.alpha.sum() == pytest.approx(energy, rel=0.05)
    # A Gaussian whose compensated opacity is below 1/255 is culled.
    tiny = lone_gaussian([0, 0, z], 1e-4, 0.9)
    assert prepare(tiny, cam, settings=settings).num_visible == 0
    assert prepare(tiny, cam).num_visible == 1


def test_radius_clip_culls_small_footprints():
    cam = Camera(K=[[60, 0, 20], [0, 60, 15], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=40, height=30)
    g = Gaussians(means=[[0, 0, 2.0], [0.2, 0, 2.0]], scales=[[0.001] * 3, [0.1] * 3],
                  quats=[[1.0, 0, 0, 0]] * 2, opacities=[0.9, 0.9], sh=np.zeros((2, 1, 3)))
    # Radii ceil(3 sqrt(lambda)), lambda = mid + sqrt(max(0.1, mid^2 - det)): 3 for the
    # point-like one (mid = 0.3009), 10 for the other (mid = 9.3).
    assert prepare(g, cam, settings=RenderSettings(radius_clip=3)).visible.tolist() == [1]
    assert sorted(prepare(g, cam, settings=RenderSettings(radius_clip=2.9)).visible) == [0, 1]
    assert prepare(g, cam, settings=RenderSettings(radius_clip=9.9)).visible.tolist() == [1]
    assert sorted(prepare(g, cam, settings=RenderSettings(radius_clip=0.1)).visible) == [0, 1]
    assert prepare(g, cam, settings=RenderSettings(radius_clip=10)).num_visible == 0


def test_alpha_is_capped_at_099():
    cam = Camera(K=[[50, 0, 10.5], [0, 50, 8.5], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=21, height=17)
    out = render(lone_gaussian([0, 0, 1.0], 0.05, 1.0), cam)
    assert out.alpha[8, 10] == pytest.approx(0.99, abs=1e-7)
    assert out.alpha.max() == pytest.approx(0.99, abs=1e-7)


def test_world_point_lands_on_projected_pixel():
    rng = np.random.default_rng(7)
    cam = make_camera(64, 48, eye=(1.0, -0.5, -2.5), target=(0.1, 0.2, 0.3))
    points = rng.uniform(-0.6, 0.6, size=(10, 3))
    uv, z = cam.project(points)
    assert (z > 0).all() and (uv[:, 0] > 0).all() and (uv[:, 0] < 64).all()
    for p, (u, v) in zip(points, uv):
        out = render(lone_gaussian(p, 1e-4, 0.9), cam)
        row, col = np.unravel_index(np.argmax(out.alpha), out.alpha.shape)
        assert (row, col) == (int(np.floor(v)), int(np.floor(u)))


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_occlusion_follows_depth_not_index(order):
    near = lone_gaussian([0, 0, 2.0], 0.3, 0.9, colour=(1.0, 0.0, 0.0))
    far = lone_gaussian([0, 0, 4.0], 0.6, 0.9, colour=(0.0, 1.0, 0.0))
    parts = [near, far]
    g = Gaussians(*(np.concatenate([getattr(parts[i], a) for i in order])
                    for a in ("means", "scales", "quats", "opacities", "sh")))
    # Both project onto the centre of pixel (16, 16), where each has alpha 0.9.
    cam = Camera(K=[[40, 0, 16.5], [0, 40, 16.5], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=32, height=32)
    out = render(g, cam)
    np.testing.assert_allclose(out.rgb[16, 16], [0.9, 0.1 * 0.9, 0.0], atol=1e-6)
    assert out.alpha[16, 16] == pytest.approx(0.99, abs=1e-6)
    assert out.depth[16, 16] == pytest.approx((0.9 * 2.0 + 0.09 * 4.0) / 0.99, rel=1e-6)


def test_culling_near_plane_and_zero_opacity():
    cam = Camera(K=[[40, 0, 16], [0, 40, 16], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=32, height=32)
    assert render(lone_gaussian([0, 0, -1.0], 0.3, 1.0), cam).alpha.max() == 0
    assert render(lone_gaussian([0, 0, 0.05], 0.01, 1.0), cam, near=0.1).alpha.max() == 0
    assert render(lone_gaussian([0, 0, 0.05], 0.01, 1.0), cam, near=0.01).alpha.max() > 0.9
    assert render(lone_gaussian([0, 0, 2.0], 0.3, 0.0), cam).alpha.max() == 0
    assert prepare(lone_gaussian([0, 0, 2.0], 0.3, 0.0), cam).num_visible == 0


# -- exactness contracts ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def world():
    rng = np.random.default_rng(11)
    g = random_gaussians(rng, 3000, k=4, spread=1.0)
    g.scales[:] *= 0.3
    cams = [make_camera(72, 56, eye=(np.sin(a) * 3, 0.3, -np.cos(a) * 3)) for a in (0.0, 0.4)]
    return Scene(g, np.zeros(3000, np.int32), None, cams), rng


def assert_same(a: RenderResult, b: RenderResult):
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_keep_equals_subset_render(world):
    scene, rng = world
    keep = rng.uniform(size=len(scene)) < 0.6
    cam = scene.cameras[0]
    assert_same(render(scene, cam, keep=keep), render(scene.subset(keep), cam))
    assert_same(prepare(scene, cam).render(keep=keep), render(scene.subset(keep), cam))



@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prepared_with_keep_runs_equals_subset(world, seed):
    # Runs of kept and dropped Gaussians, as a view's neighbourhood keeps whole views: the
    # projection skips blocks without a kept Gaussian, and must still equal the subset.
    scene, _ = world
    rng = np.random.default_rng(seed)
    lengths = rng.integers(1, 300, size=64)
    keep = np.repeat(np.arange(lengths.size) % 2 == seed % 2, lengths)[:len(scene)]
    keep = np.pad(keep, (0, len(scene) - keep.size))
    assert keep.any() and not keep.all()
    for cam in scene.cameras:
        view = prepare(scene, cam, keep=keep)
        assert_same(view.render(), render(scene.subset(keep), cam))
        np.testing.assert_array_equal(np.flatnonzero(keep)[prepare(scene.subset(keep), cam)
                                                           .visible], view.visible)


@pytest.mark.parametrize("share", [0.0, 0.02, 0.3, 1.0])
def test_prepared_with_keep_over_many_chunks_equals_subset(share):
    # Enough Gaussians for the projection to split them into many chunks, whose kept
    # Gaussians it packs together (chunks with none kept included): the same records, order
    # and renders as the subset, whatever the thread count.
    rng = np.random.default_rng(7)
    n = 40_000
    g = random_gaussians(rng, n, spread=1.2)
    g.scales[:] *= 0.2
    cam = make_camera(96, 64, eye=(0.4, 0.3, -3.0))
    scene = Scene(g, np.zeros(n, np.int32), None, [cam])
    lengths = rng.integers(1, 2500, size=200)
    runs = np.repeat(rng.uniform(size=lengths.size) < share, lengths)
    keep = np.zeros(n, bool)
    keep[:min(n, runs.size)] = runs[:n]
    subset = scene.subset(keep)
    expected = render(subset, cam)
    for threads in (1, 3):
        view = prepare(scene, cam, keep=keep, num_threads=threads)
        assert_same(view.render(), expected)
        np.testing.assert_array_equal(
            np.flatnonzero(keep)[prepare(subset, cam, num_threads=threads).visible],
            view.visible)

def test_prepared_render_equals_render(world):
    scene, _ = world
    view = prepare(scene, scene.cameras[1])
    assert isinstance(view, PreparedView)
    assert view.tile_size == 16 and view.grid == (4, 5)
    assert 0 < view.num_visible <= len(scene) and view.memory_bytes > 0
    assert view.camera is scene.cameras[1]
    assert_same(view.render(background=(0.5, 0.1, 0.0)),
                render(scene, scene.cameras[1], background=(0.5, 0.1, 0.0)))


@pytest.mark.parametrize("which", ["random", "all", "none", "one view"])
@pytest.mark.parametrize("threads", [1, 2])
def test_render_pair_equals_two_renders(world, which, threads):
    scene, rng = world
    n = len(scene)
    keep = {"random": rng.uniform(size=n) < 0.5, "all": np.ones(n, bool),
            "none": np.zeros(n, bool), "one view": np.arange(n) % 3 != 0}[which]
    view = prepare(scene, scene.cameras[0], num_threads=threads)
    a, b = view.render_pair(keep=keep, background=(0.2, 0.3, 0.4))
    assert_same(a, view.render(background=(0.2, 0.3, 0.4)))
    assert_same(b, view.render(keep=keep, background=(0.2, 0.3, 0.4)))
    with pytest.raises(ClearsplatError, match="keep"):
        view.render_pair(keep=None)
    # A base that is itself a subset, and only some tiles (exact there, start elsewhere).
    first = rng.uniform(size=n) < 0.8
    tiles = np.array([0, 3, 7, 11], dtype=np.int32)
    start = view.render(keep=first)
    a, b = view.render_pair(keep=keep & first, first=first, tiles=tiles, start=start)
    assert_same(a, start)
    full_b = view.render(keep=keep & first)
    assert_same(b, view.rerender(start, keep=keep & first, tiles=tiles))
    for t in tiles:
        r, c = divmod(int(t), view.grid[1])
        sl = (slice(16 * r, 16 * r + 16), slice(16 * c, 16 * c + 16))
        np.testing.assert_array_equal(b.rgb[sl], full_b.rgb[sl])


@pytest.mark.parametrize("count", [1, 2, 5, 9])
@pytest.mark.parametrize("threads", [1, 2])
def test_render_layers_equal_one_render_each(world, count, threads):
    # Random disjoint layers (some Gaussians in none, one layer possibly empty): the native
    # one-pass kernel and the generic two-per-pass route both equal separate renders.
    scene, rng = world
    n = len(scene)
    code = rng.integers(-2, count, size=n)
    if count > 2:
        code[code == 1] = -1                      # an empty layer
    layers = [code == k for k in range(count)]
    view = prepare(scene, scene.cameras[0], num_threads=threads)
    got = view.render_layers(layers, background=(0.2, 0.3, 0.4))
    generic = _TiledView.render_layers(view, layers, background=(0.2, 0.3, 0.4))
    assert len(got) == len(generic) == count
    for k, mask in enumerate(layers):
        one = view.render(keep=mask, background=(0.2, 0.3, 0.4))
        assert_same(got[k], one)
        assert_same(generic[k], one)
    assert view.render_layers([]) == []
    # The same layers as one array of layer ids (-1 and below mapped to -1), both routes.
    ids = np.where(code < 0, -1, code).astype(np.int16)
    by_id = view.render_layers(ids, background=(0.2, 0.3, 0.4))
    generic_ids = _TiledView.render_layers(view, ids, background=(0.2, 0.3, 0.4))
    assert len(by_id) == len(generic_ids) == count
    for k in range(count):
        assert_same(by_id[k], got[k])
        assert_same(generic_ids[k], got[k])
    assert view.render_layers(np.full(n, -1)) == []


@pytest.mark.parametrize("threads", [1, 2])
def test_render_layers_in_tiles_equal_the_whole_renders_there(world, threads):
    # Only the tiles asked for are composited: each layer equals its whole render in them and
    # is zero elsewhere; the generic route (whole renders) is exact there too.
    scene, rng = world
    n = len(scene)
    code = rng.integers(-1, 3, size=n)
    view = prepare(scene, scene.cameras[1], num_threads=threads)
    whole = view.render_layers(code, background=(0.2, 0.3, 0.4))
    tiles = np.array([1, 4, 5, view.num_tiles - 1], dtype=np.int32)
    flat, inside = view.tile_pixels(tiles)
    listed = np.zeros(scene.cameras[1].height * scene.cameras[1].width, bool)
    listed[flat[inside]] = True
    for route in (view.render_layers, lambda *a, **k: _TiledView.render_layers(view, *a, **k)):
        part = route(code, tiles=tiles, background=(0.2, 0.3, 0.4))
        assert len(part) == len(whole) == 3
        for got, want in zip(part, whole):
            for a, b in zip(got, want):
                rows_a, rows_b = a.reshape(listed.size, -1), b.reshape(listed.size, -1)
                np.testing.assert_array_equal(rows_a[listed], rows_b[listed])
                if route is view.render_layers:
                    assert not rows_a[~listed].any()
    assert all(not a.any() for r in view.render_layers(code, tiles=np.zeros(0, np.int32))
               for a in r)
    with pytest.raises(ClearsplatError, match="tile"):
        view.render_layers(code, tiles=np.array([view.num_tiles], dtype=np.int32))


def test_render_layers_reject_overlap_and_bad_masks(world):
    scene, _ = world
    n = len(scene)
    view = prepare(scene, scene.cameras[0])
    half = np.arange(n) < n // 2
    with pytest.raises(ClearsplatError, match="more than one layer"):
        view.render_layers([half, np.arange(n) < n // 2 + 1])
    with pytest.raises(ClearsplatError, match="layers"):
        view.render_layers([half, np.ones(n - 1, bool)])
    with pytest.raises(ClearsplatError, match="at most 127"):
        view.render_layers([np.zeros(n, bool)] * 128)
    ids = np.zeros(n, dtype=np.int64)
    for bad, match in ((ids[:-1], "int array"), (ids.astype(np.float32), "int array"),
                       (np.where(half, 127, -1), "-1..126"), (np.where(half, 0, -2), "-1..126")):
        with pytest.raises(ClearsplatError, match=match):
            view.render_layers(bad)


def test_rerender_equals_full_render(world):
    scene, rng = world
    view = prepare(scene, scene.cameras[0])
    n = len(scene)
    base_keep = rng.uniform(size=n) < 0.9
    base = view.render(keep=base_keep)
    blob = np.linalg.norm(scene.gaussians.means - scene.gaussians.means[0], axis=1) < 0.3
    changes = [np.zeros(n, bool),                  # nothing: no tile touched
               np.arange(n) == 5,                  # one Gaussian
               blob,                               # a clump
               rng.uniform(size=n) < 0.3]          # scattered, spanning most tiles
    for change in changes:
        keep = base_keep & ~change
        tiles = view.tiles_touched(change)
        assert tiles.dtype == np.int32 and (np.diff(tiles) > 0).all()
        got = view.rerender(base, keep=keep, tiles=tiles)
        full = view.render(keep=keep)
        for x, y in zip(got, full):
            assert np.abs(x - y).max() <= 1e-6
        assert_same(got, full)  # in fact bit for bit
    assert view.tiles_touched(changes[0]).size == 0
    assert view.tiles_touched(changes[3]).size > view.num_tiles // 2
    # Tiles outside tiles_touched are unchanged by a removal: touched tiles are enough.
    untouched = np.setdiff1d(np.arange(view.num_tiles), view.tiles_touched(blob))
    assert_same(tuple(view.gather(a, untouched) for a in view.render(keep=base_keep & ~blob)),
                tuple(view.gather(a, untouched) for a in base))


def test_tiles_touched_index_forms_and_invisible(world):
    scene, _ = world
    view = prepare(scene, scene.cameras[0])
    idx = np.array([3, 17, 400, 2999])
    mask = np.zeros(len(scene), bool)
    mask[idx] = True
    np.testing.assert_array_equal(view.tiles_touched(idx), view.tiles_touched(mask))
    invisible = np.setdiff1d(np.arange(len(scene)), view.visible)
    assert invisible.size > 0 and view.tiles_touched(invisible).size == 0


def test_rerender_tiles_equal_full_renders(world):
    scene, rng = world
    view = prepare(scene, scene.cameras[1])
    n = len(scene)
    keep = rng.uniform(size=n) < 0.95
    base = view.render(keep=keep)
    removals = [np.flatnonzero(rng.uniform(size=n) < p) for p in (0.0, 0.001, 0.01, 0.2)]
    removals.append(np.array([7, 7, 8]))  # duplicates are fine
    patches = view.rerender_tiles(keep=keep, removals=removals)
    assert len(patches) == len(removals)
    for removal, patch in zip(removals, patches):
        assert isinstance(patch, TilePatch)
        np.testing.assert_array_equal(patch.tiles, view.tiles_touched(removal))
        t = patch.tiles.size
        assert patch.rgb.shape == (t, 16, 16, 3) and patch.alpha.shape == (t, 16, 16)
        k = keep.copy()
        k[removal] = False
        full = view.render(keep=k)
        np.testing.assert_array_equal(patch.rgb, view.gather(full.rgb, patch.tiles))
        np.testing.assert_array_equal(patch.alpha, view.gather(full.alpha, patch.tiles))
        np.testing.assert_array_equal(patch.depth, view.gather(full.depth, patch.tiles))
        assert_same(view.scatter(patch, base), full)
    assert patches[0].tiles.size == 0 and patches[3].tiles.size > 10
    # Border tiles (72x56 is not a multiple of 16) are zero outside the image.
    assert (patches[3].alpha[:, 8:, :][patches[3].tiles // 5 == 3] == 0).all()
    # Explicit tile lists.
    given = [np.arange(view.num_tiles)] * 2
    patches = view.rerender_tiles(keep=keep, removals=removals[2:4], tiles_list=given)
    for removal, patch in zip(removals[2:4], patches):
        k = keep.copy()
        k[removal] = False
        np.testing.assert_array_equal(patch.rgb, view.gather(view.render(keep=k).rgb, given[0]))


def test_rerender_tiles_from_base_equal_full_renders(world):
    # With the base render, only the pixels inside the removed Gaussians' boxes are composited;
    # the patches must still equal full renders bit for bit.
    scene, rng = world
    view = prepare(scene, scene.cameras[0])
    n = len(scene)
    bg = (0.3, 0.1, 0.7)
    keep = rng.uniform(size=n) < 0.9
    base = view.render(keep=keep, background=bg)
    centre = scene.gaussians.means[view.visible[view.num_visible // 2]]
    near = np.argsort(np.linalg.norm(scene.gaussians.means - centre, axis=1))
    removals = [np.flatnonzero(rng.uniform(size=n) < p) for p in (0.0, 0.002, 0.05, 0.3)]
    removals += [near[:40],                                  # a clump: part of a few tiles
                 np.flatnonzero(~keep)[:50],                 # already gone: nothing changes
                 np.array([near[0]])]                        # a single Gaussian
    with_base = view.rerender_tiles(keep=keep, removals=removals, background=bg, base=base)
    without = view.rerender_tiles(keep=keep, removals=removals, background=bg)
    for removal, p, q in zip(removals, with_base, without):
        k = keep.copy()
        k[removal] = False
        full = view.render(keep=k, background=bg)
        for a, b, f in zip(p[1:], q[1:], full):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, view.gather(f, p.tiles))
    assert 0 < with_base[4].tiles.size < view.num_tiles // 2
    # Explicit tiles without any removed Gaussian: copied from the base.
    tiles = [np.arange(view.num_tiles)]
    (patch,) = view.rerender_tiles(keep=keep, removals=[np.array([], int)], tiles_list=tiles,
                                   background=bg, base=base)
    np.testing.assert_array_equal(patch.rgb, view.gather(base.rgb, tiles[0]))
    with pytest.raises(ClearsplatError, match="RenderResult"):
        view.rerender_tiles(keep=keep, removals=removals[:1], base=base.rgb)


def test_render_batch_equals_renders(world):
    scene, rng = world
    keeps = [None, rng.uniform(size=len(scene)) < 0.5]
    outs = render_batch(scene, scene.cameras, keeps, background=(0.2, 0.2, 0.2))
    assert len(outs) == 2
    for cam, keep, out in zip(scene.cameras, keeps, outs):
        assert_same(out, render(scene, cam, keep=keep, background=(0.2, 0.2, 0.2)))


def test_thread_count_does_not_change_results(world):
    scene, rng = world
    cam = scene.cameras[0]
    keep = rng.uniform(size=len(scene)) < 0.8
    outs = [render(scene, cam, keep=keep, num_threads=t) for t in (1, 2, 3)]
    assert_same(outs[0], outs[1])
    assert_same(outs[0], outs[2])
    mask = rng.uniform(size=(cam.height, cam.width)) < 0.5
    c1, c3 = (contributions(scene, cam, mask, num_threads=t) for t in (1, 3))
    for x, y in zip(c1, c3):
        np.testing.assert_array_equal(x, y)
    v1, v3 = prepare(scene, cam, num_threads=1), prepare(scene, cam, num_threads=3)
    removals = [np.arange(0, 3000, 7), np.arange(50)]
    for p1, p3 in zip(v1.rerender_tiles(keep=keep, removals=removals),
                      v3.rerender_tiles(keep=keep, removals=removals)):
        for x, y in zip(p1, p3):
            np.testing.assert_array_equal(x, y)


def test_one_and_two_rows_per_step_give_the_same_bits():
    # On AVX-512 machines the compositing takes two rows of pixels a step (sixteen lanes),
    # elsewhere one: every kernel must give the same bits either way. Odd image sizes, tiles cut
    # by the border and boxes ending on a tile's last row (the lone-row step) are all in.
    from clearsplat import _core

    _core.set_rows_per_step(2)
    if _core.rows_per_step() != 2:
        _core.set_rows_per_step(0)
        pytest.skip("this machine has no AVX-512: only the one-row kernels run")
    rng = np.random.default_rng(5)
    g = random_gaussians(rng, 6000, k=4, spread=1.0)
    g.scales[:] *= rng.uniform(0.05, 1.0, size=(len(g), 1))
    cam = make_camera(101, 75, f=(80.0, 85.0))
    scene = Scene(g, np.zeros(len(g), np.int32), None, [cam])
    n = len(g)
    keep = rng.uniform(size=n) < 0.9
    code = rng.integers(-1, 4, size=n)
    removals = [np.flatnonzero(rng.uniform(size=n) < p) for p in (0.002, 0.05)]
    mask = rng.uniform(size=(cam.height, cam.width)) < 0.5
    floor = rng.uniform(size=n) < 0.7

    def everything():
        view = prepare(scene, cam, num_threads=2)
        base = view.render(keep=keep, background=(0.2, 0.3, 0.4))
        out = [*base, *[a for r in view.render_pair(keep=keep) for a in r],
               *[a for r in view.render_layers(code) for a in r]]
        for with_base in (None, base):
            for patch in view.rerender_tiles(keep=keep, removals=removals, base=with_base,
                                             background=(0.2, 0.3, 0.4)):
                out += list(patch[1:])
        out += list(view.contributions(mask, keep=keep))
        out += list(view.pruned(floor).render(keep=floor | keep))
        return out

    try:
        two = everything()
        _core.set_rows_per_step(1)
        assert _core.rows_per_step() == 1
        one = everything()
    finally:
        _core.set_rows_per_step(0)
    assert len(one) == len(two) > 20
    for a, b in zip(one, two):
        assert a.dtype == b.dtype and a.shape == b.shape
        assert a.tobytes() == b.tobytes()
    assert one[1].max() > 0.9          # alpha: not an empty picture


def test_a_keep_mask_reused_changed_or_after_restrict_renders_anew(world):
    # A view remembers the last keep mask it gathered (the filter renders with the same keep
    # several times in a row): the same mask changed in place, a mask of another view, and a
    # view restricted in place must each render as a fresh view does.
    scene, rng = world
    n = len(scene)
    view, other = prepare(scene, scene.cameras[0]), prepare(scene, scene.cameras[1])
    keep = rng.uniform(size=n) < 0.7
    first = view.render(keep=keep)
    assert_same(view.render(keep=keep), first)              # the remembered gather
    keep[rng.uniform(size=n) < 0.3] = False                 # the same array, changed
    assert_same(view.render(keep=keep), prepare(scene, scene.cameras[0]).render(keep=keep))
    assert_same(other.render(keep=keep), prepare(scene, scene.cameras[1]).render(keep=keep))
    sub = rng.uniform(size=n) < 0.8
    view.render(keep=sub)
    view.restrict(sub)
    part = np.ones(int(sub.sum()), bool)
    fresh = prepare(scene.subset(np.flatnonzero(sub)), scene.cameras[0])
    assert_same(view.render(keep=part), fresh.render(keep=part))
    part[::2] = False
    assert_same(view.render(keep=part), fresh.render(keep=part))
    # The remembered mask goes with its view.
    from clearsplat.render import native
    view.render(keep=part)
    assert native._last_keep[0]() is view and native._last_keep[1].size == part.size
    del view
    assert native._last_keep[0]() is None and native._last_keep[1] is None


def test_empty_scene_and_empty_view():
    cam = make_camera(20, 10)
    g = Gaussians(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0),
                  np.zeros((0, 1, 3)))
    out = render(g, cam, background=(1.0, 0.0, 0.0))
    assert (out.rgb[..., 0] == 1).all() and (out.alpha == 0).all() and (out.depth == 0).all()
    view = prepare(g, cam)
    assert view.num_visible == 0 and view.tiles_touched(np.zeros(0, int)).size == 0


# -- bad input -------------------------------------------------------------------------------
def test_bad_input_raises():
    rng = np.random.default_rng(0)
    g = random_gaussians(rng, 10, k=1)
    cam = make_camera(20, 10)
    with pytest.raises(ClearsplatError, match="keep"):
        render(g, cam, keep=np.ones(9, bool))
    with pytest.raises(ClearsplatError, match="keep"):
        render(g, cam, keep=np.ones(10, int))
    bad = Gaussians(g.means, g.scales, g.quats, g.opacities, g.sh)
    bad.means = bad.means[:, :2]
    with pytest.raises(ClearsplatError, match="means"):
        render(bad, cam)
    bad = Gaussians(g.means, g.scales, g.quats, g.opacities, np.zeros((10, 5, 3)))
    with pytest.raises(ClearsplatError, match="sh"):
        render(bad, cam)
    bad = Gaussians(g.means, g.scales, g.quats[:9], g.opacities, g.sh)
    with pytest.raises(ClearsplatError, match="quats"):
        render(bad, cam)
    with pytest.raises(ClearsplatError, match="camera"):
        render(g, "camera")
    with pytest.raises(ClearsplatError, match="scene"):
        render(np.zeros((10, 3)), cam)
    with pytest.raises(ClearsplatError, match="near"):
        render(g, cam, near=0.0)
    with pytest.raises(ClearsplatError, match="background"):
        render(g, cam, background=(0.0, 0.0))
    with pytest.raises(ClearsplatError, match="num_threads"):
        render(g, cam, num_threads=0)
    with pytest.raises(ClearsplatError, match="keeps"):
        render_batch(g, [cam, cam], [None])
    with pytest.raises(ClearsplatError, match="mask"):
        contributions(g, cam, np.ones((20, 10), bool))
    view = prepare(g, cam)
    with pytest.raises(ClearsplatError, match="gaussians"):
        view.tiles_touched(np.array([10]))
    with pytest.raises(ClearsplatError, match="tiles"):
        view.rerender(view.render(), keep=None, tiles=np.array([view.num_tiles]))
    with pytest.raises(ClearsplatError, match="base"):
        view.rerender(view.render().rgb, keep=None, tiles=np.array([0]))
    with pytest.raises(ClearsplatError, match="tiles_list"):
        view.rerender_tiles(keep=None, removals=[np.array([1])], tiles_list=[])


# -- package layers ---------------------------------------------------------------------------
def _imports(path):
    """Modules of clearsplat a source file imports (anywhere in it), as dotted names."""
    import ast
    import pathlib
    root = pathlib.Path(__import__("clearsplat").__file__).parent
    rel = path.relative_to(root.parent).with_suffix("")
    pkg = list(rel.parts[:-1]) if rel.name != "__init__" else list(rel.parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = pkg[:len(pkg) - node.level + 1]
            mod = ".".join(base + ([node.module] if node.module else []))
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("clearsplat"):
            out.add(node.module)
    return out


def test_render_layers_point_down_and_scene_imports_neither_io_nor_render():
    import pathlib
    import clearsplat
    root = pathlib.Path(clearsplat.__file__).parent
    below = {"_kernels": set(), "base": {"_kernels"}, "native": {"_kernels", "base"},
             "_gsplat_call": {"_kernels"},
             "gsplat": {"_kernels", "base", "native", "_gsplat_call"},
             "api": {"_kernels", "base", "native", "_gsplat_call", "gsplat"}}
    for name, allowed in below.items():
        inside = {m.split(".")[2] for m in _imports(root / "render" / f"{name}.py")
                  if m.startswith("clearsplat.render.")}
        assert inside <= allowed, (name, inside - allowed)
    for low in ("scene.py", "cameras.py", "errors.py"):
        up = {m for m in _imports(root / low)
              if m.split(".")[1:2] and m.split(".")[1] in ("io", "render", "filter", "adapters")}
        assert not up, (low, up)


# -- render settings in bundles ---------------------------------------------------------------
def test_bundle_round_trips_settings_and_degree_4_sh(tmp_path):
    import json
    from clearsplat import load_scene
    rng = np.random.default_rng(21)
    g = random_gaussians(rng, 120, k=25)
    g.opacities[:] = np.clip(g.opacities, 0.01, 0.99)     # the PLY stores logits
    cam = make_camera(40, 24)
    scene = Scene(g, np.zeros(120, np.int32), None, [cam], [np.full((24, 40, 3), 0.5)],
                  render_settings=RenderSettings(antialiased=True, eps2d=0.1, radius_clip=0.1,
                                                 sh_degree=4))
    scene.save(tmp_path / "b")
    doc = json.loads((tmp_path / "b" / "cameras.json").read_text())
    assert doc["render"] == {"antialiased": True, "eps2d": 0.1, "radius_clip": 0.1,
                             "sh_degree": 4}
    header = (tmp_path / "b" / "gaussians.ply").read_bytes().split(b"end_header")[0]
    assert header.count(b"f_rest_") == 72
    back = load_scene(tmp_path / "b")
    assert back.render_settings == scene.render_settings
    assert back.gaussians.sh.shape == (120, 25, 3)
    np.testing.assert_allclose(back.gaussians.sh, g.sh, rtol=1e-6)
    a, b = render(back, cam), render(g, cam, settings=scene.render_settings)
    np.testing.assert_allclose(a.rgb, b.rgb, atol=1e-5)
    # Classic scenes write no "render" object and load as classic.
    Scene(g, np.zeros(120, np.int32), None, [cam]).save(tmp_path / "c")
    assert "render" not in json.loads((tmp_path / "c" / "cameras.json").read_text())
    assert load_scene(tmp_path / "c", require_images=False).render_settings.is_classic


@pytest.mark.parametrize("render_obj,field", [
    ({"antialiased": "yes"}, "render.antialiased"), ({"eps2d": -0.1}, "render.eps2d"),
    ({"eps2d": None}, "render.eps2d"), ({"radius_clip": float("nan")}, "render.radius_clip"),
    ({"sh_degree": 5}, "render.sh_degree"), ({"sh_degree": 2.0}, "render.sh_degree"),
    ({"mode": "antialiased"}, "render.mode"), ([True], "render")])
def test_bad_render_settings_name_the_field(tmp_path, render_obj, field):
    import json
    from clearsplat import load_scene
    g = random_gaussians(np.random.default_rng(22), 10, k=1)
    g.opacities[:] = 0.5
    Scene(g, np.zeros(10, np.int32), None, [make_camera(16, 16)]).save(tmp_path / "b")
    path = tmp_path / "b" / "cameras.json"
    doc = json.loads(path.read_text())
    doc["render"] = render_obj
    path.write_text(json.dumps(doc))
    with pytest.raises(ClearsplatError) as e:
        load_scene(tmp_path / "b", require_images=False)
    assert e.value.field == field and str(e.value.path) == str(path)


def test_filter_and_report_render_with_the_scene_settings(tmp_path, monkeypatch):
    from dataclasses import replace

    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors
    from clearsplat.render import api
    from clearsplat.report import write_report
    from clearsplat.synth.backbone import reconstruct
    from clearsplat.synth.worlds import make_world
    world = make_world("object", num_views=3, seed=2, height=64, width=96)
    scene = replace(reconstruct(world.cameras, world.images, world.depths, seed=2),
                    render_settings=AA)
    used = []
    real = api.prepare_view

    def spy(*args):
        used.append(args[5] if len(args) > 5 else None)
        return real(*args)

    monkeypatch.setattr(api, "prepare_view", spy)
    result = filter_distractors(scene, config=FilterConfig(), extractor=get_extractor("local"))
    write_report(str(tmp_path), scene, result)
    assert len(used) >= scene.num_views and all(s == AA for s in used)


def test_take_mask_equals_numpy_take():
    from clearsplat.render import _kernels
    rng = np.random.default_rng(2)
    for n, v in ((1, 1), (10, 0), (1000, 700), (100_000, 100_000)):
        mask = rng.uniform(size=n) < 0.5
        index = rng.integers(0, n, v).astype(np.int32)
        got = _kernels.take_mask(mask, index)
        assert got.dtype == np.bool_ and got.shape == (v,)
        np.testing.assert_array_equal(got, np.take(mask, index))
    with pytest.raises(ValueError, match="out of range"):
        _kernels.take_mask(np.ones(5, bool), np.array([0, 5], np.int32))
    with pytest.raises(ValueError, match="out of range"):
        _kernels.take_mask(np.ones(5, bool), np.array([-1], np.int32))


def test_sort_index_equals_numpy_stable_sort():
    from clearsplat.render import _kernels
    rng = np.random.default_rng(3)
    for v, high in ((0, 1), (1, 1), (1000, 50), (200_000, 2**31 - 1), (300_000, 1 << 22)):
        index = rng.integers(0, high, v).astype(np.int32)
        for threads in (1, 2):
            values, order = _kernels.sort_index(index, threads)
            assert values.dtype == order.dtype == np.int32
            np.testing.assert_array_equal(values, np.sort(index))
            np.testing.assert_array_equal(order, np.argsort(index, kind="stable"))
    with pytest.raises(ValueError, match="negative"):
        _kernels.sort_index(np.array([3, -1], np.int32))


def test_removal_ids_from_indices_and_masks_agree(world):
    # A removal given as Gaussian indices (looked up through the sorted visible index) and as
    # a bool mask (gathered over the visible Gaussians, or looked up when it holds few) must
    # touch the same tiles.
    scene, rng = world
    # Mostly visible (a Gaussian -> visible id map) and a small part (a sorted index).
    for share in (0.9, 0.1):
        view = prepare(scene, scene.cameras[0], keep=rng.uniform(size=len(scene)) < share)
        for _ in range(5):
            idx = rng.choice(len(scene), size=int(rng.integers(1, 6000)), replace=True)
            mask = np.zeros(len(scene), bool)
            mask[idx] = True
            np.testing.assert_array_equal(view.tiles_touched(idx), view.tiles_touched(mask))
            np.testing.assert_array_equal(view._ids(idx, "x"), view._ids(mask, "x"))
        seen = view.visible.astype(np.int64)
        for idx in (np.empty(0, np.int64), seen[:1], seen[[3, 3]], seen[[9, 2, 9, 2]]):
            mask = np.zeros(len(scene), bool)
            mask[idx] = True
            got = view._ids(idx, "x")
            assert got.dtype == np.int32
            np.testing.assert_array_equal(got, view._ids(mask, "x"))
            # A visible id is a Gaussian's position among the visible ones.
            want = np.unique([int(np.flatnonzero(seen == i)[0]) for i in idx]).astype(np.int32)
            np.testing.assert_array_equal(got, want)
        assert len(view._by_index) == (1 if share > 0.5 else 2)


def test_centres_inside_equals_numpy(world):
    scene, _ = world
    for cam in scene.cameras:
        view = prepare(scene, cam)
        u, v = view._splats[:, 0], view._splats[:, 1]
        want = np.zeros(len(scene), bool)
        want[view.visible[(u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)]] = True
        got = view.centres_inside()
        assert got.dtype == np.bool_ and got.shape == (len(scene),)
        np.testing.assert_array_equal(got, want)
        assert 0 < got.sum() < view.num_visible   # some centres lie outside, their splats in
