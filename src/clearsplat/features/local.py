"""A weight-free patch descriptor: colour, colour layout and gradient orientations.

It stands in for DINOv3 when no checkpoint is at hand. It should call "the same content,
rendered slightly differently" (blur, a 1-2 px shift, a few percent of brightness, noise)
similar and "different content" (an object present in one image only) dissimilar.

Per grid cell (``p x p`` pixels, ``p`` divisible by 4) the descriptor concatenates six
blocks, three computed on the cell and three on a context window of ``2p x 2p`` centred on
it (the cell plus a ring of ``p / 2``; the image is padded by reflection), so that a cell
sees a little around it, as a ViT patch token does:

``colour``
    Absolute mean colour of the cell (context: of the window) as a colour-kernel
    embedding: each channel value ``v`` becomes Gaussian bumps ``exp(-(v - c_k)^2 /
    (2 sigma^2))`` on centres ``c_k`` every ``sigma`` from ``-sigma`` to about
    ``1 + 2 sigma``, L2-normalised, and the block is the tensor product of the three
    channels' vectors (``K^3`` values). The dot product of two such embeddings
    approximates ``exp(-|u - v|^2 / (4 sigma^2))``, a Gaussian kernel on the RGB distance
    (a product over channels, so one channel that changes a lot is enough to tell two
    colours apart). This block never vanishes: flat, texture-less cells are compared by
    colour and do not fall to a spurious low similarity.
``layout``
    Mean colours of a 4 x 4 sub-grid (context: 4 x 4 blocks of ``p / 2``), mean-centred
    per channel over the cell and contrast-normalised softly, ``v / sqrt(|v|^2 +
    eps^2)``: a textured cell gives a unit vector independent of brightness and
    contrast, a flat cell a short one that weighs little in the cosine. (Mean-centring
    matters: the cosine of raw non-negative values is always high.)
``gradients``
    HOG-like histograms of 8 signed gradient orientations of the luminance (soft-binned,
    magnitude-weighted after subtracting a noise floor of 0.01) over 2 x 2 sub-cells of
    ``p / 2`` (context: 2 x 2 of ``p``), softly normalised as the layout.

Block weights are (colour, layout, gradients) = (1, 1, 1) on the cell and half that on
the context. After the final L2 normalisation, the cosine of two descriptors is a
weighted mean of the blocks' cosines (weights shrink for flat cells).
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from .base import FeatureExtractor, check_images, resize_bilinear

__all__ = ["LocalDescriptor"]

_N_ORIENT = 8
# Soft-normalisation knees: a layout whose sub-cell colours deviate from the cell mean
# by about _LAYOUT_EPS (RMS, in [0, 1] units) counts half; gradient histograms are
# compared per pixel of the region they cover.
_LAYOUT_EPS = 0.02
_GRAD_EPS = 0.004
_GRAD_FLOOR = 0.01


def _soft_normalise(v: np.ndarray, eps: float) -> np.ndarray:
    """``v / sqrt(|v|^2 + eps^2)`` over the last axis."""
    n2 = np.einsum("...c,...c->...", v, v)[..., None]
    return v / np.sqrt(n2 + np.float32(eps * eps))


def _block_mean(x: np.ndarray, q: int) -> np.ndarray:
    """Means of ``q x q`` blocks: (B, H, W, C) -> (B, H // q, W // q, C)."""
    return _block_sum(x, q) * np.float32(1.0 / (q * q))


def _block_sum(x: np.ndarray, q: int) -> np.ndarray:
    """Sums of ``q x q`` blocks: (B, H, W, C) -> (B, H // q, W // q, C)."""
    B, H, W, C = x.shape
    # Two reductions over axes with contiguous inner data are much faster than one
    # reduction over two strided axes.
    rows = x.reshape(B, H // q, q, W * C).sum(axis=2)
    return rows.reshape(B, H // q, W // q, q, C).sum(axis=3)


def _windows(x: np.ndarray, size: int, step: int, n_rows: int, n_cols: int) -> np.ndarray:
    """``size x size`` windows every ``step`` blocks: (B, R, S, C) -> (B, n, m, size, size, C)."""
    win = np.lib.stride_tricks.sliding_window_view(x, (size, size), axis=(1, 2))
    # sliding_window_view puts the window axes last: (B, R', S', C, size, size).
    win = win[:, : n_rows * step : step, : n_cols * step : step]
    return win.transpose(0, 1, 2, 4, 5, 3)


def _pool2(x: np.ndarray) -> np.ndarray:
    """Average 2 x 2 neighbours of the two window axes: (..., 2a, 2a, C) -> (..., a, a, C)."""
    *lead, s, _, C = x.shape
    return x.reshape(*lead, s // 2, 2, s // 2, 2, C).mean(axis=(-4, -2))


class LocalDescriptor(FeatureExtractor):
    """Weight-free per-patch descriptor (colour kernel + colour layout + HOG, with context).

    Parameters
    ----------
    patch_size : int, default 16
        Pixels per cell side; a multiple of 4, at least 8.
    colour_sigma : float, default 0.15
        Width of the colour kernel (in [0, 1] units): mean colours ``2 * colour_sigma``
        apart (RGB distance) have kernel value ``exp(-1) = 0.37``.
    context : bool, default True
        Include the context blocks.
    tau1, tau2 : float, optional
        Override the calibrated thresholds.

    Notes
    -----
    Default thresholds ``tau1 = 0.51``, ``tau2 = 0.69`` come from
    :func:`clearsplat.features.calibrate.calibrate_defaults` (numbers in that module's
    docstring).
    """

    name = "local"
    tau1 = 0.51
    tau2 = 0.69
    pairs_in_threads = True

    def __init__(self, *, patch_size: int = 16, colour_sigma: float = 0.15,
                 context: bool = True, tau1: float | None = None, tau2: float | None = None):
        patch_size = int(patch_size)
        if patch_size < 8 or patch_size % 4:
            raise ClearsplatError(f"patch_size must be a multiple of 4 and >= 8, got "
                                  f"{patch_size}", field="patch_size")
        if not 0.05 <= float(colour_sigma) <= 1.0:
            raise ClearsplatError(f"colour_sigma must be in [0.05, 1], got {colour_sigma}",
                                  field="colour_sigma")
        self.patch_size = patch_size
        self.colour_sigma = float(colour_sigma)
        # Bump centres every sigma from -sigma to 1 + sigma: the summed bumps are flat
        # enough over [0, 1] for the dot product to follow the kernel closely.
        n = int(np.ceil(1.0 / self.colour_sigma)) + 3
        self._centres = ((np.arange(n) - 1) * self.colour_sigma).astype(np.float32)
        self.context = bool(context)
        self._set_thresholds(tau1, tau2)

    # -- blocks ------------------------------------------------------------------------
    def _colour(self, means: np.ndarray) -> np.ndarray:
        """Colour-kernel embedding of (..., 3) colours -> (..., K ** 3), unit norm.

        The tensor product of the three channels' unit-norm bump vectors: the dot
        product of two embeddings is the product of the channels' kernels, i.e. a
        Gaussian kernel on the RGB distance.
        """
        d = means[..., None] - self._centres
        e = np.exp(d * d * np.float32(-0.5 / self.colour_sigma ** 2))
        e /= np.sqrt(np.einsum("...k,...k->...", e, e))[..., None]
        r, g, b = e[..., 0, :], e[..., 1, :], e[..., 2, :]
        joint = r[..., :, None, None] * g[..., None, :, None] * b[..., None, None, :]
        return joint.reshape(*means.shape[:-1], -1)

    @staticmethod
    def _layout(means: np.ndarray) -> np.ndarray:
        """Mean-centred, softly normalised (..., n, n, 3) means -> (..., n * n * 3)."""
        n_values = means.shape[-3] * means.shape[-2] * 3
        v = means - means.mean(axis=(-3, -2), keepdims=True)
        v = v.reshape(*means.shape[:-3], -1)
        return _soft_normalise(v, _LAYOUT_EPS * np.sqrt(n_values))

    @staticmethod
    def _orientation_maps(lum: np.ndarray) -> np.ndarray:
        """Soft-binned, magnitude-weighted signed orientations: (B, H, W) -> (B, H-2, W-2, 8)."""
        gx = 0.5 * (lum[:, 1:-1, 2:] - lum[:, 1:-1, :-2])
        gy = 0.5 * (lum[:, 2:, 1:-1] - lum[:, :-2, 1:-1])
        mag = np.maximum(np.sqrt(gx * gx + gy * gy) - np.float32(_GRAD_FLOOR), 0.0)
        pos = (np.arctan2(gy, gx) * np.float32(_N_ORIENT / (2 * np.pi))) % _N_ORIENT
        i0 = np.floor(pos).astype(np.int64)
        t = (pos - i0).astype(np.float32)
        i0 %= _N_ORIENT
        i1 = (i0 + 1) % _N_ORIENT
        out = np.zeros(lum.shape[:1] + gx.shape[1:] + (_N_ORIENT,), dtype=np.float32)
        flat = out.reshape(-1)
        base = np.arange(i0.size, dtype=np.int64) * _N_ORIENT
        # i1 != i0 always (8 bins), so the second scatter does not overwrite the first.
        flat[base + i0.ravel()] = (mag * (1.0 - t)).ravel()
        flat[base + i1.ravel()] = (mag * t).ravel()
        return out

    @staticmethod
    def _gradients(hist_sums: np.ndarray, n_pixels: int) -> np.ndarray:
        """Softly normalised (..., n, n, 8) histogram sums -> (..., n * n * 8)."""
        v = hist_sums.reshape(*hist_sums.shape[:-3], -1) / np.float32(n_pixels)
        # Normalise per pixel so the knee does not depend on the patch size.
        return _soft_normalise(v, _GRAD_EPS)

    # -- public ------------------------------------------------------------------------
    def features(self, images) -> np.ndarray:
        """Descriptor grid of a batch of images.

        Parameters
        ----------
        images : (B, H, W, 3) float32 in [0, 1]

        Returns
        -------
        features : (B, h, w, C) float32
            Unit-norm descriptors, ``(h, w) = self.grid_shape(H, W)``;
            ``C = 2 * (K ** 3 + 80)`` with ``K = ceil(1 / colour_sigma) + 3``
            bump centres (2160 for the defaults; half without context).
        """
        x = check_images(images)
        B, H, W, _ = x.shape
        h, w = self.grid_shape(H, W)
        p = self.patch_size
        q, r = p // 4, p // 2
        x = resize_bilinear(x, h * p, w * p)
        # Pad by half a patch (plus one pixel for the central differences) so that the
        # context window of every cell lies inside the padded image.
        xp = np.pad(x, ((0, 0), (r + 1, r + 1), (r + 1, r + 1), (0, 0)), mode="symmetric")
        core = xp[:, 1:-1, 1:-1]                       # padded by r: (B, hp + p, wp + p, 3)

        sub = _block_mean(core, q)                     # (B, 4h + 4, 4w + 4, 3)
        cell_sub = _windows(sub[:, 2:-2, 2:-2], 4, 4, h, w)     # (B, h, w, 4, 4, 3)

        lum = xp @ np.asarray([0.299, 0.587, 0.114], dtype=np.float32)
        orient = self._orientation_maps(lum)           # (B, hp + p, wp + p, 8)
        half = _block_sum(orient, r)                   # (B, 2h + 2, 2w + 2, 8)
        cell_hist = _windows(half[:, 1:-1, 1:-1], 2, 2, h, w)  # (B, h, w, 2, 2, 8)

        blocks = [
            self._colour(cell_sub.mean(axis=(-3, -2))),
            self._layout(cell_sub),
            self._gradients(cell_hist, r * r),
        ]
        if self.context:
            ctx_sub = _pool2(_windows(sub, 8, 4, h, w))      # (B, h, w, 4, 4, 3), p/2 blocks
            ctx_hist = _windows(half, 4, 2, h, w)            # (B, h, w, 4, 4, 8)
            ctx_hist = 4.0 * _pool2(ctx_hist)                # sums over p x p sub-cells
            half_w = np.float32(0.5)
            blocks += [
                half_w * self._colour(ctx_sub.mean(axis=(-3, -2))),
                half_w * self._layout(ctx_sub),
                half_w * self._gradients(ctx_hist, p * p),
            ]
        f = np.concatenate(blocks, axis=-1)
        f /= np.sqrt(np.einsum("...c,...c->...", f, f))[..., None]
        return np.ascontiguousarray(f, dtype=np.float32)
