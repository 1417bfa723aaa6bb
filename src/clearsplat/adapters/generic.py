"""Any pixel-aligned model: per-pixel arrays laid out ``(V, H, W[, spp], ...)``."""

from __future__ import annotations

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Scene
from ._common import (covariance_to_scales_quats, images_checked, make_scene,
                      opacities_checked, sh_to_clearsplat, to_numpy)

__all__ = ["from_pixel_aligned"]


def from_pixel_aligned(means, *, sh, opacities, cameras, images=None, covariances=None,
                       scales=None, quats=None, quat_order: str = "wxyz",
                       max_sh_degree: int = 3, render_settings=None) -> Scene:
    """A scene from per-pixel Gaussians of any model.

    Parameters
    ----------
    means : (V, H, W, 3) or (V, H, W, spp, 3)
        World-frame centres; view ``v``, pixel ``(row, col)``, sample ``s``.
    sh : (V, H, W[, spp], K, 3) or (V, H, W[, spp], 3, K)
        SH coefficients in the world frame (either axis order; K in 1, 4, 9, 16, 25). For plain
        colours use :func:`clearsplat.scene.rgb_to_sh_dc` and K = 1.
    opacities : (V, H, W[, spp]) or with a trailing 1
        In [0, 1].
    cameras : sequence of Camera
        The V input cameras (``cameras[v].height, .width == H, W``).
    images : (V, H, W, 3) or (V, 3, H, W), optional
        In [0, 1].
    covariances : (V, H, W[, spp], 3, 3), optional
        World-frame covariances; or give ``scales`` and ``quats`` instead.
    scales : (V, H, W[, spp], 3), optional
        Linear standard deviations.
    quats : (V, H, W[, spp], 4), optional
        Rotations in ``quat_order``.
    quat_order : {"wxyz", "xyzw"}
        ``"xyzw"`` for scipy / pixelSplat-style ``rotations``.
    max_sh_degree : int
        Bands above it are dropped (at most 4; keep the bands the model's renderer evaluates).
    render_settings : RenderSettings, optional
        How the model renders (classic 3DGS by default); for example ReSplat's
        ``RenderSettings(antialiased=True, eps2d=0.1)`` (``docs/backbones.md``).

    Returns
    -------
    Scene
        Index ``((v * H + row) * W + col) * spp + s``, ``view_id = v``,
        ``pixel_id = row * W + col``.
    """
    cams = list(cameras)
    for i, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise ClearsplatError(f"expected a Camera, got {type(c).__name__}",
                                  field=f"cameras[{i}]")
    m = to_numpy(means, "means")
    if m.ndim not in (4, 5) or m.shape[-1] != 3:
        raise ClearsplatError(f"expected (V, H, W[, spp], 3), got {m.shape}", field="means")
    v, h, w = m.shape[:3]
    spp = m.shape[3] if m.ndim == 5 else 1
    if v != len(cams):
        raise ClearsplatError(f"{v} views of means for {len(cams)} cameras", field="cameras")
    for i, c in enumerate(cams):
        if (c.height, c.width) != (h, w):
            raise ClearsplatError(f"camera is {c.height}x{c.width}, means are {h}x{w}",
                                  field=f"cameras[{i}]")
    lead = m.shape[:-1]
    n = int(np.prod(lead))
    if covariances is not None:
        if scales is not None or quats is not None:
            raise ClearsplatError("give covariances or scales + quats, not both",
                                  field="covariances")
        cov = to_numpy(covariances, "covariances")
        if cov.shape != lead + (3, 3):
            raise ClearsplatError(f"expected {lead + (3, 3)}, got {cov.shape}",
                                  field="covariances")
        sc, q = covariance_to_scales_quats(cov.reshape(n, 3, 3))
    elif scales is not None and quats is not None:
        sc = to_numpy(scales, "scales")
        q = to_numpy(quats, "quats")
        if sc.shape != lead + (3,):
            raise ClearsplatError(f"expected {lead + (3,)}, got {sc.shape}", field="scales")
        if q.shape != lead + (4,):
            raise ClearsplatError(f"expected {lead + (4,)}, got {q.shape}", field="quats")
        if quat_order == "xyzw":
            q = q[..., [3, 0, 1, 2]]
        elif quat_order != "wxyz":
            raise ClearsplatError(f"must be 'wxyz' or 'xyzw', got {quat_order!r}",
                                  field="quat_order")
        sc, q = sc.reshape(n, 3), q.reshape(n, 4)
    else:
        raise ClearsplatError("give covariances, or scales and quats", field="covariances")
    s = to_numpy(sh, "sh")
    if s.shape[:len(lead)] != lead:
        raise ClearsplatError(f"expected leading shape {lead}, got {s.shape}", field="sh")
    s = sh_to_clearsplat(s, max_sh_degree=max_sh_degree, name="sh")
    op = to_numpy(opacities, "opacities")
    if op.shape not in (lead, lead + (1,)):
        raise ClearsplatError(f"expected {lead}, got {op.shape}", field="opacities")
    op = opacities_checked(op.reshape(n), n)
    idx = np.arange(n, dtype=np.int64)
    view_id = (idx // (h * w * spp)).astype(np.int32)
    pixel_id = (idx // spp) % (h * w)
    return make_scene(m.reshape(n, 3), sc, q, op, s, view_id, pixel_id, cams,
                      images_checked(images, 0, v, h, w), render_settings)
