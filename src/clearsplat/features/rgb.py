"""Per-patch RGB difference: the paper's ablation in place of DINOv3 similarity.

The similarity of a cell is ``s = 1 - 2 * d``, where ``d`` is the mean absolute colour
difference over the cell's pixels and channels (``d`` in [0, 1], so ``s`` in [-1, 1]:
identical patches give 1, black against white gives -1). The thresholds are calibrated
on the scale of ``s`` (see :mod:`clearsplat.features.calibrate`).
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from .base import FeatureExtractor, check_images, resize_bilinear

__all__ = ["RGBDifference"]


class RGBDifference(FeatureExtractor):
    """Per-patch mean absolute RGB difference, mapped to ``1 - 2 * d``.

    Parameters
    ----------
    patch_size : int, default 16
        Pixels per cell side.
    tau1, tau2 : float, optional
        Override the calibrated thresholds.

    Notes
    -----
    Default thresholds ``tau1 = 0.63``, ``tau2 = 0.80`` come from
    :func:`clearsplat.features.calibrate.calibrate_defaults` (numbers in that module's
    docstring): ``s < 0.63`` means a mean colour difference above 0.185 (47 levels of
    255), ``s < 0.80`` above 0.10.
    """

    name = "rgb"
    tau1 = 0.63
    tau2 = 0.80

    def __init__(self, *, patch_size: int = 16, tau1: float | None = None,
                 tau2: float | None = None):
        self.patch_size = int(patch_size)
        if self.patch_size < 1:
            raise ClearsplatError(f"patch_size must be >= 1, got {patch_size}",
                                  field="patch_size")
        self._set_thresholds(tau1, tau2)

    def features(self, images) -> np.ndarray:
        """The cell's pixels, flattened.

        Parameters
        ----------
        images : (B, H, W, 3) float32 in [0, 1]

        Returns
        -------
        features : (B, h, w, p * p * 3) float32
            Pixels of the image resized to ``(h * p, w * p)``, row-major within the cell.
        """
        x = check_images(images)
        B, H, W, _ = x.shape
        h, w = self.grid_shape(H, W)
        p = self.patch_size
        x = resize_bilinear(x, h * p, w * p)
        x = x.reshape(B, h, p, w, p, 3).transpose(0, 1, 3, 2, 4, 5)
        return np.ascontiguousarray(x.reshape(B, h, w, p * p * 3))

    def similarity(self, a_images, b_images, *, workers: int | None = None) -> np.ndarray:
        """``1 - 2 * mean |a - b|`` per cell.

        Parameters
        ----------
        a_images, b_images : (B, H, W, 3) float32 in [0, 1]
        workers : int, optional
            Ignored: one vectorised pass over the whole batch.

        Returns
        -------
        sim : (B, h, w) float32 in [-1, 1]
        """
        a, b = self._check_pair(a_images, b_images)
        fa, fb = self.features(a), self.features(b)
        d = np.mean(np.abs(fa - fb), axis=-1)
        return np.clip(1.0 - 2.0 * d, -1.0, 1.0).astype(np.float32)
