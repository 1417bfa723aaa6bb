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

Each chunk runs the same calls in four blocks of tile-list positions (:data:`BLOCKS`),
front to back, carrying each pixel's transmittance from one to the next. The number of torch
calls per chunk is fixed; chunks split the tasks only where the fragments would exceed
``budget`` elements, so it does not grow with the number of tasks, removals or Gaussians
until memory requires it.
"""

from __future__ import annotations

from typing import NamedTuple

from ._kernels import TILE
from ._torch_raster import MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE, _f, exp_nonpositive

__all__ = ["ViewTensors", "composite", "BUDGET"]

_PIX = TILE * TILE
#: Fragments (and tile-list entries) one chunk may hold: about 150 bytes each at the peak
#: (some 600 MB for the default).
BUDGET = 1 << 22
#: Blocks of tile-list positions composited one after another (front to back): a pixel that
#: has stopped takes no fragment of a later block (where surfaces are opaque most pixels stop
#: within the first blocks; on the stand-in scenes at 8 views many do not, below 512).
BLOCKS = (0, 128, 512, 2048, 1 << 62)


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
              budget: int | None = None):
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
    budget : int, optional
        Entries and fragments per chunk (:data:`BUDGET` by default).

    Returns
    -------
    ``(rgbd (T, 256, 4), trans (T, 256))``: sums of ``c alpha T`` (RGB) and ``z alpha T``,
    and the final transmittance; or with ``record``, ``(task, pixel, id, weight)`` of every
    added fragment, ordered by task, pixel, then front to back.
    """
    dev = vt.geom.device
    budget = BUDGET if budget is None else budget
    n = tile.shape[0]
    lens = vt.offsets[tile + 1] - vt.offsets[tile]
    parts = [_chunk(torch, vt, tile, lens, t0, t1, keeps, keep_of, removed, removal_of,
                    region, pixel_ok, record, budget)
             for t0, t1 in _ranges(torch, lens, budget)]
    if record:
        if not parts:
            e = torch.empty(0, dtype=torch.long, device=dev)
            return e, e, e, torch.empty(0, dtype=torch.float32, device=dev)
        seg, gid, weight = (torch.cat([p[i] for p in parts]) for i in range(3))
        return seg // _PIX, seg % _PIX, gid, weight
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
    count = torch.where(inc, (lx1 - lx0 + 1).clamp_min(0) * (ly1 - ly0 + 1).clamp_min(0), 0)
    # Only the entries with fragments go on (a region leaves out most of a tile's list).
    e = torch.nonzero(count).squeeze(1)
    task, ids, j, count = task[e] - t0, ids[e], j[e], count[e]
    lx0, lx1, ly0, ly1 = lx0[e], lx1[e], ly0[e], ly1[e]
    x0, y0 = tx0[e] + lx0, ty0[e] + ly0
    # Split further where the fragments of these tasks exceed the budget.
    per_task = torch.zeros(t1 - t0, dtype=torch.long, device=dev).index_add_(0, task, count)
    ranges = _ranges(torch, per_task, budget)
    cuts = torch.tensor([a for a, _ in ranges] + [t1 - t0], device=dev)
    ends = torch.searchsorted(task, cuts).tolist()
    out = []
    for (a, b), e0, e1 in zip(ranges, ends[:-1], ends[1:]):
        sl = slice(e0, e1)
        entries = (task[sl] - a, ids[sl], j[sl], x0[sl], y0[sl], lx0[sl], lx1[sl], ly0[sl],
                   ly1[sl], count[sl])
        ok = None if pixel_ok is None else pixel_ok[t0 + a:t0 + b]
        o = _composite_entries(torch, vt, b - a, entries, ok, record)
        out.append((o[0] + (t0 + a) * _PIX, *o[1:]) if record else o)
    if record:
        return tuple(torch.cat([o[i] for o in out]) for i in range(3))
    return torch.cat([o[0] for o in out]), torch.cat([o[1] for o in out])


def _segment_sums(torch, values, per):
    """Sums of ``values`` (..., F) float64 over consecutive segments of ``per`` (S,) items."""
    run = torch.zeros((*values.shape[:-1], values.shape[-1] + 1), dtype=torch.float64,
                      device=values.device)
    run[..., 1:] = torch.cumsum(values, -1)
    end = torch.cumsum(per, 0)
    return run[..., end] - run[..., end - per]


def _composite_entries(torch, vt, num_tasks, entries, pixel_ok, record):
    """Composite ``num_tasks`` tasks from their tile-list entries, block by block of list
    positions (:data:`BLOCKS`), carrying each pixel's transmittance and sums from one block
    to the next; a pixel that has stopped takes no fragment of a later block, and an entry
    none of whose pixels is still compositing makes none."""
    task, ids, j, x0, y0, lx0, lx1, ly0, ly1, count = entries
    dev = vt.geom.device
    f = lambda c: _f(torch, c, dev)  # noqa: E731
    s = num_tasks * _PIX
    log_t = torch.zeros(s, dtype=torch.float64, device=dev)      # log transmittance so far
    sums = torch.zeros((4, s), dtype=torch.float64, device=dev)  # c alpha T (RGB), z alpha T
    stopped = (torch.zeros(s, dtype=torch.bool, device=dev) if pixel_ok is None
               else ~pixel_ok.reshape(-1))
    kept = []
    for lo, hi in zip(BLOCKS[:-1], BLOCKS[1:]):
        e = torch.nonzero((j >= lo) & (j < hi)).squeeze(1)
        if lo > 0:                   # entries with a pixel still compositing in their box
            e = e[_any_live(torch, ~stopped, task[e], lx0[e], lx1[e], ly0[e], ly1[e])]
        n = count[e]
        ent = e[torch.repeat_interleave(torch.arange(e.shape[0], device=dev), n)]
        k = torch.arange(ent.shape[0], device=dev) - (torch.cumsum(n, 0) - n).repeat_interleave(n)
        w = lx1[ent] - lx0[ent] + 1
        col, row = k % w, k // w
        seg = task[ent] * _PIX + (ly0[ent] + row) * TILE + lx0[ent] + col
        go = torch.nonzero(~stopped[seg]).squeeze(1)   # pixels that still composite
        ent, col, row, seg = ent[go], col[go], row[go], seg[go]
        g = vt.geom[ids[ent]]
        # The 3DGS per-pixel test, in the C++ code's float32 operations and order.
        dx = g[:, 0] - ((x0[ent] + col).float() + f(0.5))
        dy = g[:, 1] - ((y0[ent] + row).float() + f(0.5))
        power = f(-0.5) * (g[:, 2] * dx * dx + g[:, 4] * dy * dy) - g[:, 3] * dx * dy
        alpha = g[:, 5] * exp_nonpositive(torch, power)
        alpha = torch.where(alpha < f(MAX_ALPHA), alpha, f(MAX_ALPHA))
        on = torch.nonzero((power <= f(0.0)) & (alpha >= f(MIN_ALPHA)))
        on = on.squeeze(1)
        seg, alpha, gid = seg[on], alpha[on], ids[ent[on]]
        # Per pixel, front to back (made in list order: a stable sort keeps it).
        seg, order = torch.sort(seg, stable=True)
        alpha, gid = alpha[order], gid[order]
        per = torch.bincount(seg, minlength=s)
        first = (torch.cumsum(per, 0) - per)[seg]
        # Transmittance before and after each fragment: the pixel's carried product times
        # the product of 1 - alpha over its earlier fragments here, as float64 logarithms.
        la = torch.log1p(-alpha.double())
        run = torch.cumsum(la, 0) - la
        log_before = log_t[seg] + (run - run[first])
        before = torch.exp(log_before).float()
        add = torch.exp(log_before + la).float() >= f(MIN_TRANSMITTANCE)
        weight = torch.where(add, alpha * before, f(0.0))
        terms = vt.colour[gid].T * weight                          # (4, F)
        sums += _segment_sums(torch, terms.double(), per)
        log_t += _segment_sums(torch, torch.where(add, la, 0.0), per)
        stopped[seg[~add]] = True
        if record:
            kept.append((seg[add], gid[add], weight[add]))
    if record:
        seg = torch.cat([x[0] for x in kept])
        seg, order = torch.sort(seg, stable=True)     # by pixel, blocks front to back
        return seg, torch.cat([x[1] for x in kept])[order], torch.cat([x[2] for x in kept])[order]
    trans = torch.exp(log_t).float()
    return sums.float().T.reshape(num_tasks, _PIX, 4), trans.view(num_tasks, _PIX)


def _any_live(torch, live, task, lx0, lx1, ly0, ly1):
    """Per entry: whether its rectangle (tile-local, inclusive, maybe empty) holds a pixel of
    ``live`` ((T * 256,) bool), from each task's summed-area table."""
    t = live.shape[0] // _PIX
    table = torch.zeros((t, TILE + 1, TILE + 1), dtype=torch.int32, device=live.device)
    table[:, 1:, 1:] = live.view(t, TILE, TILE).int().cumsum(1).cumsum(2)
    flat = table.view(-1)
    base = task * (TILE + 1) ** 2
    x1, y1 = (lx1 + 1).clamp_min(lx0), (ly1 + 1).clamp_min(ly0)

    def at(y, x):
        return flat[base + y * (TILE + 1) + x]

    return (at(y1, x1) - at(ly0, x1) - at(y1, lx0) + at(ly0, lx0)) > 0
