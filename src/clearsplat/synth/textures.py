"""Procedural, band-limited surface textures for the synthetic worlds.

A :class:`Texture` maps 2D surface coordinates (metres along the surface) to an RGB
albedo. It mixes two colours with a checker, stripes and fractal value noise, then
modulates the brightness with a finer grain. Every pattern is faded out as the pixel
footprint approaches its period, so that one ray per pixel does not alias (the
images stay close to what an anti-aliased camera would record).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Texture", "value_noise", "fbm", "random_texture"]

_M1, _M2, _M3, _M4 = 0x27D4EB2D, 0x165667B1, 0x9E3779B1, 0x85EBCA6B


def _hash01(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic hash of integer lattice points to floats in [0, 1)."""
    h = (ix.astype(np.int64).astype(np.uint32) * np.uint32(_M1)
         ^ iy.astype(np.int64).astype(np.uint32) * np.uint32(_M2)
         ^ np.uint32((seed * _M3) & 0xFFFFFFFF))
    h = (h ^ (h >> np.uint32(15))) * np.uint32(_M4)
    h = (h ^ (h >> np.uint32(13))) * np.uint32(_M3)
    h = h ^ (h >> np.uint32(16))
    return h.astype(np.float64) / 4294967296.0


def value_noise(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1] on the unit lattice (C1 quintic interpolation).

    Parameters
    ----------
    x, y : array_like of float, same shape
        Lattice coordinates.
    seed : int
        Selects the random lattice values.

    Returns
    -------
    ndarray of float64, the shape of ``x``.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    sx = fx * fx * fx * (fx * (fx * 6 - 15) + 10)
    sy = fy * fy * fy * (fy * (fy * 6 - 15) + 10)
    ix, iy = x0.astype(np.int64), y0.astype(np.int64)
    v00 = _hash01(ix, iy, seed)
    v10 = _hash01(ix + 1, iy, seed)
    v01 = _hash01(ix, iy + 1, seed)
    v11 = _hash01(ix + 1, iy + 1, seed)
    a = v00 + (v10 - v00) * sx
    b = v01 + (v11 - v01) * sx
    return a + (b - a) * sy


def fbm(x: np.ndarray, y: np.ndarray, seed: int, *, octaves: int = 4,
        footprint: np.ndarray | float = 0.0) -> np.ndarray:
    """Fractal sum of value noise, zero mean, roughly in [-0.5, 0.5].

    Octave ``o`` has frequency ``2**o`` and amplitude ``0.5**o``; it is faded out where
    ``footprint`` (in lattice units) exceeds a quarter of its period.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    out = np.zeros(np.broadcast(x, y).shape)
    total = 0.0
    for o in range(octaves):
        f, a = 2.0 ** o, 0.5 ** o
        fade = np.clip(1.0 - 2.0 * (np.asarray(footprint) * f - 0.25), 0.0, 1.0)
        out += a * fade * (value_noise(x * f + 17.3 * o, y * f - 5.1 * o, seed + 101 * o) - 0.5)
        total += a
    return out / total


@dataclass(frozen=True)
class Texture:
    """A procedural albedo on 2D surface coordinates (metres).

    The pattern ``p`` = checker + stripes + noise (each weighted, each faded with the
    pixel footprint) mixes ``base`` into ``alt``; a finer grain scales the result.

    Attributes
    ----------
    base, alt : tuple of 3 floats
        The two colours, RGB in [0, 1].
    checker_period : float
        Side of a checker square in metres (0 disables it).
    checker_weight : float
    stripe_period : float
        Period of the stripes in metres (0 disables them).
    stripe_angle : float
        Direction of the stripes, radians.
    stripe_weight : float
    noise_period : float
        Lattice spacing of the coarsest noise octave, metres.
    noise_weight : float
    grain_period : float
        Lattice spacing of the brightness grain, metres.
    grain_weight : float
        Relative brightness variation of the grain.
    seed : int
    """

    base: tuple
    alt: tuple
    checker_period: float = 0.0
    checker_weight: float = 0.0
    stripe_period: float = 0.0
    stripe_angle: float = 0.0
    stripe_weight: float = 0.0
    noise_period: float = 0.2
    noise_weight: float = 0.5
    grain_period: float = 0.02
    grain_weight: float = 0.15
    seed: int = 0

    def __call__(self, uv: np.ndarray, footprint: np.ndarray | float = 0.0) -> np.ndarray:
        """Albedo at surface coordinates.

        Parameters
        ----------
        uv : (M, 2) array_like of float
            Surface coordinates in metres.
        footprint : (M,) array_like or float
            Size of the pixel on the surface, metres (anti-aliasing width).

        Returns
        -------
        (M, 3) float64 RGB in [0, 1].
        """
        uv = np.asarray(uv, dtype=np.float64)
        u, v = uv[:, 0], uv[:, 1]
        fp = np.broadcast_to(np.asarray(footprint, dtype=np.float64), u.shape)
        p = np.zeros_like(u)
        if self.checker_period > 0 and self.checker_weight > 0:
            P = self.checker_period
            c = np.sin(np.pi * u / P) * np.sin(np.pi * v / P)
            edge = np.maximum(np.pi * fp / P, 0.05)
            fade = np.clip(1.5 - 2.0 * fp / P, 0.0, 1.0)
            p += self.checker_weight * np.clip(c / edge, -1.0, 1.0) * fade
        if self.stripe_period > 0 and self.stripe_weight > 0:
            P = self.stripe_period
            w = u * np.cos(self.stripe_angle) + v * np.sin(self.stripe_angle)
            s = np.sin(2.0 * np.pi * w / P)
            edge = np.maximum(2.0 * np.pi * fp / P, 0.1)
            fade = np.clip(1.5 - 2.0 * fp / P, 0.0, 1.0)
            p += self.stripe_weight * np.clip(s / edge, -1.0, 1.0) * fade
        if self.noise_weight > 0:
            P = self.noise_period
            p += 2.0 * self.noise_weight * fbm(u / P, v / P, self.seed, footprint=fp / P)
        t = np.clip(0.5 + 0.5 * p, 0.0, 1.0)[:, None]
        rgb = (1.0 - t) * np.asarray(self.base) + t * np.asarray(self.alt)
        if self.grain_weight > 0:
            P = self.grain_period
            g = fbm(u / P, v / P, self.seed + 7919, octaves=2, footprint=fp / P)
            rgb = rgb * (1.0 + 2.0 * self.grain_weight * g)[:, None]
        return np.clip(rgb, 0.0, 1.0)


def _hsv(h: float, s: float, v: float) -> tuple:
    i = int(h * 6.0) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]


def random_texture(rng: np.random.Generator, *, scale: float = 1.0, saturation=(0.3, 0.8),
                   value=(0.35, 0.9), hue=None) -> Texture:
    """A random coloured texture whose detail is sized for an object of size ``scale`` (m).

    Parameters
    ----------
    rng : numpy.random.Generator
    scale : float
        Typical size of the surface; periods are drawn as fractions of it.
    saturation, value : (float, float)
        Ranges for the HSV saturation and value of the base colour.
    hue : float, optional
        Hue of the base colour in [0, 1); random when omitted.
    """
    h = rng.uniform() if hue is None else hue
    s = rng.uniform(*saturation)
    v = rng.uniform(*value)
    base = _hsv(h, s, v)
    h2 = (h + rng.uniform(0.08, 0.5)) % 1.0
    alt = _hsv(h2, rng.uniform(*saturation), rng.uniform(*value))
    kind = rng.integers(3)  # 0 checker-led, 1 stripe-led, 2 noise-led
    return Texture(
        base=tuple(float(c) for c in base), alt=tuple(float(c) for c in alt),
        checker_period=float(scale * rng.uniform(0.12, 0.3)),
        checker_weight=float(rng.uniform(0.5, 0.9) if kind == 0 else rng.uniform(0.0, 0.3)),
        stripe_period=float(scale * rng.uniform(0.08, 0.25)),
        stripe_angle=float(rng.uniform(0, np.pi)),
        stripe_weight=float(rng.uniform(0.5, 0.9) if kind == 1 else rng.uniform(0.0, 0.3)),
        noise_period=float(scale * rng.uniform(0.15, 0.4)),
        noise_weight=float(rng.uniform(0.5, 0.9) if kind == 2 else rng.uniform(0.15, 0.4)),
        grain_period=float(scale * rng.uniform(0.03, 0.06)),
        grain_weight=float(rng.uniform(0.08, 0.18)),
        seed=int(rng.integers(2**31 - 1)),
    )
