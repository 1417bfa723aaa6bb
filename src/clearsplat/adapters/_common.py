"""Shared pieces of the backbone adapters: array conversion, covariances, cameras, layouts.

Nothing here imports PyTorch: a tensor is recognised by its ``detach`` method and converted
with ``.detach().float().cpu().numpy()`` (``.float()`` only for floating tensors, so that
bfloat16 and half outputs convert too).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, Scene

__all__ = ["to_numpy", "covariance_to_scales_quats", "quats_to_matrices",
           "scales_quats_to_covariance", "SCALE_FLOOR_RATIO", "SCALE_FLOOR_ABS",
           "NEGATIVE_TOLERANCE"]

#: Smallest scale kept, relative to the largest scale of the same Gaussian: eigenvalues of a
#: covariance below ``(SCALE_FLOOR_RATIO * s_max) ** 2`` (round-off, flat Gaussians) are
#: raised to it, so every scale is positive. 1e-5 is far below a pixel at any depth.
SCALE_FLOOR_RATIO = 1e-5
#: Absolute floor on scales, for an all-zero covariance.
SCALE_FLOOR_ABS = 1e-12
#: A covariance whose smallest eigenvalue is below ``-NEGATIVE_TOLERANCE * lambda_max`` is not
#: positive semi-definite beyond float32 round-off and is refused.
NEGATIVE_TOLERANCE = 1e-4


# ------------------------------------------------------------------------------------------------
# arrays
# ------------------------------------------------------------------------------------------------
def to_numpy(x, name: str, *, dtype=np.float64) -> np.ndarray:
    """A NumPy copy of an array or a PyTorch tensor (any device, any float dtype)."""
    if x is None:
        raise ClearsplatError("is required", field=name)
    if hasattr(x, "detach"):                        # torch.Tensor, without importing torch
        t = x.detach()
        if getattr(t, "is_floating_point", lambda: False)():
            t = t.float()
        x = t.cpu().numpy()
    try:
        arr = np.asarray(x)
    except Exception as e:  # noqa: BLE001 - report anything unconvertible as bad input
        raise ClearsplatError(f"cannot convert to an array ({e})", field=name) from None
    if dtype is None:
        return arr
    if arr.dtype.kind not in "biuf":
        raise ClearsplatError(f"expected numbers, got dtype {arr.dtype}", field=name)
    out = arr.astype(dtype)
    if out.dtype.kind == "f" and not np.isfinite(out).all():
        i = np.unravel_index(int(np.argmax(~np.isfinite(out))), out.shape)
        raise ClearsplatError(f"non-finite value at index {tuple(int(j) for j in i)}",
                              field=name)
    return out


def field_of(obj, name: str):
    """Attribute ``name`` of a Gaussians-like object, or key ``name`` of a dict."""
    if isinstance(obj, dict):
        if name not in obj:
            raise ClearsplatError(f"missing key {name!r} (have {sorted(obj)})", field=name)
        return obj[name]
    if not hasattr(obj, name):
        raise ClearsplatError(f"{type(obj).__name__} has no attribute {name!r}", field=name)
    return getattr(obj, name)


def take_batch(arr: np.ndarray, batch: int, core_ndim: int, name: str) -> np.ndarray:
    """``arr[batch]`` when ``arr`` has a leading batch axis, else ``arr`` (then batch must be 0)."""
    if arr.ndim == core_ndim + 1:
        if not -arr.shape[0] <= batch < arr.shape[0]:
            raise ClearsplatError(f"batch {batch} out of range for shape {arr.shape}",
                                  field=name)
        return arr[batch]
    if arr.ndim == core_ndim:
        if batch not in (0, -1):
            raise ClearsplatError(f"has no batch axis (shape {arr.shape}) but batch={batch}",
                                  field=name)
        return arr
    raise ClearsplatError(f"expected {core_ndim} or {core_ndim + 1} dimensions, got shape "
                          f"{arr.shape}", field=name)


# ------------------------------------------------------------------------------------------------
# covariances <-> scales and rotations
# ------------------------------------------------------------------------------------------------
def quats_to_matrices(quats) -> np.ndarray:
    """Rotation matrices (N, 3, 3) from quaternions ``w, x, y, z`` (N, 4), normalised first."""
    q = np.asarray(quats, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrices_to_quats(rot) -> np.ndarray:
    """Quaternions ``w, x, y, z`` (N, 4) with ``w >= 0`` from rotation matrices (N, 3, 3)."""
    xyzw = Rotation.from_matrix(np.asarray(rot, dtype=np.float64)).as_quat()
    q = np.concatenate([xyzw[..., 3:], xyzw[..., :3]], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)


def scales_quats_to_covariance(scales, quats) -> np.ndarray:
    """``R S S^T R^T`` (N, 3, 3) in float64 (the convention of ``docs/conventions.md``)."""
    r = quats_to_matrices(quats)
    s2 = np.asarray(scales, dtype=np.float64) ** 2
    return np.einsum("nij,nj,nkj->nik", r, s2, r)


def covariance_to_scales_quats(cov, *, name: str = "covariances"):
    """Scales and rotations of 3D covariances by eigen-decomposition.

    Parameters
    ----------
    cov : (N, 3, 3) array_like
        Symmetric positive semi-definite matrices (symmetrised before use).
    name : str
        Field named in errors.

    Returns
    -------
    scales : (N, 3) float32
        Square roots of the eigenvalues, largest first; eigenvalues below
        ``(SCALE_FLOOR_RATIO * s_max)**2`` (and below ``SCALE_FLOOR_ABS**2``) are raised to
        that floor, so a flat or degenerate Gaussian keeps a tiny positive thickness.
    quats : (N, 4) float32
        ``w, x, y, z`` of the eigenvector basis, made a proper rotation (det +1) by flipping
        the last axis when needed; ``w >= 0``.

    Raises
    ------
    ClearsplatError
        A non-finite matrix, or one with an eigenvalue below
        ``-NEGATIVE_TOLERANCE * lambda_max`` (not a covariance).
    """
    c = np.asarray(cov, dtype=np.float64)
    if c.ndim != 3 or c.shape[1:] != (3, 3):
        raise ClearsplatError(f"expected shape (N, 3, 3), got {c.shape}", field=name)
    if not np.isfinite(c).all():
        i = int(np.argmax(~np.isfinite(c).all(axis=(1, 2))))
        raise ClearsplatError(f"non-finite covariance (Gaussian {i})", field=name)
    c = 0.5 * (c + np.swapaxes(c, 1, 2))
    lam, vec = np.linalg.eigh(c)                     # ascending
    lam, vec = lam[:, ::-1], vec[:, :, ::-1]         # largest first
    top = np.maximum(lam[:, 0], 0.0)
    bad = lam[:, 2] < -NEGATIVE_TOLERANCE * top - 1e-30
    if bad.any():
        i = int(np.argmax(bad))
        raise ClearsplatError(f"not positive semi-definite: Gaussian {i} has eigenvalues "
                              f"{lam[i].tolist()}", field=name)
    floor = np.maximum((SCALE_FLOOR_RATIO ** 2) * top, SCALE_FLOOR_ABS ** 2)
    lam = np.maximum(lam, floor[:, None])
    flip = np.linalg.det(vec) < 0
    vec[flip, :, 2] *= -1.0
    quats = matrices_to_quats(vec) if len(vec) else np.zeros((0, 4))
    return np.sqrt(lam).astype(np.float32), quats.astype(np.float32)


# ------------------------------------------------------------------------------------------------
# spherical harmonics, opacities, images
# ------------------------------------------------------------------------------------------------
_VALID_K = {1: 0, 4: 1, 9: 2, 16: 3, 25: 4, 36: 5}


def sh_to_clearsplat(sh: np.ndarray, *, max_sh_degree: int, name: str = "harmonics"):
    """Coefficients (..., 3, d_sh) (model order) or (..., K, 3) (clearsplat order) ->
    (M, K, 3) float32 with bands above ``max_sh_degree`` (at most 4) dropped.

    The two orders cannot be confused: 3 is never a valid number of coefficients.
    """
    if sh.ndim < 2:
        raise ClearsplatError(f"expected (..., 3, d_sh), got shape {sh.shape}", field=name)
    if sh.shape[-2] == 3 and sh.shape[-1] in _VALID_K:
        sh = np.swapaxes(sh, -1, -2)
    elif not (sh.shape[-1] == 3 and sh.shape[-2] in _VALID_K):
        raise ClearsplatError(f"expected (..., 3, d_sh) or (..., d_sh, 3) with d_sh a square "
                              f"(1, 4, 9, 16, 25), got shape {sh.shape}", field=name)
    if not 0 <= int(max_sh_degree) <= 4:
        raise ClearsplatError(f"must be 0..4, got {max_sh_degree}", field="max_sh_degree")
    k = min(sh.shape[-2], (int(max_sh_degree) + 1) ** 2)
    return np.ascontiguousarray(sh[..., :k, :].reshape(-1, k, 3), dtype=np.float32)


def opacities_checked(op: np.ndarray, n: int, name: str = "opacities") -> np.ndarray:
    """(n,) or (n, 1) opacities in [0, 1] -> (n,) float32."""
    op = op.reshape(op.shape[0], -1) if op.ndim > 1 else op
    if op.ndim == 2 and op.shape[1] == 1:
        op = op[:, 0]
    if op.shape != (n,):
        raise ClearsplatError(f"expected {n} values, got shape {op.shape}", field=name)
    if n and (op.min() < 0.0 or op.max() > 1.0):
        raise ClearsplatError(f"values outside [0, 1] (min {op.min():.4g}, max {op.max():.4g}):"
                              " pass opacities after the sigmoid, not logits", field=name)
    return op.astype(np.float32)


def images_checked(images, batch: int, num_views: int, height: int, width: int):
    """(B,) V x (3, H, W) or (H, W, 3) images in [0, 1] -> list of (H, W, 3) float32."""
    if images is None:
        return None
    arr = take_batch(to_numpy(images, "images", dtype=np.float32), batch, 4, "images")
    if arr.shape == (num_views, 3, height, width):
        arr = np.moveaxis(arr, 1, -1)
    elif arr.shape != (num_views, height, width, 3):
        raise ClearsplatError(f"expected ({num_views}, 3, {height}, {width}) or ({num_views}, "
                              f"{height}, {width}, 3), got {arr.shape}", field="images")
    lo, hi = float(arr.min()), float(arr.max())
    if lo < -1e-3 or hi > 1 + 1e-3:
        raise ClearsplatError(f"values outside [0, 1] (min {lo:.3g}, max {hi:.3g}): pass the "
                              "images before the model's normalisation shim", field="images")
    return [np.ascontiguousarray(np.clip(a, 0.0, 1.0)) for a in arr]


# ------------------------------------------------------------------------------------------------
# cameras
# ------------------------------------------------------------------------------------------------
def cameras_from_model(extrinsics, intrinsics, *, batch: int, height: int, width: int,
                       normalized_intrinsics: bool) -> list:
    """Cameras from OpenCV camera-to-world ``[B, V, 4, 4]`` and intrinsics ``[B, V, 3, 3]``.

    With ``normalized_intrinsics`` (pixelSplat family: ``fx/W, fy/H, cx/W, cy/H``) the pixel
    intrinsics are ``diag(W, H, 1) @ K``. Their pixel centres sit at ``(i + 0.5) / W``, the
    clearsplat convention, so nothing else changes.
    """
    height, width = _size(height, width)
    ext = take_batch(to_numpy(extrinsics, "extrinsics"), batch, 3, "extrinsics")
    intr = take_batch(to_numpy(intrinsics, "intrinsics"), batch, 3, "intrinsics")
    if ext.ndim != 3 or ext.shape[1:] not in ((4, 4), (3, 4)):
        raise ClearsplatError(f"expected (V, 4, 4), got {ext.shape}", field="extrinsics")
    if intr.shape != (ext.shape[0], 3, 3):
        raise ClearsplatError(f"expected ({ext.shape[0]}, 3, 3), got {intr.shape}",
                              field="intrinsics")
    if normalized_intrinsics:
        intr = np.diag([float(width), float(height), 1.0]) @ intr
    cams = []
    for v in range(ext.shape[0]):
        try:
            cams.append(Camera(K=intr[v], camera_to_world=ext[v], width=width, height=height))
        except ClearsplatError as e:
            where = "extrinsics" if e.field == "camera_to_world" else "intrinsics"
            raise ClearsplatError(e.reason, field=f"{where}[{v}]") from None
    return cams


def _size(height, width) -> tuple[int, int]:
    if height is None or width is None or int(height) <= 0 or int(width) <= 0:
        raise ClearsplatError(f"image size must be given and positive, got {height}x{width}",
                              field="height/width")
    return int(height), int(width)


# ------------------------------------------------------------------------------------------------
# layouts
# ------------------------------------------------------------------------------------------------
def grid_layout(n: int, *, num_views: int, height: int, width: int, spp: int | None,
                grid: tuple | None, allow_coarse: bool, model: str):
    """Resolve a ``(v, row, col, s)`` layout of ``n`` Gaussians.

    Index ``((v * gh + row) * gw + col) * spp + s``. On the image grid (``gh, gw == H, W``)
    ``pixel_id = row * W + col``; on a coarser grid the Gaussians are not pixel-aligned and
    ``pixel_id = -1``.

    Returns
    -------
    view_id : (n,) int32
    pixel_id : (n,) int64
    (gh, gw, spp) : tuple of int
    """
    v, h, w = int(num_views), int(height), int(width)
    if grid is None:
        if n % (v * h * w) == 0 and n >= v * h * w:
            grid = (h, w)
        elif allow_coarse:
            s = 1 if spp is None else int(spp)
            per_view = n / (v * s)
            f = np.sqrt(h * w / per_view) if per_view > 0 else 0.0
            f_int = int(round(f)) if f > 0 else 0
            if f_int < 1 or h % f_int or w % f_int or (h // f_int) * (w // f_int) * v * s != n:
                raise ClearsplatError(
                    f"{n} Gaussians do not fit {v} views of {h}x{w} pixels on any integer "
                    f"downsampled grid with {s} per cell; pass grid=(rows, cols)",
                    field="gaussians")
            grid = (h // f_int, w // f_int)
        else:
            raise ClearsplatError(
                f"{n} Gaussians are not a multiple of views x height x width = {v}x{h}x{w} "
                f"= {v * h * w} ({model} predicts Gaussians per pixel; check height/width and "
                "that the border was not trimmed)", field="gaussians")
    gh, gw = (int(grid[0]), int(grid[1]))
    if gh <= 0 or gw <= 0:
        raise ClearsplatError(f"grid must be positive, got {grid}", field="grid")
    cells = v * gh * gw
    if n % cells:
        raise ClearsplatError(f"{n} Gaussians are not a multiple of views x grid = "
                              f"{v}x{gh}x{gw}", field="gaussians")
    per = n // cells
    if spp is not None and int(spp) != per:
        raise ClearsplatError(f"{n} Gaussians on {v}x{gh}x{gw} cells make {per} per cell, "
                              f"not spp={spp}", field="spp")
    idx = np.arange(n, dtype=np.int64)
    view_id = (idx // (gh * gw * per)).astype(np.int32)
    if (gh, gw) == (h, w):
        pixel_id = (idx // per) % (h * w)
    else:
        pixel_id = np.full(n, -1, dtype=np.int64)
    return view_id, pixel_id, (gh, gw, per)


def make_scene(means, scales, quats, opacities, sh, view_id, pixel_id, cameras, images,
               render_settings=None) -> Scene:
    """Build and validate the scene (``render_settings``: the backbone's renderer)."""
    g = Gaussians(means=means, scales=scales, quats=quats, opacities=opacities, sh=sh)
    scene = Scene(g, view_id=view_id, pixel_id=pixel_id, cameras=cameras, images=images,
                  render_settings=render_settings)
    scene.validate()
    return scene
