"""NoPoSplat and YoNoSplat: pose-free, pixel-aligned Gaussians in the first view's frame.

Both predict, per input pixel, a Gaussian whose centre, covariance and harmonics are expressed
in the camera frame of the first context view (the canonical frame; the rendering cameras are
given relative to it). The encoders' ``UnifiedGaussianAdapter`` does not rotate the harmonics
(``harmonics=sh``), so the model's colours are those of SH read in that frame. The layout is
the pixelSplat one, ``"b v r srf spp ... -> b (v r srf spp) ..."``. YoNoSplat can predict on a
grid downsampled by ``gaussian_downsample_ratio``; such Gaussians are not pixel-aligned.
Sources: ``docs/backbones.md``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from ..scene import Scene
from ._common import (cameras_from_model, covariance_to_scales_quats, grid_layout,
                      images_checked, make_scene)
from .pixelsplat import native_arrays
from .sh_rotation import rotate_sh

__all__ = ["from_noposplat", "from_yonosplat"]


def from_noposplat(gaussians, extrinsics, intrinsics, images=None, *, height: int, width: int,
                   batch: int = 0, spp: int | None = None, grid: tuple | None = None,
                   max_sh_degree: int = 3, normalized_intrinsics: bool = True,
                   frame: str = "first_view") -> Scene:
    """A scene from NoPoSplat's (or YoNoSplat's) native output.

    With ``frame="first_view"`` the Gaussians live in the first view's camera frame and
    ``extrinsics[:, 0]`` says where that frame is in the world of ``extrinsics``: everything
    (centres, covariances and the spherical harmonics, rotated band by band with
    :func:`clearsplat.adapters.rotate_sh`) is moved by it. With the model's own relative poses
    (``extrinsics[:, 0]`` the identity) nothing moves; with poses in another world frame (at
    the model's scale), the scene lands there and renders the same colours. With
    ``frame="extrinsics"`` the Gaussians are already in the frame of ``extrinsics`` (the model
    placed them with these very poses) and nothing moves.

    Parameters
    ----------
    gaussians : Gaussians dataclass or dict
        ``means [B, G, 3]``, ``covariances [B, G, 3, 3]``, ``harmonics [B, G, 3, d_sh]``
        (NoPoSplat uses ``sh_degree: 4``; bands above ``max_sh_degree`` are dropped),
        ``opacities [B, G]``.
    extrinsics : [B, V, 4, 4]
        OpenCV camera-to-world of the context views (ground truth or predicted).
    intrinsics : [B, V, 3, 3]
        Normalised intrinsics (pixels with ``normalized_intrinsics=False``).
    images : [B, V, 3, H, W] or [B, V, H, W, 3], optional
        In [0, 1]: the images *before* the model's normalisation shim (NoPoSplat feeds
        ``(x - 0.5) / 0.5``).
    height, width, batch, spp, max_sh_degree, normalized_intrinsics
        As in :func:`clearsplat.adapters.from_depthsplat`.
    grid : (rows, cols), optional
        Per-view grid when the model predicts below image resolution (YoNoSplat's
        ``gaussian_downsample_ratio``); inferred when left out.
    frame : {"first_view", "extrinsics"}
        Where the Gaussians are: in the first context camera's frame (NoPoSplat always;
        YoNoSplat with its predicted poses, ``pose_free: true``), or already in the frame of the
        ``extrinsics`` passed (YoNoSplat run with ``pose_free: false``, which places every
        view's local points with ``context["extrinsics"]`` as given, relative or not).

    Returns
    -------
    Scene
        ``view_id = v``; ``pixel_id = row * W + col`` on the full grid, -1 on a coarser one.
    """
    cameras = cameras_from_model(extrinsics, intrinsics, batch=batch, height=height,
                                 width=width, normalized_intrinsics=normalized_intrinsics)
    means, cov, sh, op = native_arrays(gaussians, batch, max_sh_degree)
    view_id, pixel_id, _ = grid_layout(len(means), num_views=len(cameras), height=height,
                                       width=width, spp=spp, grid=grid, allow_coarse=True,
                                       model="NoPoSplat")
    if frame not in ("first_view", "extrinsics"):
        raise ClearsplatError(f"must be 'first_view' or 'extrinsics', got {frame!r}",
                              field="frame")
    first = cameras[0].camera_to_world
    rot, t = first[:3, :3], first[:3, 3]
    if frame == "first_view" and not np.array_equal(first, np.eye(4)):
        means = means @ rot.T + t
        cov = np.einsum("ij,njk,lk->nil", rot, cov, rot)
        if sh.shape[1] > 1:
            sh = rotate_sh(sh, rot)
    scales, quats = covariance_to_scales_quats(cov)
    return make_scene(means, scales, quats, op, sh, view_id, pixel_id, cameras,
                      images_checked(images, batch, len(cameras), height, width))


def from_yonosplat(gaussians, extrinsics, intrinsics, images=None, **kwargs) -> Scene:
    """YoNoSplat's native output; same layout and options as :func:`from_noposplat`.

    YoNoSplat places each view's local points with ``c2w`` (``visualization_dump["c2w"]``):
    its predicted poses made relative to the first view when ``pose_free`` (the released
    setting), else ``context["extrinsics"]`` exactly as given. So:

    - ``pose_free: true``: the Gaussians are in the first view's frame. Pass the predicted
      poses (``visualization_dump["pred_camera_poses"]``; nothing moves), or other poses of the
      same views at the model's scale (``frame="first_view"``, the default: the scene moves by
      ``extrinsics[:, 0]``).
    - ``pose_free: false``: the Gaussians are in the frame of the extrinsics the model was
      given, relative or not; pass those with ``frame="extrinsics"`` (nothing moves). With
      relative poses (first view the identity) both settings agree.
    """
    return from_noposplat(gaussians, extrinsics, intrinsics, images, **kwargs)
