"""The torch backend: TorchView against the native rasterizer and the NumPy reference, the
filter's decisions with ``backend="torch"``, the command line, and the number of torch ops.

Tolerance (float32): the projection, culling, boxes, tiles and depth order are computed with
the native code's operations in the same order, so visible sets, tiles and contribution lists
must be equal. Compositing forms each pixel's products and sums of up to a few hundred
fragments as float64 scans where the C++ loop multiplies and adds in float32 one fragment at
a time: each differs from the exact value by at most about ``n`` float32 ulps (``n * 6e-8``
relative, n fragments), so colours and alpha are compared to ``TOL = 1e-5`` absolute (measured:
at most 4e-7), and depth as ``depth * alpha`` (depth alone amplifies rounding where alpha is
tiny) to ``TOL`` times the largest depth.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import reference_rasterizer as ref  # noqa: E402
from clearsplat import Camera, ClearsplatError, Gaussians, RenderSettings  # noqa: E402
from clearsplat.cameras import look_at  # noqa: E402
from clearsplat.cli import main  # noqa: E402
from clearsplat.features import get_extractor  # noqa: E402
from clearsplat.filter import FilterConfig, filter_distractors, filter_prediction  # noqa: E402
from clearsplat.filter.backend import TorchBackend, backend_for  # noqa: E402
from clearsplat.filter.verify import Verifier  # noqa: E402
from clearsplat.render import _torch_composite, prepare  # noqa: E402
from clearsplat.render.torch_view import prepare_torch, upload_torch  # noqa: E402
from clearsplat.scene import rgb_to_sh_dc  # noqa: E402
from clearsplat.synth.backbone import reconstruct  # noqa: E402
from clearsplat.synth.worlds import make_world  # noqa: E402

TOL = 1e-5
# The CUDA twins of the CPU tests below run where PyTorch sees a GPU and skip elsewhere.
ON_DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs PyTorch with a CUDA GPU"))]


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """One torch thread in this module: torch's OpenMP runtime and the native core's spin
    against each other on a busy machine (``docs/method.md``, "The torch backend"), which only
    makes these tests slow."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def make_camera(width, height, *, eye=(0.3, 0.2, -3.0), f=(50.0, 55.0)) -> Camera:
    return Camera(K=[[f[0], 0, width / 2 + 0.3], [0, f[1], height / 2 - 0.2], [0, 0, 1]],
                  camera_to_world=look_at(eye, (0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)),
                  width=width, height=height)


def random_scene(seed: int, n: int = 800, k: int = 16) -> Gaussians:
    """Anisotropic Gaussians around the origin, some behind the camera, many beside it."""
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3)) * 1.2
    means[: n // 10, 2] = rng.uniform(-6.0, -3.05, n // 10)
    opac = rng.uniform(0, 1, n)
    opac[:3] = (0.0, 1.0, 0.999)
    return Gaussians(means=means, scales=np.exp(rng.uniform(np.log(0.01), np.log(0.25), (n, 3))),
                     quats=rng.normal(size=(n, 4)), opacities=opac,
                     sh=rng.normal(size=(n, k, 3)) * 0.4)


def assert_close(a, b):
    """Two RenderResults (or TilePatches) within the float32 tolerance."""
    np.testing.assert_allclose(a.rgb, b.rgb, atol=TOL, rtol=0)
    np.testing.assert_allclose(a.alpha, b.alpha, atol=TOL, rtol=0)
    scale = max(1.0, float(np.abs(b.depth).max(initial=0.0)))
    np.testing.assert_allclose(a.depth * a.alpha, b.depth * b.alpha, atol=TOL * scale, rtol=0)


CASES = [(72, 40, 1, 0, RenderSettings()), (64, 48, 4, 1, RenderSettings()),
         (33, 17, 9, 2, RenderSettings(antialiased=True)),
         (88, 56, 16, 3, RenderSettings(eps2d=0.1, radius_clip=1.0)),
         (40, 70, 25, 4, RenderSettings(antialiased=True, sh_degree=2))]


@pytest.fixture(params=CASES, ids=[f"{w}x{h}-k{k}-s{s}" for w, h, k, s, _ in CASES])
def pair(request):
    """(native PreparedView, TorchView, Gaussians, settings) of one random scene."""
    w, h, k, seed, settings = request.param
    g = random_scene(seed, k=k)
    cam = make_camera(w, h)
    return (prepare(g, cam, settings=settings), prepare_torch(g, cam, settings=settings), g,
            settings)


# -- TorchView against the native rasterizer and the reference --------------------------------
def test_projection_binning_and_order_are_the_native_ones(pair):
    pv, tv, g, _ = pair
    assert tv.num_visible == pv.num_visible > 100
    np.testing.assert_array_equal(tv.visible, pv.visible)          # same order, front to back
    rec = np.concatenate([tv._t.geom.numpy(), tv._t.colour.numpy()], 1)
    np.testing.assert_array_equal(rec, pv._splats[:, :10])         # the same float32 records
    boxes = pv._splats[:, 10:12].copy().view(np.int16).reshape(-1, 4)
    np.testing.assert_array_equal(tv._t.box.numpy(), boxes)
    np.testing.assert_array_equal(tv._rect.numpy(), pv._rects)
    np.testing.assert_array_equal(tv._t.offsets.numpy(), pv._offsets)
    np.testing.assert_array_equal(tv._t.lists.numpy(), pv._lists)
    np.testing.assert_array_equal(tv.centres_inside(), pv.centres_inside())


@pytest.mark.parametrize("device", ON_DEVICES)
def test_render_matches_native_and_reference(pair, device):
    pv, tv, g, settings = pair
    if device != "cpu":
        tv = prepare_torch(g, tv.camera, settings=settings, device=device)
    keep = np.random.default_rng(5).random(len(g)) > 0.3
    for k, bg in ((None, (0.0, 0.0, 0.0)), (keep, (0.2, 0.5, 1.0))):
        out = tv.render(keep=k, background=bg)
        assert out.rgb.dtype == np.float32 and out.rgb.shape == (tv.camera.height,
                                                                 tv.camera.width, 3)
        assert_close(out, pv.render(keep=k, background=bg))
    # The float64 NumPy reference (slow: once), within its tolerance of tests/test_render.py.
    rgb, alpha, depth, _ = ref.render(g, tv.camera, keep=keep, background=bg, settings=settings)
    np.testing.assert_allclose(out.rgb, rgb, atol=1e-4, rtol=0)
    np.testing.assert_allclose(out.alpha, alpha, atol=1e-4, rtol=0)
    assert out.alpha.max() > 0.9 and out.alpha.min() < 0.7             # not a trivial image


def test_render_pair_rerender_and_tiles_touched(pair):
    pv, tv, g, _ = pair
    rng = np.random.default_rng(7)
    keep = rng.random(len(g)) > 0.2
    small = np.argsort(np.asarray(g.scales).max(1))          # small ones touch few tiles
    removal = small[keep[small]][:8]
    tiles = tv.tiles_touched(removal)
    np.testing.assert_array_equal(tiles, pv.tiles_touched(removal))
    assert tiles.dtype == np.int32 and 0 < tiles.size < tv.num_tiles
    without = keep.copy()
    without[removal] = False
    a, b = tv.render_pair(keep=without, first=keep)
    assert_close(a, pv.render(keep=keep))
    assert_close(b, pv.render(keep=without))
    start = pv.render(keep=keep)
    a, b = tv.render_pair(keep=without, first=keep, tiles=tiles, start=start)
    na, nb = pv.render_pair(keep=without, first=keep, tiles=tiles, start=start)
    assert_close(a, na)
    assert_close(b, nb)
    again = tv.rerender(tv.render(keep=keep), keep=without, tiles=tiles)
    assert_close(again, pv.render(keep=without))   # exact wherever a removal can change it


def test_render_layers_match_native(pair):
    pv, tv, g, _ = pair
    code = np.random.default_rng(3).integers(-1, 3, size=len(g))
    layers = [code == k for k in range(3)]
    for a, b in zip(tv.render_layers(layers), pv.render_layers(layers)):
        assert_close(a, b)
    by_id = tv.render_layers(code)
    assert len(by_id) == 3
    for a, b in zip(by_id, pv.render_layers(layers)):
        assert_close(a, b)


@pytest.mark.parametrize("with_base", [False, True])
def test_rerender_tiles_matches_native(pair, with_base):
    pv, tv, g, _ = pair
    rng = np.random.default_rng(11)
    keep = rng.random(len(g)) > 0.2
    removals = [np.flatnonzero(keep)[rng.integers(0, keep.sum(), m)] for m in (1, 5, 30)]
    removals += [np.zeros(len(g), bool), rng.random(len(g)) > 0.9]      # empty, a bool mask
    base = pv.render(keep=keep) if with_base else None
    got = tv.rerender_tiles(keep=keep, removals=removals, base=base)
    want = pv.rerender_tiles(keep=keep, removals=removals, base=base)
    assert len(got) == len(want) == len(removals)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a.tiles, b.tiles)
        assert a.rgb.shape == b.rgb.shape and a.alpha.dtype == np.float32
        assert_close(a, b)
    assert got[3].tiles.size == 0 and got[2].tiles.size > 0
    # Given tile lists instead of the touched ones.
    lists = [np.arange(0, tv.num_tiles, 3), np.array([0]), np.array([], int), [1, 2],
             np.arange(tv.num_tiles)]
    for a, b in zip(tv.rerender_tiles(keep=keep, removals=removals, tiles_list=lists, base=base),
                    pv.rerender_tiles(keep=keep, removals=removals, tiles_list=lists, base=base)):
        np.testing.assert_array_equal(a.tiles, b.tiles)
        assert_close(a, b)


def test_chunked_compositing_gives_the_same_results(monkeypatch):
    g = random_scene(1, n=300)
    tv = prepare_torch(g, make_camera(64, 48))
    whole = tv.render()
    rng = np.random.default_rng(3)
    removals = [rng.integers(0, len(g), 5) for _ in range(4)]
    patches = tv.rerender_tiles(keep=None, removals=removals, base=whole)
    monkeypatch.setattr(_torch_composite, "BUDGET", 3000)    # several chunks of tasks
    assert_close(tv.render(), whole)
    for a, b in zip(tv.rerender_tiles(keep=None, removals=removals, base=whole), patches):
        np.testing.assert_array_equal(a.tiles, b.tiles)
        assert_close(a, b)


def test_contributions_match_native(pair):
    pv, tv, g, _ = pair
    h, w = tv.camera.height, tv.camera.width
    mask = np.zeros((h, w), bool)
    mask[h // 4:3 * h // 4, w // 5:w // 2] = True
    mask[-1, -1] = True
    keep = np.random.default_rng(2).random(len(g)) > 0.25
    a, b = tv.contributions(mask, keep=keep), pv.contributions(mask, keep=keep)
    assert a.pixel.size > 100
    np.testing.assert_array_equal(a.pixel, b.pixel)
    np.testing.assert_array_equal(a.gaussian, b.gaussian)
    np.testing.assert_allclose(a.weight, b.weight, atol=TOL, rtol=0)
    assert a.pixel.dtype == np.int64 and a.weight.dtype == np.float32


def test_a_lone_isotropic_gaussian_has_its_closed_form():
    # On the optical axis the Jacobian is diag(f / z): Sigma2D = (f s / z)^2 I + eps2d I.
    z, s, o, f = 4.0, 0.05, 0.8, 60.0
    colour = np.array([1.0, 0.5, 0.25])
    g = Gaussians(means=[[0.0, 0.0, z]], scales=[[s] * 3], quats=[[1.0, 0, 0, 0]],
                  opacities=[o], sh=rgb_to_sh_dc(np.array([[colour]])))
    cam = Camera(K=[[f, 0, 24.0], [0, f, 16.0], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=48, height=32)
    out = prepare_torch(g, cam).render(background=(0.0, 0.0, 1.0))
    var = (f * s / z) ** 2 + 0.3
    xx, yy = np.meshgrid(np.arange(48) + 0.5, np.arange(32) + 0.5)
    alpha = o * np.exp(-0.5 * ((xx - 24.0) ** 2 + (yy - 16.0) ** 2) / var)
    alpha = np.where(alpha >= 1 / 255, np.minimum(alpha, 0.99), 0.0)
    np.testing.assert_allclose(out.alpha, alpha, atol=1e-6, rtol=0)
    np.testing.assert_allclose(out.rgb, alpha[..., None] * colour
                               + (1 - alpha)[..., None] * [0.0, 0.0, 1.0], atol=1e-6, rtol=0)
    # alpha = 1 - T holds alpha to float32 ulps of 1: depth = D / alpha to about 6e-8 / alpha.
    np.testing.assert_allclose(out.depth * out.alpha, z * alpha, atol=1e-6 * z, rtol=0)
    np.testing.assert_allclose(out.depth[alpha > 0.1], z, rtol=1e-5)
    assert (out.depth[alpha == 0] == 0).all() and out.alpha.max() > 0.55


def test_bad_input_names_the_field():
    g = random_scene(0, n=50)
    tv = prepare_torch(g, make_camera(32, 32))
    with pytest.raises(ClearsplatError) as e:
        tv.render(keep=np.ones(49, bool))
    assert e.value.field == "keep"
    with pytest.raises(ClearsplatError) as e:
        tv.render(keep=torch.ones(50, dtype=torch.float32))
    assert e.value.field == "keep"
    with pytest.raises(ClearsplatError) as e:
        tv.rerender_tiles(keep=None, removals=[[0], [50]])
    assert e.value.field == "removals[1]"
    with pytest.raises(ClearsplatError) as e:
        tv.rerender(tv.render(), keep=None, tiles=[tv.num_tiles])
    assert e.value.field == "tiles"
    with pytest.raises(ClearsplatError) as e:
        upload_torch(g, device="tpu")
    assert e.value.field == "device"
    # A keep mask may be a torch bool tensor on the device.
    keep = torch.from_numpy(np.arange(50) % 2 == 0)
    assert_close(tv.render(keep=keep), tv.render(keep=keep.numpy()))


def test_without_torch_the_error_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ImportError, match=r"pip install clearsplat\[gpu\]"):
        upload_torch(random_scene(0, n=10))
    with pytest.raises(ClearsplatError, match=r"pip install clearsplat\[gpu\]") as e:
        backend_for(FilterConfig(backend="torch"))
    assert e.value.field == "backend"


# -- the filter --------------------------------------------------------------------------------
def decisions(result):
    return [(c.view, c.range, c.round, c.accepted, c.reason, c.gaussians.tolist(),
             None if c.expanded is None else c.expanded.tolist()) for c in result.candidates]


@pytest.mark.parametrize("device", ON_DEVICES)
@pytest.mark.parametrize("family,views,height,width",
                         [("object", 4, 64, 112), ("street", 4, 48, 80), ("object", 8, 32, 64)])
def test_the_filter_makes_the_native_decisions(family, views, height, width, device):
    world = make_world(family, num_views=views, seed=1, height=height, width=width)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    extractor = get_extractor("local")
    native = filter_distractors(scene, config=FilterConfig(), extractor=extractor)
    config = FilterConfig(backend="torch", device=device)
    assert isinstance(backend_for(config), TorchBackend) and backend_for(config).incremental
    result = filter_distractors(scene, config=config, extractor=extractor)
    assert native.removed.sum() > 0 and sum(c.accepted for c in native.candidates) > 0
    np.testing.assert_array_equal(result.removed, native.removed)
    assert decisions(result) == decisions(native)
    for a, b in zip(result.candidates, native.candidates):
        for test, score in b.scores.items():
            assert abs(a.scores[test] - score) < 1e-5, (a.index, test)


@pytest.mark.parametrize("device", ON_DEVICES)
def test_filter_prediction_gives_the_keep_mask_on_the_device(device):
    world = make_world("object", num_views=4, seed=2, height=48, width=80)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=2)
    native = filter_distractors(scene)
    keep = filter_prediction(scene, device=device)
    assert isinstance(keep, torch.Tensor) and keep.dtype == torch.bool
    assert keep.device.type == device and tuple(keep.shape) == (len(scene),)
    np.testing.assert_array_equal(keep.cpu().numpy(), native.keep)
    assert not native.keep.all()
    mask = native.keep_tensor(torch.device(device))
    assert mask.dtype == torch.bool and torch.equal(mask, keep)
    with pytest.raises(ClearsplatError) as e:
        filter_prediction(scene, device="tpu")
    assert e.value.field == "device"


@pytest.mark.parametrize("device", ON_DEVICES)
def test_cli_filter_with_the_torch_backend(tmp_path, capsys, device):
    world = make_world("object", num_views=4, seed=1, height=48, width=80)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    scene.save(tmp_path / "scene")
    assert main(["filter", str(tmp_path / "scene"), "--out", str(tmp_path / "native")]) == 0
    assert main(["filter", str(tmp_path / "scene"), "--out", str(tmp_path / "torch"),
                 "--set", "backend=torch", "--set", f"device={device}"]) == 0
    capsys.readouterr()
    removed = np.load(tmp_path / "torch" / "removed.npy")
    assert 0 < removed.sum() < removed.size // 10
    np.testing.assert_array_equal(removed, np.load(tmp_path / "native" / "removed.npy"))
    assert main(["filter", str(tmp_path / "scene"), "--out", str(tmp_path / "bad"),
                 "--set", "backend=native", "--set", "device=cuda"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "backend" in err[0] and "'native' renders on the CPU" in err[0]


# -- launch counts -----------------------------------------------------------------------------
def count_ops(fn) -> int:
    """The torch ops ``fn()`` calls: aten events not inside another aten op (those inside
    depend on the data, e.g. shortcuts for empty tensors, not on what the code issues)."""
    from torch.profiler import ProfilerActivity, profile
    fn()                                # warm: a view builds some lookups on first use
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        fn()
    return sum(1 for e in prof.events() if e.name.startswith("aten::") and (
        e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::")))


@pytest.fixture(scope="module")
def view_and_candidates():
    world = make_world("object", num_views=4, seed=1, height=64, width=112)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    # View 1 verifies removals of view 0's Gaussians from R_1^-1 (without view 1's own).
    rng = np.random.default_rng(0)
    ids = np.flatnonzero(scene.view_id == 0)
    removals = [np.sort(ids[rng.integers(0, ids.size, 25)]) for _ in range(20)]
    return scene, prepare_torch(scene, scene.cameras[1]), scene.view_id != 1, removals


def test_rerender_tiles_op_count_does_not_grow_with_removals(view_and_candidates):
    scene, tv, keep, removals = view_and_candidates
    base = tv.render(keep=keep)
    counts = {m: count_ops(lambda: tv.rerender_tiles(keep=keep, removals=removals[:m], base=base))
              for m in (1, 5, 20)}
    assert counts[1] == counts[5] == counts[20], counts
    assert counts[1] < 1500                    # batched calls, not a loop per task
    tasks = sum(p.tiles.size for p in tv.rerender_tiles(keep=keep, removals=removals, base=base))
    assert tasks > 100                         # the 20 removals do make many (removal, tile) pairs


def test_verification_op_count_does_not_grow_with_candidates(view_and_candidates):
    scene, tv, keep, removals = view_and_candidates
    h, w = tv.camera.height, tv.camera.width
    images = [scene.images[1].astype(np.float32)]
    verifier = Verifier([tv], images, epsilon=0.002, incremental=True)
    base = tv.render(keep=keep)
    q = np.zeros((h, w), bool)
    counts = {}
    for m in (1, 20):
        counts[m] = count_ops(lambda: verifier.score_view(0, keep, base, removals[:m], q))
    assert counts[1] == counts[20], counts
    parts = verifier.score_view(0, keep, base, removals, q)
    assert len(parts) == 20 and any(p.den > 0 for p in parts)
