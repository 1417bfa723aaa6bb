"""The feature-extractor interface and the patch grid it works on.

The distractor proposal compares an input image ``I_i`` with the exclusion render
``R_i^{-i}`` patch by patch (paper, "Distractor Proposal"): ``s_i(u) = sim(Phi(I_i)(u),
Phi(R_i^{-i})(u))``. Every extractor maps a batch of images to a feature grid and a
per-cell similarity in [-1, 1], and carries the two similarity boundaries ``tau1 < tau2``
calibrated for its own similarity scale.

The grid
--------
An extractor with patch size ``p`` puts ``h = max(1, round(H / p))`` cells over an image
of height ``H`` (and likewise ``w`` over the width): it resizes the image to
``(h * p, w * p)`` when ``H`` or ``W`` is not a multiple of ``p`` (a ViT does the same)
and cuts that into ``p x p`` patches. In input pixels, cell ``(r, c)`` covers rows
``floor(r * H / h) .. floor((r + 1) * H / h) - 1`` and columns
``floor(c * W / w) .. floor((c + 1) * W / w) - 1``; :func:`cell_slices`,
:func:`upsample_nearest` and :func:`cell_average` use exactly that mapping, so
per-cell quantities of the renderer (patch-average opacity and depth) line up with the
feature grid.

Images are float32 RGB in [0, 1], indexed ``[row, col]`` (``docs/conventions.md``).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .._threads import thread_map
from ..errors import ClearsplatError

__all__ = [
    "FeatureExtractor",
    "cell_average",
    "cell_edges",
    "cell_slices",
    "check_images",
    "cosine_similarity",
    "grid_shape_for",
    "resize_bilinear",
    "upsample_nearest",
]


def grid_shape_for(height: int, width: int, patch_size: int) -> tuple[int, int]:
    """Grid of ``patch_size`` cells nearest to an image size.

    Parameters
    ----------
    height, width : int
        Image size in pixels, both >= 1.
    patch_size : int
        Pixels per cell side.

    Returns
    -------
    (h, w) : tuple of int
        ``max(1, floor(height / patch_size + 0.5))`` and the same for the width.
    """
    height, width, patch_size = int(height), int(width), int(patch_size)
    if height < 1 or width < 1:
        raise ClearsplatError(f"image size must be at least 1x1, got {height}x{width}",
                              field="images")
    if patch_size < 1:
        raise ClearsplatError(f"patch_size must be >= 1, got {patch_size}", field="patch_size")
    return (max(1, math.floor(height / patch_size + 0.5)),
            max(1, math.floor(width / patch_size + 0.5)))


def cell_edges(n_cells: int, n_pixels: int) -> np.ndarray:
    """Pixel boundaries of ``n_cells`` cells over ``n_pixels`` pixels.

    Returns
    -------
    edges : (n_cells + 1,) int64
        ``edges[k] = floor(k * n_pixels / n_cells)``; cell ``k`` covers pixels
        ``edges[k] .. edges[k + 1] - 1``.
    """
    n_cells, n_pixels = int(n_cells), int(n_pixels)
    if n_cells < 1 or n_pixels < 1:
        raise ClearsplatError(f"need at least one cell and one pixel, got {n_cells} cells "
                              f"over {n_pixels} pixels", field="grid")
    return (np.arange(n_cells + 1, dtype=np.int64) * n_pixels) // n_cells


def cell_slices(grid_shape: tuple[int, int], height: int, width: int
                ) -> tuple[list[slice], list[slice]]:
    """Row and column slices of every grid cell in an image of ``height x width``.

    Parameters
    ----------
    grid_shape : (h, w)
        The feature grid.
    height, width : int
        The image size.

    Returns
    -------
    rows, cols : list of slice
        Cell ``(r, c)`` is ``image[rows[r], cols[c]]``. A cell can be empty when the grid
        is finer than the image.
    """
    h, w = grid_shape
    re, ce = cell_edges(h, height), cell_edges(w, width)
    return ([slice(int(re[r]), int(re[r + 1])) for r in range(int(h))],
            [slice(int(ce[c]), int(ce[c + 1])) for c in range(int(w))])


@functools.lru_cache(maxsize=64)
def _cell_index(grid_shape: tuple[int, int], height: int, width: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Cell row of every image row and cell column of every image column (read-only: one
    pair per grid and image size is kept and shared)."""
    h, w = int(grid_shape[0]), int(grid_shape[1])
    re, ce = cell_edges(h, height), cell_edges(w, width)
    # The cell of pixel y is the k with edges[k] <= y < edges[k + 1].
    rows = np.searchsorted(re, np.arange(height), side="right") - 1
    cols = np.searchsorted(ce, np.arange(width), side="right") - 1
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def upsample_nearest(grid: np.ndarray, height: int, width: int) -> np.ndarray:
    """Nearest-neighbour upsampling of a per-cell array to image resolution.

    Parameters
    ----------
    grid : (h, w, ...) array
        One value (or trailing vector) per cell; any dtype (bool masks stay bool).
    height, width : int
        The image size, at least ``h x w``.

    Returns
    -------
    image : (height, width, ...) array, same dtype
        Pixel ``(y, x)`` takes the value of the cell that covers it (see
        :func:`cell_slices`).
    """
    grid = np.asarray(grid)
    if grid.ndim < 2:
        raise ClearsplatError(f"grid must have at least 2 dimensions, got shape {grid.shape}",
                              field="grid")
    h, w = grid.shape[:2]
    if height < h or width < w:
        raise ClearsplatError(f"cannot upsample a {h}x{w} grid to a smaller image "
                              f"{height}x{width}", field="grid")
    rows, cols = _cell_index((int(h), int(w)), int(height), int(width))
    # Rows, then columns: two gathers along one axis each, several times faster than one
    # gather with broadcast (row, column) indices, and the same values.
    return grid.take(rows, axis=0).take(cols, axis=1)


def cell_average(values: np.ndarray, grid_shape: tuple[int, int], *,
                 mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Average of a per-pixel quantity over each grid cell.

    Parameters
    ----------
    values : (H, W) array
        Per-pixel values (accumulated opacity, depth).
    grid_shape : (h, w)
        The feature grid.
    mask : (H, W) bool, optional
        Only these pixels count (valid depth). All pixels when omitted.

    Returns
    -------
    mean : (h, w) float32
        Mean over the counted pixels of each cell; NaN where a cell has none, so any
        comparison with it is False.
    count : (h, w) int64
        Number of counted pixels per cell.
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2:
        raise ClearsplatError(f"values must be (H, W), got shape {values.shape}", field="values")
    H, W = values.shape
    if mask is None:
        weights = np.ones((H, W))
    else:
        mask = np.asarray(mask)
        if mask.shape != (H, W):
            raise ClearsplatError(f"mask must have shape {(H, W)}, got {mask.shape}",
                                  field="mask")
        weights = mask.astype(np.float64)
    h, w = int(grid_shape[0]), int(grid_shape[1])
    re, ce = cell_edges(h, H), cell_edges(w, W)
    if np.any(np.diff(re) == 0) or np.any(np.diff(ce) == 0):
        raise ClearsplatError(f"a {h}x{w} grid has empty cells on a {H}x{W} image",
                              field="grid")

    def pooled(x):
        x = np.add.reduceat(x, re[:-1], axis=0)
        return np.add.reduceat(x, ce[:-1], axis=1)

    total = pooled(np.where(weights > 0, values, 0.0))
    count = pooled(weights)
    mean = np.full((h, w), np.nan)
    np.divide(total, count, out=mean, where=count > 0)
    return mean.astype(np.float32), np.rint(count).astype(np.int64)


def check_images(images, *, field: str = "images") -> np.ndarray:
    """Validate a batch of RGB images and return it as float32 in [0, 1].

    Parameters
    ----------
    images : (B, H, W, 3) array_like
        Float RGB. Values outside [0, 1] (a rendering's highlights) are clipped.
    field : str
        Name used in error messages.

    Returns
    -------
    images : (B, H, W, 3) float32, C-contiguous
    """
    arr = np.asarray(images)
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise ClearsplatError(f"expected a batch of RGB images (B, H, W, 3), got shape "
                              f"{arr.shape}", field=field)
    if arr.shape[0] < 1 or arr.shape[1] < 1 or arr.shape[2] < 1:
        raise ClearsplatError(f"empty image batch of shape {arr.shape}", field=field)
    if not np.issubdtype(arr.dtype, np.floating):
        raise ClearsplatError(f"images must be float RGB in [0, 1], got dtype {arr.dtype}",
                              field=field)
    arr = arr.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise ClearsplatError("images contain NaN or infinite values", field=field)
    return np.ascontiguousarray(np.clip(arr, 0.0, 1.0))


def _resize_matrix(n_out: int, n_in: int) -> np.ndarray:
    """(n_out, n_in) linear-interpolation weights, pixel centres at +0.5."""
    x = (np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5
    x = np.clip(x, 0.0, n_in - 1)
    i0 = np.floor(x).astype(np.int64)
    i1 = np.minimum(i0 + 1, n_in - 1)
    t = x - i0
    m = np.zeros((n_out, n_in))
    np.add.at(m, (np.arange(n_out), i0), 1.0 - t)
    np.add.at(m, (np.arange(n_out), i1), t)
    return m


def resize_bilinear(images: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear resize with pixel centres at +0.5 (``align_corners=False``), no antialiasing.

    Parameters
    ----------
    images : (B, H, W, C) float32
    height, width : int
        Output size.

    Returns
    -------
    resized : (B, height, width, C) float32
        ``images`` itself when the size already matches.
    """
    B, H, W, C = images.shape
    if (H, W) == (height, width):
        return images
    my = _resize_matrix(height, H).astype(np.float32)
    mx = _resize_matrix(width, W).astype(np.float32)
    out = np.einsum("yh,bhwc->bywc", my, images, optimize=True)
    return np.einsum("xw,bywc->byxc", mx, out, optimize=True).astype(np.float32)


def cosine_similarity(a: np.ndarray, b: np.ndarray, *, eps: float = 1e-12) -> np.ndarray:
    """Cosine similarity along the last axis, clipped to [-1, 1].

    Parameters
    ----------
    a, b : (..., C) array
        Feature vectors. A zero vector has similarity 0 with anything.

    Returns
    -------
    sim : (...) float32
    """
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    num = np.einsum("...c,...c->...", a, b)
    den = np.sqrt(np.einsum("...c,...c->...", a, a) * np.einsum("...c,...c->...", b, b))
    return np.clip(num / np.maximum(den, eps), -1.0, 1.0).astype(np.float32)


class FeatureExtractor:
    """Base class of the extractors behind the distractor proposal.

    Subclasses set the attributes and implement :meth:`features`; :meth:`similarity`
    is the per-cell cosine of the two feature grids unless a subclass says otherwise.

    Attributes
    ----------
    name : str
        Registry name (``"local"``, ``"rgb"``, ``"dinov2"``, ``"dinov3"``).
    patch_size : int
        Input pixels per cell side (before the resize to a multiple of it, see the
        module docstring).
    tau1, tau2 : float
        Similarity boundaries of the two proposal ranges, ``tau1 < tau2``, calibrated
        for this extractor: range 1 is ``s < tau1``, range 2 is ``tau1 <= s < tau2``.
    pairs_in_threads : bool
        :meth:`similarity` may compute several image pairs at once, one per CPU core (for
        NumPy extractors, whose array operations release the GIL; each pair's result is the
        same as alone).
    """

    name: str = "base"
    patch_size: int = 16
    tau1: float = 0.5
    tau2: float = 0.7
    pairs_in_threads: bool = False

    def _set_thresholds(self, tau1: float | None, tau2: float | None) -> None:
        t1 = float(self.tau1 if tau1 is None else tau1)
        t2 = float(self.tau2 if tau2 is None else tau2)
        if not (-1.0 <= t1 < t2 <= 1.0):
            raise ClearsplatError(f"need -1 <= tau1 < tau2 <= 1, got tau1={t1}, tau2={t2}",
                                  field="tau1")
        self.tau1, self.tau2 = t1, t2

    def grid_shape(self, height: int, width: int) -> tuple[int, int]:
        """Feature grid ``(h, w)`` for an image of ``height x width`` pixels."""
        return grid_shape_for(height, width, self.patch_size)

    def features(self, images) -> np.ndarray:
        """Feature grid of a batch of images.

        Parameters
        ----------
        images : (B, H, W, 3) float32 in [0, 1]

        Returns
        -------
        features : (B, h, w, C) float32
            ``(h, w) = self.grid_shape(H, W)``.
        """
        raise NotImplementedError

    def similarity(self, a_images, b_images, *, workers: int | None = None) -> np.ndarray:
        """Per-cell similarity of two image batches of the same shape.

        Parameters
        ----------
        a_images, b_images : (B, H, W, 3) float32 in [0, 1]
        workers : int, optional
            Threads for the image pairs where :attr:`pairs_in_threads` allows them (default:
            the cores, at most ``OMP_NUM_THREADS``); the result does not depend on it.

        Returns
        -------
        sim : (B, h, w) float32 in [-1, 1]
            Cosine similarity of the two feature grids, 1 for identical images.
        """
        a, b = self._check_pair(a_images, b_images)

        def pair(k: int) -> np.ndarray:
            return cosine_similarity(*np.split(self.features(np.stack([a[k], b[k]])), 2))

        # One pair at a time (per thread): the descriptors' temporaries stay small enough to be
        # reused instead of faulting in fresh pages (3-5x faster next to a large scene in
        # memory).
        out = thread_map(pair, range(len(a)), workers=workers if self.pairs_in_threads else 1)
        return np.concatenate(out, axis=0)

    @staticmethod
    def _check_pair(a_images, b_images) -> tuple[np.ndarray, np.ndarray]:
        a = check_images(a_images, field="a_images")
        b = check_images(b_images, field="b_images")
        if a.shape != b.shape:
            raise ClearsplatError(f"the two image batches differ in shape: {a.shape} vs "
                                  f"{b.shape}", field="b_images")
        return a, b

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(name={self.name!r}, patch_size={self.patch_size}, "
                f"tau1={self.tau1}, tau2={self.tau2})")
