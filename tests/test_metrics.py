"""PSNR, SSIM, LPIPS availability and filter accuracy."""

import math

import numpy as np
import pytest

from clearsplat import ClearsplatError
from clearsplat.metrics import (LpipsUnavailable, lpips, lpips_available, psnr, removal_stats,
                                ssim)

skimage_metrics = pytest.importorskip("skimage.metrics")


def _pair(seed, shape=(40, 56, 3), noise=0.1):
    rng = np.random.default_rng(seed)
    a = rng.uniform(size=shape)
    b = np.clip(a + rng.normal(scale=noise, size=shape), 0, 1)
    return a, b


# -- PSNR --------------------------------------------------------------------------------------

@pytest.mark.parametrize("c", [0.5, 0.1, 0.01])
def test_psnr_constant_error_closed_form(c):
    a = np.zeros((8, 9, 3), dtype=np.float32)
    assert psnr(a, a + np.float32(c)) == pytest.approx(-20 * math.log10(c), rel=1e-6)


def test_psnr_random_against_formula():
    a, b = _pair(0)
    mse = np.mean((a - b) ** 2)
    assert psnr(a, b) == pytest.approx(10 * math.log10(1 / mse), rel=1e-12)
    assert psnr(a * 255, b * 255, data_range=255) == pytest.approx(psnr(a, b), rel=1e-12)
    assert psnr(a[..., 0], b[..., 0]) == pytest.approx(
        10 * math.log10(1 / np.mean((a[..., 0] - b[..., 0]) ** 2)), rel=1e-12)


def test_psnr_identical_is_infinite():
    a, _ = _pair(1)
    assert psnr(a, a) == math.inf


def test_psnr_bad_shapes():
    with pytest.raises(ClearsplatError, match="shape"):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ClearsplatError, match="shape"):
        psnr(np.zeros((4, 4, 3, 2)), np.zeros((4, 4, 3, 2)))


# -- SSIM --------------------------------------------------------------------------------------

def _skimage_ssim(a, b, **kw):
    return skimage_metrics.structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0,
        **kw)


@pytest.mark.parametrize("seed, noise", [(0, 0.02), (1, 0.1), (2, 0.4)])
def test_ssim_matches_skimage_rgb(seed, noise):
    a, b = _pair(seed, noise=noise)
    assert ssim(a, b) == pytest.approx(_skimage_ssim(a, b, channel_axis=-1), abs=1e-12)


def test_ssim_matches_skimage_on_smooth_images_and_gray():
    y, x = np.mgrid[0:48, 0:64] / 10.0
    a = 0.5 + 0.4 * np.sin(x) * np.cos(y)
    b = 0.5 + 0.35 * np.sin(x + 0.2) * np.cos(y)
    assert ssim(a, b) == pytest.approx(_skimage_ssim(a, b), abs=1e-12)
    # float32 inputs: computed in float64 here, scikit-image computes in float32
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    assert ssim(a32, b32) == pytest.approx(
        _skimage_ssim(a32.astype(np.float64), b32.astype(np.float64)), abs=1e-12)
    assert ssim(a32, b32) == pytest.approx(_skimage_ssim(a32, b32), abs=1e-5)


def test_ssim_identity_and_constant_images():
    a, _ = _pair(3)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    # two constant images: (2 m1 m2 + C1) / (m1^2 + m2^2 + C1), the structure term is 1
    m1, m2, c1 = 0.2, 0.6, 0.01 ** 2
    const = ssim(np.full((16, 16), m1), np.full((16, 16), m2))
    assert const == pytest.approx((2 * m1 * m2 + c1) / (m1 ** 2 + m2 ** 2 + c1), rel=1e-9)


def test_ssim_needs_the_window():
    with pytest.raises(ClearsplatError, match="11x11"):
        ssim(np.zeros((10, 30, 3)), np.zeros((10, 30, 3)))


# -- LPIPS -------------------------------------------------------------------------------------

def test_lpips_is_unavailable_or_real():
    a, b = _pair(4, shape=(32, 32, 3))
    if lpips_available():
        assert lpips(a, a) == pytest.approx(0.0, abs=1e-6)
        assert lpips(a, b) > 0.0
    else:
        with pytest.raises(LpipsUnavailable, match="unavailable"):
            lpips(a, b)
        assert issubclass(LpipsUnavailable, ClearsplatError)


# -- filter accuracy ---------------------------------------------------------------------------

def test_removal_stats_hand_counts():
    truth = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=bool)
    removed = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], dtype=bool)
    s = removal_stats(removed, truth)
    assert s["n"] == 10 and s["n_distractor"] == 4 and s["n_static"] == 6
    assert s["n_removed"] == 4 and s["n_removed_distractor"] == 3
    assert s["n_removed_static"] == 1 and s["n_missed"] == 1
    assert s["recall"] == pytest.approx(3 / 4)
    assert s["precision"] == pytest.approx(3 / 4)
    assert s["static_removed"] == pytest.approx(1 / 6)
    assert s["removed_share"] == pytest.approx(4 / 10)


def test_removal_stats_random_against_loops():
    rng = np.random.default_rng(7)
    truth = rng.uniform(size=500) < 0.2
    removed = rng.uniform(size=500) < 0.3
    tp = sum(1 for r, t in zip(removed, truth) if r and t)
    fp = sum(1 for r, t in zip(removed, truth) if r and not t)
    s = removal_stats(removed, truth)
    assert s["recall"] == tp / sum(truth)
    assert s["static_removed"] == fp / (500 - sum(truth))
    assert s["precision"] == tp / (tp + fp)


def test_removal_stats_empty_cases():
    s = removal_stats(np.zeros(3, dtype=bool), np.zeros(3, dtype=bool))
    assert math.isnan(s["recall"]) and math.isnan(s["precision"])
    assert s["static_removed"] == 0.0 and s["removed_share"] == 0.0
    s = removal_stats(np.ones(2, dtype=bool), np.ones(2, dtype=bool))
    assert s["recall"] == 1.0 and math.isnan(s["static_removed"])


def test_removal_stats_bad_input():
    with pytest.raises(ClearsplatError) as err:
        removal_stats(np.zeros(3, dtype=bool), np.zeros(4, dtype=bool))
    assert err.value.field == "removed"
    with pytest.raises(ClearsplatError) as err:
        removal_stats(np.zeros(3), np.zeros(3, dtype=bool))
    assert err.value.field == "removed"
    with pytest.raises(ClearsplatError) as err:
        removal_stats(np.zeros(3, dtype=bool), np.zeros((3, 1), dtype=bool))
    assert err.value.field == "truth"
