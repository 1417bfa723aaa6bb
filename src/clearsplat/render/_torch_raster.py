"""The native rasterizer's math in batched torch ops, on any torch device.

The twin of ``cpp/project.cpp``, ``cpp/binning.cpp`` and ``cpp/composite.cpp`` for
:class:`clearsplat.render.torch_view.TorchView`: the same projection (EWA splatting in float64,
``eps2d``, the antialiasing compensation, the square ``ceil(3 sqrt(lambda_max))`` extent with
the pixel-centre rule, the pixel box where alpha can reach 1/255), the same stable depth sort
and tile binning, and the same compositing rule (alpha capped at 0.99, contributions below
1/255 skipped, a pixel stops before its transmittance would fall below 1e-4). Conventions:
``docs/conventions.md`` ("Rasterization").

Nothing here loops over Gaussians or pixels in Python; compositing is in
:mod:`clearsplat.render._torch_composite`.

Where the bits can differ from the CPU rasterizer: compositing forms the products and sums
over a pixel's fragments as scans (in float64) where the C++ loop multiplies and adds in
float32 one fragment after another, so colours, alpha and depth agree to float32 rounding
(about 1e-6), not bit for bit. The projection, the culling, the boxes and the
tiles are computed with the C++ code's operations in the same order and agree exactly.
"""

from __future__ import annotations

import numpy as np

from ._kernels import TILE
from .._sh import C0 as _C0, C1 as _C1, C2 as _C2, C3 as _C3, C4 as _C4

__all__ = ["project", "bin_tiles", "rect_tiles", "exp_nonpositive"]

MIN_ALPHA = float(np.float32(1.0) / np.float32(255.0))   # cs::kMinAlpha, as a float32 value
MAX_ALPHA = 0.99
MIN_TRANSMITTANCE = 1e-4
_TILE_PIXELS = TILE * TILE



# -- float32 polynomials of the C++ code (Cephes), so that boxes and alphas agree bit for bit --
_CONSTS: dict = {}


def _f(torch, x, device):
    """A float32 scalar tensor (cached): float32 arithmetic with the C++ constants."""
    key = (x, str(device))
    c = _CONSTS.get(key)
    if c is None:
        c = _CONSTS[key] = torch.tensor(x, dtype=torch.float32, device=device)
    return c


def exp_nonpositive(torch, x):
    """``cs::exp_nonpositive``: exp(x) for float32 x <= 0 (x below -87 taken as -87)."""
    f = lambda c: _f(torch, c, x.device)  # noqa: E731
    x = torch.where(x < f(-87.0), f(-87.0), x)
    fx = x * f(1.44269504088896341) + f(0.5)
    n = torch.trunc(fx)
    n = torch.where(n > fx, n - f(1.0), n)
    x = x - n * f(0.693359375)
    x = x - n * f(-2.12194440e-4)
    z = x * x
    y = x * f(1.9875691500e-4) + f(1.3981999507e-3)
    for c in (8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1):
        y = y * x + f(c)
    y = y * z + x + f(1.0)
    bits = ((n.to(torch.int32) + 127) << 23).view(torch.float32)
    return y * bits


def _box_radius2(torch, opacity):
    """``box_radius2`` (cpp/project.cpp): 2 ln(255 o) in float32 (Cephes logf), as float64,
    clamped at 0."""
    f = lambda c: _f(torch, c, opacity.device)  # noqa: E731
    x = opacity * f(255.0)
    x = torch.where(x > f(1.0), x, f(1.0))
    bits = x.view(torch.int32)
    e = (((bits >> 23) & 0xFF) - 126).to(torch.float32)
    m = ((bits & 0x007FFFFF) | 0x3F000000).view(torch.float32)
    small = m < f(0.70710678118654752)
    e = torch.where(small, e - f(1.0), e)
    m = torch.where(small, m + m - f(1.0), m - f(1.0))
    z = m * m
    y = m * f(7.0376836292e-2) - f(1.1514610310e-1)
    for c in (1.1676998740e-1, -1.2420140846e-1, 1.4249322787e-1, -1.6668057665e-1,
              2.0000714765e-1, -2.4999993993e-1, 3.3333331174e-1):
        y = y * m + f(c)
    y = y * m * z
    y = y + e * f(-2.12194440e-4)
    y = y - f(0.5) * z
    r = f(2.0) * (m + y + e * f(0.693359375))
    return torch.where(r > f(0.0), r, f(0.0)).double()


def _centre_range(torch, c, e, last):
    """Pixels ``[lo, hi]`` whose centres lie within ``[c - e, c + e]``, clamped to
    ``[0, last]``, and whether that range is non-empty (``centre_range`` in project.cpp)."""
    a, b = c - e - 0.5, c + e - 0.5
    ok = (b >= 0.0) & (a <= last)
    a = torch.where(ok, a.clamp(0.0, last), 0.0)
    b = torch.where(ok, b.clamp(0.0, last), 0.0)
    fa = torch.trunc(a)
    lo = torch.where(fa < a, fa + 1.0, fa)
    hi = torch.trunc(b)
    return lo, hi, ok & (lo <= hi)


def _sh_rgb(torch, sh, dirs):
    """``max(0, SH(d) + 0.5)`` per channel in float64, summed in the C++ order; (N, 3)."""
    k = sh.shape[1]
    coeffs = sh.double()
    if k == 1:
        return (_C0 * coeffs[:, 0] + 0.5).clamp_min(0.0)
    x, y, z = dirs.unbind(1)
    basis = [torch.full_like(x, _C0), -_C1 * y, _C1 * z, -_C1 * x]
    if k > 4:
        xx, yy, zz = x * x, y * y, z * z
        basis += [_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2.0 * zz - xx - yy),
                  _C2[3] * x * z, _C2[4] * (xx - yy)]
        if k > 9:
            basis += [_C3[0] * y * (3.0 * xx - yy), _C3[1] * x * y * z,
                      _C3[2] * y * (4.0 * zz - xx - yy),
                      _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                      _C3[4] * x * (4.0 * zz - xx - yy), _C3[5] * z * (xx - yy),
                      _C3[6] * x * (xx - 3.0 * yy)]
            if k > 16:
                xy, xz, yz, z7 = x * y, x * z, y * z, 7.0 * zz
                basis += [_C4[0] * xy * (xx - yy), _C4[1] * yz * (3.0 * xx - yy),
                          _C4[2] * xy * (z7 - 1.0), _C4[3] * yz * (z7 - 3.0),
                          _C4[4] * (zz * (35.0 * zz - 30.0) + 3.0), _C4[5] * xz * (z7 - 3.0),
                          _C4[6] * (xx - yy) * (z7 - 1.0), _C4[7] * xz * (xx - 3.0 * yy),
                          _C4[8] * (xx * (xx - 3.0 * yy) - yy * (3.0 * xx - yy))]
    acc = torch.zeros_like(coeffs[:, 0])
    for j in range(k):                     # at most 25 terms, in the C++ order
        acc = acc + basis[j][:, None] * coeffs[:, j]
    return (acc + 0.5).clamp_min(0.0)


def project(torch, g, camera, *, near: float, settings, keep=None):
    """Project, cull and sort front to back (``cs::project``).

    Parameters
    ----------
    g : object with float32 tensors ``means`` (N, 3), ``scales`` (N, 3), ``quats`` (N, 4),
        ``opacities`` (N,), ``sh`` (N, K, 3) on one device
    camera : Camera
    near : float
    settings : RenderSettings
    keep : (N,) bool tensor, optional

    Returns
    -------
    rec : (V, 10) float32
        ``u, v, conic a, b, c, opacity, r, g, b, depth`` per visible Gaussian, front to back.
    box : (V, 4) int64
        Pixel box ``x0, x1, y0, y1`` (inclusive) where alpha can reach 1/255.
    rect : (V, 4) int64
        Tile range ``x0, y0, x1, y1`` (inclusive) it is binned into.
    index : (V,) int64
        Gaussian index of each.
    """
    dev = g.means.device
    V = np.asarray(camera.world_to_camera, dtype=np.float64)[:3, :4].ravel().tolist()
    fx, fy, cx, cy = (float(camera.K[0, 0]), float(camera.K[1, 1]), float(camera.K[0, 2]),
                      float(camera.K[1, 2]))
    width, height = camera.width, camera.height
    m = g.means.double()
    mx, my, mz = m.unbind(1)
    tz = V[8] * mx + V[9] * my + V[10] * mz + V[11]
    tx = V[0] * mx + V[1] * my + V[2] * mz + V[3]
    ty = V[4] * mx + V[5] * my + V[6] * mz + V[7]
    opacity = g.opacities.double()
    ok = (tz >= near) & (opacity >= MIN_ALPHA) & (opacity < 1e30)
    qw, qx, qy, qz = g.quats.double().unbind(1)
    qn2 = qw * qw + qx * qx + qy * qy + qz * qz
    ok &= (qn2 > 0.0) & (qn2 < 1e300)
    k2 = 2.0 / qn2
    R00, R01 = 1 - k2 * (qy * qy + qz * qz), k2 * (qx * qy - qw * qz)
    R02, R10 = k2 * (qx * qz + qw * qy), k2 * (qx * qy + qw * qz)
    R11, R12 = 1 - k2 * (qx * qx + qz * qz), k2 * (qy * qz - qw * qx)
    R20, R21 = k2 * (qx * qz - qw * qy), k2 * (qy * qz + qw * qx)
    R22 = 1 - k2 * (qx * qx + qy * qy)
    s0, s1, s2 = g.scales.double().unbind(1)
    limx, limy = 1.3 * float(width) / (2.0 * fx), 1.3 * float(height) / (2.0 * fy)
    iz = 1.0 / tz
    xz = (tx * iz).clamp(-limx, limx)
    yz = (ty * iz).clamp(-limy, limy)
    j00, j02 = fx * iz, -fx * xz * iz
    j11, j12 = fy * iz, -fy * yz * iz
    A0, A1, A2 = j00 * V[0] + j02 * V[8], j00 * V[1] + j02 * V[9], j00 * V[2] + j02 * V[10]
    B0, B1, B2 = j11 * V[4] + j12 * V[8], j11 * V[5] + j12 * V[9], j11 * V[6] + j12 * V[10]
    AM0 = (A0 * R00 + A1 * R10 + A2 * R20) * s0
    AM1 = (A0 * R01 + A1 * R11 + A2 * R21) * s1
    AM2 = (A0 * R02 + A1 * R12 + A2 * R22) * s2
    BM0 = (B0 * R00 + B1 * R10 + B2 * R20) * s0
    BM1 = (B0 * R01 + B1 * R11 + B2 * R21) * s1
    BM2 = (B0 * R02 + B1 * R12 + B2 * R22) * s2
    ca0 = AM0 * AM0 + AM1 * AM1 + AM2 * AM2
    cb = AM0 * BM0 + AM1 * BM1 + AM2 * BM2
    cc0 = BM0 * BM0 + BM1 * BM1 + BM2 * BM2
    ca, cc = ca0 + settings.eps2d, cc0 + settings.eps2d
    det = ca * cc - cb * cb
    ok &= (det > 0.0) & (det < 1e300)
    if settings.antialiased:
        ratio = ((ca0 * cc0 - cb * cb) / det).clamp_min(0.0)
        opacity = opacity * torch.sqrt(torch.where(ok, ratio, 0.0))
        ok &= opacity >= MIN_ALPHA
        e2 = (2.0 * torch.log((255.0 * opacity).clamp_min(1.0))).clamp_min(0.0)
    else:
        e2 = _box_radius2(torch, g.opacities)
    mid = 0.5 * (ca + cc)
    lam = mid + torch.sqrt((mid * mid - det).clamp_min(0.1))
    r3 = 3.0 * torch.sqrt(lam)
    ok &= r3 < 1e9
    r3 = torch.where(ok, r3, 0.0)
    radius = torch.trunc(r3)
    radius = radius + (radius < r3).double()
    ok &= radius > float(settings.radius_clip)
    u = fx * tx * iz + cx
    v = fy * ty * iz + cy
    last_x, last_y = float(width - 1), float(height - 1)
    c0, c1, okx = _centre_range(torch, u, radius, last_x)
    r0, r1, oky = _centre_range(torch, v, radius, last_y)
    ex = torch.sqrt(e2 * ca) * (1.0 + 1e-3) + 1e-3
    ey = torch.sqrt(e2 * cc) * (1.0 + 1e-3) + 1e-3
    bx0, bx1, okbx = _centre_range(torch, u, ex, last_x)
    by0, by1, okby = _centre_range(torch, v, ey, last_y)
    x0, x1 = torch.maximum(c0, bx0), torch.minimum(c1, bx1)
    y0, y1 = torch.maximum(r0, by0), torch.minimum(r1, by1)
    ok &= okx & oky & okbx & okby & (x0 <= x1) & (y0 <= y1)
    if keep is not None:
        ok &= keep
    idx = torch.nonzero(ok).squeeze(1)
    # The record of each survivor (finish_one), in float32.
    ca_, cb_, cc_ = ca[idx], cb[idx], cc[idx]
    idet = 1.0 / (ca_ * cc_ - cb_ * cb_)
    conic = torch.stack([cc_ * idet, -cb_ * idet, ca_ * idet], 1).float()
    d = m[idx] - torch.tensor(np.asarray(camera.position, np.float64), device=dev)
    if g.sh.shape[1] > 1:
        dn2 = d[:, :1] * d[:, :1] + d[:, 1:2] * d[:, 1:2] + d[:, 2:3] * d[:, 2:3]
        d = torch.where(dn2 > 0.0, d * (1.0 / torch.sqrt(dn2)), d)
    rgb = _sh_rgb(torch, g.sh[idx], d).float()
    rec = torch.cat([u[idx, None].float(), v[idx, None].float(), conic,
                     opacity[idx, None].float(), rgb, tz[idx, None].float()], 1)
    finite = torch.isfinite(rgb.sum(1)) & torch.isfinite(conic[:, 0] + conic[:, 1] + conic[:, 2])
    rec, idx = rec[finite], idx[finite]
    box = torch.stack([bx0, bx1, by0, by1], 1)[idx].long()
    rect = torch.stack([x0, y0, x1, y1], 1)[idx].long() // TILE
    # Front to back: by float32 depth (positive, so its order), ties by Gaussian index.
    order = torch.sort(rec[:, 9], stable=True).indices
    return rec[order].contiguous(), box[order], rect[order], idx[order]


def rect_tiles(torch, rect, cols: int):
    """Every (item, tile) pair of inclusive tile ranges ``rect`` (M, 4) ``x0, y0, x1, y1``:
    ``(item (P,), tile (P,))`` in item order, row-major within an item."""
    w = rect[:, 2] - rect[:, 0] + 1
    count = w * (rect[:, 3] - rect[:, 1] + 1)
    item = torch.repeat_interleave(torch.arange(rect.shape[0], device=rect.device), count)
    j = torch.arange(item.shape[0], device=rect.device) - (torch.cumsum(count, 0) - count)[item]
    tile = (rect[item, 1] + j // w[item]) * cols + rect[item, 0] + j % w[item]
    return item, tile


def bin_tiles(torch, rect, rows: int, cols: int):
    """Tile lists (``cs::bin_tiles``): ``offsets`` (rows * cols + 1,) and the ids of each tile,
    ascending (front to back)."""
    item, tile = rect_tiles(torch, rect, cols)
    tile, order = torch.sort(tile, stable=True)
    counts = torch.bincount(tile, minlength=rows * cols)
    offsets = torch.zeros(rows * cols + 1, dtype=torch.long, device=rect.device)
    offsets[1:] = torch.cumsum(counts, 0)
    return offsets, item[order]
