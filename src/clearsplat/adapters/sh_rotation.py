"""Rotation of real spherical-harmonic colour coefficients, degrees 0 to 4.

A Gaussian's colour seen along the unit direction ``d`` is ``sum_k sh[k] * Y_k(d) + 0.5``
with the real SH basis of the original 3DGS code (``docs/conventions.md``). Expressing the same
Gaussian in a frame rotated by ``R`` (directions ``d' = R d``) needs coefficients ``sh'`` with
``sum_k sh'[k] Y_k(R d) = sum_k sh[k] Y_k(d)`` for every ``d``. Each band ``l`` maps to itself
(the band is closed under rotation), so ``sh'_l = D_l(R) sh_l`` with a ``(2l+1)`` square matrix.

``D_l`` is found exactly by evaluating the basis: for sample directions ``d_i``,
``Y_l(d_i) D_l = Y_l(R^T d_i)``. With at least ``2l + 1`` well-spread directions the system
has a unique solution, which is exact up to float64 round-off (no quadrature approximation).
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from .._sh import C0 as _C0, C1 as _C1, C2 as _C2, C3 as _C3, C4 as _C4

__all__ = ["sh_basis", "sh_rotation_matrices", "rotate_sh"]


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """The 3DGS real SH basis at unit directions.

    Parameters
    ----------
    dirs : (M, 3) array_like
        Unit directions ``x, y, z``.
    degree : int
        0 to 4.

    Returns
    -------
    (M, (degree + 1) ** 2) float64
    """
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = [np.full_like(x, _C0)]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * zz - xx - yy), _C2[3] * x * z,
                _C2[4] * (xx - yy)]
    if degree >= 3:
        out += [_C3[0] * y * (3 * xx - yy), _C3[1] * x * y * z, _C3[2] * y * (4 * zz - xx - yy),
                _C3[3] * z * (2 * zz - 3 * xx - 3 * yy), _C3[4] * x * (4 * zz - xx - yy),
                _C3[5] * z * (xx - yy), _C3[6] * x * (xx - 3 * yy)]
    if degree >= 4:
        z7 = 7 * zz
        out += [_C4[0] * x * y * (xx - yy), _C4[1] * y * z * (3 * xx - yy),
                _C4[2] * x * y * (z7 - 1), _C4[3] * y * z * (z7 - 3),
                _C4[4] * (zz * (35 * zz - 30) + 3), _C4[5] * x * z * (z7 - 3),
                _C4[6] * (xx - yy) * (z7 - 1), _C4[7] * x * z * (xx - 3 * yy),
                _C4[8] * (xx * (xx - 3 * yy) - yy * (3 * xx - yy))]
    return np.stack(out, axis=1)


def _sample_dirs() -> np.ndarray:
    # A fixed Fibonacci sphere: well spread, deterministic, many more than 7 per band.
    n = 64
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_DIRS = _sample_dirs()
_PINV = {l: np.linalg.pinv(sh_basis(_DIRS, l)[:, l * l:(l + 1) ** 2]) for l in range(1, 5)}


def sh_rotation_matrices(rotation, degree: int) -> list:
    """Per-band matrices ``D_l`` for ``l = 1..degree``.

    Parameters
    ----------
    rotation : (3, 3) or (N, 3, 3) array_like
        Rotation taking the old frame to the new one (``d_new = R d_old``).
    degree : int

    Returns
    -------
    list of (2l+1, 2l+1) or (N, 2l+1, 2l+1) float64 arrays, index ``l - 1``.
    """
    r = np.asarray(rotation, dtype=np.float64)
    single = r.ndim == 2
    r = r[None] if single else r
    out = []
    for l in range(1, degree + 1):
        # Y_l(R^T d_i) for every rotation: (N, M, 2l+1)
        back = np.einsum("nji,mj->nmi", r, _DIRS)
        yb = sh_basis(back.reshape(-1, 3), l)[:, l * l:(l + 1) ** 2].reshape(len(r), len(_DIRS), -1)
        # Y_l(d_i) D = Y_l(R^T d_i)  =>  D = pinv(Y_l(d_i)) Y_l(R^T d_i)
        d = np.einsum("km,nmj->nkj", _PINV[l], yb)
        out.append(d[0] if single else d)
    return out


def rotate_sh(sh, rotation) -> np.ndarray:
    """Coefficients of the same colour function in a frame rotated by ``rotation``.

    Parameters
    ----------
    sh : (N, K, 3) array_like
        Coefficients, K in {1, 4, 9, 16, 25}; the DC term does not change.
    rotation : (3, 3) or (N, 3, 3) array_like
        Proper rotation(s) ``R`` with ``d_new = R d_old`` (for a camera-frame SH and an
        OpenCV camera-to-world matrix, its rotation block).

    Returns
    -------
    (N, K, 3) float32
        ``sum_k out[k] Y_k(R d) == sum_k sh[k] Y_k(d)`` for every direction ``d``.
    """
    c = np.asarray(sh, dtype=np.float64)
    if c.ndim != 3 or c.shape[2] != 3 or c.shape[1] not in (1, 4, 9, 16, 25):
        raise ClearsplatError(f"expected (N, K, 3) with K in 1, 4, 9, 16, 25, got {c.shape}",
                              field="sh")
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape[-2:] != (3, 3) or r.ndim not in (2, 3) or (r.ndim == 3 and len(r) != len(c)):
        raise ClearsplatError(f"expected (3, 3) or ({len(c)}, 3, 3), got {r.shape}",
                              field="rotation")
    rr = r if r.ndim == 3 else r[None]
    if not (np.allclose(np.einsum("nji,njk->nik", rr, rr), np.eye(3), atol=1e-5)
            and np.allclose(np.linalg.det(rr), 1.0, atol=1e-5)):
        raise ClearsplatError("not a proper rotation (orthonormal, det +1)", field="rotation")
    degree = int(round(np.sqrt(c.shape[1]))) - 1
    out = c.copy()
    for l, d in enumerate(sh_rotation_matrices(r, degree), start=1):
        band = slice(l * l, (l + 1) ** 2)
        if d.ndim == 2:
            out[:, band] = np.einsum("ij,njc->nic", d, c[:, band])
        else:
            out[:, band] = np.einsum("nij,njc->nic", d, c[:, band])
    return out.astype(np.float32)
