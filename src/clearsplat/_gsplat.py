"""Render on a CUDA GPU through gsplat, returning what the CPU rasterizer returns.

:func:`render_gsplat` calls ``gsplat.rasterization`` (nerfstudio-project/gsplat,
``gsplat/rendering.py``) with the clearsplat conventions, which are also gsplat's: world-to-camera
view matrices (``viewmats``), pixel intrinsics ``Ks``, OpenCV camera axes, quaternions
``w x y z`` (normalised inside), linear scales, opacities in [0, 1], SH coefficients
``[N, K, 3]`` evaluated as ``max(0, SH(d) + 0.5)`` with ``d`` from the camera centre to the
Gaussian.

Differences from the CPU path (:func:`clearsplat.render.render`), all small:

- gsplat adds the same 0.3-pixel 2D blur (``eps2d=0.3``) in ``"classic"`` mode, but clamps the
  Jacobian per side of an off-centre principal point (``(W - cx) / fx + 0.3 tan_fov`` on one side,
  ``cx / fx + 0.3 tan_fov`` on the other) where the CPU path clamps ``x/z`` to ``1.3 W / (2 fx)``
  on both sides: identical for a centred principal point.
- gsplat computes its own screen extent of each Gaussian and culls those whose radius is at
  most ``radius_clip`` (0 here: only empty footprints); the edges differ by contributions below
  1/255, which both paths skip anyway.
- Gaussians are sorted per tile by float depth on the GPU; exact depth ties may blend in another
  order. Sums run in float32 in another order: expect differences around 1e-5, not bit equality.
- Depth: gsplat's ``"RGB+D"`` accumulates ``sum z_i a_i T_i``; it is divided by alpha here (0
  where alpha is 0), matching the CPU path's expected depth.
- The background is composited here, ``rgb + (1 - alpha) * background``, as on the CPU.
"""

from __future__ import annotations

import numpy as np

from .cameras import Camera
from .errors import ClearsplatError
from .render import RenderResult
from .scene import Gaussians, Scene

__all__ = ["render_gsplat"]

_HINT = ("render_gsplat needs PyTorch with CUDA, the gsplat package (`pip install gsplat`) "
         "and a CUDA GPU")


def _import_gsplat(device: str):
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


def render_gsplat(scene, camera: Camera, *, keep=None, background=(0.0, 0.0, 0.0),
                  near: float = 0.01, device: str = "cuda") -> RenderResult:
    """Render a scene from a camera with gsplat on a GPU.

    Parameters
    ----------
    scene : Scene or Gaussians
    camera : Camera
    keep : (N,) bool, optional
        Render only these Gaussians.
    background : 3 floats
        RGB behind the Gaussians.
    near : float
        Near plane (gsplat's ``near_plane``).
    device : str
        Torch device, ``"cuda"`` or ``"cuda:1"``...

    Returns
    -------
    RenderResult
        ``rgb`` (H, W, 3), ``alpha`` (H, W), ``depth`` (H, W) float32 NumPy arrays, as from
        :func:`clearsplat.render.render`.

    Raises
    ------
    ImportError
        Without PyTorch, gsplat or a CUDA GPU (the message says what to install).
    ClearsplatError
        Bad ``keep``, ``background`` or ``camera``.
    """
    g = scene.gaussians if isinstance(scene, Scene) else scene
    if not isinstance(g, Gaussians):
        raise ClearsplatError(f"expected a Scene or Gaussians, got {type(scene).__name__}",
                              field="scene")
    if not isinstance(camera, Camera):
        raise ClearsplatError(f"expected a Camera, got {type(camera).__name__}", field="camera")
    bg = np.asarray(background, dtype=np.float32)
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise ClearsplatError(f"expected 3 finite values, got {background!r}",
                              field="background")
    n = len(g)
    if keep is not None:
        keep = np.asarray(keep)
        if keep.shape != (n,) or keep.dtype != bool:
            raise ClearsplatError(f"expected ({n},) bool, got {keep.shape} {keep.dtype}",
                                  field="keep")
        g = g.subset(keep)
    torch, rasterization = _import_gsplat(device)
    h, w = camera.height, camera.width
    if len(g) == 0:
        rgb = np.broadcast_to(bg, (h, w, 3)).copy()
        zeros = np.zeros((h, w), dtype=np.float32)
        return RenderResult(rgb, zeros, zeros.copy())

    def t(a):
        return torch.as_tensor(np.ascontiguousarray(a, dtype=np.float32), device=device)

    with torch.no_grad():
        colors, alphas, _ = rasterization(
            means=t(g.means), quats=t(g.quats), scales=t(g.scales), opacities=t(g.opacities),
            colors=t(g.sh), viewmats=t(camera.world_to_camera)[None], Ks=t(camera.K)[None],
            width=w, height=h, near_plane=float(near), sh_degree=g.sh_degree, packed=False,
            eps2d=0.3, radius_clip=0.0, render_mode="RGB+D", rasterize_mode="classic")
    colors = colors[0].detach().cpu().numpy().astype(np.float32)
    alpha = alphas[0, ..., 0].detach().cpu().numpy().astype(np.float32)
    rgb = colors[..., :3] + (1.0 - alpha)[..., None] * bg
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(alpha > 0, colors[..., 3] / alpha, 0.0).astype(np.float32)
    return RenderResult(np.ascontiguousarray(rgb, dtype=np.float32), alpha, depth)
