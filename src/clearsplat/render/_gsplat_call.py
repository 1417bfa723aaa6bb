"""The one call into ``gsplat.rasterization``, for the gsplat versions users have.

gsplat's ``rasterization`` (``gsplat/rendering.py``) takes the same keywords from 1.4 to the
current development version, but its leading batch dimensions differ:

- 1.4.x, 1.5.0-1.5.2: none (``means`` must be ``[N, 3]``, ``viewmats`` ``[C, 4, 4]``);
- 1.5.3: ``[..., N, 3]`` for everything, SH coefficients included (``[..., N, K, 3]``);
- the development version (1.6): ``[..., N, 3]`` for the Gaussians, but SH coefficients must be
  ``[N, K, 3]``, shared by the batch (checked in its C++ code: a RuntimeError, not an
  AssertionError).

:func:`batch_layout` finds out which the installed gsplat accepts with one tiny call (kept per
``rasterization`` function); without batch support the renders run one call each. The render
settings (:class:`clearsplat.scene.RenderSettings`) go in as ``rasterize_mode``, ``eps2d``,
``radius_clip`` and ``sh_degree``, which all these versions take.
"""

from __future__ import annotations

import numpy as np

from ..scene import RenderSettings
from ._kernels import TILE

__all__ = ["import_gsplat", "tensor", "rasterize", "batch_layout", "sh_degree_of"]

_HINT = ("clearsplat's GPU path (render_gsplat, prepare_gsplat) needs PyTorch with CUDA, the "
         "gsplat package (`pip install gsplat`) and a CUDA GPU")

#: Batch layouts: ``"shared_sh"`` (Gaussians batched, SH ``[N, K, 3]``), ``"batched"``
#: (everything batched); None means no batch dimensions (one call per render).
LAYOUTS = ("shared_sh", "batched")
_layouts: dict = {}     # rasterization function -> layout it accepts (or None)


def import_gsplat(device):
    """torch and ``gsplat.rasterization``, or ImportError saying what is missing."""
    try:
        import torch
    except ImportError as e:
        raise ImportError(f"{_HINT}: PyTorch is not installed ({e})") from None
    try:
        from gsplat import rasterization
    except ImportError as e:
        raise ImportError(f"{_HINT}: gsplat is not installed ({e})") from None
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        raise ImportError(f"{_HINT}: torch.cuda.is_available() is False")
    return torch, rasterization


def tensor(torch, a, device):
    """A float32 tensor of a NumPy array on ``device`` (shares memory on the CPU)."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not a.flags.writeable:      # torch.from_numpy warns on read-only arrays
        a = a.copy()
    return torch.from_numpy(a).to(device)


def sh_degree_of(num_coeffs: int, settings: RenderSettings) -> int:
    """The SH degree gsplat evaluates: the coefficients' degree, capped by the settings."""
    degree = int(round(np.sqrt(num_coeffs))) - 1
    return degree if settings.sh_degree is None else min(degree, int(settings.sh_degree))


def rasterize(torch, rasterization, *, means, quats, scales, opacities, sh, viewmats, Ks,
              width: int, height: int, near: float, backgrounds, settings: RenderSettings):
    """One ``gsplat.rasterization`` call with clearsplat's conventions (no autograd).

    Inputs are already laid out for the installed gsplat (see :func:`batch_layout`); ``sh`` is
    ``[..., N, K, 3]`` or ``[N, K, 3]``.
    """
    with torch.no_grad():
        return rasterization(
            means=means, quats=quats, scales=scales, opacities=opacities, colors=sh,
            viewmats=viewmats, Ks=Ks, width=int(width), height=int(height),
            near_plane=float(near), sh_degree=sh_degree_of(sh.shape[-2], settings),
            packed=False, tile_size=TILE, eps2d=float(settings.eps2d),
            radius_clip=float(settings.radius_clip), backgrounds=backgrounds,
            render_mode="RGB+D",
            rasterize_mode="antialiased" if settings.antialiased else "classic")


def probe_args(torch, layout: str, device) -> dict:
    """Inputs of a two-render batch of one Gaussian in front of a 16x16 camera, in ``layout``."""
    def t(a):
        return tensor(torch, a, device)
    b = 2
    means = t([[0.0, 0.0, 2.0]]).expand(b, 1, 3)
    sh = t(np.zeros((1, 1, 3)))
    return dict(means=means, quats=t([[1.0, 0, 0, 0]]).expand(b, 1, 4),
                scales=t([[0.1, 0.1, 0.1]]).expand(b, 1, 3),
                opacities=t([0.5]).expand(b, 1).contiguous(),
                sh=sh if layout == "shared_sh" else sh.expand(b, 1, 1, 3),
                viewmats=t(np.eye(4)).expand(b, 1, 4, 4),
                Ks=t([[16.0, 0, 8], [0, 16, 8], [0, 0, 1]]).expand(b, 1, 3, 3),
                backgrounds=t(np.zeros(3)).expand(b, 1, 3))


def accepts(torch, rasterization, layout: str, device) -> bool:
    """Whether ``rasterization`` takes a batch in ``layout`` (False on its shape assertions)."""
    try:
        colors, alphas, _ = rasterize(torch, rasterization, width=16, height=16, near=0.01,
                                      settings=RenderSettings(),
                                      **probe_args(torch, layout, device))
    except (AssertionError, ValueError, TypeError):
        return False
    except RuntimeError as e:         # a shape check in gsplat's C++ code (TORCH_CHECK)
        if "shape" in str(e):
            return False
        raise
    return tuple(colors.shape) == (2, 1, 16, 16, 4) and tuple(alphas.shape) == (2, 1, 16, 16, 1)


def batch_layout(torch, rasterization, device):
    """The batch layout the installed gsplat accepts (see ``LAYOUTS``), or None for none."""
    if rasterization not in _layouts:
        _layouts[rasterization] = next(
            (lay for lay in LAYOUTS if accepts(torch, rasterization, lay, device)), None)
    return _layouts[rasterization]
