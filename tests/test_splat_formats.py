"""Exports for viewers: .splat, .spz and the plain 3DGS PLY; round trips and byte layouts."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest

from clearsplat.errors import ClearsplatError
from clearsplat.io import read_ply
from clearsplat.io.splat_formats import (SPLAT_RECORD, read_splat, read_spz, write_plain_ply,
                                         write_splat, write_spz)
from clearsplat.scene import SH_C0, Gaussians


def random_gaussians(n=400, k=16, seed=0, extent=3.0):
    rng = np.random.default_rng(seed)
    return Gaussians(means=rng.normal(size=(n, 3)) * extent,
                     scales=np.exp(rng.uniform(-6, 0.5, (n, 3))),
                     quats=rng.normal(size=(n, 4)), opacities=rng.uniform(0, 1, n),
                     sh=rng.uniform(-0.9, 0.9, (n, k, 3)))


def unit(q):
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def same_rotation(a, b):
    """|<a, b>| of unit quaternions: 1 for the same rotation (q and -q alike)."""
    return np.abs(np.sum(unit(a.astype(np.float64)) * unit(b.astype(np.float64)), axis=1))


# ------------------------------------------------------------------------------------------------
# .splat
# ------------------------------------------------------------------------------------------------
def test_splat_record_layout_by_hand(tmp_path):
    """One Gaussian, its 32 bytes computed from the layout description."""
    g = Gaussians(means=[[1.5, -2.0, 0.25]], scales=[[0.1, 0.2, 0.3]], quats=[[2.0, 0, 0, 0]],
                  opacities=[0.5], sh=[[[0.0, 1.0, -1.0]]])
    write_splat(tmp_path / "a.splat", g)
    data = (tmp_path / "a.splat").read_bytes()
    assert len(data) == 32
    assert struct.unpack("<3f", data[:12]) == (1.5, -2.0, 0.25)
    assert np.allclose(struct.unpack("<3f", data[12:24]), (0.1, 0.2, 0.3))
    rgb = [round(255 * (0.5 + SH_C0 * c)) for c in (0.0, 1.0, -1.0)]
    assert list(data[24:28]) == rgb + [128]            # 127.5 rounds to even
    assert list(data[28:32]) == [255, 128, 128, 128]    # w = 1 -> 256, clipped


def test_splat_round_trip(tmp_path):
    g = random_gaussians(k=1)
    write_splat(tmp_path / "a.splat", g, sort=False)
    h = read_splat(tmp_path / "a.splat")
    assert len(h) == len(g)
    assert np.array_equal(h.means, g.means) and np.array_equal(h.scales, g.scales)
    assert np.abs(h.opacities - g.opacities).max() <= 0.5 / 255 + 1e-6
    rgb = np.clip(0.5 + SH_C0 * g.sh[:, 0], 0, 1)
    assert np.abs((0.5 + SH_C0 * h.sh[:, 0]) - rgb).max() <= 0.5 / 255 + 1e-6
    assert same_rotation(h.quats, g.quats).min() > 0.999


def test_splat_sorted_largest_first(tmp_path):
    g = random_gaussians(k=1, seed=3)
    write_splat(tmp_path / "a.splat", g)
    rec = np.frombuffer((tmp_path / "a.splat").read_bytes(), SPLAT_RECORD)
    size = np.prod(g.scales.astype(np.float64), axis=1) * g.opacities
    expected = np.argsort(-size)
    assert np.all(np.diff(size[expected]) < 0)          # no ties in this draw
    assert np.array_equal(rec["position"], g.means[expected])


def test_splat_bad_size(tmp_path):
    (tmp_path / "bad.splat").write_bytes(b"\0" * 33)
    with pytest.raises(ClearsplatError, match="multiple of 32"):
        read_splat(tmp_path / "bad.splat")


# ------------------------------------------------------------------------------------------------
# .spz
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [1, 4, 9, 16, 25])
def test_spz_round_trip(tmp_path, k):
    g = random_gaussians(k=k, seed=k)
    write_spz(tmp_path / "a.spz", g)
    h = read_spz(tmp_path / "a.spz")
    assert len(h) == len(g) and h.sh.shape == g.sh.shape
    assert np.abs(h.means - g.means).max() <= 0.5 / 4096 + 1e-6           # 12 fractional bits
    log_err = np.abs(np.log(h.scales) - np.log(g.scales)).max()
    assert log_err <= 0.5 / 16 + 1e-5                                      # 1/16 steps in log
    assert np.abs(h.opacities - g.opacities).max() <= 0.5 / 255 + 1e-6
    assert np.abs(h.sh[:, 0] - g.sh[:, 0]).max() <= 0.5 / (0.15 * 255) + 1e-5
    # smallest three in 9 bits of magnitude: each component within 0.5 / 511 / sqrt(2)
    assert same_rotation(h.quats, g.quats).min() > 1 - 1e-5
    if k > 1:
        band1 = np.abs(h.sh[:, 1:4] - g.sh[:, 1:4]).max()
        rest = np.abs(h.sh[:, 4:] - g.sh[:, 4:]).max() if k > 4 else 0
        assert band1 <= 8 / 128 + 1e-6 and rest <= 16 / 128 + 1e-6   # 5 and 4 bits


def test_spz_bytes_by_hand(tmp_path):
    """One Gaussian, checked field by field against the format description."""
    g = Gaussians(means=[[1.0, 2.0, -0.5]], scales=[[np.exp(-2.0)] * 3],
                  quats=[[1.0, 0.0, 0.0, 0.0]], opacities=[1.0], sh=[[[0.0, 0.0, 0.0]]])
    write_spz(tmp_path / "a.spz", g)
    raw = gzip.decompress((tmp_path / "a.spz").read_bytes())
    magic, version, n, degree, bits, flags, reserved = struct.unpack_from("<IIIBBBB", raw)
    assert (magic, version, n, degree, bits, flags, reserved) == (0x5053474E, 3, 1, 0, 12, 0, 0)
    body = raw[16:]
    assert len(body) == 9 + 1 + 3 + 3 + 4
    fixed = [int.from_bytes(body[3 * i:3 * i + 3], "little", signed=True) for i in range(3)]
    assert fixed == [4096, -8192, 2048]            # RDF -> RUB: y and z negated
    assert body[9] == 255                          # alpha
    assert list(body[10:13]) == [128, 128, 128]    # 0.15 * 0 * 255 + 127.5 -> 128
    assert list(body[13:16]) == [128, 128, 128]    # (-2 + 10) * 16
    comp = int.from_bytes(body[16:20], "little")
    assert comp >> 30 == 3 and comp & ((1 << 30) - 1) == 0   # w largest, x = y = z = 0


def test_spz_far_positions_use_fewer_fractional_bits(tmp_path):
    g = random_gaussians(n=50, k=1, extent=1.0)
    g.means[0] = (5000.0, 0, 0)
    write_spz(tmp_path / "a.spz", g)
    raw = gzip.decompress((tmp_path / "a.spz").read_bytes())
    assert raw[13] < 12
    assert np.abs(read_spz(tmp_path / "a.spz").means - g.means).max() <= 0.5 / (1 << raw[13])


def test_spz_bad_files(tmp_path):
    (tmp_path / "a.spz").write_bytes(b"not gzip")
    with pytest.raises(ClearsplatError, match="gzip"):
        read_spz(tmp_path / "a.spz")
    (tmp_path / "b.spz").write_bytes(gzip.compress(struct.pack("<IIIBBBB", 1, 3, 0, 0, 12, 0, 0)))
    with pytest.raises(ClearsplatError, match="magic"):
        read_spz(tmp_path / "b.spz")
    (tmp_path / "c.spz").write_bytes(gzip.compress(struct.pack("<IIIBBBB", 0x5053474E, 3, 10,
                                                               0, 12, 0, 0)))
    with pytest.raises(ClearsplatError, match="truncated"):
        read_spz(tmp_path / "c.spz")


# ------------------------------------------------------------------------------------------------
# plain PLY
# ------------------------------------------------------------------------------------------------
def test_plain_ply_has_only_3dgs_properties(tmp_path):
    from clearsplat.io import write_ply
    g = random_gaussians(k=4)
    g.extra["confidence"] = np.linspace(0, 1, len(g)).astype(np.float32)
    write_ply(tmp_path / "ours.ply", g, view_id=np.zeros(len(g), int),
              pixel_id=np.arange(len(g)))
    ours, _, _ = read_ply(tmp_path / "ours.ply")
    write_plain_ply(tmp_path / "plain.ply", ours)
    header = (tmp_path / "plain.ply").read_bytes().split(b"end_header")[0].decode()
    props = [line.split()[-1] for line in header.splitlines() if line.startswith("property")]
    assert props == (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
                     + [f"f_rest_{i}" for i in range(9)]
                     + ["opacity", "scale_0", "scale_1", "scale_2",
                        "rot_0", "rot_1", "rot_2", "rot_3"])
    back, view_id, pixel_id = read_ply(tmp_path / "plain.ply")
    assert view_id is None and pixel_id is None
    for name in ("means", "scales", "quats", "opacities", "sh"):
        assert np.array_equal(getattr(back, name), getattr(ours, name)), name
