"""gsplat GPU path: same results as the CPU rasterizer (needs torch with CUDA and gsplat)."""

from __future__ import annotations

import numpy as np
import pytest

from clearsplat import Camera, ClearsplatError, Gaussians
from clearsplat.render import render


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


def test_missing_gsplat_raises_import_error_with_hint():
    from clearsplat._gsplat import render_gsplat
    g, cam = _scene(n=3)
    try:
        import gsplat  # noqa: F401
        import torch
        if torch.cuda.is_available():
            pytest.skip("gsplat and CUDA are available")
    except ImportError:
        pass
    with pytest.raises(ImportError, match="pip install gsplat"):
        render_gsplat(g, cam)


def test_bad_input_is_reported_before_the_gpu():
    from clearsplat._gsplat import render_gsplat
    g, cam = _scene(n=3)
    with pytest.raises(ClearsplatError) as e:
        render_gsplat(g, cam, background=(0, 0))
    assert e.value.field == "background"
    with pytest.raises(ClearsplatError) as e:
        render_gsplat(g, cam, keep=np.ones(2, bool))
    assert e.value.field == "keep"


@pytest.fixture
def gpu():
    torch = pytest.importorskip("torch")
    pytest.importorskip("gsplat")
    if not torch.cuda.is_available():
        pytest.skip("no CUDA GPU")
    from clearsplat._gsplat import render_gsplat
    return render_gsplat


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_gsplat_matches_cpu_render(gpu, sh_degree):
    g, cam = _scene(seed=sh_degree, sh_degree=sh_degree)
    keep = np.random.default_rng(9).uniform(size=len(g)) > 0.3
    bg = (0.2, 0.4, 0.6)
    cpu = render(g, cam, keep=keep, background=bg)
    out = gpu(g, cam, keep=keep, background=bg)
    for name in ("rgb", "alpha", "depth"):
        a, b = getattr(cpu, name), getattr(out, name)
        assert a.shape == b.shape and b.dtype == np.float32
    assert np.abs(cpu.rgb - out.rgb).mean() < 1e-3
    assert np.abs(cpu.rgb - out.rgb).max() < 2e-2
    assert np.abs(cpu.alpha - out.alpha).max() < 2e-2
    covered = (cpu.alpha > 0.5) & (out.alpha > 0.5)
    assert np.abs(cpu.depth - out.depth)[covered].max() < 1e-2
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
