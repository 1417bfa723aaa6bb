"""AnySplat: per-pixel Gaussians, optionally fused into voxels.

AnySplat (``src/model/encoder/anysplat.py``) predicts per-pixel anchors on a ``[V, H, W]``
grid. Without voxelisation it keeps the pixels of ``conf_valid_mask`` (all of them unless
``render_conf``), in ``(v, row, col)`` order. With voxelisation (``voxelize: true``),
``voxelizaton_with_fusion`` rounds each pixel's point to a voxel, takes
``torch.unique(..., return_inverse=True)`` over the flattened ``(v, h, w)`` pixels and fuses
the pixels of a voxel with confidence-softmax weights; Gaussian ``k`` is voxel ``k``.

What is lost with voxels: a voxel mixes pixels, possibly from several views. This adapter gives
the voxel to the view that contributes most (summed fusion weights when ``confidence`` is
given, else pixel counts; ties go to the lower view index) and sets ``pixel_id = -1``; the
filter then associates it through the rasterizer. Minority views of a mixed voxel are not
recorded.

The Gaussians are in the frame of the predicted poses (``pred_context_pose``), harmonics as
the model renders them (not rotated by the encoder).

Pixel convention: AnySplat unprojects pixel ``(row, col)`` at image coordinates
``(col, row)`` with ``cx = W / 2`` (VGGT's integer pixel grid), half a pixel before the centre
``(col + 0.5, row + 0.5)`` that clearsplat (and gsplat) use. ``vggt_pixels=True`` (default)
moves the cameras' principal points by +0.5 px, so every Gaussian projects into the pixel
that produced it and the scene renders aligned with its input images.

``voxel_inverse`` is not among AnySplat's outputs (``inference()`` returns the Gaussians and
the poses): :func:`anysplat_voxel_inverse` recomputes it from the encoder's own outputs.

AnySplat renders with gsplat (``rasterize_mode="classic"``, ``radius_clip=0.1``, every SH
band it predicts, degree 4), so the scene keeps band 4 and carries those render settings.
Sources: ``docs/backbones.md``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from ..scene import RenderSettings, Scene
from ._common import (cameras_from_model, covariance_to_scales_quats, images_checked,
                      make_scene, take_batch, to_numpy)
from .pixelsplat import native_arrays

__all__ = ["from_anysplat", "anysplat_voxel_inverse", "RENDER_SETTINGS"]

#: How AnySplat's decoder (``decoder_splatting_cuda.py``) calls gsplat: classic, eps2d 0.3,
#: ``radius_clip=0.1``, all SH bands.
RENDER_SETTINGS = RenderSettings(radius_clip=0.1)


def from_anysplat(gaussians, extrinsics, intrinsics, images=None, *, height: int, width: int,
                  batch: int = 0, voxel_inverse=None, valid_mask=None, confidence=None,
                  kept=None, max_sh_degree: int = 4, normalized_intrinsics: bool = True,
                  vggt_pixels: bool = True) -> Scene:
    """A scene from AnySplat's native output.

    Parameters
    ----------
    gaussians : Gaussians dataclass or dict
        ``means [B, N, 3]``, ``covariances [B, N, 3, 3]``, ``harmonics [B, N, 3, d_sh]``,
        ``opacities [B, N]``. Padding rows past the real count (batched voxels) are ignored.
    extrinsics, intrinsics : [B, V, 4, 4], [B, V, 3, 3]
        ``pred_context_pose["extrinsic"]`` (camera-to-world) and ``["intrinsic"]``
        (normalised), or the poses the Gaussians are expressed in.
    images : [B, V, 3, H, W] or [B, V, H, W, 3], optional
        In [0, 1], before the normalisation shim.
    height, width, batch, normalized_intrinsics
        As in :func:`clearsplat.adapters.from_depthsplat`.
    max_sh_degree : int, default 4
        Bands above it are dropped; gsplat evaluates all of AnySplat's (degree 4).
    voxel_inverse : [B, V*H*W] or [B, V, H, W] int, optional
        With voxelisation: the ``inverse_indices`` of the voxel fusion (pixel -> voxel).
    valid_mask : [B, V, H, W] bool, optional
        Without voxelisation: ``conf_valid_mask`` (default: every pixel).
    confidence : [B, V, H, W], optional
        With voxelisation: the per-pixel confidence ``conf`` the fusion weighted by; the voxel's
        view is then the one with the largest summed softmax weight.
    kept : (N,) bool or int array, optional
        With ``gs_prune``: which of the voxels/pixels survived, in order.
    vggt_pixels : bool
        The intrinsics follow VGGT's integer pixel grid (AnySplat's own ``pred_context_pose``):
        the principal points are moved by +0.5 px to clearsplat's pixel centres. False for
        intrinsics already in clearsplat's convention.

    Returns
    -------
    Scene
        Without voxels: pixel-aligned. With voxels: ``view_id`` by majority, ``pixel_id = -1``.
    """
    cameras = cameras_from_model(extrinsics, intrinsics, batch=batch, height=height,
                                 width=width, normalized_intrinsics=normalized_intrinsics)
    if vggt_pixels:
        cameras = [_half_pixel(c) for c in cameras]
    v, h, w = len(cameras), int(height), int(width)
    means, cov, sh, op = native_arrays(gaussians, batch, max_sh_degree)
    if voxel_inverse is not None and valid_mask is not None:
        raise ClearsplatError("give voxel_inverse (voxelize on) or valid_mask (off), not both",
                              field="voxel_inverse/valid_mask")
    if voxel_inverse is not None:
        inv = _per_pixel(voxel_inverse, "voxel_inverse", batch, v * h * w, dtype=None)
        if inv.dtype.kind not in "iu":
            raise ClearsplatError(f"expected integers, got dtype {inv.dtype}",
                                  field="voxel_inverse")
        inv = inv.astype(np.int64)
        if inv.min() < 0:
            raise ClearsplatError("negative voxel index", field="voxel_inverse")
        count = int(inv.max()) + 1
        pix_view = np.repeat(np.arange(v), h * w)
        if confidence is not None:
            conf = _per_pixel(confidence, "confidence", batch, v * h * w, dtype=np.float64)
            top = np.full(count, -np.inf)
            np.maximum.at(top, inv, conf)
            weight = np.exp(conf - top[inv])
        else:
            weight = np.ones(v * h * w)
        votes = np.zeros((count, v))
        np.add.at(votes, (inv, pix_view), weight)
        view_id = np.argmax(votes, axis=1).astype(np.int32)
        pixel_id = np.full(count, -1, dtype=np.int64)
    else:
        mask = np.ones((v, h, w), dtype=bool) if valid_mask is None else \
            to_numpy(valid_mask, "valid_mask", dtype=bool)
        if mask.shape != (v, h, w):
            mask = take_batch(mask, batch, 3, "valid_mask")
        if mask.shape != (v, h, w):
            raise ClearsplatError(f"expected ({v}, {h}, {w}), got {mask.shape}",
                                  field="valid_mask")
        flat = np.flatnonzero(mask.reshape(-1))
        count = len(flat)
        view_id = (flat // (h * w)).astype(np.int32)
        pixel_id = (flat % (h * w)).astype(np.int64)
    if kept is not None:
        k = to_numpy(kept, "kept", dtype=None).reshape(-1)
        if k.dtype == bool:
            if k.size != count:
                raise ClearsplatError(f"expected {count} flags, got {k.size}", field="kept")
            k = np.flatnonzero(k)
        view_id, pixel_id = view_id[k], pixel_id[k]
        count = len(k)
    if len(means) < count:
        raise ClearsplatError(f"{len(means)} Gaussians for {count} voxels/pixels",
                              field="gaussians")
    means, cov, sh, op = means[:count], cov[:count], sh[:count], op[:count]
    scales, quats = covariance_to_scales_quats(cov)
    return make_scene(means, scales, quats, op, sh, view_id, pixel_id, cameras,
                      images_checked(images, batch, v, h, w), RENDER_SETTINGS)


def _per_pixel(x, name: str, batch: int, size: int, *, dtype) -> np.ndarray:
    """A per-pixel array ([B,] V*H*W or [B,] V, H, W) of one batch item, flattened."""
    arr = to_numpy(x, name, dtype=dtype)
    if arr.size != size:
        if arr.ndim < 2 or not -arr.shape[0] <= batch < arr.shape[0]:
            raise ClearsplatError(f"expected {size} values (V*H*W) per batch item, got shape "
                                  f"{arr.shape}", field=name)
        arr = arr[batch]
    if arr.size != size:
        raise ClearsplatError(f"expected {size} values (V*H*W), got shape {arr.shape}",
                              field=name)
    return arr.reshape(-1)


def _half_pixel(cam):
    from ..cameras import Camera
    k = cam.K.copy()
    k[0, 2] += 0.5
    k[1, 2] += 0.5
    return Camera(K=k, camera_to_world=cam.camera_to_world, width=cam.width, height=cam.height)


def anysplat_voxel_inverse(pose_encoding, depth, *, voxel_size: float, batch: int = 0,
                           num_gaussians: int | None = None) -> np.ndarray:
    """The pixel -> voxel index of AnySplat's voxel fusion, from the encoder's own outputs.

    Repeats what the encoder does (``src/model/encoder/anysplat.py``): the last camera-head
    pose encoding ``pred_pose_enc_list[-1]`` (``absT_quaR_FoV``: translation, quaternion
    ``x y z w``, vertical and horizontal field of view) -> world-to-camera ``[R | T]`` and
    pixel intrinsics (``f = (size / 2) / (tan(fov / 2) + 1e-3)``, ``c = size / 2``) -> the depth
    unprojected on VGGT's integer pixel grid -> ``round(point / voxel_size)`` ->
    ``unique(dim=0, return_inverse=True)`` over the ``(v, h, w)``-flattened pixels. It works in
    float32 in the encoder's order of operations; it does not use the returned camera-to-world
    ``pred_context_pose["extrinsic"]``, whose inversion moves points by round-off and flips
    boundary voxels.

    Parameters
    ----------
    pose_encoding : [B, V, 9] tensor or array
        ``encoder_output.pred_pose_enc_list[-1]``.
    depth : [B, V, H, W] or [B, V, H, W, 1]
        ``encoder_output.depth_dict["depth"]``.
    voxel_size : float
        The encoder's ``voxel_size`` (0.002 in the released configs).
    batch : int
        Which batch item.
    num_gaussians : int, optional
        The number of Gaussians (voxels) of that item: checked against the voxel count.

    Returns
    -------
    inverse : (V * H * W,) int64
        Voxel index of every pixel, ``(v, row, col)`` order; pass as ``voxel_inverse`` to
        :func:`from_anysplat`.

    Raises
    ------
    ClearsplatError
        Wrong shapes, or a voxel count other than ``num_gaussians`` (wrong ``voxel_size``, or
        ``gs_prune``: then pass ``kept`` too and leave ``num_gaussians`` out).

    Notes
    -----
    PyTorch and NumPy may round a float32 sum differently in its last bit, so a point lying
    within round-off of a voxel boundary can land in the neighbouring voxel. For the encoder's
    exact indices run its own functions on the same tensors (``docs/backbones.md``).
    """
    enc = take_batch(to_numpy(pose_encoding, "pose_encoding", dtype=np.float32), batch, 2,
                     "pose_encoding")
    d = to_numpy(depth, "depth", dtype=np.float32)
    if d.ndim == 5 and d.shape[-1] == 1:
        d = d[..., 0]
    d = take_batch(d, batch, 3, "depth")
    if enc.ndim != 2 or enc.shape[1] != 9:
        raise ClearsplatError(f"expected (V, 9), got {enc.shape}", field="pose_encoding")
    if d.ndim != 3 or d.shape[0] != enc.shape[0]:
        raise ClearsplatError(f"expected ({enc.shape[0]}, H, W), got {d.shape}", field="depth")
    if not voxel_size > 0:
        raise ClearsplatError(f"must be positive, got {voxel_size}", field="voxel_size")
    v, h, w = d.shape
    f32 = np.float32
    t, q = enc[:, :3], enc[:, 3:7]
    i, j, k, r = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    two_s = f32(2.0) / (q * q).sum(-1)
    rot = np.stack([
        1 - two_s * (j * j + k * k), two_s * (i * j - k * r), two_s * (i * k + j * r),
        two_s * (i * j + k * r), 1 - two_s * (i * i + k * k), two_s * (j * k - i * r),
        two_s * (i * k - j * r), two_s * (j * k + i * r), 1 - two_s * (i * i + j * j),
    ], -1).reshape(v, 3, 3).astype(f32)
    fy = f32(h / 2.0) / (np.tan(enc[:, 7] / f32(2.0)) + f32(1e-3))
    fx = f32(w / 2.0) / (np.tan(enc[:, 8] / f32(2.0)) + f32(1e-3))
    u = np.arange(w, dtype=f32)[None, None, :]
    vv = np.arange(h, dtype=f32)[None, :, None]
    x_cam = (u - f32(w / 2)) * d / fx[:, None, None]             # (V, H, W)
    y_cam = (vv - f32(h / 2)) * d / fy[:, None, None]
    cam = np.stack([x_cam, y_cam, d], -1)
    rt = np.swapaxes(rot, 1, 2)                                   # camera-to-world rotation
    top = -(rt @ t[:, :, None])[:, :, 0]                          # camera-to-world translation
    pts = np.zeros(cam.shape, dtype=f32)
    for a in range(3):                                            # row a of [R^T | -R^T T]
        pts[..., a] = (rt[:, a, 0, None, None] * cam[..., 0] + rt[:, a, 1, None, None] *
                       cam[..., 1] + rt[:, a, 2, None, None] * cam[..., 2] +
                       top[:, a, None, None])
    idx = np.round(pts.reshape(-1, 3) / f32(voxel_size)).astype(np.int32)
    _, inverse = np.unique(idx, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1).astype(np.int64)
    count = int(inverse.max()) + 1 if inverse.size else 0
    if num_gaussians is not None and count != int(num_gaussians):
        raise ClearsplatError(f"{count} voxels for {num_gaussians} Gaussians (wrong voxel_size, "
                              "or gs_prune: then pass kept= to from_anysplat)",
                              field="voxel_inverse")
    return inverse
