"""pixelSplat, MVSplat, DepthSplat and ReSplat: Gaussians per pixel (or per latent cell).

Native output (``src/model/types.py`` of each repository, a ``Gaussians`` dataclass):
``means [B, G, 3]``, ``covariances [B, G, 3, 3]`` (world), ``harmonics [B, G, 3, d_sh]``
(channel axis before the SH axis), ``opacities [B, G]`` in [0, 1]. The encoders flatten
``"b v r srf spp ... -> b (v r srf spp) ..."`` with ``r = (h w)`` row-major, so Gaussian
``((v * H + row) * W + col) * spp + s`` comes from pixel ``(row, col)`` of view ``v``.
Cameras are OpenCV camera-to-world ``extrinsics [B, V, 4, 4]`` and ``intrinsics [B, V, 3, 3]``
normalised by the image size. Sources and details: ``docs/backbones.md``.
"""

from __future__ import annotations

from ..errors import ClearsplatError
from ..scene import RenderSettings, Scene
from ._common import (cameras_from_model, covariance_to_scales_quats, field_of, grid_layout,
                      images_checked, make_scene, opacities_checked, sh_to_clearsplat,
                      take_batch, to_numpy)

__all__ = ["from_depthsplat", "from_mvsplat", "from_pixelsplat", "from_resplat",
           "RESPLAT_RENDER_SETTINGS"]

#: ReSplat renders with gsplat, ``rasterize_mode="antialiased"``, ``eps2d=0.1``.
RESPLAT_RENDER_SETTINGS = RenderSettings(antialiased=True, eps2d=0.1)


def native_arrays(gaussians, batch: int, max_sh_degree: int):
    """means (G, 3), covariances (G, 3, 3), sh (G, K, 3), opacities (G,) of one batch item."""
    means = take_batch(to_numpy(field_of(gaussians, "means"), "means"), batch, 2, "means")
    cov = take_batch(to_numpy(field_of(gaussians, "covariances"), "covariances"), batch, 3,
                     "covariances")
    harm = to_numpy(field_of(gaussians, "harmonics"), "harmonics")
    harm = take_batch(harm, batch, 3, "harmonics")
    op = to_numpy(field_of(gaussians, "opacities"), "opacities")
    op = take_batch(op, batch, 1 if op.ndim in (1, 2) and op.shape[-1] != 1 else 2, "opacities")
    g = means.shape[0]
    if means.shape != (g, 3):
        raise ClearsplatError(f"expected (G, 3), got {means.shape}", field="means")
    if cov.shape != (g, 3, 3):
        raise ClearsplatError(f"expected ({g}, 3, 3), got {cov.shape}", field="covariances")
    sh = sh_to_clearsplat(harm, max_sh_degree=max_sh_degree)
    if sh.shape[0] != g:
        raise ClearsplatError(f"expected {g} Gaussians, got shape {harm.shape}",
                              field="harmonics")
    return means, cov, sh, opacities_checked(op, g)


def check_batch_concat(gaussians, extrinsics, model: str) -> None:
    """Refuse Gaussians whose batch axis is a multiple of the cameras' (DepthSplat in train mode).

    DepthSplat's encoder with ``supervise_intermediate_depth`` and more than one depth
    prediction (its depth network returns the intermediate scales only in training mode)
    concatenates the Gaussians of every intermediate depth along the batch axis:
    ``B * num_depths`` items, the final prediction last. Adapting item 0 would silently take
    the coarsest intermediate depth.
    """
    means = field_of(gaussians, "means")
    ext_shape = getattr(extrinsics, "shape", None)
    shape = getattr(means, "shape", None)
    if shape is None or ext_shape is None or len(shape) != 3 or len(ext_shape) != 4:
        return
    b, gb = int(ext_shape[0]), int(shape[0])
    if gb != b and b > 0 and gb % b == 0:
        raise ClearsplatError(
            f"{gb} batch items of Gaussians for {b} of cameras: {model} concatenated the "
            f"Gaussians of {gb // b} depth predictions along the batch axis (a model in train "
            f"mode with supervise_intermediate_depth); call model.eval(), or pass the final "
            f"prediction, the last {b} items (means[-{b}:], ...)", field="gaussians")


def _from_grid(gaussians, extrinsics, intrinsics, images, *, height, width, batch, spp, grid,
               allow_coarse, max_sh_degree, normalized_intrinsics, model,
               render_settings=None) -> Scene:
    check_batch_concat(gaussians, extrinsics, model)
    cameras = cameras_from_model(extrinsics, intrinsics, batch=batch, height=height,
                                 width=width, normalized_intrinsics=normalized_intrinsics)
    means, cov, sh, op = native_arrays(gaussians, batch, max_sh_degree)
    view_id, pixel_id, _ = grid_layout(len(means), num_views=len(cameras), height=height,
                                       width=width, spp=spp, grid=grid,
                                       allow_coarse=allow_coarse, model=model)
    scales, quats = covariance_to_scales_quats(cov)
    return make_scene(means, scales, quats, op, sh, view_id, pixel_id, cameras,
                      images_checked(images, batch, len(cameras), height, width),
                      render_settings)


def from_depthsplat(gaussians, extrinsics, intrinsics, images=None, *, height: int, width: int,
                    batch: int = 0, spp: int | None = None, max_sh_degree: int = 3,
                    normalized_intrinsics: bool = True) -> Scene:
    """A scene from the native output of DepthSplat (and pixelSplat, MVSplat).

    Parameters
    ----------
    gaussians : Gaussians dataclass or dict
        With ``means [B, G, 3]``, ``covariances [B, G, 3, 3]`` (world frame),
        ``harmonics [B, G, 3, d_sh]`` (already rotated to world by the model) and
        ``opacities [B, G]`` in [0, 1]; PyTorch tensors (any device/dtype) or NumPy arrays.
        The batch axis may be left out. ``G = V * H * W * spp`` in the order
        ``((v * H + row) * W + col) * spp + s``.
    extrinsics : [B, V, 4, 4]
        OpenCV camera-to-world, the ``context["extrinsics"]`` the model was given.
    intrinsics : [B, V, 3, 3]
        ``context["intrinsics"]``: normalised (``fx/W, fy/H, cx/W, cy/H``) unless
        ``normalized_intrinsics=False`` (then in pixels).
    images : [B, V, 3, H, W] or [B, V, H, W, 3], optional
        ``context["image"]`` in [0, 1] (before any normalisation shim). Needed by the filter.
    height, width : int
        Input image size in pixels.
    batch : int
        Which batch item to adapt.
    spp : int, optional
        Gaussians per pixel (``num_surfaces * gaussians_per_pixel``); inferred from ``G``.
    max_sh_degree : int
        Bands above it are dropped (4 at most). The original 3DGS rasterizer these models
        render with evaluates degree 3 at most, hence the default.
    normalized_intrinsics : bool

    Returns
    -------
    Scene
        Pixel-aligned: ``view_id = v``, ``pixel_id = row * W + col``. Scales and rotations come
        from the covariances (:func:`clearsplat.adapters.covariance_to_scales_quats`).

    Raises
    ------
    ClearsplatError
        Naming the field: wrong shapes, ``G`` not a multiple of ``V * H * W`` (trimmed
        borders), opacities outside [0, 1] (logits), images outside [0, 1], non-rigid cameras,
        covariances that are not positive semi-definite, and Gaussians with ``k * B`` batch
        items for ``B`` cameras (DepthSplat in train mode concatenates its intermediate-depth
        Gaussians along the batch axis; call ``model.eval()`` or pass the last ``B`` items).
    """
    return _from_grid(gaussians, extrinsics, intrinsics, images, height=height, width=width,
                      batch=batch, spp=spp, grid=None, allow_coarse=False,
                      max_sh_degree=max_sh_degree, normalized_intrinsics=normalized_intrinsics,
                      model="DepthSplat")


def from_mvsplat(gaussians, extrinsics, intrinsics, images=None, **kwargs) -> Scene:
    """MVSplat's native output; same layout and options as :func:`from_depthsplat`."""
    return from_depthsplat(gaussians, extrinsics, intrinsics, images, **kwargs)


def from_pixelsplat(gaussians, extrinsics, intrinsics, images=None, **kwargs) -> Scene:
    """pixelSplat's native output; same layout and options as :func:`from_depthsplat`."""
    return from_depthsplat(gaussians, extrinsics, intrinsics, images, **kwargs)


def from_resplat(gaussians, extrinsics, intrinsics, images=None, *, height: int, width: int,
                 batch: int = 0, grid: tuple | None = None, max_sh_degree: int = 4,
                 normalized_intrinsics: bool = True) -> Scene:
    """A scene from ReSplat's native output: Gaussians on a per-view latent grid.

    ReSplat predicts one Gaussian per cell of a ``H/f x W/f`` grid per view (``f`` =
    ``latent_downsample``, divided by ``sqrt(init_gaussian_multiple)``, which the encoder
    unrolls into a finer grid ``"(h x w y)"``), ordered ``(v, row, col)``.

    Parameters
    ----------
    grid : (rows, cols), optional
        The per-view grid; inferred from ``G / V`` and the image aspect ratio.
    Other parameters
        As in :func:`from_depthsplat` (``spp`` is 1). The harmonics are used as the model
        renders them (its encoder does not rotate them; the renderer reads them as world-frame).
        ReSplat renders with gsplat, which evaluates every band it predicts: ``max_sh_degree``
        defaults to 4, and the scene carries its settings, ``RESPLAT_RENDER_SETTINGS``
        (antialiased, eps2d 0.1).

    Returns
    -------
    Scene
        ``view_id`` from the grid; ``pixel_id = -1`` unless the grid is the full image grid
        (then pixel-aligned). Association to pixels goes through the rasterizer
        (:func:`clearsplat.contributions`).
    """
    return _from_grid(gaussians, extrinsics, intrinsics, images, height=height, width=width,
                      batch=batch, spp=1 if grid is not None else None, grid=grid,
                      allow_coarse=True, max_sh_degree=max_sh_degree,
                      normalized_intrinsics=normalized_intrinsics, model="ReSplat",
                      render_settings=RESPLAT_RENDER_SETTINGS)
