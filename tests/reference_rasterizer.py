"""A slow, plain NumPy rasterizer with the semantics of ``docs/conventions.md`` ("Rasterization").

It mirrors the forward pass of the original 3DGS code in float64, one tile and one pixel at a
time, and evaluates every pixel of a tile against every Gaussian of the tile (the native code
visits only the pixels where alpha can reach 1/255). Meant for images of a few thousand pixels.

Definitions shared with the native code (``src/clearsplat/cpp``):

- a Gaussian is binned into the tiles holding a pixel centre ``(col + 0.5, row + 0.5)`` with
  ``|col + 0.5 - u| <= r`` and ``|row + 0.5 - v| <= r`` (per axis), ``r`` the integer radius;
- a tile's Gaussians are composited by ascending camera z rounded to float32, ties by index;
- render settings (``clearsplat.RenderSettings``): ``eps2d`` is added to the 2D covariance's
  diagonal; antialiased mode multiplies the opacity by ``sqrt(det(cov2d) / det(cov2d + eps2d
  I))`` before culling and compositing (gsplat's ``rasterize_mode="antialiased"``); Gaussians
  with ``r <= radius_clip`` are culled; SH bands above ``sh_degree`` are ignored.

SH degree 4 is written here as the textbook real spherical harmonics (with the 3DGS signs),
independently of the native code; ``tests/test_gsplat.py`` checks this module against gsplat's
own pure-PyTorch functions where a gsplat wheel is installed.
"""

from __future__ import annotations

import numpy as np

TILE = 16
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


# Degree 4: N_4m * P_4^|m|(z) * {cos, sin}(|m| phi) r^4 in Cartesian form, with the 3DGS signs
# ((-1)^m for odd m). N_4m from sqrt((2l + 1) (l - |m|)! / (4 pi (l + |m|)!)) (times sqrt 2).
_PI = np.pi
SH_C4 = (0.75 * np.sqrt(35 / _PI), -0.75 * np.sqrt(35 / (2 * _PI)), 0.75 * np.sqrt(5 / _PI),
         -0.75 * np.sqrt(5 / (2 * _PI)), 3 / 16 * np.sqrt(1 / _PI), -0.75 * np.sqrt(5 / (2 * _PI)),
         0.375 * np.sqrt(5 / _PI), -0.75 * np.sqrt(35 / (2 * _PI)), 3 / 16 * np.sqrt(35 / _PI))


def sh_basis(d: np.ndarray, k: int) -> np.ndarray:
    """Real SH basis of the 3DGS code, (M, k), for unit directions d (M, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    cols = [np.full_like(x, SH_C0)]
    if k > 1:
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if k > 4:
        cols += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * z * z - x * x - y * y),
                 SH_C2[3] * x * z, SH_C2[4] * (x * x - y * y)]
    if k > 9:
        cols += [SH_C3[0] * y * (3 * x * x - y * y), SH_C3[1] * x * y * z,
                 SH_C3[2] * y * (4 * z * z - x * x - y * y),
                 SH_C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y),
                 SH_C3[4] * x * (4 * z * z - x * x - y * y), SH_C3[5] * z * (x * x - y * y),
                 SH_C3[6] * x * (x * x - 3 * y * y)]
    if k > 16:
        x2, y2, z2 = x * x, y * y, z * z
        cols += [SH_C4[0] * x * y * (x2 - y2), SH_C4[1] * y * z * (3 * x2 - y2),
                 SH_C4[2] * x * y * (7 * z2 - 1), SH_C4[3] * y * z * (7 * z2 - 3),
                 SH_C4[4] * (35 * z2 * z2 - 30 * z2 + 3), SH_C4[5] * x * z * (7 * z2 - 3),
                 SH_C4[6] * (x2 - y2) * (7 * z2 - 1), SH_C4[7] * x * z * (x2 - 3 * y2),
                 SH_C4[8] * (x2 * x2 - 6 * x2 * y2 + y2 * y2)]
    return np.stack(cols, axis=1)


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(M, 4) quaternions w, x, y, z (normalised here) to (M, 3, 3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def project(gaussians, camera, *, near: float = 0.01, settings=None) -> dict:
    """Per-Gaussian projection (float64). Culled Gaussians have ``visible`` False.

    ``settings``: a ``clearsplat.RenderSettings`` (None: classic 3DGS, eps2d 0.3)."""
    antialiased = bool(getattr(settings, "antialiased", False))
    eps2d = float(getattr(settings, "eps2d", 0.3))
    radius_clip = float(getattr(settings, "radius_clip", 0.0))
    sh_degree = getattr(settings, "sh_degree", None)
    means = gaussians.means.astype(np.float64)
    n = means.shape[0]
    W = camera.world_to_camera[:3, :3]
    t = means @ W.T + camera.world_to_camera[:3, 3]
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    width, height = camera.width, camera.height

    R = quat_to_rotmat(gaussians.quats.astype(np.float64))
    M = R * gaussians.scales.astype(np.float64)[:, None, :]
    sigma = M @ np.transpose(M, (0, 2, 1))

    z = t[:, 2]
    zs = np.where(z >= near, z, 1.0)  # placeholder depth for culled ones (no division by 0)
    limx, limy = 1.3 * width / (2 * fx), 1.3 * height / (2 * fy)
    xz = np.clip(t[:, 0] / zs, -limx, limx)
    yz = np.clip(t[:, 1] / zs, -limy, limy)
    J = np.zeros((n, 2, 3))
    J[:, 0, 0] = fx / zs
    J[:, 0, 2] = -fx * xz * zs / zs**2
    J[:, 1, 1] = fy / zs
    J[:, 1, 2] = -fy * yz * zs / zs**2
    T = J @ W
    cov0 = T @ sigma @ np.transpose(T, (0, 2, 1))
    cov = cov0 + eps2d * np.eye(2)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    opacity = gaussians.opacities.astype(np.float64)
    if antialiased:
        det0 = np.linalg.det(cov0)
        opacity = opacity * np.sqrt(np.maximum(0.0, det0 / np.where(det > 0, det, 1.0)))
    dets = np.where(det > 0, det, 1.0)
    conic = np.stack([c / dets, -b / dets, a / dets], axis=1)
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
    radius = np.ceil(3 * np.sqrt(lam))
    u = fx * t[:, 0] / zs + cx
    v = fy * t[:, 1] / zs + cy

    # Tiles holding a pixel centre within the radius.
    c0, c1 = np.ceil(u - radius - 0.5), np.floor(u + radius - 0.5)
    r0, r1 = np.ceil(v - radius - 0.5), np.floor(v + radius - 0.5)
    on_image = (c1 >= 0) & (c0 <= width - 1) & (r1 >= 0) & (r0 <= height - 1)
    c0, c1 = np.clip(c0, 0, width - 1), np.clip(c1, 0, width - 1)
    r0, r1 = np.clip(r0, 0, height - 1), np.clip(r1, 0, height - 1)
    rect = np.stack([c0 // TILE, r0 // TILE, c1 // TILE, r1 // TILE], axis=1).astype(np.int64)

    d = means - camera.position
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    k = gaussians.sh.shape[1] if sh_degree is None else min(gaussians.sh.shape[1],
                                                             (sh_degree + 1) ** 2)
    colour = np.einsum("nk,nkc->nc", sh_basis(d, k), gaussians.sh[:, :k].astype(np.float64))
    colour = np.maximum(colour + 0.5, 0.0)

    visible = (z >= near) & (det > 0) & on_image & (radius > radius_clip) \
        & (opacity >= 1.0 / 255.0)
    return {"visible": visible, "u": u, "v": v, "conic": conic, "depth": z, "radius": radius,
            "rect": rect, "colour": colour, "opacity": opacity}


def render(gaussians, camera, *, keep=None, background=(0.0, 0.0, 0.0), near: float = 0.01,
           mask=None, settings=None):
    """Render like ``clearsplat.render``; also return the contributions at ``mask`` pixels.

    Returns
    -------
    rgb (H, W, 3), alpha (H, W), depth (H, W) float64, and a list of
    ``(pixel, gaussian, weight)`` tuples ordered by pixel then front to back.
    """
    p = project(gaussians, camera, near=near, settings=settings)
    n = len(gaussians)
    use = p["visible"] & (np.ones(n, bool) if keep is None else np.asarray(keep))
    width, height = camera.width, camera.height
    bg = np.asarray(background, dtype=np.float64)
    rgb = np.zeros((height, width, 3))
    alpha = np.zeros((height, width))
    depth = np.zeros((height, width))
    contribs = {}
    depth32 = p["depth"].astype(np.float32)
    for ty in range(-(-height // TILE)):
        for tx in range(-(-width // TILE)):
            rect = p["rect"]
            inside = use & (rect[:, 0] <= tx) & (tx <= rect[:, 2]) \
                & (rect[:, 1] <= ty) & (ty <= rect[:, 3])
            ids = np.flatnonzero(inside)
            ids = ids[np.lexsort((ids, depth32[ids]))]  # front to back, ties by index
            for row in range(ty * TILE, min((ty + 1) * TILE, height)):
                for col in range(tx * TILE, min((tx + 1) * TILE, width)):
                    dx = p["u"][ids] - (col + 0.5)
                    dy = p["v"][ids] - (row + 0.5)
                    ca, cb, cc = p["conic"][ids].T
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    a = np.minimum(0.99, p["opacity"][ids] * np.exp(np.minimum(power, 0.0)))
                    T, C, D = 1.0, np.zeros(3), 0.0
                    for j, gid in enumerate(ids):
                        if power[j] > 0 or a[j] < 1.0 / 255.0:
                            continue
                        test_T = T * (1.0 - a[j])
                        if test_T < 1e-4:
                            break
                        C += p["colour"][gid] * a[j] * T
                        D += p["depth"][gid] * a[j] * T
                        if mask is not None and mask[row, col]:
                            contribs.setdefault(row * width + col, []).append(
                                (row * width + col, int(gid), a[j] * T))
                        T = test_T
                    rgb[row, col] = C + T * bg
                    alpha[row, col] = 1.0 - T
                    depth[row, col] = D / (1.0 - T) if T < 1.0 else 0.0
    flat = [c for q in sorted(contribs) for c in contribs[q]]
    return rgb, alpha, depth, flat
