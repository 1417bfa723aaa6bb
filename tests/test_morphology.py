"""The filter's SciPy-free morphology equals SciPy's on seeded random masks."""

import numpy as np
import pytest
from scipy import ndimage

from clearsplat.filter.masks import dilate, dilate8, label8, touched_components
from clearsplat.filter.proposal import connected_regions


@pytest.mark.parametrize("seed", range(40))
def test_label8_matches_scipy(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 40, size=2) if seed < 30 else rng.integers(100, 300, size=2)
    mask = rng.random((h, w)) < rng.uniform(0.05, 0.7)
    if seed % 3 == 0:       # blobs and long snakes rather than noise
        from scipy.ndimage import uniform_filter
        mask = uniform_filter(rng.random((h, w)), size=5) > rng.uniform(0.45, 0.55)
    want, n_want = ndimage.label(mask, structure=np.ones((3, 3), bool))
    got, n_got = label8(mask)
    assert n_got == n_want
    assert np.array_equal(got, want)


def test_label8_empty_and_full():
    labels, n = label8(np.zeros((3, 4), bool))
    assert n == 0 and not labels.any()
    labels, n = label8(np.ones((3, 4), bool))
    assert n == 1 and (labels == 1).all()


def test_connected_regions_diagonal_touch_is_one_region():
    r = np.zeros((4, 4), np.int8)
    r[0, 0] = r[1, 1] = 2
    r[3, 3] = 2
    regions = connected_regions(r, 2)
    assert len(regions) == 2
    assert regions[0].sum() == 2 and regions[1][3, 3]


@pytest.mark.parametrize("seed", range(20))
def test_dilate_matches_scipy(seed):
    rng = np.random.default_rng(100 + seed)
    h, w = rng.integers(1, 60, size=2)
    mask = rng.random((h, w)) < rng.uniform(0.0, 0.05)
    r = int(rng.integers(0, 12))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disk = (yy * yy + xx * xx) <= r * r
    want = ndimage.binary_dilation(mask, structure=disk) if r > 0 else mask
    assert np.array_equal(dilate(mask, r), want)


@pytest.mark.parametrize("seed", range(20))
def test_dilate8_matches_scipy(seed):
    rng = np.random.default_rng(200 + seed)
    h, w = rng.integers(1, 50, size=2)
    mask = rng.random((h, w)) < rng.uniform(0.0, 0.6)
    want = ndimage.binary_dilation(mask, structure=np.ones((3, 3), bool))
    assert np.array_equal(dilate8(mask), want)


def test_dilate8_closed_form():
    mask = np.zeros((4, 5), bool)
    mask[0, 0] = True       # a corner pixel reaches its three neighbours, nothing outside
    want = np.zeros((4, 5), bool)
    want[:2, :2] = True
    assert np.array_equal(dilate8(mask), want)
    assert not dilate8(np.zeros((3, 3), bool)).any()


def test_label8_long_chains_match_scipy():
    """A serpentine (one component joined row pair by row pair), a comb whose teeth join only
    at the bottom, and diagonal staircases (corner contacts only)."""
    snake = np.zeros((41, 30), bool)
    snake[::4] = True
    snake[1::8, -1] = snake[2::8, -1] = snake[3::8, -1] = True
    snake[5::8, 0] = snake[6::8, 0] = snake[7::8, 0] = True
    comb = np.zeros((25, 31), bool)
    comb[:, ::2] = True
    comb[-1] = True
    stairs = np.eye(30, dtype=bool) | np.eye(30, k=5, dtype=bool) | np.eye(30, k=-9, dtype=bool)
    for mask in (snake, comb, stairs, stairs[::-1], ~stairs):
        want, n_want = ndimage.label(mask, structure=np.ones((3, 3), bool))
        got, n_got = label8(mask)
        assert n_got == n_want
        assert np.array_equal(got, want)
    assert label8(snake)[1] == 1 and label8(comb)[1] == 1


@pytest.mark.parametrize("seed", range(10))
def test_touched_components_is_the_union_of_the_components_touched(seed):
    rng = np.random.default_rng(seed)
    mask = rng.uniform(size=(30, 41)) < 0.45
    labels, count = label8(mask)
    where = rng.uniform(size=mask.shape) < 0.01
    expected = np.zeros(mask.shape, bool)
    for k in range(1, count + 1):
        if (where & (labels == k)).any():
            expected |= labels == k
    np.testing.assert_array_equal(touched_components(labels, where), expected)
    assert not touched_components(labels, np.zeros_like(where)).any()
