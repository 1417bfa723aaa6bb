"""The one interface of the rendering backends: result types, input checks, the tile grid.

Both backends (:mod:`clearsplat.render.native`, the CPU rasterizer, and
:mod:`clearsplat.render.gsplat`, gsplat on a CUDA GPU) return these types and check their
inputs with these functions, so a caller never sees which one rendered. Nothing here imports
a backend.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import SH_COUNTS, Gaussians, RenderSettings, Scene
from ._kernels import TILE

__all__ = ["TILE", "RenderResult", "Contributions", "TilePatch"]

_MAX_SIZE = 32767  # the pixel boxes are int16

class RenderResult(NamedTuple):
    """One rendered view.

    Attributes
    ----------
    rgb : (H, W, 3) float32
        ``sum c_i a_i T_i + T_final * background``.
    alpha : (H, W) float32
        ``1 - T_final``.
    depth : (H, W) float32
        Expected camera z, ``sum z_i a_i T_i / alpha``; 0 where alpha is 0.
    """

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


class Contributions(NamedTuple):
    """Blending weights the compositing added, ordered by pixel, then front to back.

    Attributes
    ----------
    pixel : (M,) int64
        Flat pixel index ``row * W + col``.
    gaussian : (M,) int64
        Index of the Gaussian in the scene.
    weight : (M,) float32
        ``alpha * T`` of that Gaussian at that pixel.
    """

    pixel: np.ndarray
    gaussian: np.ndarray
    weight: np.ndarray


class TilePatch(NamedTuple):
    """Re-composited tiles (pixels outside the image in border tiles are 0).

    Attributes
    ----------
    tiles : (T,) int32
        Tile ids ``tile_row * grid[1] + tile_col``, ascending.
    rgb : (T, 16, 16, 3) float32
    alpha : (T, 16, 16) float32
    depth : (T, 16, 16) float32
    """

    tiles: np.ndarray
    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


# -- input checks ----------------------------------------------------------------------------
def _gaussians(scene) -> Gaussians:
    if isinstance(scene, Scene):
        return scene.gaussians
    if isinstance(scene, Gaussians):
        return scene
    raise ClearsplatError(f"expected a Scene or Gaussians, got {type(scene).__name__}",
                          field="scene")


def _check_gaussians(g: Gaussians) -> None:
    """Shapes only (cheap); non-finite Gaussians are culled by the rasterizer."""
    n = len(g)
    for name, shape in (("means", (n, 3)), ("scales", (n, 3)), ("quats", (n, 4)),
                        ("opacities", (n,))):
        arr = np.asarray(getattr(g, name))
        if arr.shape != shape:
            raise ClearsplatError(f"expected shape {shape}, got {arr.shape}", field=name)
    sh = np.asarray(g.sh)
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3 or sh.shape[1] not in SH_COUNTS:
        raise ClearsplatError(f"expected shape ({n}, K, 3) with K in 1, 4, 9, 16, 25, got "
                              f"{sh.shape}", field="sh")
    if n >= 2**31 - 1:
        raise ClearsplatError(f"at most 2**31 - 2 Gaussians, got {n}", field="means")


def _check_settings(settings, scene) -> RenderSettings:
    """The settings to render with: ``settings``, else the scene's, else classic 3DGS."""
    if settings is None:
        return scene.render_settings if isinstance(scene, Scene) else RenderSettings()
    if not isinstance(settings, RenderSettings):
        raise ClearsplatError(f"expected RenderSettings, got {type(settings).__name__}",
                              field="settings")
    return settings


def sh_to_evaluate(g: Gaussians, settings: RenderSettings) -> np.ndarray:
    """The SH coefficients the renderer evaluates: ``g.sh`` cut to ``settings.sh_degree``."""
    d = settings.sh_degree
    if d is None or d >= g.sh_degree:
        return g.sh
    return g.sh[:, :(d + 1) ** 2]


def _check_camera(camera, field: str = "camera") -> Camera:
    if not isinstance(camera, Camera):
        raise ClearsplatError(f"expected a Camera, got {type(camera).__name__}", field=field)
    if camera.width > _MAX_SIZE or camera.height > _MAX_SIZE:
        raise ClearsplatError(f"image size {camera.width}x{camera.height} above {_MAX_SIZE}",
                              field=field)
    return camera


def _check_keep(keep, n: int, field: str = "keep") -> np.ndarray | None:
    if keep is None:
        return None
    keep = np.asarray(keep)
    if keep.dtype != np.bool_ or keep.shape != (n,):
        raise ClearsplatError(f"expected a ({n},) bool array, got {keep.dtype} {keep.shape}",
                              field=field)
    return np.ascontiguousarray(keep)



def _check_layers(layers, n: int) -> tuple[np.ndarray, int]:
    """``layers`` as (n,) int8 labels, each Gaussian's layer (-1: none), and the layer count.

    ``layers``: a sequence of disjoint (n,) bool masks (layer k: mask k), or an (n,) integer
    array of layer ids (-1: none; layers 0 to its largest id). At most 127 layers.
    """
    if isinstance(layers, np.ndarray) and layers.dtype != np.bool_:
        if not np.issubdtype(layers.dtype, np.integer) or layers.shape != (n,):
            raise ClearsplatError(f"expected an ({n},) int array of layer ids or a list of "
                                  f"(N,) bool masks, got {layers.dtype} {layers.shape}",
                                  field="layers")
        top = int(layers.max()) if n else -1
        if n and (top > 126 or int(layers.min()) < -1):
            raise ClearsplatError("layer ids must lie in -1..126 (at most 127 layers)",
                                  field="layers")
        return np.ascontiguousarray(layers, dtype=np.int8), top + 1
    masks = [_check_keep(m, n, f"layers[{k}]") for k, m in enumerate(layers)]
    if any(m is None for m in masks):
        raise ClearsplatError("expected (N,) bool masks, not None", field="layers")
    if len(masks) > 127:
        raise ClearsplatError(f"at most 127 layers, got {len(masks)}", field="layers")
    labels = np.full(n, -1, dtype=np.int8)
    for k, m in enumerate(masks):
        if len(masks) > 1 and (labels[m] >= 0).any():
            raise ClearsplatError("a Gaussian is in more than one layer", field="layers")
        labels[m] = k
    return labels, len(masks)


def _layer_masks(labels: np.ndarray, count: int) -> list:
    """The (n,) bool mask of each of ``count`` layers of :func:`_check_layers`' labels."""
    return [labels == k for k in range(count)]


def _check_near(near) -> float:
    near = float(near)
    if not (np.isfinite(near) and near > 0):
        raise ClearsplatError(f"expected a positive finite near plane, got {near}", field="near")
    return near


def _check_background(background) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float32)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)):
        raise ClearsplatError(f"expected 3 finite values, got {background!r}", field="background")
    return bg


def _check_indices(gaussians, n: int, field: str) -> np.ndarray:
    """Gaussian indices from an int index array or an (n,) bool mask, as int64."""
    a = np.asarray(gaussians)
    if a.dtype == np.bool_:
        if a.shape != (n,):
            raise ClearsplatError(f"expected a ({n},) bool mask, got shape {a.shape}", field=field)
        return np.flatnonzero(a)
    if a.size == 0:
        return np.empty(0, dtype=np.int64)
    if not np.issubdtype(a.dtype, np.integer) or a.ndim != 1:
        raise ClearsplatError(f"expected a 1-D int index array or bool mask, got {a.dtype} "
                              f"{a.shape}", field=field)
    if a.min() < 0 or a.max() >= n:
        raise ClearsplatError(f"Gaussian index out of range 0..{n - 1}", field=field)
    return a.astype(np.int64, copy=False)


# -- prepared view ---------------------------------------------------------------------------
class _TiledView:
    """The tile grid of a view's ``camera`` and the checks against it (shared by
    :class:`PreparedView` and the GPU views of ``clearsplat.render.gsplat``)."""

    tile_size = TILE
    camera: Camera

    @property
    def grid(self) -> tuple[int, int]:
        return (-(-self.camera.height // TILE), -(-self.camera.width // TILE))

    @property
    def num_tiles(self) -> int:
        rows, cols = self.grid
        return rows * cols

    def tile_pixels(self, tiles) -> tuple[np.ndarray, np.ndarray]:
        """Flat pixel indices of ``tiles`` in tile-major, row-major order, and which exist.

        Parameters
        ----------
        tiles : (T,) int
            Tile ids ``tile_row * grid[1] + tile_col``.

        Returns
        -------
        flat, inside : (T * 16 * 16,) int64 and bool
            ``flat`` is ``row * W + col``, 0 where the tile reaches past the image border
            (``inside`` False there).
        """
        t = self.tile_size
        height, width = self.camera.height, self.camera.width
        ty, tx = np.divmod(np.asarray(tiles).astype(np.int64), self.grid[1])
        yy, xx = np.mgrid[0:t, 0:t]
        rows = ty[:, None, None] * t + yy[None]
        cols = tx[:, None, None] * t + xx[None]
        inside = ((rows < height) & (cols < width)).ravel()
        flat = np.where(inside, (rows * width + cols).ravel(), 0)
        return flat, inside

    def render_layers(self, layers, *, tiles=None, background=(0.0, 0.0, 0.0)) -> list:
        """Each of ``layers`` rendered on its own: ``[self.render(keep=m) for m in layers]``,
        bit for bit, in fewer passes over the tile lists (two layers per
        :meth:`render_pair` here; the native view composites every layer in one pass).

        Parameters
        ----------
        layers : sequence of (N,) bool, or (N,) int
            Disjoint subsets of the Gaussians (at most 127): one mask per layer, or each
            Gaussian's layer id (-1: in none; layers 0 to the largest id).
        tiles : int array of tile ids, optional
            Only these tiles are asked for: the renders need be exact there alone (here they
            are whole renders; the native view composites only these tiles).
        background : 3 floats

        Returns
        -------
        list of RenderResult, one per layer
        """
        layers = _layer_masks(*_check_layers(layers, self.num_gaussians))
        out = []
        for k in range(0, len(layers) - 1, 2):
            out.extend(self.render_pair(keep=layers[k + 1], first=layers[k],
                                        background=background))
        if len(layers) % 2:
            out.append(self.render(keep=layers[-1], background=background))
        return out

    def _check_tiles(self, tiles, field: str = "tiles") -> np.ndarray:
        t = np.asarray(tiles)
        if t.size == 0:
            return np.empty(0, dtype=np.int32)
        if not np.issubdtype(t.dtype, np.integer) or t.ndim != 1:
            raise ClearsplatError(f"expected a 1-D int array of tile ids, got {t.dtype} {t.shape}",
                                  field=field)
        if t.min() < 0 or t.max() >= self.num_tiles:
            raise ClearsplatError(f"tile id out of range 0..{self.num_tiles - 1}", field=field)
        return np.unique(t).astype(np.int32)

    def _check_result(self, base, field: str = "base") -> RenderResult:
        h, w = self.camera.height, self.camera.width
        if not isinstance(base, RenderResult) or np.shape(base.rgb) != (h, w, 3) \
                or np.shape(base.alpha) != (h, w) or np.shape(base.depth) != (h, w):
            raise ClearsplatError(f"expected a RenderResult of a {w}x{h} view", field=field)
        return base
