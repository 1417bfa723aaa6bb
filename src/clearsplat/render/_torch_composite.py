"""Batched front-to-back compositing of tile *tasks* in torch (the twin of
``cpp/composite.cpp``).

A task is one tile composited with one keep mask (a row of ``keeps``) and, optionally, without
one removal's Gaussians (``removed``: sorted keys ``removal * V + id``). Every task's tile list
is expanded to *fragments*: (task, Gaussian, pixel) with the pixel inside the Gaussian's box,
in the task's region of its tile, in list (front-to-back) order. Fragments with ``power > 0``
or ``alpha < 1/255`` are dropped (the C++ loop skips them without touching the pixel), the
rest are sorted stably by pixel, and the transmittance before each fragment is the product of
``1 - alpha`` over the earlier fragments of its pixel: a running sum of ``log(1 - alpha)`` in
float64 over the sorted fragments, restarted at each pixel (one ``cumsum``: a product scan
without padding every pixel to the deepest one). The pixel stops at the first fragment whose
product would fall below 1e-4: that fragment and all later ones add nothing, and the final
transmittance is the last product at or above 1e-4. The per-pixel sums of ``c alpha T`` and
``z alpha T`` are differences of a float64 running sum, so the result does not depend on the
device's scheduling (no atomic adds).

The number of torch calls per chunk is fixed; chunks split the tasks only where the
fragments would exceed ``budget`` elements, so it does not grow with the number of tasks,
removals or Gaussians until memory requires it.
"""

from __future__ import annotations

from typing import NamedTuple

from ._kernels import TILE
from ._torch_raster import MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE, _f, exp_nonpositive

__all__ = ["ViewTensors", "composite", "BUDGET"]

_PIX = TILE * TILE
#: Fragments (and tile-list entries) one chunk may hold: about 40 bytes each at the peak.
BUDGET = 1 << 22


class ViewTensors(NamedTuple):
    """A prepared view's tensors (see :func:`clearsplat.render._torch_raster.project`)."""

    geom: object      # (V, 6) float32 u, v, conic a b c, opacity
    colour: object    # (V, 4) float32 r, g, b, depth
    box: object       # (V, 4) int64 pixel box x0, x1, y0, y1
    offsets: object   # (num_tiles + 1,) int64
    lists: object     # (P,) int64 ids, ascending per tile
    width: int
    height: int
    cols: int


def _ranges(torch, weights, budget: int) -> list[tuple[int, int]]:
    """Consecutive index ranges whose ``weights`` sum to at most ``budget`` (a single heavier
    item alone); one host read."""
    if weights.shape[0] == 0:
        return []
    run = torch.cumsum(weights, 0).tolist()
    out, start, base = [], 0, 0
    for i, total in enumerate(run):
        if total - base > budget and i > start:
            out.append((start, i))
            start, base = i, run[i - 1]
    out.append((start, len(run)))
    return out


def composite(torch, vt: ViewTensors, tile, *, keeps=None, keep_of=None, removed=None,
              removal_of=None, region=None, pixel_ok=None, record: bool = False,
              budget: int = BUDGET):
    """Composite tasks.

    Parameters
    ----------
    tile : (T,) int64
        The tile of each task.
    keeps : (K, V) bool, optional
        Keep masks over the visible Gaussians (None: all); task t uses ``keeps[keep_of[t]]``.
    removed : (M,) int64 sorted, optional
        Keys ``removal_of[t] * V + id`` of the Gaussians each task leaves out.
    region : (T, 4) int64, optional
        Inclusive pixel rectangle ``x0, x1, y0, y1`` (tile-local) outside which nothing is
        composited (an empty one composites nothing).
    pixel_ok : (T, 256) bool, optional
        Pixels composited (tile-local, row-major); the others are left at T = 1.
    record : bool
        Return the added fragments instead of images.

    Returns
    -------
    ``(rgbd (T, 256, 4), trans (T, 256))``: sums of ``c alpha T`` (RGB) and ``z alpha T``,
    and the final transmittance; or with ``record``, ``(task, pixel, id, weight)`` of every
    added fragment, ordered by task, pixel, then front to back.
    """
    dev = vt.geom.device
    n = tile.shape[0]
    lens = vt.offsets[tile + 1] - vt.offsets[tile]
    parts = [_chunk(torch, vt, tile, lens, t0, t1, keeps, keep_of, removed, removal_of,
                    region, pixel_ok, record, budget)
             for t0, t1 in _ranges(torch, lens, budget)]
    if record:
        if not parts:
            e = torch.empty(0, dtype=torch.long, device=dev)
            return e, e, e, torch.empty(0, dtype=torch.float32, device=dev)
        return tuple(torch.cat([p[i] for p in parts]) for i in range(4))
    if not parts:
        return (torch.zeros((n, _PIX, 4), device=dev), torch.ones((n, _PIX), device=dev))
    return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])


def _chunk(torch, vt, tile, lens, t0, t1, keeps, keep_of, removed, removal_of, region,
           pixel_ok, record, budget):
    """Tasks ``t0:t1`` (their entries within ``budget``): entries, then fragments."""
    dev = vt.geom.device
    ar = torch.arange(t0, t1, device=dev)
    lc = lens[t0:t1]
    task = torch.repeat_interleave(ar, lc)
    j = torch.arange(task.shape[0], device=dev) - (torch.cumsum(lc, 0) - lc)[task - t0]
    ids = vt.lists[vt.offsets[tile[task]] + j]
    inc = torch.ones_like(ids, dtype=torch.bool) if keeps is None else keeps[keep_of[task], ids]
    if removed is not None and removed.numel():
        key = removal_of[task] * vt.geom.shape[0] + ids
        at = torch.searchsorted(removed, key).clamp_max(removed.shape[0] - 1)
        inc &= removed[at] != key
    # The entry's box within its tile (and the task's region), tile-local.
    tx0 = (tile[task] % vt.cols) * TILE
    ty0 = (tile[task] // vt.cols) * TILE
    box = vt.box[ids]
    lx0 = (box[:, 0] - tx0).clamp_min(0)
    lx1 = torch.minimum(box[:, 1] - tx0, (vt.width - 1 - tx0).clamp_max(TILE - 1))
    ly0 = (box[:, 2] - ty0).clamp_min(0)
    ly1 = torch.minimum(box[:, 3] - ty0, (vt.height - 1 - ty0).clamp_max(TILE - 1))
    if region is not None:
        r = region[task]
        lx0, lx1 = torch.maximum(lx0, r[:, 0]), torch.minimum(lx1, r[:, 1])
        ly0, ly1 = torch.maximum(ly0, r[:, 2]), torch.minimum(ly1, r[:, 3])
    bw = (lx1 - lx0 + 1).clamp_min(0)
    count = torch.where(inc, bw * (ly1 - ly0 + 1).clamp_min(0), 0)
    # Split further where the fragments of these tasks exceed the budget.
    per_task = torch.zeros(t1 - t0, dtype=torch.long, device=dev).index_add_(0, task - t0, count)
    ends = [0] + torch.cumsum(lc, 0).tolist()
    out = []
    for a, b in _ranges(torch, per_task, budget):
        sl = slice(ends[a], ends[b])
        out.append(_fragments(torch, vt, t0 + a, t0 + b, task[sl], ids[sl], tx0[sl], ty0[sl],
                              lx0[sl], ly0[sl], bw[sl], count[sl], pixel_ok, record))
    if record:
        return tuple(torch.cat([o[i] for o in out]) for i in range(4))
    return torch.cat([o[0] for o in out]), torch.cat([o[1] for o in out])


def _fragments(torch, vt, t0, t1, task, ids, tx0, ty0, lx0, ly0, bw, count, pixel_ok, record):
    """Composite the fragments of tasks ``t0:t1`` (their entries given)."""
    dev = vt.geom.device
    f = lambda c: _f(torch, c, dev)  # noqa: E731
    live = torch.nonzero(count).squeeze(1)          # entries with fragments
    count = count[live]
    # Per entry: its first fragment, box width, pixel origin and pixel-slot base, gathered
    # once per fragment as one row.
    first = torch.cumsum(count, 0) - count
    x0, y0 = tx0[live] + lx0[live], ty0[live] + ly0[live]
    slot = (task[live] - t0) * _PIX + ly0[live] * TILE + lx0[live]
    rows = torch.stack([first, bw[live], x0, y0, slot, live], 1)
    ent = torch.repeat_interleave(torch.arange(live.shape[0], device=dev), count)
    e = rows[ent]
    k = torch.arange(ent.shape[0], device=dev) - e[:, 0]
    col, row = k % e[:, 1], k // e[:, 1]
    seg = e[:, 4] + row * TILE + col                # (task - t0) * 256 + pixel
    g = vt.geom[ids[e[:, 5]]]
    # The 3DGS per-pixel test, in the C++ code's float32 operations and order.
    dx = g[:, 0] - ((e[:, 2] + col).float() + f(0.5))
    dy = g[:, 1] - ((e[:, 3] + row).float() + f(0.5))
    power = f(-0.5) * (g[:, 2] * dx * dx + g[:, 4] * dy * dy) - g[:, 3] * dx * dy
    alpha = g[:, 5] * exp_nonpositive(torch, power)
    alpha = torch.where(alpha < f(MAX_ALPHA), alpha, f(MAX_ALPHA))
    on = (power <= f(0.0)) & (alpha >= f(MIN_ALPHA))
    if pixel_ok is not None:
        on &= pixel_ok.view(-1)[seg + t0 * _PIX]
    keep = torch.nonzero(on).squeeze(1)
    seg, alpha, gid = seg[keep], alpha[keep], ids[e[keep, 5]]
    # Per pixel, front to back (fragments were made in list order: a stable sort keeps it).
    seg, order = torch.sort(seg, stable=True)
    alpha, gid = alpha[order], gid[order]
    s = (t1 - t0) * _PIX
    per = torch.bincount(seg, minlength=s)
    first = (torch.cumsum(per, 0) - per)[seg]       # each fragment's pixel's first fragment
    # Transmittance before and after each fragment: the product of 1 - alpha over the pixel's
    # earlier fragments, as a float64 running sum of logarithms restarted at every pixel.
    la = torch.log1p(-alpha.double())
    run = torch.cumsum(la, 0) - la                   # sum over all earlier fragments
    log_before = run - run[first]
    before = torch.exp(log_before).float()
    after = torch.exp(log_before + la).float()
    add = after >= f(MIN_TRANSMITTANCE)
    weight = alpha * before
    if record:
        return seg[add] // _PIX + t0, seg[add] % _PIX, gid[add], weight[add]
    # The final transmittance: the last product at or above 1e-4 (products only decrease).
    trans = torch.ones(s, device=dev).scatter_reduce_(0, seg[add], after[add], "amin")
    # Per-pixel sums of c alpha T and z alpha T: differences of a float64 running sum over the
    # sorted fragments (deterministic on every device, unlike scattered atomic adds).
    terms = vt.colour[gid].T * torch.where(add, weight, f(0.0))       # (4, F)
    run = torch.zeros((4, seg.shape[0] + 1), dtype=torch.float64, device=dev)
    run[:, 1:] = torch.cumsum(terms.double(), 1)
    end = torch.cumsum(per, 0)
    sums = (run[:, end] - run[:, end - per]).float().T
    return sums.reshape(t1 - t0, _PIX, 4), trans.view(t1 - t0, _PIX)
