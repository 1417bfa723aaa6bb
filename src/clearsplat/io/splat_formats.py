"""Gaussians in the files that splat viewers read: ``.splat``, ``.spz`` and a plain 3DGS PLY.

``.splat`` (the web viewers' layout, no header, 32 bytes per Gaussian, little-endian)::

    position  float32 x 3     x, y, z
    scale     float32 x 3     linear standard deviations (exp of the PLY's log scales)
    colour    uint8 x 4       R, G, B = 255 (0.5 + SH_C0 f_dc), A = 255 opacity
    rotation  uint8 x 4       w, x, y, z of the unit quaternion, 128 + 128 q (clipped)

Only the DC colour survives; the Gaussians are written largest first (``exp(sum log
scale) * opacity``, descending), the order in which the web viewers expect them.

``.spz`` (Niantic's compressed format, version 3, as its reference implementation writes it):
a gzip stream of a 16-byte header (magic ``0x5053474e``, version 3, count, SH degree,
fractional bits, flags, reserved) and then, attribute by attribute, positions (24-bit signed
fixed point with ``fractional bits``, at most 12), alphas (``255 opacity``), colours
(``255 (0.15 f_dc + 0.5)``), scales (``16 (log scale + 10)``), rotations (the smallest three of
the unit quaternion ``x y z w`` in 10 bits each, 2 bits for the index of the largest), and the
higher SH bands (coefficient-major, channel inner; ``128 + 128 c`` rounded to 5 bits for band
1, 4 bits above). The format stores RUB axes; like the reference ``ply_to_spz`` tool we take
the PLY's axes as RDF and flip ``y`` and ``z`` (positions, rotations and SH signs) on the way
in, and back on the way out. Version 4 (zstd streams) is not read.

A plain 3DGS PLY (:func:`write_plain_ply`) has exactly the original code's properties: ``x y z
nx ny nz f_dc_* f_rest_* opacity scale_* rot_*``, nothing of clearsplat's (``view_id``,
``pixel_id``, other extras).
"""

from __future__ import annotations

import gzip
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError
from ..scene import SH_C0, Gaussians
from .ply import RAW_PREFIX, atomic_write_bytes, write_ply

__all__ = ["write_splat", "read_splat", "write_spz", "read_spz", "write_plain_ply",
           "SPLAT_RECORD"]

#: One ``.splat`` record.
SPLAT_RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4),
                         ("rot", "u1", 4)])
_SPZ_MAGIC = 0x5053474E
_SPZ_HEADER = struct.Struct("<IIIBBBB")
_SPZ_COLOR_SCALE = 0.15
_SQRT1_2 = np.float32(0.7071067811865476)
# RDF -> RUB (x, -y, -z): sign of each SH coefficient of bands 1..3 (the reference's table
# with x = 1, y = z = -1), positions and quaternion x, y, z.
_SPZ_FLIP_P = np.array([1.0, -1.0, -1.0], np.float32)
_SPZ_FLIP_SH = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1,
                         -1, 1, -1, 1, 1, -1, 1, -1, -1], np.float32)


def _u8(x) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def _unit_quats(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# ------------------------------------------------------------------------------------------------
# .splat
# ------------------------------------------------------------------------------------------------
def write_splat(path, gaussians: Gaussians, *, sort: bool = True) -> None:
    """Write Gaussians as a ``.splat`` file (32 bytes each, see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        Written atomically.
    gaussians : Gaussians
        Validated first; only the DC colour is kept.
    sort : bool, default True
        Largest and most opaque first, as the web viewers expect; False keeps the order.
    """
    g = gaussians
    g.validate(path=path)
    order = np.arange(len(g))
    if sort and len(g):
        size = np.exp(np.log(g.scales.astype(np.float64)).sum(axis=1)) * g.opacities
        order = np.argsort(-size, kind="stable")
    rec = np.zeros(len(g), SPLAT_RECORD)
    rec["position"] = g.means[order]
    rec["scale"] = g.scales[order]
    rgb = 0.5 + SH_C0 * g.sh[order, 0].astype(np.float64)
    rec["rgba"][:, :3] = _u8(np.clip(rgb, 0, 1) * 255)
    rec["rgba"][:, 3] = _u8(g.opacities[order].astype(np.float64) * 255)
    rec["rot"] = _u8(_unit_quats(g.quats[order]) * 128 + 128)
    atomic_write_bytes(path, rec.tobytes())


def read_splat(path) -> Gaussians:
    """Read a ``.splat`` file: DC-only Gaussians (colour and rotation quantised to 8 bits)."""
    data = Path(path).read_bytes()
    if len(data) % SPLAT_RECORD.itemsize:
        raise ClearsplatError(f"size {len(data)} is not a multiple of "
                              f"{SPLAT_RECORD.itemsize} bytes", path=path, field="splat")
    rec = np.frombuffer(data, SPLAT_RECORD)
    rgba = rec["rgba"].astype(np.float32) / 255
    quats = (rec["rot"].astype(np.float32) - 128) / 128
    quats[np.linalg.norm(quats, axis=1) == 0] = (1, 0, 0, 0)
    g = Gaussians(means=rec["position"], scales=rec["scale"], quats=quats,
                  opacities=rgba[:, 3], sh=((rgba[:, :3] - 0.5) / SH_C0)[:, None, :])
    g.validate(path=path)
    return g


# ------------------------------------------------------------------------------------------------
# .spz
# ------------------------------------------------------------------------------------------------
def _quantize_sh(x, bucket: int) -> np.ndarray:
    q = (np.round(x * 128.0) + 128.0).astype(np.int64)
    q = (q + bucket // 2) // bucket * bucket
    return np.clip(q, 0, 255).astype(np.uint8)


def _pack_smallest_three(q_xyzw: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions ``x y z w`` -> (N, 4) bytes, as the spz reference packs them."""
    n = len(q_xyzw)
    largest = np.argmax(np.abs(q_xyzw), axis=1)
    negate = q_xyzw[np.arange(n), largest] < 0
    comp = largest.astype(np.uint32)
    for i in range(4):
        use = largest != i
        negbit = ((q_xyzw[:, i] < 0) ^ negate).astype(np.uint32)
        mag = (np.float32(511) * (np.abs(q_xyzw[:, i]).astype(np.float32) / _SQRT1_2)
               + np.float32(0.5)).astype(np.uint32)
        comp = np.where(use, (comp << np.uint32(10)) | (negbit << np.uint32(9)) | mag, comp)
    return comp.astype("<u4").view(np.uint8).reshape(n, 4)


def _unpack_smallest_three(r: np.ndarray) -> np.ndarray:
    comp = r.copy().view("<u4").reshape(-1).astype(np.uint32)
    n = len(comp)
    largest = (comp >> np.uint32(30)).astype(np.int64)
    q = np.zeros((n, 4), np.float32)
    for i in range(3, -1, -1):
        use = largest != i
        mag = (comp & np.uint32(511)).astype(np.float32)
        neg = (comp >> np.uint32(9)) & np.uint32(1)
        val = _SQRT1_2 * mag / np.float32(511)
        q[:, i] = np.where(use, np.where(neg == 1, -val, val), 0)
        comp = np.where(use, comp >> np.uint32(10), comp)
    rest = np.sum(q * q, axis=1)
    q[np.arange(n), largest] = np.sqrt(np.maximum(0, 1 - rest))
    return q


def write_spz(path, gaussians: Gaussians) -> None:
    """Write Gaussians as a version-3 ``.spz`` file (see the module docstring).

    Raises
    ------
    ClearsplatError
        If a position is beyond the 24-bit fixed-point range (|x| >= 2**23 after the
        largest usable fractional bits) or the Gaussians are invalid.
    """
    g = gaussians
    g.validate(path=path)
    n, k = len(g), g.sh.shape[1]
    degree = g.sh_degree
    means = g.means.astype(np.float64) * _SPZ_FLIP_P
    extent = float(np.abs(means).max()) if n else 0.0
    bits = 12
    while bits > 0 and extent * (1 << bits) >= (1 << 23) - 1:
        bits -= 1
    if extent * (1 << bits) >= (1 << 23) - 1:
        raise ClearsplatError(f"positions up to {extent:.4g} are beyond the .spz range "
                              f"(|x| < {2**23 - 1})", path=path, field="means")
    fixed = np.round(means * (1 << bits)).astype(np.int64).reshape(-1) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF],
                         axis=1).astype(np.uint8)
    alphas = _u8(g.opacities.astype(np.float32) * np.float32(255))
    colors = _u8(g.sh[:, 0].astype(np.float32) * np.float32(_SPZ_COLOR_SCALE * 255)
                 + np.float32(0.5 * 255))
    scales = _u8((np.log(g.scales.astype(np.float32)) + np.float32(10)) * np.float32(16))
    q = _unit_quats(g.quats).astype(np.float32)
    q_xyzw = np.concatenate([q[:, 1:] * _SPZ_FLIP_P, q[:, :1]], axis=1)
    rotations = _pack_smallest_three(q_xyzw) if n else np.zeros((0, 4), np.uint8)
    sh_bytes = b""
    if k > 1:
        rest = g.sh[:, 1:, :] * _SPZ_FLIP_SH[:k - 1, None]
        buckets = np.where(np.arange(1, k) <= 3, 1 << (8 - 5), 1 << (8 - 4))
        sh_bytes = _quantize_sh(rest, buckets[None, :, None]).tobytes()
    header = _SPZ_HEADER.pack(_SPZ_MAGIC, 3, n, degree, bits, 0, 0)
    raw = b"".join([header, positions.tobytes(), alphas.tobytes(), colors.tobytes(),
                    scales.tobytes(), rotations.tobytes(), sh_bytes])
    atomic_write_bytes(path, gzip.compress(raw, compresslevel=6, mtime=0))


def read_spz(path) -> Gaussians:
    """Read a version 2 or 3 ``.spz`` file (the gzip layout) into Gaussians."""
    data = Path(path).read_bytes()
    try:
        raw = gzip.decompress(data)
    except (OSError, EOFError, zlib.error) as e:
        hint = " (a version-4 zstd .spz is not supported)" if data[:4] == b"NGSP" else ""
        raise ClearsplatError(f"not a gzip-compressed .spz file{hint}: {e}", path=path,
                              field="spz") from None
    if len(raw) < _SPZ_HEADER.size:
        raise ClearsplatError("truncated header", path=path, field="header")
    magic, version, n, degree, bits, flags, _ = _SPZ_HEADER.unpack_from(raw)
    if magic != _SPZ_MAGIC:
        raise ClearsplatError(f"bad magic {magic:#x}", path=path, field="header")
    if version not in (2, 3) or degree > 4:
        raise ClearsplatError(f"version {version} with SH degree {degree} is not supported "
                              "(versions 2 and 3, degree <= 4)", path=path, field="header")
    k = (degree + 1) ** 2
    rot_bytes = 4 if version >= 3 else 3
    sizes = [9 * n, n, 3 * n, 3 * n, rot_bytes * n, 3 * (k - 1) * n]
    if len(raw) < _SPZ_HEADER.size + sum(sizes):
        raise ClearsplatError(f"truncated: {n} Gaussians need {sum(sizes)} bytes", path=path,
                              field="data")
    parts, off = [], _SPZ_HEADER.size
    for s in sizes:
        parts.append(np.frombuffer(raw, np.uint8, s, off))
        off += s
    pos, alphas, colors, scales, rot, sh = parts
    p = pos.reshape(-1, 3).astype(np.int64)
    fixed = p[:, 0] | (p[:, 1] << 8) | (p[:, 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    means = (fixed.astype(np.float64) / (1 << bits)).reshape(n, 3) * _SPZ_FLIP_P
    if version >= 3:
        q_xyzw = _unpack_smallest_three(rot.reshape(n, 4))
    else:
        xyz = rot.reshape(n, 3).astype(np.float32) / np.float32(127.5) - 1
        w = np.sqrt(np.maximum(0, 1 - np.sum(xyz * xyz, axis=1)))
        q_xyzw = np.concatenate([xyz, w[:, None]], axis=1)
    quats = np.concatenate([q_xyzw[:, 3:], q_xyzw[:, :3] * _SPZ_FLIP_P], axis=1)
    quats[np.linalg.norm(quats, axis=1) == 0] = (1, 0, 0, 0)
    out_sh = np.zeros((n, k, 3), np.float32)
    out_sh[:, 0] = ((colors.reshape(n, 3) / np.float32(255)) - np.float32(0.5)) \
        / np.float32(_SPZ_COLOR_SCALE)
    if k > 1:
        out_sh[:, 1:] = (sh.reshape(n, k - 1, 3).astype(np.float32) - 128) / 128 \
            * _SPZ_FLIP_SH[:k - 1, None]
    g = Gaussians(means=means, scales=np.exp(scales.reshape(n, 3) / np.float32(16) - 10),
                  quats=quats, opacities=alphas / np.float32(255), sh=out_sh)
    g.validate(path=path)
    return g


# ------------------------------------------------------------------------------------------------
# plain PLY
# ------------------------------------------------------------------------------------------------
def write_plain_ply(path, gaussians: Gaussians) -> None:
    """Write a PLY with exactly the original 3DGS properties (zero normals), nothing else.

    Values are written as :func:`clearsplat.io.write_ply` writes them (raw columns reused
    where unchanged), so reading the file back gives the same Gaussians.
    """
    g = gaussians
    n = len(g)
    keep = {k: v for k, v in g.extra.items()
            if k.startswith(RAW_PREFIX) and k[len(RAW_PREFIX):] not in ("view_id", "pixel_id")}
    zeros = np.zeros(n, np.float32)
    plain = Gaussians(means=g.means, scales=g.scales, quats=g.quats, opacities=g.opacities,
                      sh=g.sh, extra={"nx": zeros, "ny": zeros, "nz": zeros, **keep})
    write_ply(path, plain)
