"""Thin wrappers over the native rasterizer kernels (``clearsplat._core``).

One function per kernel: each makes its inputs contiguous with the dtype the kernel takes,
checks shapes, and calls the kernel (which releases the GIL). Defaults and the validation of
user input live in :mod:`clearsplat.render.base` and the backends; these functions assume
that has happened.

The packed per-Gaussian record (``splats``, (V, 12) float32) is, per row: ``u, v`` (projected
centre), ``conic_a, conic_b, conic_c`` (inverse 2D covariance), ``opacity``, ``r, g, b``,
``depth`` (camera z), then two float slots holding the int16 pixel box ``x0, x1`` and
``y0, y1`` outside which alpha stays below 1/255 (see ``cpp/raster.h``).
"""

from __future__ import annotations

import numpy as np

from .. import _core

__all__ = ["TILE", "project", "bin_tiles", "tiles_touched", "composite", "composite_layers",
           "composite_patches",
           "contributions", "max_threads", "sort_index"]

#: Tile edge in pixels (``cs::kTile``).
TILE = 16
_NO_KEEP = np.empty(0, dtype=np.uint8)


def max_threads() -> int:
    """Threads the native core uses when ``num_threads`` is 0."""
    return int(_core.max_threads())


def _c(a, dtype) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=dtype)


def _mask(keep) -> np.ndarray:
    """(n,) bool or uint8 -> uint8 view, or an empty array for None (keep everything)."""
    if keep is None:
        return _NO_KEEP
    keep = np.ascontiguousarray(keep)
    return keep.view(np.uint8) if keep.dtype == np.bool_ else keep.astype(np.uint8)


def _expect(a: np.ndarray, shape: tuple, name: str) -> None:
    if a.shape != shape:
        raise ValueError(f"clearsplat.render._kernels: {name} has shape {a.shape}, "
                         f"expected {shape}")


def project(means, scales, quats, opacities, sh, keep, world_to_camera, K, position,
            width: int, height: int, near: float, num_threads: int, *, eps2d: float = 0.3,
            antialiased: bool = False, radius_clip: float = 0.0):
    """Project, cull and sort front to back (``eps2d``, ``antialiased``, ``radius_clip`` as in
    :class:`clearsplat.scene.RenderSettings`).

    Returns
    -------
    splats : (V, 12) float32
        Packed records of the visible Gaussians, ordered by camera z (ties by index).
    rects : (V, 4) uint16
        Inclusive tile range ``x0, y0, x1, y1`` each one is binned into.
    index : (V,) int32
        Gaussian index of each visible Gaussian.
    """
    means, scales, quats = _c(means, np.float32), _c(scales, np.float32), _c(quats, np.float32)
    opacities, sh = _c(opacities, np.float32), _c(sh, np.float32)
    n = means.shape[0]
    _expect(means, (n, 3), "means")
    _expect(scales, (n, 3), "scales")
    _expect(quats, (n, 4), "quats")
    _expect(opacities, (n,), "opacities")
    _expect(sh, (n, sh.shape[1] if sh.ndim == 3 else -1, 3), "sh")
    keep = _mask(keep)
    if keep.size:
        _expect(keep, (n,), "keep")
    view = _c(np.asarray(world_to_camera, dtype=np.float64)[:3, :4], np.float64)
    K = np.asarray(K, dtype=np.float64)
    intrinsics = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dtype=np.float64)
    return _core.project(means, scales, quats, opacities, sh, keep, view, intrinsics,
                         _c(position, np.float64), int(width), int(height), float(near),
                         float(eps2d), bool(antialiased), float(radius_clip), int(num_threads))


def bin_tiles(rects, grid_w: int, grid_h: int, num_threads: int):
    """Tile lists: ``offsets`` (grid_w * grid_h + 1,) int64 and ``lists`` (P,) int32."""
    rects = _c(rects, np.uint16)
    _expect(rects, (rects.shape[0], 4), "rects")
    return _core.bin_tiles(rects, int(grid_w), int(grid_h), int(num_threads))


def tiles_touched(rects, group_offsets, ids, grid_w: int, grid_h: int, num_threads: int):
    """Sorted unique tiles of each group of ids: CSR ``(offsets (G + 1,) int64, tiles int32)``."""
    group_offsets, ids = _c(group_offsets, np.int64), _c(ids, np.int32)
    return _core.tiles_touched(_c(rects, np.uint16), group_offsets, ids, int(grid_w),
                               int(grid_h), int(num_threads))


def composite(splats, offsets, lists, keep, tiles, width: int, height: int, background,
              rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, num_threads: int) -> None:
    """Composite ``tiles`` into the float32 outputs (H, W, 3), (H, W), (H, W) in place."""
    for a, shape in ((rgb, (height, width, 3)), (alpha, (height, width)), (depth, (height, width))):
        if a.dtype != np.float32 or not a.flags.c_contiguous or a.shape != shape:
            raise ValueError(f"clearsplat.render._kernels: outputs must be C-contiguous "
                             f"float32 {shape}")
    _core.composite(_c(splats, np.float32), _c(offsets, np.int64), _c(lists, np.int32),
                    _mask(keep), _c(tiles, np.int32), int(width), int(height),
                    _c(background, np.float32), rgb, alpha, depth, int(num_threads))


def composite_pair(splats, offsets, lists, keep_a, keep, tiles, width: int, height: int,
                   background, outputs_a, outputs_b, num_threads: int) -> None:
    """Composite ``tiles`` twice in one pass: the Gaussians in ``keep_a`` (all when None) into
    ``outputs_a`` and those in ``keep`` into ``outputs_b`` ((rgb, alpha, depth) each, in place);
    the masks are (V,) over the visible Gaussians."""
    for outs in (outputs_a, outputs_b):
        for a, shape in zip(outs, ((height, width, 3), (height, width), (height, width))):
            if a.dtype != np.float32 or not a.flags.c_contiguous or a.shape != shape:
                raise ValueError(f"clearsplat.render._kernels: outputs must be C-contiguous "
                             f"float32 {shape}")
    _core.composite_pair(_c(splats, np.float32), _c(offsets, np.int64), _c(lists, np.int32),
                         _mask(keep_a), _mask(keep), _c(tiles, np.int32), int(width),
                         int(height), _c(background, np.float32), *outputs_a, *outputs_b,
                         int(num_threads))


def composite_layers(splats, offsets, lists, layer, num_layers: int, tiles, width: int,
                     height: int, background, num_threads: int):
    """Composite every layer in ``tiles`` (unique int32 tile ids) in one pass over their lists:
    the visible Gaussians with ``layer == k`` ((V,) int8, negative: in none) into ``(rgb (K, H,
    W, 3), alpha (K, H, W), depth (K, H, W))[k]``, each equal to its own :func:`composite` bit
    for bit there; the pixels of the other tiles are zero."""
    shape = (num_layers, height, width)
    make = np.empty if len(tiles) == len(offsets) - 1 else np.zeros    # every tile: all written
    rgb = make(shape + (3,), dtype=np.float32)
    alpha, depth = make(shape, dtype=np.float32), make(shape, dtype=np.float32)
    _core.composite_layers(_c(splats, np.float32), _c(offsets, np.int64), _c(lists, np.int32),
                           _c(layer, np.int8), int(num_layers), _c(tiles, np.int32), int(width),
                           int(height), _c(background, np.float32), rgb, alpha, depth,
                           int(num_threads))
    return rgb, alpha, depth


def composite_patches(splats, offsets, lists, rects, keep, removal_offsets, removal_ids,
                      task_offsets, task_tiles, width: int, height: int, background,
                      num_threads: int, base=None):
    """Re-composite (removal, tile) tasks; returns patches (T, 16, 16, 3), (T, 16, 16) x 2.

    ``base``: None or (rgb (H, W, 3), alpha (H, W), depth (H, W)), the render of ``keep``;
    pixels no removed Gaussian reaches are then copied from it instead of composited."""
    task_tiles = _c(task_tiles, np.int32)
    if base is None:
        base = (np.empty(0, np.float32),) * 3
    else:
        base = (_c(base[0], np.float32), _c(base[1], np.float32), _c(base[2], np.float32))
        _expect(base[0], (height, width, 3), "base rgb")
        _expect(base[1], (height, width), "base alpha")
        _expect(base[2], (height, width), "base depth")
    t = task_tiles.shape[0]
    rgb = np.empty((t, TILE, TILE, 3), dtype=np.float32)
    alpha = np.empty((t, TILE, TILE), dtype=np.float32)
    depth = np.empty((t, TILE, TILE), dtype=np.float32)
    _core.composite_patches(_c(splats, np.float32), _c(offsets, np.int64), _c(lists, np.int32),
                            _c(rects, np.uint16), _mask(keep), _c(removal_offsets, np.int64),
                            _c(removal_ids, np.int32), _c(task_offsets, np.int64), task_tiles,
                            int(width), int(height), _c(background, np.float32), *base, rgb,
                            alpha, depth, int(num_threads))
    return rgb, alpha, depth


def contributions(splats, offsets, lists, keep, mask, width: int, height: int,
                  num_threads: int):
    """Added ``(pixel int64, id int32, weight float32)`` at the pixels where ``mask`` is set."""
    mask = _mask(mask)
    _expect(mask, (height, width), "mask")
    return _core.contributions(_c(splats, np.float32), _c(offsets, np.int64), _c(lists, np.int32),
                               _mask(keep), mask, int(width), int(height), int(num_threads))


def live_entries(splats, offsets, lists, floor, width: int, height: int,
                 num_threads: int) -> np.ndarray:
    """(P,) bool: the tile-list entries that a render of any subset containing ``floor`` (V,)
    bool over the visible Gaussians can use."""
    floor = _mask(floor)
    lists = _c(lists, np.int32)
    live = np.empty(lists.shape[0], dtype=np.uint8)
    _core.live_entries(_c(splats, np.float32), _c(offsets, np.int64), lists, floor, int(width),
                       int(height), live, int(num_threads))
    return live.view(np.bool_)


def restrict_view(splats, rects, index, offsets, lists, keep) -> tuple[int, int]:
    """Restrict a prepared view's arrays, in place, to the subset ``keep`` (N,) bool of its
    scene, renumbered as the subset scene: the kept records and tile-list entries move to the
    front of their arrays and ``offsets`` is rewritten. Returns the new counts of records and
    entries. The arrays must be C-contiguous and of the kernel's dtypes."""
    for a, dt in ((splats, np.float32), (rects, np.uint16), (index, np.int32),
                  (offsets, np.int64), (lists, np.int32)):
        if a.dtype != dt or not a.flags.c_contiguous or not a.flags.writeable:
            raise ValueError("restrict_view needs writeable C-contiguous arrays of the "
                             "prepared view's dtypes")
    num, pairs = _core.restrict_view(splats, rects, index, offsets, lists, _mask(keep))
    return int(num), int(pairs)


def sort_index(index: np.ndarray, num_threads: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``(np.sort(index), np.argsort(index, kind="stable"))`` as int32, for non-negative int32
    indices (a radix sort)."""
    return _core.sort_index(_c(index, np.int32), int(num_threads))


def take_mask(mask: np.ndarray, index: np.ndarray, num_threads: int = 1) -> np.ndarray:
    """``mask[index]`` for an (N,) bool mask and int32 indices, as (V,) bool (``np.take`` widens
    the indices to int64 first)."""
    return _core.take_mask(_mask(mask), _c(index, np.int32), num_threads).view(np.bool_)


def centres_inside(splats, index, n: int, width: int, height: int) -> np.ndarray:
    """(n,) bool: the Gaussians ``index`` whose projected centre (``splats[:, :2]``) lies in
    the image."""
    return _core.centres_inside(_c(splats, np.float32), _c(index, np.int32), int(n), int(width),
                                int(height)).view(np.bool_)
