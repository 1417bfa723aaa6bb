"""``TorchView.rerender_tiles``: every removal of a view re-composited in one batch.

Each removal becomes its (removal, tile) tasks, the tiles its Gaussians are binned into (or
the given ones); all tasks composite together (:func:`clearsplat.render._torch_composite.
composite`), each without its removal's Gaussians, which are looked up by the key
``removal * V + id`` in one sorted tensor. With a ``base`` render, only the pixels inside the
removed Gaussians' boxes are composited and the others are copied from it, as the C++ code does
(compositing never visits a Gaussian outside its box, so they are the base render there).
The number of torch calls does not depend on the number of removals.
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from . import _torch_composite as tc
from . import _torch_raster as tr
from .base import TILE, RenderResult, TilePatch, _check_indices

__all__ = ["rerender_tiles"]

_PIX = TILE * TILE


def _flatten(removals: list, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(removal, gaussian) int64 pairs of index arrays or (n,) bool masks."""
    arrays = [np.asarray(r.cpu() if hasattr(r, "cpu") else r) for r in removals]
    arrays = [_check_indices(a, n, f"removals[{i}]") for i, a in enumerate(arrays)]
    sizes = np.fromiter((a.size for a in arrays), dtype=np.int64, count=len(arrays))
    ids = np.concatenate(arrays) if arrays else np.empty(0, np.int64)
    return np.repeat(np.arange(len(arrays), dtype=np.int64), sizes), ids


def rerender_tiles(view, *, keep, removals, tiles_list=None, background=(0.0, 0.0, 0.0),
                   base: RenderResult | None = None) -> list[TilePatch]:
    """See :meth:`clearsplat.render.native.PreparedView.rerender_tiles`."""
    torch, dev = view._torch, view.device
    keep_v = view._keep(keep)
    bg = view._bg(background)
    removals = list(removals)
    count = len(removals)
    if base is not None:
        h, w = view.camera.height, view.camera.width
        if not isinstance(base, RenderResult) or np.shape(base.rgb) != (h, w, 3):
            raise ClearsplatError(f"expected a RenderResult of this view ({h}x{w})",
                                  field="base")
    if tiles_list is not None:
        tiles_list = list(tiles_list)
        if len(tiles_list) != count:
            raise ClearsplatError(f"{len(tiles_list)} tile lists for {count} removals",
                                  field="tiles_list")
    pair_r, pair_g = _flatten(removals, view.num_gaussians)
    nv, nt, cols = view.num_visible, view.num_tiles, view.grid[1]
    r = torch.from_numpy(pair_r).to(dev)
    vid = view._visible_ids()[torch.from_numpy(pair_g).to(dev)]
    keys = torch.unique(r[vid >= 0] * nv + vid[vid >= 0])     # sorted: by removal, then id
    item, tile = tr.rect_tiles(torch, view._rect[keys % nv], cols)
    touched = (keys // nv)[item] * nt + tile                  # (removal, tile) of every pair
    if tiles_list is None:
        tasks = torch.unique(touched)
    else:
        sets = [view._check_tiles(t, f"tiles_list[{i}]").astype(np.int64)
                for i, t in enumerate(tiles_list)]
        sizes = np.fromiter((s.size for s in sets), dtype=np.int64, count=count)
        flat = np.concatenate(sets) if sets else np.empty(0, np.int64)
        flat += np.repeat(np.arange(count, dtype=np.int64), sizes) * nt
        tasks = torch.from_numpy(flat).to(dev)
    task_r, task_tile = tasks // nt, tasks % nt
    n = task_tile.shape[0]
    offsets = np.zeros(count + 1, dtype=np.int64)
    offsets[1:] = np.cumsum(torch.bincount(task_r, minlength=count).cpu().numpy())
    region = changed = None
    if base is not None:
        region, changed = _changed(torch, view, tasks, touched, keys[item] % nv, tile)
    sums, trans = tc.composite(torch, view._t, task_tile,
                               keeps=None if keep_v is None else keep_v[None],
                               keep_of=torch.zeros_like(task_tile), removed=keys,
                               removal_of=task_r, region=region, pixel_ok=changed)
    rgb, alpha, depth = view._finish(torch, sums, trans, bg)
    flat, inside = view._pixels(task_tile)
    if base is not None:
        b = [torch.from_numpy(np.array(a, np.float32)).to(dev).reshape(-1, c)
             for a, c in ((base.rgb, 3), (base.alpha, 1), (base.depth, 1))]
        rgb = torch.where(changed[..., None], rgb, b[0][flat])
        alpha = torch.where(changed, alpha, b[1][flat, 0])
        depth = torch.where(changed, depth, b[2][flat, 0])
    rgb = torch.where(inside[..., None], rgb, 0.0).reshape(n, TILE, TILE, 3).cpu().numpy()
    alpha = torch.where(inside, alpha, 0.0).reshape(n, TILE, TILE).cpu().numpy()
    depth = torch.where(inside, depth, 0.0).reshape(n, TILE, TILE).cpu().numpy()
    task_tiles = task_tile.cpu().numpy().astype(np.int32)
    return [TilePatch(task_tiles[a:b], rgb[a:b], alpha[a:b], depth[a:b])
            for a, b in zip(offsets[:-1], offsets[1:])]


def _changed(torch, view, tasks, touched, ids, tile):
    """Per task, the bounding rectangle (tile-local ``x0, x1, y0, y1``; empty when none) and
    the (T, 256) pixels of the boxes of its removal's Gaussians binned into its tile."""
    dev = view.device
    n = tasks.shape[0]
    t = torch.searchsorted(tasks, touched).clamp_max(max(n - 1, 0))
    on = tasks[t] == touched if n else torch.zeros_like(touched, dtype=torch.bool)
    t, ids, tile = t[on], ids[on], tile[on]
    box = view._t.box[ids]
    tx0, ty0 = (tile % view.grid[1]) * TILE, (tile // view.grid[1]) * TILE
    x0, x1 = (box[:, 0] - tx0).clamp_min(0), (box[:, 1] - tx0).clamp_max(TILE - 1)
    y0, y1 = (box[:, 2] - ty0).clamp_min(0), (box[:, 3] - ty0).clamp_max(TILE - 1)
    region = torch.tensor([TILE, -1, TILE, -1], device=dev).repeat(n, 1)
    for c, (v, how) in enumerate(((x0, "amin"), (x1, "amax"), (y0, "amin"), (y1, "amax"))):
        region[:, c].scatter_reduce_(0, t, v, how)
    bw = (x1 - x0 + 1).clamp_min(0)
    count = bw * (y1 - y0 + 1).clamp_min(0)
    pair = torch.repeat_interleave(torch.arange(count.shape[0], device=dev), count)
    k = torch.arange(pair.shape[0], device=dev) - (torch.cumsum(count, 0) - count)[pair]
    p = (y0[pair] + k // bw[pair]) * TILE + x0[pair] + k % bw[pair]
    changed = torch.zeros(n * _PIX, dtype=torch.bool, device=dev)
    changed[t[pair] * _PIX + p] = True
    return region, changed.view(n, _PIX)
