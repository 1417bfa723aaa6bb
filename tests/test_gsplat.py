"""gsplat GPU path: same results as the CPU rasterizer (needs torch with CUDA and gsplat)."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from clearsplat import Camera, ClearsplatError, Gaussians
from clearsplat.cameras import look_at
from clearsplat.render import prepare, render


def _scene(seed=0, n=400, sh_degree=2):
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    g = Gaussians(means=rng.uniform(-1, 1, (n, 3)) * [1.0, 0.8, 0.5] + [0, 0, 4],
                  scales=np.exp(rng.uniform(-4, -2, (n, 3))), quats=q,
                  opacities=rng.uniform(0.2, 0.95, n),
                  sh=np.concatenate([rng.normal(0, 1, (n, 1, 3)),
                                     rng.normal(0, 0.2, (n, k - 1, 3))], axis=1))
    cam = Camera(K=[[60.0, 0, 40], [0, 60.0, 30], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=80, height=60)
    return g, cam


def _skip_if_gpu_ready():
    """Skip a test of the missing-GPU errors where gsplat and CUDA are there."""
    try:
        import gsplat  # noqa: F401
        import torch
    except ImportError:
        return
    if torch.cuda.is_available():
        pytest.skip("gsplat and CUDA are available")


def test_missing_gsplat_raises_import_error_with_hint():
    from clearsplat.render.gsplat import render_gsplat
    g, cam = _scene(n=3)
    _skip_if_gpu_ready()
    with pytest.raises(ImportError, match="pip install gsplat"):
        render_gsplat(g, cam)


def test_bad_input_is_reported_before_the_gpu():
    from clearsplat.render.gsplat import render_gsplat
    g, cam = _scene(n=3)
    with pytest.raises(ClearsplatError) as e:
        render_gsplat(g, cam, background=(0, 0))
    assert e.value.field == "background"
    with pytest.raises(ClearsplatError) as e:
        render_gsplat(g, cam, keep=np.ones(2, bool))
    assert e.value.field == "keep"


def _need_cuda_gsplat():
    torch = pytest.importorskip("torch")
    pytest.importorskip("gsplat")
    if not torch.cuda.is_available():
        pytest.skip("no CUDA GPU")
    from clearsplat.render import gsplat as _gsplat
    return _gsplat


@pytest.fixture
def gpu():
    return _need_cuda_gsplat().render_gsplat


def _assert_close(out, cpu):
    for name in ("rgb", "alpha", "depth"):
        a, b = getattr(cpu, name), getattr(out, name)
        assert a.shape == b.shape and b.dtype == np.float32
    assert np.abs(cpu.rgb - out.rgb).mean() < 1e-3
    assert np.abs(cpu.rgb - out.rgb).max() < 2e-2
    assert np.abs(cpu.alpha - out.alpha).max() < 2e-2
    # Depth is the ratio of two accumulated sums, D / alpha: compare D = depth * alpha like the
    # colours (same tolerances), relative to the depth scale. The ratio itself moves by about
    # the depth spread times the alpha difference over alpha (an H100 run: 0.012 at a pixel
    # with alpha 0.58 and an alpha difference of 0.0016).
    scale = float(np.median(cpu.depth[cpu.alpha > 0.5]))
    weighted = np.abs(cpu.depth * cpu.alpha - out.depth * out.alpha)
    assert weighted.mean() < 1e-3 * scale
    assert weighted.max() < 2e-2 * scale


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_gsplat_matches_cpu_render(gpu, sh_degree):
    g, cam = _scene(seed=sh_degree, sh_degree=sh_degree)
    keep = np.random.default_rng(9).uniform(size=len(g)) > 0.3
    bg = (0.2, 0.4, 0.6)
    _assert_close(gpu(g, cam, keep=keep, background=bg),
                  render(g, cam, keep=keep, background=bg))
    empty = gpu(g, cam, keep=np.zeros(len(g), bool), background=bg)
    assert np.allclose(empty.rgb, bg) and (empty.alpha == 0).all()


def test_render_device_routes_to_gsplat_or_says_what_is_missing():
    from clearsplat import ClearsplatError, render
    g, cam = _scene(0)
    with pytest.raises(ClearsplatError, match="device"):
        render(g, cam, device="tpu")
    try:
        import gsplat  # noqa: F401
        import torch
        have_gpu = torch.cuda.is_available()
    except ImportError:
        have_gpu = False
    if not have_gpu:
        with pytest.raises(ImportError, match="gsplat"):
            render(g, cam, device="cuda")


# -- GsplatView on the CPU through a fake gsplat ----------------------------------------------
# ``rasterization`` emulated with clearsplat's own CPU rasterizer (with the render settings the
# call passes), in the batch layout of one gsplat version: "batched" (1.5.3), "shared_sh" (the
# development version: SH [N, K, 3] only) or None (1.4-1.5.2: no batch dimensions), with
# gsplat's AssertionError for what that version refuses. Outputs in gsplat 1.5.3's layout:
# colours [..., C, H, W, 4] (RGB composited over ``backgrounds``, then the accumulated depth
# sum z_i a_i T_i), alphas [..., C, H, W, 1], meta with means2d [..., C, N, 2], radii
# [..., C, N, 2] int32 (0 where culled) and depths [..., C, N]. It checks the arguments the
# GPU path relies on and takes its cameras from a registry keyed by the float32 view matrix and
# intrinsics it must receive, so a camera-to-world matrix (or a transposed one) finds nothing.
class FakeGsplat:
    def __init__(self, layout="batched", settings=None):
        from clearsplat import RenderSettings
        self.cameras = {}
        self.calls = []          # batch shape of each call (but the batch-layout probe)
        self.layout = layout
        self.settings = RenderSettings() if settings is None else settings   # expected

    @staticmethod
    def _key(viewmat, K, width, height):
        return (np.asarray(viewmat, np.float32).tobytes(), np.asarray(K, np.float32).tobytes(),
                int(width), int(height))

    def add(self, *cameras):
        for cam in cameras:
            self.cameras[self._key(cam.world_to_camera, cam.K, cam.width, cam.height)] = cam

    def rasterization(self, *, means, quats, scales, opacities, colors, viewmats, Ks, width,
                      height, near_plane, sh_degree, packed, tile_size, eps2d, radius_clip,
                      backgrounds, render_mode, rasterize_mode):
        import torch
        from clearsplat import RenderSettings
        batch = tuple(means.shape[:-2])
        n, c = means.shape[-2], viewmats.shape[-3]
        probe = means.shape[-2:] == (1, 3) and width == 16 and height == 16 and batch == (2,)
        if probe:
            # The batch-layout probe (one Gaussian, two renders of a 16x16 view); not counted.
            self.cameras.setdefault(self._key(viewmats[0, 0], Ks[0, 0], 16, 16), Camera(
                K=Ks[0, 0].numpy(), camera_to_world=np.linalg.inv(viewmats[0, 0].numpy()),
                width=16, height=16))
        else:
            assert (packed, tile_size, render_mode) == (False, 16, "RGB+D")
            s = self.settings
            assert (eps2d, radius_clip) == (s.eps2d, s.radius_clip)
            assert rasterize_mode == ("antialiased" if s.antialiased else "classic")
            k = colors.shape[-2]
            assert sh_degree == min(int(np.sqrt(k)) - 1, 4 if s.sh_degree is None else s.sh_degree)
        # What each gsplat version accepts (its shape assertions).
        if self.layout is None:
            assert means.shape == (n, 3) and viewmats.shape == (c, 4, 4)
        if self.layout == "shared_sh":
            assert colors.dim() == 3 and colors.shape[0] == n, colors.shape
        if self.layout == "batched":
            assert colors.shape[:-2] == batch + (n,), colors.shape
        assert (sh_degree + 1) ** 2 <= colors.shape[-2]
        assert opacities.shape == batch + (n,) and viewmats.shape == batch + (c, 4, 4)
        assert backgrounds.shape == batch + (c, 3)
        if not probe:
            self.calls.append(batch)
        if colors.dim() == 3:
            colors = colors.expand(batch + tuple(colors.shape))
        flat = [t.reshape((-1,) + tuple(t.shape[len(batch):])).numpy()
                for t in (means, quats, scales, opacities, colors, viewmats, Ks, backgrounds)]
        settings = RenderSettings(antialiased=rasterize_mode == "antialiased", eps2d=eps2d,
                                  radius_clip=radius_clip, sh_degree=sh_degree)
        b = flat[0].shape[0]
        out_c = np.zeros((b, c, height, width, 4), np.float32)
        out_a = np.zeros((b, c, height, width, 1), np.float32)
        radii = np.zeros((b, c, n, 2), np.int32)
        means2d = np.zeros((b, c, n, 2), np.float32)
        depths = np.zeros((b, c, n), np.float32)
        for i in range(b):
            g = Gaussians(means=flat[0][i], quats=flat[1][i], scales=flat[2][i],
                          opacities=flat[3][i], sh=flat[4][i])
            for j in range(c):
                cam = self.cameras[self._key(flat[5][i, j], flat[6][i, j], width, height)]
                pv = prepare(g, cam, near=near_plane, settings=settings)
                r = pv.render(background=flat[7][i, j])
                out_c[i, j, ..., :3] = r.rgb
                out_c[i, j, ..., 3] = r.depth * r.alpha
                out_a[i, j, ..., 0] = r.alpha
                u, v, depth = pv._splats[:, 0], pv._splats[:, 1], pv._splats[:, 9]
                x0, y0, x1, y1 = (pv._rects[:, k].astype(np.float64) * 16 for k in range(4))
                # A box whose gsplat tile range covers the CPU tiles [x0, x1] x [y0, y1].
                rx = np.ceil(np.maximum(u - x0, x1 + 16 - u))
                ry = np.ceil(np.maximum(v - y0, y1 + 16 - v))
                radii[i, j, pv._index] = np.stack([rx, ry], axis=1).astype(np.int32)
                means2d[i, j, pv._index] = np.stack([u, v], axis=1)
                depths[i, j, pv._index] = depth
        shape = batch + (c,)
        meta = {"radii": torch.from_numpy(radii.reshape(shape + (n, 2))),
                "means2d": torch.from_numpy(means2d.reshape(shape + (n, 2))),
                "depths": torch.from_numpy(depths.reshape(shape + (n,)))}
        return (torch.from_numpy(out_c.reshape(shape + (height, width, 4))),
                torch.from_numpy(out_a.reshape(shape + (height, width, 1))), meta)


def _install(monkeypatch, fake):
    module = types.ModuleType("gsplat")
    module.rasterization = fake.rasterization
    monkeypatch.setitem(sys.modules, "gsplat", module)
    return fake


@pytest.fixture
def fake_gsplat(monkeypatch):
    pytest.importorskip("torch")
    return _install(monkeypatch, FakeGsplat())


def _world(seed=0, n=500, sh_degree=2):
    """Seeded Gaussians with some behind the cameras, beside the frustum and below 1/255
    opacity, and two cameras (one rotated, off-centre principal point; 70x45: border tiles)."""
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    means = rng.normal(size=(n, 3)) * [0.9, 0.7, 0.6]
    means[: n // 10, 2] = rng.uniform(-6.0, -3.1, n // 10)
    opac = rng.uniform(0.05, 0.99, n)
    opac[n // 10: n // 10 + 5] = 0.002
    g = Gaussians(means=means, scales=np.exp(rng.uniform(np.log(0.01), np.log(0.2), (n, 3))),
                  quats=rng.normal(size=(n, 4)), opacities=opac,
                  sh=rng.normal(size=(n, k, 3)) * 0.4)
    cams = [Camera(K=[[90.0, 0, 55.3], [0, 93.0, 34.8], [0, 0, 1]],
                   camera_to_world=look_at(eye, (0, 0, 0), up=(0, -1, 0)), width=110, height=70)
            for eye in ((0.3, 0.2, -3.0), (-1.2, 0.4, -2.8))]
    return g, cams


def _assert_same(a, b, *, exact_depth=False):
    """GsplatView result ``a`` against the PreparedView result ``b``."""
    for name in ("rgb", "alpha", "depth"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.dtype == np.float32
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.alpha, b.alpha)
    if exact_depth:
        np.testing.assert_array_equal(a.depth, b.depth)
    else:
        # The fake hands back depth * alpha rounded to float32 and the view divides by alpha
        # again: two roundings, so a few ulps (relative 1e-6) instead of bit equality.
        np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6, atol=0)
        assert ((a.depth == 0) == (b.depth == 0)).all()


def test_gsplat_view_equals_prepared_view(fake_gsplat):
    from clearsplat.render.gsplat import prepare_gsplat_views
    g, cams = _world()
    fake_gsplat.add(*cams)
    views = prepare_gsplat_views(g, cams, device="cpu")
    assert views[0].gaussians is views[1].gaussians          # one upload for the scene
    n = len(g)
    rng = np.random.default_rng(5)
    bg = (0.2, 0.4, 0.6)
    for gv, cam in zip(views, cams):
        pv = prepare(g, cam)
        assert (gv.camera, gv.num_gaussians, gv.grid, gv.num_tiles, gv.tile_size) \
            == (cam, pv.num_gaussians, pv.grid, pv.num_tiles, pv.tile_size)
        assert gv.num_visible == pv.num_visible and 0 < pv.num_visible < n
        np.testing.assert_array_equal(gv.centres_inside(), pv.centres_inside())
        keeps = [None, np.ones(n, bool), np.zeros(n, bool), rng.uniform(size=n) > 0.3]
        for keep in keeps:
            _assert_same(gv.render(keep=keep, background=bg), pv.render(keep=keep, background=bg))
        many = gv.render_many(keeps, background=bg)
        for keep, r in zip(keeps, many):
            _assert_same(r, pv.render(keep=keep, background=bg))
        for r, s in zip(gv.render_many(keeps, background=bg, batch_size=1), many):
            _assert_same(r, s, exact_depth=True)
        code = rng.integers(-1, 3, size=n)
        layers = [code == k for k in range(3)]
        for r, s in zip(gv.render_layers(layers, background=bg),
                        pv.render_layers(layers, background=bg)):
            _assert_same(r, s)

        own = rng.uniform(size=n) > 0.6
        first = rng.uniform(size=n) > 0.1
        for kw in ({}, {"first": first}):
            for x, y in zip(gv.render_pair(keep=~own, **kw), pv.render_pair(keep=~own, **kw)):
                _assert_same(x, y)

        removed = rng.choice(n, 6, replace=False)
        tiles = gv.tiles_touched(removed)
        assert tiles.dtype == np.int32 and (np.diff(tiles) > 0).all()
        # gsplat's boxes hold the CPU tiles (the fake's radii are built to), so re-rendering
        # them gives the full render, and the results equal the CPU ones in the same tiles.
        assert set(pv.tiles_touched(removed)) <= set(tiles) and tiles.size < gv.num_tiles
        mask = np.zeros(n, bool)
        mask[removed] = True
        np.testing.assert_array_equal(gv.tiles_touched(mask), tiles)
        assert gv.tiles_touched(np.array([], dtype=np.int64)).size == 0
        base = gv.render(keep=first, background=bg)
        keep = first & ~mask
        re = gv.rerender(base, keep=keep, tiles=tiles, background=bg)
        _assert_same(re, pv.rerender(base, keep=keep, tiles=tiles, background=bg),
                     exact_depth=True)
        _assert_same(re, pv.render(keep=keep, background=bg))
        _assert_same(gv.rerender(base, keep=keep, background=bg),
                     pv.render(keep=keep, background=bg))
        _assert_same(gv.rerender(base, keep=keep, tiles=[], background=bg), base,
                     exact_depth=True)
        start = pv.render(keep=first)
        for kw in ({"start": start}, {}):
            got = gv.render_pair(first=first, keep=keep, tiles=tiles, **kw)
            want = pv.render_pair(first=first, keep=keep, tiles=tiles, **kw)
            for x, y in zip(got, want):
                _assert_same(x, y)
        for x, y in zip(gv.render_pair(keep=keep, tiles=[], start=start),
                        pv.render_pair(keep=keep, tiles=[], start=start)):
            _assert_same(x, y, exact_depth=True)

        region = np.zeros((cam.height, cam.width), bool)
        region[10:30, 20:50] = True
        for k in (None, own):
            got, want = gv.contributions(region, keep=k), pv.contributions(region, keep=k)
            for x, y in zip(got, want):
                np.testing.assert_array_equal(x, y)
                assert x.dtype == y.dtype
    # A batched pair is one gsplat call; batch_size=1 one call per render.
    fake_gsplat.calls.clear()
    views[0].render_pair(keep=~own)
    assert fake_gsplat.calls == [(2,)]


def test_gsplat_view_projection_is_kept_once(fake_gsplat):
    from clearsplat.render.gsplat import prepare_gsplat
    g, cams = _world(1, n=200, sh_degree=0)
    fake_gsplat.add(cams[0])
    gv = prepare_gsplat(g, cams[0], device="cpu")
    keep = np.random.default_rng(2).uniform(size=len(g)) > 0.5
    gv.render(keep=keep)                                    # does not give the projection
    assert len(fake_gsplat.calls) == 1
    inside = gv.centres_inside()                            # one render of everything
    assert len(fake_gsplat.calls) == 2
    gv.tiles_touched(np.arange(10))
    assert gv.num_visible == prepare(g, cams[0]).num_visible
    assert len(fake_gsplat.calls) == 2
    np.testing.assert_array_equal(inside, prepare(g, cams[0]).centres_inside())
    empty = gv.render(keep=np.zeros(len(g), bool), background=(1, 0, 0))
    assert len(fake_gsplat.calls) == 2                      # nothing to render: no call
    assert (empty.rgb == np.float32([1, 0, 0])).all() and not empty.alpha.any()
    # From a batch whose second render has all Gaussians (render_pair(first=None, ...)).
    gv2 = prepare_gsplat(gv.gaussians, cams[0])
    gv2.render_many([keep, None])
    assert fake_gsplat.calls[-1] == (2,) and len(fake_gsplat.calls) == 3
    np.testing.assert_array_equal(gv2.centres_inside(), inside)
    np.testing.assert_array_equal(gv2.tiles_touched(np.arange(10)), gv.tiles_touched(np.arange(10)))
    assert len(fake_gsplat.calls) == 3


def test_gsplat_view_empty_scene(fake_gsplat):
    from clearsplat.render.gsplat import prepare_gsplat
    g, cams = _world(n=20)
    g = g.subset(np.zeros(len(g), bool))
    gv = prepare_gsplat(g, cams[0], device="cpu")
    assert gv.num_visible == 0 and gv.tiles_touched(np.zeros(0, bool)).size == 0
    assert not gv.centres_inside().size
    r = gv.render(background=(0.5, 0.5, 0.5))
    assert (r.rgb == 0.5).all() and not r.alpha.any() and not r.depth.any()
    assert fake_gsplat.calls == []


def test_render_gsplat_through_fake_equals_cpu(fake_gsplat):
    from clearsplat.render.gsplat import render_gsplat
    g, cams = _world(3, n=300, sh_degree=3)
    fake_gsplat.add(cams[1])
    keep = np.random.default_rng(3).uniform(size=len(g)) > 0.2
    _assert_same(render_gsplat(g, cams[1], keep=keep, background=(0.1, 0.2, 0.3), device="cpu"),
                 render(g, cams[1], keep=keep, background=(0.1, 0.2, 0.3)))


def test_gsplat_view_bad_input(fake_gsplat):
    from clearsplat.render.gsplat import prepare_gsplat, upload_gaussians
    g, cams = _world(n=50)
    fake_gsplat.add(cams[0])
    n = len(g)
    with pytest.raises(ClearsplatError) as e:
        prepare_gsplat(g, "camera", device="cpu")
    assert e.value.field == "camera"
    with pytest.raises(ClearsplatError) as e:
        prepare_gsplat(g, cams[0], near=0, device="cpu")
    assert e.value.field == "near"
    with pytest.raises(ClearsplatError) as e:
        upload_gaussians(g, device="nonsense")
    assert e.value.field == "device"
    dev = upload_gaussians(g, device="cpu")
    with pytest.raises(ClearsplatError) as e:
        prepare_gsplat(dev, cams[0], device="cuda")
    assert e.value.field == "device"
    gv = prepare_gsplat(dev, cams[0])
    base = gv.render()
    cases = [
        (lambda: gv.render(keep=np.ones(n - 1, bool)), "keep"),
        (lambda: gv.render(keep=np.ones(n, np.int8)), "keep"),
        (lambda: gv.render(background=(0, 0)), "background"),
        (lambda: gv.render_pair(keep=None), "keep"),
        (lambda: gv.render_pair(keep=np.ones(n, bool), first=np.ones(2, bool)), "first"),
        (lambda: gv.render_pair(keep=np.ones(n, bool), tiles=[gv.num_tiles]), "tiles"),
        (lambda: gv.render_pair(keep=np.ones(n, bool), tiles=[0], start=base.rgb), "start"),
        (lambda: gv.rerender(base.rgb, keep=None), "base"),
        (lambda: gv.rerender(base, keep=None, tiles=[[0]]), "tiles"),
        (lambda: gv.render_many([None, np.ones(3, bool)]), "keeps[1]"),
        (lambda: gv.render_many([None], batch_size=0), "batch_size"),
        (lambda: gv.tiles_touched([n]), "gaussians"),
        (lambda: gv.tiles_touched(np.ones(3, bool)), "gaussians"),
        (lambda: gv.contributions(np.ones((2, 2), bool)), "mask"),
    ]
    for call, field in cases:
        with pytest.raises(ClearsplatError) as e:
            call()
        assert e.value.field == field, field


def test_prepare_gsplat_without_gpu_says_what_is_missing():
    from clearsplat.render.gsplat import prepare_gsplat, prepare_gsplat_views
    g, cams = _world(n=20)
    _skip_if_gpu_ready()
    with pytest.raises(ImportError, match="pip install gsplat"):
        prepare_gsplat(g, cams[0])
    with pytest.raises(ImportError, match="pip install gsplat"):
        prepare_gsplat_views(g, cams)
    with pytest.raises(ClearsplatError) as e:     # bad input first, even without a GPU
        prepare_gsplat(g, object())
    assert e.value.field == "camera"


# -- conventions against gsplat's pure-PyTorch reference (CPU) -------------------------------
def test_projection_conventions_match_gsplat_reference():
    torch = pytest.importorskip("torch")
    pytest.importorskip("gsplat")
    from gsplat.cuda import _torch_impl as gs
    g, cams = _world(7, n=300, sh_degree=3)
    cam = Camera(K=[[90.0, 0, 55.0], [0, 93.0, 35.0], [0, 0, 1]],   # centred principal point
                 camera_to_world=cams[1].camera_to_world, width=110, height=70)
    pv = prepare(g, cam)
    sp, idx = pv._splats, pv._index

    def t(a):
        return torch.as_tensor(np.asarray(a, np.float64))

    covars, _ = gs._quat_scale_to_covar_preci(t(g.quats), t(g.scales), compute_preci=False)
    radii, means2d, depths, conics, _ = gs._fully_fused_projection(
        t(g.means), covars, t(cam.world_to_camera)[None], t(cam.K)[None], cam.width,
        cam.height, eps2d=0.3, near_plane=0.01)
    radii, means2d = radii[0].numpy(), means2d[0].numpy()
    depths, conics = depths[0].numpy(), conics[0].numpy()
    visible = (radii > 0).all(axis=1)
    both = visible[idx]
    assert both.sum() >= 0.9 * idx.size > 0
    ids = idx[both]
    np.testing.assert_allclose(sp[both, 0], means2d[ids, 0], atol=1e-4, rtol=0)
    np.testing.assert_allclose(sp[both, 1], means2d[ids, 1], atol=1e-4, rtol=0)
    np.testing.assert_allclose(sp[both, 9], depths[ids], rtol=1e-6)
    scale = np.abs(conics[ids]).max(axis=1, keepdims=True)
    assert (np.abs(sp[both, 2:5] - conics[ids]) / scale).max() < 1e-4
    # gsplat's box radius ceil(3.33 sqrt(Sigma2D_xx)) from our conic, within a pixel.
    ca, cb, cc = sp[both, 2].astype(np.float64), sp[both, 3], sp[both, 4]
    det = ca * cc - cb * cb
    ours = np.stack([np.ceil(3.33 * np.sqrt(cc / det)), np.ceil(3.33 * np.sqrt(ca / det))], 1)
    assert np.abs(ours - radii[ids]).max() <= 1
    # SH colours: gsplat evaluates from the camera centre towards the Gaussian, + 0.5, >= 0.
    dirs = t(g.means) - t(cam.position)
    rgb = torch.clamp_min(gs._spherical_harmonics(3, dirs, t(g.sh)) + 0.5, 0.0).numpy()
    np.testing.assert_allclose(sp[:, 6:9], rgb[idx], atol=1e-5, rtol=0)


def test_tile_rule_matches_gsplat_reference():
    torch = pytest.importorskip("torch")
    pytest.importorskip("gsplat")
    from gsplat.cuda import _torch_impl as gs
    from clearsplat.render.gsplat import GsplatView, upload_gaussians
    g, cams = _world(8, n=150)
    cam = cams[0]
    covars, _ = gs._quat_scale_to_covar_preci(torch.as_tensor(g.quats), torch.as_tensor(g.scales),
                                              compute_preci=False)
    radii, means2d, depths, _, _ = gs._fully_fused_projection(
        torch.as_tensor(g.means), covars,
        torch.as_tensor(cam.world_to_camera, dtype=torch.float32)[None],
        torch.as_tensor(cam.K, dtype=torch.float32)[None], cam.width, cam.height)
    rows, cols = -(-cam.height // 16), -(-cam.width // 16)
    _, isect_ids, flatten_ids = gs._isect_tiles(means2d, radii, depths, 16, cols, rows)
    tile_of = ((isect_ids >> 32) & ((1 << (rows * cols).bit_length()) - 1)).numpy()
    gauss_of = flatten_ids.numpy() % len(g)
    # No gsplat call here: the view is given the reference projection directly.
    gv = GsplatView(upload_gaussians(g, device="cpu"), cam, near=0.01)
    gv._store_projection(means2d[0].numpy(), radii[0].numpy())
    assert gv.num_visible == int((radii[0] > 0).all(-1).sum()) > 0
    rng = np.random.default_rng(0)
    for chosen in [np.arange(len(g)), *(rng.choice(len(g), 5, replace=False) for _ in range(20))]:
        want = np.unique(tile_of[np.isin(gauss_of, chosen)])
        np.testing.assert_array_equal(gv.tiles_touched(chosen), want)


# -- GsplatView on a real GPU -----------------------------------------------------------------
@pytest.fixture
def gpu_views():
    return _need_cuda_gsplat().prepare_gsplat_views


def test_gsplat_view_matches_cpu_on_gpu(gpu_views):
    g, cams = _world(11, n=800, sh_degree=3)
    views = gpu_views(g, cams)
    n = len(g)
    rng = np.random.default_rng(4)
    bg = (0.2, 0.4, 0.6)
    for gv, cam in zip(views, cams):
        pv = prepare(g, cam)
        own = rng.uniform(size=n) > 0.6
        keep = rng.uniform(size=n) > 0.3
        for k in (None, keep):
            _assert_close(gv.render(keep=k, background=bg), pv.render(keep=k, background=bg))
        for x, y in zip(gv.render_pair(keep=~own), pv.render_pair(keep=~own)):
            _assert_close(x, y)
        empty = gv.render(keep=np.zeros(n, bool), background=bg)
        assert np.allclose(empty.rgb, bg) and (empty.alpha == 0).all()
        # Visibility and centres agree with the CPU except at the image border.
        assert abs(gv.num_visible - pv.num_visible) <= 0.05 * pv.num_visible
        assert (gv.centres_inside() != pv.centres_inside()).mean() < 0.01
        # Exactness of the tile sets on the GPU: re-rendering only the touched tiles gives the
        # full render (the renders are deterministic).
        removed = np.flatnonzero(rng.uniform(size=n) < 0.05)
        after = keep.copy()
        after[removed] = False
        base = gv.render(keep=keep)
        full = gv.render(keep=after)
        part = gv.rerender(base, keep=after, tiles=gv.tiles_touched(removed))
        for name in ("rgb", "alpha", "depth"):
            np.testing.assert_allclose(getattr(part, name), getattr(full, name), atol=1e-6)
        batched = gv.render_many([None, keep, after], batch_size=3)
        looped = gv.render_many([None, keep, after], batch_size=1)
        for x, y in zip(batched, looped):
            for name in ("rgb", "alpha", "depth"):
                np.testing.assert_allclose(getattr(x, name), getattr(y, name), atol=1e-6)


# -- filter_distractors(device=...) ----------------------------------------------------------
def _filter_world():
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=4, seed=2, height=64, width=112)
    return reconstruct(world.cameras, world.images, world.depths, seed=2)


def test_filter_on_gpu_path_equals_cpu_filter(fake_gsplat, monkeypatch):
    # The whole GPU path of the filter (views, full-image verification renders, joint test)
    # through the fake gsplat, which is the CPU rasterizer: the same decisions as on the CPU.
    from clearsplat.render import gsplat as _gsplat
    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors
    scene = _filter_world()
    fake_gsplat.add(*scene.cameras)
    chosen = []

    def on_cpu_torch(scene, cameras, *, device):
        chosen.append(device)
        return real(scene, cameras, device="cpu")   # torch CPU tensors into the fake

    real = _gsplat.prepare_gsplat_views
    monkeypatch.setattr(_gsplat, "prepare_gsplat_views", on_cpu_torch)
    extractor = get_extractor("local")
    # Two rounds: the second runs on the Gaussians the first kept, through the GPU path too.
    cpu = filter_distractors(scene, config=FilterConfig(rounds=2), extractor=extractor)
    gpu = filter_distractors(scene, config=FilterConfig(device="cuda:0", rounds=2),
                             extractor=extractor)
    assert chosen == ["cuda:0", "cuda:0"]      # one upload of the Gaussians per round
    assert {c.round for c in gpu.candidates} == {1, 2}
    assert len(fake_gsplat.calls) > 10
    assert cpu.removed.sum() > 0
    np.testing.assert_array_equal(gpu.keep, cpu.keep)
    assert [c.accepted for c in gpu.candidates] == [c.accepted for c in cpu.candidates]
    for a, b in zip(gpu.candidates, cpu.candidates):
        assert a.scores.keys() == b.scores.keys()
        for k in a.scores:
            assert a.scores[k] == pytest.approx(b.scores[k], rel=1e-4, abs=1e-9)


def test_filter_on_gpu_path_with_neighbourhoods_equals_cpu_filter(fake_gsplat, monkeypatch):
    # Bounded neighbourhoods on the GPU path: each view's keep masks narrowed to the views it
    # holds; the native path prepares its views on that subset. The same decisions.
    from clearsplat.render import gsplat as _gsplat
    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors
    from clearsplat.synth import make_world, reconstruct
    world = make_world("street", num_views=6, seed=2, height=48, width=80)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=2)
    fake_gsplat.add(*scene.cameras)
    real = _gsplat.prepare_gsplat_views
    monkeypatch.setattr(_gsplat, "prepare_gsplat_views",
                        lambda scene, cameras, *, device: real(scene, cameras, device="cpu"))
    extractor = get_extractor("local")
    cfg = FilterConfig(neighbours=2, verify_views="mutual", min_relative_score=0.0)
    cpu = filter_distractors(scene, config=cfg, extractor=extractor)
    gpu = filter_distractors(scene, config=cfg.replace(device="cuda:0"), extractor=extractor)
    assert cpu.removed.sum() > 0
    np.testing.assert_array_equal(gpu.keep, cpu.keep)
    assert [c.verify_views for c in gpu.candidates] == [c.verify_views for c in cpu.candidates]
    for a, b in zip(gpu.candidates, cpu.candidates):
        for k in a.scores:
            assert a.scores[k] == pytest.approx(b.scores[k], rel=1e-4, abs=1e-9)


def test_filter_device_is_validated():
    from clearsplat.filter import FilterConfig
    for bad in ("gpu", "cuda:x", "CUDA", 0):
        with pytest.raises(ClearsplatError) as e:
            FilterConfig(device=bad)
        assert e.value.field == "device"
    assert FilterConfig(device="cuda:1").device == "cuda:1"


def test_filter_on_gpu(gpu_views):
    # On a real GPU: the same distractors as the CPU filter, up to borderline candidates.
    from clearsplat.features import get_extractor
    from clearsplat.filter import FilterConfig, filter_distractors
    scene = _filter_world()
    extractor = get_extractor("local")
    cpu = filter_distractors(scene, extractor=extractor)
    gpu = filter_distractors(scene, config=FilterConfig(device="cuda"), extractor=extractor)
    both = (cpu.removed & gpu.removed).sum()
    either = (cpu.removed | gpu.removed).sum()
    assert cpu.removed.sum() > 0 and both / either >= 0.9


@pytest.mark.parametrize("layout", [None, "shared_sh", "batched"])
@pytest.mark.parametrize("settings", [None, "aa"])
def test_every_batch_layout_and_the_scene_settings_reach_gsplat(monkeypatch, layout, settings):
    # gsplat 1.4-1.5.2 (no batch dims), the development version (SH shared) and 1.5.3: the
    # view finds what the installed gsplat takes, renders the scene's settings, equals the CPU.
    pytest.importorskip("torch")
    from clearsplat import RenderSettings, Scene
    from clearsplat.render import _gsplat_call
    from clearsplat.render.gsplat import prepare_gsplat_views
    s = RenderSettings(antialiased=True, eps2d=0.1, radius_clip=0.1) if settings else None
    fake = _install(monkeypatch, FakeGsplat(layout, s))
    g, cams = _world(3, n=200, sh_degree=4 if settings else 2)
    g.scales[::2] *= 0.05
    fake.add(*cams)
    scene = Scene(g, np.zeros(len(g), np.int32), None, cams,
                  render_settings=s or RenderSettings())
    views = prepare_gsplat_views(scene, cams, device="cpu")
    rng = np.random.default_rng(2)
    keeps = [None, rng.uniform(size=len(g)) > 0.3, rng.uniform(size=len(g)) > 0.6]
    for gv, cam in zip(views[1:], cams[1:]):      # the rotated, off-centre camera
        pv = prepare(scene, cam)
        fake.calls.clear()
        many = gv.render_many(keeps)
        assert fake.calls == ([()] * 3 if layout is None else [(3,)])
        for keep, r in zip(keeps, many):
            _assert_same(r, pv.render(keep=keep))
        for x, y in zip(gv.render_pair(keep=keeps[1]), pv.render_pair(keep=keeps[1])):
            _assert_same(x, y)
        region = np.ones((cam.height, cam.width), bool)
        np.testing.assert_array_equal(gv.contributions(region).weight,
                                      pv.contributions(region).weight)
    assert _gsplat_call._layouts[fake.rasterization] == layout
    if settings:
        classic = prepare(g, cams[0]).render()
        assert np.abs(classic.rgb - views[0].render().rgb).max() > 1e-2


# -- real gsplat versions, on the CPU ---------------------------------------------------------
# gsplat's CUDA kernels cannot run here, but its Python entry point (``rasterization``, with the
# shape assertions that differ between versions) and its pure-PyTorch reference
# (``gsplat.cuda._torch_impl``) can. Point CLEARSPLAT_GSPLAT_TREES at unpacked gsplat wheels or
# source trees (folders holding ``gsplat/``, separated by os.pathsep), for example:
#   pip download --no-deps gsplat==1.5.2 -d w && python -m zipfile -e w/gsplat-*.whl t152
# gsplat's compiled backend is replaced by "not built" (``_C = None``), a state gsplat handles.
def _gsplat_trees():
    import os
    trees = [p for p in os.environ.get("CLEARSPLAT_GSPLAT_TREES", "").split(os.pathsep) if p]
    return trees or [pytest.param(None, marks=pytest.mark.skip(
        reason="set CLEARSPLAT_GSPLAT_TREES to unpacked gsplat wheels"))]


class _Reached(Exception):
    """Raised by a stubbed gsplat kernel: the call got past every shape check before it."""


@pytest.fixture
def gsplat_tree(request, monkeypatch):
    import importlib
    pytest.importorskip("torch")
    path = request.param

    def purge():
        for name in [n for n in sys.modules if n == "gsplat" or n.startswith("gsplat.")]:
            del sys.modules[name]

    for name in [n for n in sys.modules if n == "gsplat" or n.startswith("gsplat.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.syspath_prepend(path)
    importlib.invalidate_caches()
    backend = types.ModuleType("gsplat.cuda._backend")
    backend._C = None
    sys.modules["gsplat.cuda._backend"] = backend
    try:
        import gsplat
        import gsplat.cuda._torch_impl  # noqa: F401
        import gsplat.rendering  # noqa: F401
        assert gsplat.__file__.startswith(str(path)), gsplat.__file__
        yield gsplat
    finally:
        purge()


def _version(gsplat):
    return tuple(int(x) for x in gsplat.__version__.split("+")[0].split(".")[:3])


def _expected_layout(version):
    if version >= (1, 6, 0):
        return "shared_sh"
    return "batched" if version >= (1, 5, 3) else None


def _stub_kernels(gsplat, monkeypatch):
    """Record what ``rasterization`` hands its first kernels, then stop with _Reached."""
    import torch
    R, T = gsplat.rendering, gsplat.cuda._torch_impl
    seen = {}
    if hasattr(R, "fully_fused_projection") and _version(gsplat) < (1, 6, 0):
        import inspect
        sig = inspect.signature(R.fully_fused_projection)

        def project(*args, **kwargs):
            a = sig.bind(*args, **kwargs).arguments
            seen["project"] = a
            covars = a.get("covars")
            if covars is None:
                covars, _ = T._quat_scale_to_covar_preci(a["quats"], a["scales"], True, False)
            return T._fully_fused_projection(
                a["means"], covars, a["viewmats"], a["Ks"], a["width"], a["height"],
                eps2d=a["eps2d"], near_plane=a["near_plane"], far_plane=a["far_plane"],
                calc_compensations=a["calc_compensations"])

        def sh(degree, dirs, coeffs, **kwargs):
            seen["sh"] = (degree, tuple(dirs.shape), tuple(coeffs.shape))
            raise _Reached("spherical_harmonics")

        monkeypatch.setattr(R, "fully_fused_projection", project)
        monkeypatch.setattr(R, "spherical_harmonics", sh)
    else:
        # The development version: one fused C++ op. Its SH check (csrc/Rendering.cpp: "SH
        # colors must have shape [N, K, D]") is repeated here, as the RuntimeError it raises.
        import gsplat.cuda._wrapper as W

        def fused(name):
            def call(*args):
                seen["fused"] = args
                colors, sh_degree = args[5], args[25]
                if sh_degree >= 0 and colors.dim() != 3:
                    raise RuntimeError(f"SH colors must have shape [N, K, D], got "
                                       f"{list(colors.shape)}")
                raise _Reached(name)
            return call

        monkeypatch.setattr(R, "_make_lazy_cuda_func", fused)
        monkeypatch.setattr(R, "_make_lazy_cuda_obj", lambda name: name)
        monkeypatch.setattr(W, "_make_lazy_cuda_obj", lambda name: name)
        for name in ("FThetaCameraDistortionParameters", "UnscentedTransformParameters"):
            if hasattr(R, name):
                monkeypatch.setattr(R, name, lambda *a, **k: None)
    return seen


@pytest.mark.parametrize("gsplat_tree", _gsplat_trees(), indirect=True)
def test_call_shapes_against_real_gsplat_versions(gsplat_tree, monkeypatch):
    import torch
    from clearsplat import RenderSettings, Scene
    from clearsplat.render import _gsplat_call
    from clearsplat.render.gsplat import prepare_gsplat
    gs = gsplat_tree
    seen = _stub_kernels(gs, monkeypatch)
    expected = _expected_layout(_version(gs))
    # The probe: which batch layouts this version's rasterization takes.
    for layout in _gsplat_call.LAYOUTS:
        try:
            ok = _gsplat_call.accepts(torch, gs.rasterization, layout, "cpu")
        except _Reached:
            ok = True
        assert ok == (layout == expected), (gs.__version__, layout)
    # A view's renders in the layout the probe finds, with antialiased degree-4 settings.
    monkeypatch.setitem(_gsplat_call._layouts, gs.rasterization, expected)
    settings = RenderSettings(antialiased=True, eps2d=0.1, radius_clip=0.1)
    g, cams = _world(4, n=50, sh_degree=4)
    scene = Scene(g, np.zeros(50, np.int32), None, cams, render_settings=settings)
    view = prepare_gsplat(scene, cams[0], device="cpu")
    keeps = [np.ones(50, bool), np.arange(50) % 2 == 0, np.arange(50) % 3 == 0]
    for batch in (keeps[:1], keeps):
        seen.clear()
        with pytest.raises(_Reached):
            view.render_many(batch, batch_size=len(batch))
        b = () if len(batch) == 1 or expected is None else (len(batch),)
        if "project" in seen:
            p = seen["project"]
            assert tuple(p["means"].shape) == b + (50, 3)
            assert (p["eps2d"], p["radius_clip"], p["calc_compensations"]) == (0.1, 0.1, True)
            assert p["width"] == cams[0].width and p["height"] == cams[0].height
            degree, dirs, coeffs = seen["sh"]
            assert degree == 4 and coeffs[-2:] == (25, 3) and dirs[:len(b)] == b
        else:
            args = seen["fused"]
            assert tuple(args[0].shape) == b + (50, 3) and tuple(args[5].shape) == (50, 25, 3)
            assert (args[11], args[14], args[19], args[25]) == (0.1, 0.1, True, 4)


@pytest.mark.parametrize("gsplat_tree", _gsplat_trees(), indirect=True)
def test_reference_rasterizer_against_gsplat_pure_pytorch(gsplat_tree):
    # The test reference's SH (degrees 0-4) and antialiased projection against gsplat's own
    # pure-PyTorch twins of its kernels.
    import reference_rasterizer as ref
    import torch
    from clearsplat import RenderSettings
    T = gsplat_tree.cuda._torch_impl
    rng = np.random.default_rng(8)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for degree in range(5):
        k = (degree + 1) ** 2
        coeffs = rng.normal(size=(400, k, 3))
        want = np.einsum("nk,nkc->nc", ref.sh_basis(d, k), coeffs)
        got = T._spherical_harmonics(degree, torch.tensor(d, dtype=torch.float32),
                                     torch.tensor(coeffs, dtype=torch.float32)).numpy()
        np.testing.assert_allclose(got, want, atol=2e-5, rtol=0)
    # Projection: a centred principal point (gsplat's per-side frustum clamp then equals the
    # reference's), Gaussians in front of the camera, many of them sub-pixel.
    w, h = 64, 40
    cam = Camera(K=[[50.0, 0, w / 2], [0, 52.0, h / 2], [0, 0, 1]],
                 camera_to_world=look_at((0.3, 0.2, -3.0), (0, 0, 0), up=(0, -1, 0)),
                 width=w, height=h)
    g, _ = _world(9, n=300, sh_degree=0)
    g.means[:, 2] = np.abs(g.means[:, 2])
    g.scales[::2] *= 0.05
    for eps2d in (0.1, 0.3):
        settings = RenderSettings(antialiased=True, eps2d=eps2d)
        p = ref.project(g, cam, settings=settings)
        R = ref.quat_to_rotmat(g.quats.astype(np.float64))
        M = R * g.scales.astype(np.float64)[:, None, :]
        covars = M @ np.transpose(M, (0, 2, 1))
        f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
        radii, means2d, depths, conics, comp = T._fully_fused_projection(
            f32(g.means), f32(covars), f32(cam.world_to_camera)[None], f32(cam.K)[None], w, h,
            eps2d=eps2d, near_plane=0.01, far_plane=1e10, calc_compensations=True)
        both = p["visible"] & (radii.reshape(1, 300, -1)[0] > 0).all(-1).numpy()
        assert both.sum() > 100
        uv = np.stack([p["u"], p["v"]], axis=1)
        np.testing.assert_allclose(means2d[0].numpy()[both], uv[both], atol=1e-3, rtol=1e-5)
        np.testing.assert_allclose(conics[0].numpy()[both], p["conic"][both], rtol=1e-3,
                                   atol=1e-5)
        want = p["opacity"]
        floor = getattr(gsplat_tree.cuda._torch_impl, "MIN_COMPENSATION", None)
        if floor is not None:
            # gsplat's development version floors the compensation at 0.005 (1.5.x does not;
            # clearsplat follows the released versions; docs/backbones.md).
            want = g.opacities * np.maximum(want / g.opacities, floor)
        np.testing.assert_allclose((comp[0].numpy() * g.opacities)[both], want[both],
                                   atol=1e-5, rtol=1e-4)
        np.testing.assert_allclose(depths[0].numpy()[both], p["depth"][both], rtol=1e-5)
