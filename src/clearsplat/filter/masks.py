"""Image-mask morphology the stages share: 8-connected components, disk and 3x3 dilation.

Both are exact equivalents of the SciPy functions named in their docstrings (tested against
them), written with array operations so that a filter run needs no SciPy.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["label8", "touched_components", "dilate", "dilate8"]


def label8(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected components of a (h, w) bool mask: labels 1..count (0 outside), numbered
    in the order of each component's first pixel in row-major order.

    The numbering of ``scipy.ndimage.label`` with a 3x3 structure, without importing SciPy.
    Works on runs (horizontal stretches of True): two runs of neighbouring rows touch when
    their column ranges overlap or meet at a corner. The components of that graph of runs come
    from hooking each root to the smallest root it touches and pointer jumping, all in array
    operations; each component ends up named by its first run.
    """
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    labels = np.zeros((h, w), dtype=np.int32)
    if not mask.any():
        return labels, 0
    padded = np.zeros((h, w + 2), dtype=np.int8)
    padded[:, 1:-1] = mask
    edges = np.diff(padded, axis=1)           # +1 where a run starts, -1 past its end
    row, start = np.nonzero(edges == 1)
    _, end = np.nonzero(edges == -1)          # exclusive; runs in row-major order
    runs = start.size
    # Touching pairs (a, b), b in the next row: s_b <= e_a and s_a <= e_b. Keys row * W + col
    # (W > w) keep the rows apart, so one search over all runs finds b's range for every a.
    wide = w + 2
    lo = np.searchsorted(row * wide + end, (row + 1) * wide + start, side="left")
    hi = np.searchsorted(row * wide + start, (row + 1) * wide + end, side="right")
    count = np.maximum(hi - lo, 0)
    a = np.repeat(np.arange(runs), count)
    b = np.repeat(lo, count) + (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count,
                                                                          count))
    root = np.arange(runs)
    while a.size:
        ra, rb = root[a], root[b]
        differ = ra != rb
        if not differ.any():
            break
        a, b, ra, rb = a[differ], b[differ], ra[differ], rb[differ]
        np.minimum.at(root, np.maximum(ra, rb), np.minimum(ra, rb))   # hook to a smaller root
        while True:                                                   # then point to roots
            up = root[root]
            if np.array_equal(up, root):
                break
            root = up
    is_root = root == np.arange(runs)
    number = np.cumsum(is_root).astype(np.int32)     # a root's component number, in run order
    lengths = end - start
    flat = labels.reshape(-1)
    offsets = np.repeat(row * w + start, lengths) + (
        np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths))
    flat[offsets] = np.repeat(number[root], lengths)
    return labels, int(is_root.sum())


def touched_components(labels: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Bool mask of the shape of ``labels``: the components (labels > 0, as :func:`label8`
    numbers them) that hold a pixel of ``where`` (a bool mask of the same shape)."""
    reached = np.zeros(int(labels.max(initial=0)) + 1, dtype=bool)
    reached[labels[where]] = True
    reached[0] = False
    return reached[labels]


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate a (H, W) bool mask by a disk of ``radius`` pixels (Euclidean)."""
    if radius <= 0 or not mask.any():
        return mask.copy()
    r = int(radius)
    # Dilate only the region's bounding box grown by r: same result, far less work.
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, mask.shape[0])
    c0, c1 = max(cols[0] - r, 0), min(cols[-1] + r + 1, mask.shape[1])
    out = np.zeros_like(mask, dtype=bool)
    out[r0:r1, c0:c1] = _dilate_disk(mask[r0:r1, c0:c1], r)
    return out


def dilate8(mask: np.ndarray) -> np.ndarray:
    """Dilate a (H, W) bool mask by the 3x3 square: each pixel with any of its 8 neighbours (or
    itself) set; zeros outside the image. Equal to ``scipy.ndimage.binary_dilation`` with
    ``structure=np.ones((3, 3))``."""
    rows = mask.copy()
    rows[1:] |= mask[:-1]
    rows[:-1] |= mask[1:]
    out = rows.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


def _dilate_disk(mask: np.ndarray, r: int) -> np.ndarray:
    """Binary dilation by the disk ``dy^2 + dx^2 <= r^2`` with zeros outside ``mask``.

    Row by row: the disk's row at offset ``dy`` is the run ``|dx| <= k(dy)``, so the result is
    the union over ``dy`` of ``mask`` dilated horizontally by ``k(dy)`` (a difference of
    running sums) and shifted by ``dy``. Equal to ``scipy.ndimage.binary_dilation`` with that
    structure, without importing SciPy.
    """
    h, w = mask.shape
    run = np.zeros((h, w + 1), dtype=np.int32)
    np.cumsum(mask, axis=1, out=run[:, 1:])
    cols = np.arange(w)
    out = np.zeros((h, w), dtype=bool)
    rows: dict = {}
    for dy in range(-min(r, h - 1), min(r, h - 1) + 1):
        k = math.isqrt(r * r - dy * dy)
        if k not in rows:
            hi = np.minimum(cols + k + 1, w)
            lo = np.maximum(cols - k, 0)
            rows[k] = run[:, hi] > run[:, lo]
        wide = rows[k]
        # out[y] |= wide[y + dy]
        if dy >= 0:
            out[:h - dy] |= wide[dy:]
        else:
            out[-dy:] |= wide[:h + dy]
    return out
