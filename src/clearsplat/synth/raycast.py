"""Analytic ray casting of textured primitives (the ground truth of the synthetic worlds).

Rays come from :meth:`clearsplat.Camera.pixel_rays`: ``origin + t * d`` with ``d`` not
normalised, so the hit parameter ``t`` is the camera depth (camera z) directly.

Every primitive answers two questions on a flat batch of rays: where is the nearest hit
in front of the origin (:meth:`intersect`, ``inf`` for a miss, plus an integer face code),
and what are the normal and surface coordinates there (:meth:`surface`). Shading is
Lambertian with one fixed directional light plus a sky term, so colours do not depend on
the viewpoint and the views of a world are consistent. Nothing casts shadows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .textures import Texture

__all__ = ["Plane", "Sphere", "Box", "Cylinder", "Hits", "cast", "shade", "LIGHT_DIR"]

#: Direction towards the light (world, z up).
LIGHT_DIR = np.array([0.45, -0.35, 0.82]) / np.linalg.norm([0.45, -0.35, 0.82])
_EPS = 1e-6


def _rotation(R) -> np.ndarray:
    return np.eye(3) if R is None else np.asarray(R, dtype=np.float64)


@dataclass(eq=False)
class _Primitive:
    texture: Texture
    #: emissive surfaces (the sky) show their texture unshaded.
    emissive: bool = field(default=False, kw_only=True)
    name: str = field(default="", kw_only=True)


@dataclass(eq=False)
class Plane(_Primitive):
    """A plane through ``point`` with unit ``normal``; optionally a rectangle.

    ``axis_u`` (in the plane) and ``normal x axis_u`` span the texture coordinates;
    ``half_size`` ``(hu, hv)`` bounds it to a rectangle centred on ``point``.
    """

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    axis_u: tuple = (1.0, 0.0, 0.0)
    half_size: tuple = (np.inf, np.inf)

    def __post_init__(self):
        self._p = np.asarray(self.point, dtype=np.float64)
        n = np.asarray(self.normal, dtype=np.float64)
        self._n = n / np.linalg.norm(n)
        u = np.asarray(self.axis_u, dtype=np.float64)
        u = u - self._n * (u @ self._n)
        self._u = u / np.linalg.norm(u)
        self._v = np.cross(self._n, self._u)

    def intersect(self, o, d):
        dn = d @ self._n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self._p - o) @ self._n) / dn
        t = np.where(np.abs(dn) > 1e-12, t, np.inf)
        t = np.where(t > _EPS, t, np.inf)
        if np.isfinite(self.half_size[0]) or np.isfinite(self.half_size[1]):
            q = o + d * np.where(np.isfinite(t), t, 0.0)[:, None] - self._p
            inside = (np.abs(q @ self._u) <= self.half_size[0]) & \
                     (np.abs(q @ self._v) <= self.half_size[1])
            t = np.where(inside, t, np.inf)
        return t, np.zeros(t.shape, dtype=np.int8)

    def bounds(self):
        """Bounding sphere ``(centre, radius)``, or None when unbounded."""
        if np.isfinite(self.half_size[0]) and np.isfinite(self.half_size[1]):
            return self._p, float(np.hypot(*self.half_size))
        return None

    def surface(self, x, face):
        q = x - self._p
        uv = np.stack([q @ self._u, q @ self._v], axis=1)
        return np.broadcast_to(self._n, x.shape), uv


@dataclass(eq=False)
class Sphere(_Primitive):
    """A sphere; ``inside=True`` sees it from within (a sky dome) with inward normals."""

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    rotation: np.ndarray | None = None
    inside: bool = False

    def __post_init__(self):
        self._c = np.asarray(self.center, dtype=np.float64)
        self._R = _rotation(self.rotation)

    def intersect(self, o, d):
        oc = o - self._c
        a = np.einsum("ij,ij->i", d, d)
        b = 2.0 * (d @ oc) if oc.ndim == 1 else 2.0 * np.einsum("ij,ij->i", d, oc)
        c = float(oc @ oc) - self.radius ** 2
        disc = b * b - 4.0 * a * c
        ok = disc >= 0
        sq = np.sqrt(np.where(ok, disc, 0.0))
        t0 = (-b - sq) / (2.0 * a)
        t1 = (-b + sq) / (2.0 * a)
        if self.inside:
            t = np.where(ok & (t1 > _EPS), t1, np.inf)
        else:
            t = np.where(t0 > _EPS, t0, np.where(t1 > _EPS, t1, np.inf))
            t = np.where(ok, t, np.inf)
        return t, np.zeros(t.shape, dtype=np.int8)

    def bounds(self):
        """Bounding sphere ``(centre, radius)``, or None when seen from inside."""
        return None if self.inside else (self._c, float(self.radius))

    def surface(self, x, face):
        n = (x - self._c) / self.radius
        local = n @ self._R
        lon = np.arctan2(local[:, 1], local[:, 0])
        lat = np.arcsin(np.clip(local[:, 2], -1.0, 1.0))
        uv = np.stack([lon * self.radius, lat * self.radius], axis=1)
        return (-n if self.inside else n), uv


@dataclass(eq=False)
class Box(_Primitive):
    """An oriented box: ``center``, ``half`` extents along the columns of ``rotation``.

    ``inside=True`` sees it from within (a room) with inward normals.
    """

    center: tuple = (0.0, 0.0, 0.0)
    half: tuple = (0.5, 0.5, 0.5)
    rotation: np.ndarray | None = None
    inside: bool = False

    def __post_init__(self):
        self._c = np.asarray(self.center, dtype=np.float64)
        self._h = np.asarray(self.half, dtype=np.float64)
        self._R = _rotation(self.rotation)

    def intersect(self, o, d):
        lo = (o - self._c) @ self._R
        ld = self._R.T @ d.T  # (3, M): contiguous rows are much faster to work on
        near, far = [], []
        for k in range(3):  # slab method, one axis at a time
            dk = ld[k]
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / dk
                ta = (-self._h[k] - lo[k]) * inv
                tb = (self._h[k] - lo[k]) * inv
            # a ray parallel to a slab is either inside it for all t or misses it.
            inside = abs(lo[k]) <= self._h[k]
            par = dk == 0
            near.append(np.where(par, -np.inf if inside else np.inf, np.minimum(ta, tb)))
            far.append(np.where(par, np.inf if inside else -np.inf, np.maximum(ta, tb)))
        t_near = np.maximum(np.maximum(near[0], near[1]), near[2])
        t_far = np.minimum(np.minimum(far[0], far[1]), far[2])
        hit = t_near <= t_far
        if self.inside:
            t = np.where(hit & (t_far > _EPS), t_far, np.inf)
            axis = np.where(far[0] == t_far, 0, np.where(far[1] == t_far, 1, 2))
        else:
            t = np.where(hit & (t_near > _EPS), t_near, np.inf)
            axis = np.where(near[0] == t_near, 0, np.where(near[1] == t_near, 1, 2))
        return t, axis.astype(np.int8)

    def bounds(self):
        """Bounding sphere ``(centre, radius)``, or None when seen from inside."""
        return None if self.inside else (self._c, float(np.linalg.norm(self._h)))

    def surface(self, x, face):
        local = (x - self._c) @ self._R
        rows = np.arange(len(x))
        sign = np.sign(local[rows, face])
        n_local = np.zeros_like(local)
        n_local[rows, face] = sign
        n = n_local @ self._R.T
        a1 = (face + 1) % 3
        a2 = (face + 2) % 3
        # offset per face so that opposite faces do not show the same pattern
        off = (face * 2 + (sign > 0)) * 3.7
        uv = np.stack([local[rows, a1] + off, local[rows, a2] - off], axis=1)
        return (-n if self.inside else n), uv


@dataclass(eq=False)
class Cylinder(_Primitive):
    """A capped cylinder from ``base`` up ``height`` along the third column of ``rotation``."""

    base: tuple = (0.0, 0.0, 0.0)
    radius: float = 0.5
    height: float = 1.0
    rotation: np.ndarray | None = None

    def __post_init__(self):
        self._b = np.asarray(self.base, dtype=np.float64)
        self._R = _rotation(self.rotation)

    def intersect(self, o, d):
        lo = (o - self._b) @ self._R
        ld = d @ self._R
        if lo.ndim == 1:
            lo = np.broadcast_to(lo, ld.shape)
        a = ld[:, 0] ** 2 + ld[:, 1] ** 2
        b = 2.0 * (lo[:, 0] * ld[:, 0] + lo[:, 1] * ld[:, 1])
        c = lo[:, 0] ** 2 + lo[:, 1] ** 2 - self.radius ** 2
        disc = b * b - 4.0 * a * c
        ok = (disc >= 0) & (a > 1e-18)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = (-b - sq) / (2.0 * np.where(ok, a, 1.0))
        z = lo[:, 2] + t_side * ld[:, 2]
        t_side = np.where(ok & (t_side > _EPS) & (z >= 0) & (z <= self.height), t_side, np.inf)
        best, face = t_side, np.zeros(len(ld), dtype=np.int8)
        for code, zc in ((1, 0.0), (2, self.height)):
            with np.errstate(divide="ignore", invalid="ignore"):
                tc = (zc - lo[:, 2]) / ld[:, 2]
            tc = np.where(np.isfinite(tc) & (tc > _EPS), tc, np.inf)
            px = lo[:, 0] + np.where(np.isfinite(tc), tc, 0.0) * ld[:, 0]
            py = lo[:, 1] + np.where(np.isfinite(tc), tc, 0.0) * ld[:, 1]
            tc = np.where(px * px + py * py <= self.radius ** 2, tc, np.inf)
            closer = tc < best
            best = np.where(closer, tc, best)
            face = np.where(closer, code, face).astype(np.int8)
        return best, face

    def bounds(self):
        """Bounding sphere ``(centre, radius)``."""
        centre = self._b + self._R[:, 2] * self.height / 2
        return centre, float(np.hypot(self.radius, self.height / 2))

    def surface(self, x, face):
        local = (x - self._b) @ self._R
        side = face == 0
        n_local = np.zeros_like(local)
        rxy = np.maximum(np.hypot(local[:, 0], local[:, 1]), 1e-12)
        n_local[:, 0] = np.where(side, local[:, 0] / rxy, 0.0)
        n_local[:, 1] = np.where(side, local[:, 1] / rxy, 0.0)
        n_local[:, 2] = np.where(side, 0.0, np.where(face == 2, 1.0, -1.0))
        ang = np.arctan2(local[:, 1], local[:, 0]) * self.radius
        uv = np.where(side[:, None], np.stack([ang, local[:, 2]], axis=1),
                      local[:, :2] + 5.3 * face[:, None])
        return n_local @ self._R.T, uv


@dataclass
class Hits:
    """Nearest hits of a ray batch.

    Attributes
    ----------
    t : (M,) float64
        Camera depth of the hit, ``inf`` where nothing was hit.
    index : (M,) int32
        Index of the primitive hit, -1 for a miss.
    face : (M,) int8
        Face code within that primitive.
    """

    t: np.ndarray
    index: np.ndarray
    face: np.ndarray


def cast(primitives, origin, directions, *, camera=None) -> Hits:
    """Nearest hit of each ray among ``primitives``.

    Parameters
    ----------
    primitives : sequence of Plane, Sphere, Box or Cylinder
    origin : (3,) array_like
    directions : (M, 3) array_like
        Not necessarily normalised; ``t`` is in units of their length.
    camera : Camera, optional
        When the rays are ``camera.pixel_rays()`` flattened row-major (M = H * W), each
        bounded primitive is only tested against the pixels of its projected bounding box.
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    m = len(d)
    best = np.full(m, np.inf)
    index = np.full(m, -1, dtype=np.int32)
    face = np.zeros(m, dtype=np.int8)
    culled = [_screen_pixels(camera, p.bounds()) if camera is not None else (None, 0.0)
              for p in primitives]
    # near to far, so that far primitives only test the rays nothing nearer has hit
    for i in sorted(range(len(primitives)), key=lambda k: culled[k][1]):
        prim = primitives[i]
        sel, z_min = culled[i]
        if sel is None:
            t, f = prim.intersect(o, d)
            closer = t < best
            best = np.where(closer, t, best)
            index[closer] = i
            face[closer] = f[closer]
            continue
        sel = sel[best[sel] > z_min]
        if len(sel):
            t, f = prim.intersect(o, d[sel])
            closer = t < best[sel]
            rows = sel[closer]
            best[rows] = t[closer]
            index[rows] = i
            face[rows] = f[closer]
    return Hits(best, index, face)


def _screen_pixels(camera, bounds):
    """Pixels a bounding sphere may cover and the least camera depth it reaches.

    Returns ``(None, -inf)`` when every pixel must be tested, otherwise flat indices
    (possibly empty) and the camera depth of the sphere's nearest point.
    """
    if bounds is None:
        return None, -np.inf
    centre, r = bounds
    x, y, z = camera.to_camera(np.asarray(centre)[None])[0]
    if z + r <= 0:
        return np.empty(0, dtype=np.int64), np.inf
    if z - r <= 1e-3:
        return None, -np.inf
    zs = np.array([z - r, z + r])
    u = camera.fx * np.concatenate([(x - r) / zs, (x + r) / zs]) + camera.cx
    v = camera.fy * np.concatenate([(y - r) / zs, (y + r) / zs]) + camera.cy
    c0, c1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 1, camera.width)
    r0, r1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 1, camera.height)
    if c0 >= c1 or r0 >= r1:
        return np.empty(0, dtype=np.int64), np.inf
    rows = np.arange(r0, r1)[:, None] * camera.width
    return (rows + np.arange(c0, c1)[None, :]).ravel(), z - r


def shade(primitives, hits: Hits, origin, directions, *, pixel_angle: float,
          background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Colour of each hit: Lambertian albedo under :data:`LIGHT_DIR` plus ambient light.

    Parameters
    ----------
    primitives : the sequence given to :func:`cast`.
    hits : Hits
    origin : (3,) array_like
    directions : (M, 3) array_like
    pixel_angle : float
        Angular size of a pixel (1 / focal length), used as the anti-aliasing width.
    background : (3,) colour for rays that hit nothing.

    Returns
    -------
    (M, 3) float64 RGB in [0, 1].
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    rgb = np.empty((len(d), 3))
    rgb[:] = background
    for i, prim in enumerate(primitives):
        sel = np.flatnonzero(hits.index == i)
        if not len(sel):
            continue
        t = hits.t[sel]
        ds = d[sel]
        x = o + ds * t[:, None]
        n, uv = prim.surface(x, hits.face[sel])
        dlen = np.linalg.norm(ds, axis=1)
        cos_inc = np.abs(np.einsum("ij,ij->i", n, ds)) / dlen
        footprint = t * dlen * pixel_angle / np.maximum(cos_inc, 0.25)
        albedo = prim.texture(uv, footprint)
        if prim.emissive:
            rgb[sel] = albedo
            continue
        lam = np.maximum(n @ LIGHT_DIR, 0.0)
        sky = 0.5 + 0.5 * n[:, 2]
        rgb[sel] = albedo * (0.22 + 0.18 * sky + 0.75 * lam)[:, None]
    return np.clip(rgb, 0.0, 1.0)
