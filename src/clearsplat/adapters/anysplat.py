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
the model renders them (not rotated by the encoder). AnySplat renders with gsplat
(``rasterize_mode="classic"``, ``radius_clip=0.1``, every SH band it predicts, degree 4), so
the scene keeps band 4 and carries those render settings. Sources: ``docs/backbones.md``.
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from ..scene import RenderSettings, Scene
from ._common import (cameras_from_model, covariance_to_scales_quats, images_checked,
                      make_scene, take_batch, to_numpy)
from .pixelsplat import native_arrays

__all__ = ["from_anysplat", "RENDER_SETTINGS"]

#: How AnySplat's decoder (``decoder_splatting_cuda.py``) calls gsplat: classic, eps2d 0.3,
#: ``radius_clip=0.1``, all SH bands.
RENDER_SETTINGS = RenderSettings(radius_clip=0.1)


def from_anysplat(gaussians, extrinsics, intrinsics, images=None, *, height: int, width: int,
                  batch: int = 0, voxel_inverse=None, valid_mask=None, confidence=None,
                  kept=None, max_sh_degree: int = 4,
                  normalized_intrinsics: bool = True) -> Scene:
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

    Returns
    -------
    Scene
        Without voxels: pixel-aligned. With voxels: ``view_id`` by majority, ``pixel_id = -1``.
    """
    cameras = cameras_from_model(extrinsics, intrinsics, batch=batch, height=height,
                                 width=width, normalized_intrinsics=normalized_intrinsics)
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
