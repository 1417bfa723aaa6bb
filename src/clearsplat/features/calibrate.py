"""Calibrating ``tau1`` / ``tau2`` for extractors whose similarity is not DINOv3's.

The paper's boundaries (``tau1 = 0.50``, ``tau2 = 0.70``) are for the cosine of DINOv3
features. For another extractor we pick them from its own similarity distributions on
"same content, re-rendered" cells and "different content" cells:

- ``tau1`` (strict level) lies halfway between the 1st percentile of the same-content
  similarities and the median of the different-content ones;
- ``tau2`` (loose level) lies halfway between the 5th percentile of the same-content
  similarities and the 95th percentile of the different-content ones.

The mild re-rendering perturbations below leave a wide gap between the two populations;
putting the boundaries in the middle of it, rather than at a quantile of the same-content
side alone, leaves room for the larger errors of a real feed-forward rendering.

Default pairs (:func:`make_calibration_pairs`): 256 x 448 crops of six scikit-image
sample images (astronaut, chelsea, coffee, rocket, stereo_motorcycle left,
immunohistochemistry), 4 same and 4 different pairs per image, seed 0. The first image
``a`` is the crop plus Gaussian noise (sigma 0.01); the second ``b``, the "rendering", is
the crop shifted by (dy, dx) in {-1, 0, 1}^2 (not both 0), blurred with a Gaussian of
sigma in U(0.5, 1.0) and scaled in brightness by U(0.95, 1.05). A different pair pastes
into ``a`` a rectangle (side U(48, 128) px) cut from another of the images; the cells
entirely inside it are the different cells.

Results with seed 0 (``calibrate_defaults``, re-derived by ``tests/test_features.py``;
10 752 same cells, 527 different cells; Q = quantile):

=========  =====  =====  ===================  ===================  ===========  ===========
extractor  tau1   tau2   same Q .01 / Q .05   diff Q .50 / Q .95   diff < tau1  diff < tau2
=========  =====  =====  ===================  ===================  ===========  ===========
local      0.51   0.69   0.874 / 0.914        0.153 / 0.473        96.6 %       99.8 %
rgb        0.63   0.80   0.791 / 0.849        0.461 / 0.742        75.3 %       98.3 %
=========  =====  =====  ===================  ===================  ===========  ===========

No same cell falls below either boundary for ``local``; 1.3 % fall below ``tau2`` for
``rgb``. On a harsher check (blur sigma 1.5, 2 px shift, +8 % brightness against an 80 px
patch of the same image pasted elsewhere, 24 pairs) the area under the ROC curve is 0.96
for ``local`` and 0.88 for ``rgb``; the 1st percentile of same-content similarity is then
0.67 for both, above either ``tau1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ClearsplatError
from .base import FeatureExtractor, cell_average, check_images

__all__ = [
    "ThresholdCalibration",
    "calibrate_defaults",
    "calibrate_thresholds",
    "make_calibration_pairs",
    "perturb_rendering",
]

SAMPLE_IMAGES = ("astronaut", "chelsea", "coffee", "rocket", "stereo_motorcycle",
                 "immunohistochemistry")


@dataclass(frozen=True)
class ThresholdCalibration:
    """Result of :func:`calibrate_thresholds`.

    Attributes
    ----------
    tau1, tau2 : float
        The boundaries (two decimals).
    same_below_tau1, same_below_tau2 : float
        Fraction of same-content cells below each boundary.
    different_below_tau1, different_below_tau2 : float
        Fraction of different-content cells below each boundary.
    n_same, n_different : int
        Number of cells of each kind.
    same_quantiles, different_quantiles : dict
        Similarity quantiles (keys 0.01, 0.05, 0.5, 0.95) of each kind.
    """

    tau1: float
    tau2: float
    same_below_tau1: float
    same_below_tau2: float
    different_below_tau1: float
    different_below_tau2: float
    n_same: int
    n_different: int
    same_quantiles: dict
    different_quantiles: dict


def calibrate_thresholds(extractor: FeatureExtractor, pairs_same, pairs_different, *,
                         same_quantile1: float = 0.01, different_quantile1: float = 0.5,
                         same_quantile2: float = 0.05, different_quantile2: float = 0.95
                         ) -> ThresholdCalibration:
    """Choose ``tau1 < tau2`` for an extractor from labelled image pairs.

    Each boundary lies halfway between a low quantile of the same-content similarities
    and a quantile of the different-content similarities:
    ``tau_k = (Q_same(same_quantile_k) + Q_diff(different_quantile_k)) / 2``, rounded to
    two decimals (``tau2`` is raised to ``tau1 + 0.01`` if needed).

    Parameters
    ----------
    extractor : FeatureExtractor
    pairs_same : iterable of (a, b)
        ``(H, W, 3)`` float32 images showing the same content; every cell counts.
    pairs_different : iterable of (a, b, mask)
        ``mask`` ``(H, W)`` bool marks pixels of ``a`` whose content ``b`` lacks; cells
        entirely inside it count as different (cells partly inside are ignored).
    same_quantile1, different_quantile1 : float
        Quantiles in (0, 1) that place ``tau1`` (strict level).
    same_quantile2, different_quantile2 : float
        Quantiles in (0, 1) that place ``tau2`` (loose level).

    Returns
    -------
    ThresholdCalibration
    """
    qs_given = (same_quantile1, different_quantile1, same_quantile2, different_quantile2)
    if not all(0.0 < float(q) < 1.0 for q in qs_given):
        raise ClearsplatError(f"quantiles must lie in (0, 1), got {qs_given}",
                              field="same_quantile1")
    same = [extractor.similarity(check_images(a[None]), check_images(b[None]))[0].ravel()
            for a, b in pairs_same]
    diff = []
    for a, b, mask in pairs_different:
        s = extractor.similarity(check_images(a[None]), check_images(b[None]))[0]
        cover, _ = cell_average(np.asarray(mask, dtype=np.float32), s.shape)
        diff.append(s[cover >= 1.0])
    if not same or not diff:
        raise ClearsplatError("need at least one same and one different pair",
                              field="pairs_same")
    same_s = np.concatenate(same).astype(np.float64)
    diff_s = np.concatenate(diff).astype(np.float64)
    if diff_s.size == 0:
        raise ClearsplatError("no cell lies entirely inside a mask", field="pairs_different")

    def boundary(q_same, q_diff):
        mid = 0.5 * (np.quantile(same_s, q_same) + np.quantile(diff_s, q_diff))
        return round(float(mid), 2)

    tau1 = boundary(same_quantile1, different_quantile1)
    tau2 = max(boundary(same_quantile2, different_quantile2), round(tau1 + 0.01, 2))
    qs = (0.01, 0.05, 0.5, 0.95)
    return ThresholdCalibration(
        tau1=tau1, tau2=tau2,
        same_below_tau1=float(np.mean(same_s < tau1)),
        same_below_tau2=float(np.mean(same_s < tau2)),
        different_below_tau1=float(np.mean(diff_s < tau1)),
        different_below_tau2=float(np.mean(diff_s < tau2)),
        n_same=int(same_s.size), n_different=int(diff_s.size),
        same_quantiles={q: float(np.quantile(same_s, q)) for q in qs},
        different_quantiles={q: float(np.quantile(diff_s, q)) for q in qs},
    )


def _gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter
    return gaussian_filter(image, sigma=(sigma, sigma, 0), mode="nearest").astype(np.float32)


def perturb_rendering(source: np.ndarray, y0: int, x0: int, height: int, width: int,
                      rng: np.random.Generator) -> np.ndarray:
    """A "re-rendering" of ``source[y0:y0+height, x0:x0+width]``.

    Shifted by one pixel in a random direction, blurred (sigma U(0.5, 1)) and scaled in
    brightness (U(0.95, 1.05)). ``source`` must extend one pixel beyond the crop.

    Returns
    -------
    (height, width, 3) float32 in [0, 1]
    """
    shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    dy, dx = shifts[rng.integers(len(shifts))]
    crop = source[y0 + dy: y0 + dy + height, x0 + dx: x0 + dx + width]
    out = _gaussian_blur(crop, float(rng.uniform(0.5, 1.0))) * rng.uniform(0.95, 1.05)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _sample_images() -> list[np.ndarray]:
    try:
        from skimage import data
    except ImportError as exc:  # pragma: no cover - exercised only without scikit-image
        raise ImportError("calibration pairs need scikit-image: pip install "
                          "\"clearsplat[bench]\"") from exc
    out = []
    for name in SAMPLE_IMAGES:
        img = getattr(data, name)()
        if isinstance(img, tuple):          # stereo_motorcycle: (left, right, disparity)
            img = img[0]
        out.append(np.asarray(img[..., :3], dtype=np.float32) / 255.0)
    return out


def make_calibration_pairs(*, size: tuple[int, int] = (256, 448), pairs_per_image: int = 4,
                           seed: int = 0):
    """Same-content and different-content pairs from scikit-image's sample images.

    See the module docstring for the recipe.

    Returns
    -------
    pairs_same : list of (a, b)
    pairs_different : list of (a, b, mask)
    """
    H, W = size
    rng = np.random.default_rng(seed)
    images = _sample_images()
    same, different = [], []
    for k, src in enumerate(images):
        if src.shape[0] < H + 2 or src.shape[1] < W + 2:
            raise ClearsplatError(f"sample image {SAMPLE_IMAGES[k]} is smaller than "
                                  f"{H + 2}x{W + 2}", field="size")
        for j in range(2 * pairs_per_image):
            y0 = int(rng.integers(1, src.shape[0] - H))
            x0 = int(rng.integers(1, src.shape[1] - W))
            a = src[y0:y0 + H, x0:x0 + W].copy()
            b = perturb_rendering(src, y0, x0, H, W, rng)
            if j >= pairs_per_image:
                other = images[(k + 1 + int(rng.integers(len(images) - 1))) % len(images)]
                ph, pw = (int(v) for v in rng.integers(48, 129, size=2))
                py, px = int(rng.integers(0, H - ph)), int(rng.integers(0, W - pw))
                oy = int(rng.integers(0, other.shape[0] - ph))
                ox = int(rng.integers(0, other.shape[1] - pw))
                a[py:py + ph, px:px + pw] = other[oy:oy + ph, ox:ox + pw]
                mask = np.zeros((H, W), dtype=bool)
                mask[py:py + ph, px:px + pw] = True
            a = np.clip(a + rng.normal(0.0, 0.01, a.shape), 0.0, 1.0).astype(np.float32)
            if j >= pairs_per_image:
                different.append((a, b, mask))
            else:
                same.append((a, b))
    return same, different


def calibrate_defaults(extractor: FeatureExtractor, *, seed: int = 0
                       ) -> ThresholdCalibration:
    """:func:`calibrate_thresholds` with its defaults on :func:`make_calibration_pairs`."""
    same, different = make_calibration_pairs(seed=seed)
    return calibrate_thresholds(extractor, same, different)
