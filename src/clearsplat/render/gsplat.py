"""Render on a CUDA GPU through gsplat, returning what the CPU rasterizer returns.

Two entry points, both calling ``gsplat.rasterization`` (nerfstudio-project/gsplat,
``gsplat/rendering.py``):

- :func:`render_gsplat`: one render of a scene (uploads the Gaussians every call).
- :func:`prepare_gsplat` / :func:`prepare_gsplat_views` -> :class:`GsplatView`: the GPU
  counterpart of :class:`clearsplat.render.native.PreparedView` for the filter. A scene's
  Gaussians are uploaded once (:func:`upload_gaussians` -> :class:`DeviceGaussians`) and shared by the views of
  all its cameras; every render takes a NumPy ``keep`` mask and returns NumPy arrays.

The call uses the clearsplat conventions, which are also gsplat's: world-to-camera view matrices
(``viewmats``), pixel intrinsics ``Ks``, OpenCV camera axes, quaternions ``w x y z`` (normalised
inside), linear scales, opacities in [0, 1], SH coefficients ``[N, K, 3]`` evaluated as
``max(0, SH(d) + 0.5)`` with ``d`` from the camera centre to the Gaussian, pixel centres at +0.5,
``packed=False``, ``render_mode="RGB+D"``; the scene's render settings give ``rasterize_mode``,
``eps2d``, ``radius_clip`` and ``sh_degree`` (see :mod:`clearsplat.render._gsplat_call` for the
gsplat versions supported and their batch dimensions).

Differences from the CPU path (:func:`clearsplat.render.render`), all small:

- gsplat adds the same ``eps2d`` 2D blur (and the same antialiasing compensation), but clamps the Jacobian per side of an off-centre
  principal point (``(W - cx) / fx + 0.3 tan_fov`` on one side, ``cx / fx + 0.3 tan_fov`` on the
  other) where the CPU path clamps ``x/z`` to ``1.3 W / (2 fx)`` on both sides: identical for a
  centred principal point.
- gsplat clamps alpha at 0.999 (the CPU path, like the original 3DGS code, at 0.99) and stops a
  pixel when the transmittance would reach 1e-4 (``<=``; the CPU path: drop below, ``<``). Only
  Gaussians with ``opacity * exp(..) > 0.99`` render differently.
- Screen extents: gsplat's box is ``ceil(e sqrt(Sigma2D_xx))`` by ``ceil(e sqrt(Sigma2D_yy))``
  with ``e = min(3.33, sqrt(2 ln(255 o)))`` (where alpha reaches 1/255), the CPU path's a
  square of ``ceil(3 sqrt(lambda_max))`` with a pixel-centre rule; the binning differs only
  where contributions are below 1/255, which both skip. So the visible sets differ at the image
  border, and :meth:`GsplatView.tiles_touched` is gsplat's own tile set, not the CPU one.
- Gaussians are sorted per tile by float depth on the GPU (a stable radix sort over the
  Gaussians in index order, so removing some never reorders the rest, as on the CPU). Sums run
  in float32 in another order: expect differences around 1e-5, not bit equality.
- Depth: gsplat's ``"RGB+D"`` accumulates ``sum z_i a_i T_i``; it is divided by alpha here (0
  where alpha is 0), matching the CPU path's expected depth. The background goes in through
  gsplat's ``backgrounds`` (``rgb + T_final * background``, as on the CPU; zero for the depth
  channel).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, RenderSettings, Scene
from ._gsplat_call import batch_layout, import_gsplat, rasterize, tensor
from .base import (TILE, Contributions, RenderResult, _check_background, _check_camera,
                   _check_gaussians, _check_indices, _check_keep, _check_layers, _check_near,
                   _check_settings, _gaussians, _layer_masks, _TiledView)
from .native import PreparedView, check_threads, prepare_view

__all__ = ["render_gsplat", "upload_gaussians", "DeviceGaussians", "GsplatView",
           "prepare_gsplat", "prepare_gsplat_views"]

#: Device memory one batched call of :meth:`GsplatView.render_many` may use for the per-render
#: copies gsplat makes (its batch dimensions need contiguous ``[B, N, ...]`` inputs).
_BATCH_BYTES = 1 << 30


def _results(colors, alphas, height: int, width: int) -> list[RenderResult]:
    """RenderResults from gsplat's ``[..., H, W, 4]`` colours (RGB + accumulated depth) and
    ``[..., H, W, 1]`` alphas."""
    colors = colors.detach().reshape(-1, height, width, 4).cpu().numpy()
    alphas = alphas.detach().reshape(-1, height, width).cpu().numpy()
    out = []
    for c, a in zip(colors, alphas):
        alpha = np.array(a, dtype=np.float32, order="C")
        depth = np.zeros((height, width), dtype=np.float32)
        np.divide(c[..., 3], alpha, out=depth, where=alpha > 0)
        out.append(RenderResult(np.array(c[..., :3], dtype=np.float32, order="C"), alpha, depth))
    return out


def _background_result(bg: np.ndarray, height: int, width: int) -> RenderResult:
    """The render of no Gaussian."""
    zeros = np.zeros((height, width), np.float32)
    return RenderResult(np.broadcast_to(bg, (height, width, 3)).astype(np.float32), zeros,
                        zeros.copy())


def render_gsplat(scene, camera: Camera, *, keep=None, background=(0.0, 0.0, 0.0),
                  near: float = 0.01, device: str = "cuda",
                  settings: RenderSettings | None = None) -> RenderResult:
    """Render a scene from a camera with gsplat on a GPU.

    Parameters
    ----------
    scene : Scene or Gaussians
    camera : Camera
    keep : (N,) bool, optional
        Render only these Gaussians.
    background : 3 floats
        RGB behind the Gaussians.
    near : float
        Near plane (gsplat's ``near_plane``).
    device : str
        Torch device, ``"cuda"`` or ``"cuda:1"``...
    settings : RenderSettings, optional
        By default the scene's (classic 3DGS for Gaussians).

    Returns
    -------
    RenderResult
        ``rgb`` (H, W, 3), ``alpha`` (H, W), ``depth`` (H, W) float32 NumPy arrays, as from
        :func:`clearsplat.render.render`.

    Raises
    ------
    ImportError
        Without PyTorch, gsplat or a CUDA GPU (the message says what to install).
    ClearsplatError
        Bad ``keep``, ``background`` or ``camera``.
    """
    settings = _check_settings(settings, scene)
    g = scene.gaussians if isinstance(scene, Scene) else scene
    if not isinstance(g, Gaussians):
        raise ClearsplatError(f"expected a Scene or Gaussians, got {type(scene).__name__}",
                              field="scene")
    if not isinstance(camera, Camera):
        raise ClearsplatError(f"expected a Camera, got {type(camera).__name__}", field="camera")
    bg = np.asarray(background, dtype=np.float32)
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise ClearsplatError(f"expected 3 finite values, got {background!r}",
                              field="background")
    n = len(g)
    if keep is not None:
        keep = np.asarray(keep)
        if keep.shape != (n,) or keep.dtype != bool:
            raise ClearsplatError(f"expected ({n},) bool, got {keep.shape} {keep.dtype}",
                                  field="keep")
        g = g.subset(keep)
    torch, rasterization = import_gsplat(device)
    h, w = camera.height, camera.width
    if len(g) == 0:
        return _background_result(bg, h, w)

    def t(a):
        return tensor(torch, a, device)

    colors, alphas, _ = rasterize(
        torch, rasterization, means=t(g.means), quats=t(g.quats), scales=t(g.scales),
        opacities=t(g.opacities), sh=t(g.sh), viewmats=t(camera.world_to_camera)[None],
        Ks=t(camera.K)[None], width=w, height=h, near=near, backgrounds=t(bg)[None],
        settings=settings)
    return _results(colors, alphas, h, w)[0]


# -- uploaded Gaussians ----------------------------------------------------------------------
class DeviceGaussians:
    """A scene's Gaussians as float32 torch tensors on one device, uploaded once.

    Made by :func:`upload_gaussians`; pass it to :func:`prepare_gsplat` for every camera so
    the views share one copy (the tensors are only read, never modified).

    Attributes
    ----------
    gaussians : Gaussians
        The host Gaussians (not copied; used for :meth:`GsplatView.contributions`).
    device : str
        The torch device.
    num_gaussians : int
    sh_degree : int
    settings : RenderSettings
        How every view of these Gaussians renders (the scene's by default).
    means, quats, scales : torch.Tensor
        (N, 3), (N, 4), (N, 3) float32.
    opacities : torch.Tensor
        (N,) float32.
    sh : torch.Tensor
        (N, K, 3) float32.
    memory_bytes : int
        Device bytes held.
    """

    def __init__(self, gaussians: Gaussians, *, device: str, torch, rasterization,
                 settings: RenderSettings | None = None):
        self.gaussians = gaussians
        self.settings = RenderSettings() if settings is None else settings
        self.device = str(device)
        self.num_gaussians = len(gaussians)
        self.sh_degree = gaussians.sh_degree
        self._torch, self._rasterization = torch, rasterization
        self.means = tensor(torch, gaussians.means, device)
        self.quats = tensor(torch, gaussians.quats, device)
        self.scales = tensor(torch, gaussians.scales, device)
        self.opacities = tensor(torch, gaussians.opacities, device)
        self.sh = tensor(torch, gaussians.sh, device)

    @property
    def memory_bytes(self) -> int:
        return int(sum(t.numel() * t.element_size()
                       for t in (self.means, self.quats, self.scales, self.opacities, self.sh)))

    def __repr__(self) -> str:
        return (f"DeviceGaussians({self.num_gaussians} Gaussians on {self.device}, "
                f"{self.memory_bytes / 2**20:.1f} MiB)")


def upload_gaussians(scene, *, device: str = "cuda",
                     settings: RenderSettings | None = None) -> DeviceGaussians:
    """Upload a scene's Gaussians to a torch device once, for :func:`prepare_gsplat`.

    Parameters
    ----------
    scene : Scene or Gaussians
    device : str
        Torch device, ``"cuda"``, ``"cuda:1"``... (gsplat renders on CUDA only).
    settings : RenderSettings, optional
        By default the scene's (classic 3DGS for Gaussians).

    Returns
    -------
    DeviceGaussians

    Raises
    ------
    ImportError
        Without PyTorch, gsplat or (for a CUDA device) a CUDA GPU.
    ClearsplatError
        Malformed Gaussians or an unknown device.
    """
    g = _gaussians(scene)
    _check_gaussians(g)
    settings = _check_settings(settings, scene)
    if not isinstance(device, str):
        raise ClearsplatError(f"expected a torch device name, got {device!r}", field="device")
    torch, rasterization = import_gsplat(device)
    try:
        torch.device(device)
    except (RuntimeError, ValueError) as e:
        raise ClearsplatError(f"not a torch device: {device!r} ({e})", field="device") from None
    return DeviceGaussians(g, device=device, torch=torch, rasterization=rasterization,
                           settings=settings)


# -- prepared GPU view -----------------------------------------------------------------------
class GsplatView(_TiledView):
    """One camera rendered through gsplat: the GPU counterpart of ``PreparedView``.

    Made by :func:`prepare_gsplat` or :func:`prepare_gsplat_views`. Implements what
    ``filter_distractors`` uses of :class:`clearsplat.render.native.PreparedView`, with the same
    signatures, shapes and dtypes (NumPy in, NumPy out): :meth:`render`, :meth:`render_pair`,
    :meth:`rerender`, :meth:`tiles_touched`, :meth:`centres_inside`, :meth:`contributions`,
    and ``camera``, ``num_gaussians``, ``num_visible``, ``grid``, ``num_tiles``, ``tile_size``.
    Not implemented: ``rerender_tiles``, ``gather``, ``scatter`` (verification on the GPU runs
    full re-renders, ``incremental=False``).

    Removal sets the opacity of the removed Gaussians to 0 on the device: gsplat culls
    Gaussians below opacity 1/255 in its projection and skips contributions with alpha below
    1/255, so that equals rendering the subset, and the order of the others does not change.
    Every render is a full render, exact everywhere; ``tiles`` only says which pixels come from
    it and which from ``start``/``base``, as in ``PreparedView``.

    The projection of the whole scene (gsplat's ``means2d`` and ``radii``) is kept on the host
    from the first render of all Gaussians (made on demand): per visible Gaussian its index, its
    tile range and whether its centre is inside the image, 13 bytes.

    Attributes
    ----------
    camera : Camera
    gaussians : DeviceGaussians
        The uploaded Gaussians (shared with the other views of the scene).
    near : float
    tile_size : int
        16.
    grid : (int, int)
        Rows and columns of tiles, as in ``PreparedView``.
    num_gaussians : int
    num_visible : int
        Gaussians with a positive radius in gsplat's projection of the whole scene: in front of
        the near plane, opacity at least 1/255, box overlapping the image (gsplat's culling; the
        CPU path's differs at the image border).
    """

    def __init__(self, gaussians: DeviceGaussians, camera: Camera, *, near: float):
        self.gaussians = gaussians
        self.camera = camera
        self.near = float(near)
        torch, dev = gaussians._torch, gaussians.device
        self._viewmat = tensor(torch, camera.world_to_camera, dev)[None]   # (1, 4, 4)
        self._K = tensor(torch, camera.K, dev)[None]                       # (1, 3, 3)
        self._index = None    # (V,) int32 visible Gaussians, ascending
        self._rects = None    # (V, 4) uint16 tile range [x0, x1) x [y0, y1) as x0, y0, x1, y1
        self._inside = None   # (V,) bool centre inside the image
        self._cpu = None      # PreparedView for contributions(), built on demand

    # -- properties ------------------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        return self.gaussians.num_gaussians

    @property
    def num_visible(self) -> int:
        self._projection()
        return int(self._index.shape[0])

    @property
    def memory_bytes(self) -> int:
        """Host bytes held by this view (the shared device Gaussians not counted)."""
        arrays = [a for a in (self._index, self._rects, self._inside) if a is not None]
        total = sum(a.nbytes for a in arrays)
        return int(total + (self._cpu.memory_bytes if self._cpu is not None else 0))

    def __repr__(self) -> str:
        vis = "?" if self._index is None else str(self.num_visible)
        return (f"GsplatView({self.camera.width}x{self.camera.height} on "
                f"{self.gaussians.device}, {vis} of {self.num_gaussians} Gaussians visible)")

    # -- projection ------------------------------------------------------------------------
    def _projection(self) -> None:
        """Make sure the projection of all Gaussians is known (one render if not)."""
        if self._index is None:
            self._render_keeps([None], np.zeros(3, np.float32))

    def _store_projection(self, means2d: np.ndarray, radii: np.ndarray) -> None:
        """Keep gsplat's projection of all Gaussians: visible ids, tile ranges, centres inside.

        The tile range is gsplat's intersection rule (``isect_tiles``), in float32 as on the
        GPU: columns ``[floor(u/16 - rx/16), ceil(u/16 + rx/16))`` clamped to the grid, the
        same for rows. These are exactly the tiles whose lists hold the Gaussian.
        """
        radii = np.asarray(radii)
        if radii.ndim == 1:                       # gsplat < 1.5: one radius per Gaussian
            radii = np.stack([radii, radii], axis=-1)
        index = np.flatnonzero((radii > 0).all(axis=-1)).astype(np.int32)
        m = np.asarray(means2d, dtype=np.float32)[index]
        r = radii[index].astype(np.float32)
        rows, cols = self.grid
        t = np.float32(TILE)
        lo = np.floor(m / t - r / t)
        hi = np.ceil(m / t + r / t)
        limit = np.array([cols, rows], dtype=np.float32)
        lo = np.clip(lo, 0, limit)
        hi = np.clip(hi, 0, limit)
        self._rects = np.concatenate([lo, hi], axis=1).astype(np.uint16)
        w, h = self.camera.width, self.camera.height
        self._inside = (m[:, 0] >= 0) & (m[:, 0] < w) & (m[:, 1] >= 0) & (m[:, 1] < h)
        self._index = index

    def centres_inside(self) -> np.ndarray:
        """(N,) bool: the visible Gaussians whose projected centre lies inside the image.

        As ``PreparedView.centres_inside``, with gsplat's projection and culling.
        """
        self._projection()
        out = np.zeros(self.num_gaussians, dtype=bool)
        out[self._index[self._inside]] = True
        return out

    def tiles_touched(self, gaussians) -> np.ndarray:
        """Tiles whose gsplat lists hold any of ``gaussians``: the only tiles their removal can
        change.

        Parameters
        ----------
        gaussians : int array of Gaussian indices, or (N,) bool mask
            Gaussians not visible in this view touch nothing.

        Returns
        -------
        (T,) int32 sorted unique tile ids. gsplat's boxes are not the CPU path's, so the set
        differs from ``PreparedView.tiles_touched`` at the edges of footprints; it is exact for
        the renders of this view.
        """
        a = np.asarray(gaussians)
        n = self.num_gaussians
        if a.dtype == np.bool_:
            if a.shape != (n,):
                raise ClearsplatError(f"expected a ({n},) bool mask, got shape {a.shape}",
                                      field="gaussians")
            mask = a
        else:
            mask = np.zeros(n, dtype=bool)
            mask[_check_indices(a, n, "gaussians")] = True
        self._projection()
        rects = self._rects[np.take(mask, self._index)].astype(np.int64)
        rows, cols = self.grid
        x0, y0, x1, y1 = rects.T
        ok = (x1 > x0) & (y1 > y0)
        x0, y0, x1, y1 = x0[ok], y0[ok], x1[ok], y1[ok]
        # Each box adds +1 inside it through the corners of a 2D difference array, summed up.
        stride = cols + 1
        corners = np.concatenate([y0 * stride + x0, y0 * stride + x1, y1 * stride + x0,
                                  y1 * stride + x1])
        signs = np.repeat(np.array([1.0, -1.0, -1.0, 1.0]), x0.size)
        acc = np.bincount(corners, weights=signs, minlength=(rows + 1) * stride)
        cover = acc.reshape(rows + 1, stride).cumsum(axis=0).cumsum(axis=1)[:rows, :cols]
        return np.flatnonzero(cover.ravel() > 0.5).astype(np.int32)

    # -- checks ----------------------------------------------------------------------------
    def _tile_pixels(self, tiles: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels of ``tiles``."""
        rows, cols = self.grid
        on = np.zeros(rows * cols, dtype=bool)
        on[tiles] = True
        on = on.reshape(rows, cols).repeat(TILE, axis=0).repeat(TILE, axis=1)
        return on[:self.camera.height, :self.camera.width]

    def _paste(self, start: RenderResult | None, full: RenderResult, pixels: np.ndarray
               ) -> RenderResult:
        """``full`` at ``pixels``, ``start`` (zeros without it) elsewhere."""
        if start is None:
            return RenderResult(np.where(pixels[..., None], full.rgb, np.float32(0)),
                                np.where(pixels, full.alpha, np.float32(0)),
                                np.where(pixels, full.depth, np.float32(0)))
        return RenderResult(
            np.where(pixels[..., None], full.rgb, start.rgb).astype(np.float32),
            np.where(pixels, full.alpha, start.alpha).astype(np.float32),
            np.where(pixels, full.depth, start.depth).astype(np.float32))

    @staticmethod
    def _copy(r: RenderResult | None, h: int, w: int) -> RenderResult:
        if r is None:
            return RenderResult(np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32),
                                np.zeros((h, w), np.float32))
        return RenderResult(*(np.array(a, dtype=np.float32, order="C", copy=True) for a in r))

    # -- rendering -------------------------------------------------------------------------
    def _batch_size(self, batch_size, count: int) -> int:
        if batch_size is None:
            k = self.gaussians.sh.shape[1]
            # gsplat copies means, quats, scales, opacities, SH and SH directions per batch
            # element and keeps projected means, radii, depths, conics, colours per element.
            per = max(1, self.num_gaussians) * (160 + 12 * k)
            return int(max(1, min(count, _BATCH_BYTES // per)))
        if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) \
                or batch_size < 1:
            raise ClearsplatError(f"expected a positive int, got {batch_size!r}",
                                  field="batch_size")
        return int(batch_size)

    def _render_keeps(self, keeps: list, bg: np.ndarray, batch_size: int | None = None
                      ) -> list[RenderResult]:
        """Render checked keep masks (None: all), ``batch_size`` per gsplat call."""
        h, w = self.camera.height, self.camera.width
        n = self.num_gaussians
        out: list = [None] * len(keeps)
        todo = []
        for i, k in enumerate(keeps):
            if k is not None and k.all():
                k = None                  # the same opacities: its meta is the projection
            if n == 0 or (k is not None and not k.any()):
                out[i] = _background_result(bg, h, w)
                if n == 0 and self._index is None:
                    self._store_projection(np.zeros((0, 2), np.float32),
                                           np.zeros((0, 2), np.int32))
            else:
                todo.append((i, k))
        step = self._batch_size(batch_size, len(todo))
        for s in range(0, len(todo), step):
            chunk = todo[s:s + step]
            for (i, _), r in zip(chunk, self._raster([k for _, k in chunk], bg)):
                out[i] = r
        return out

    def _raster(self, keeps: list, bg: np.ndarray) -> list[RenderResult]:
        """One gsplat call for ``keeps`` (None: all), batched over a leading dimension; one call
        per keep where the installed gsplat has no batch dimensions."""
        d = self.gaussians
        torch, dev = d._torch, d.device
        b = len(keeps)
        layout = batch_layout(torch, d._rasterization, dev) if b > 1 else None
        if b > 1 and layout is None:
            return [r for k in keeps for r in self._raster([k], bg)]
        bgt = tensor(torch, bg, dev)[None]                         # (1, 3)

        def opacities(k):
            if k is None:
                return d.opacities
            return d.opacities * torch.from_numpy(np.array(k, dtype=bool)).to(dev)

        if b == 1:
            args = dict(means=d.means, quats=d.quats, scales=d.scales,
                        opacities=opacities(keeps[0]), sh=d.sh, viewmats=self._viewmat,
                        Ks=self._K, backgrounds=bgt)
        else:
            n = d.num_gaussians
            args = dict(means=d.means.expand(b, n, 3), quats=d.quats.expand(b, n, 4),
                        scales=d.scales.expand(b, n, 3),
                        opacities=torch.stack([opacities(k) for k in keeps]),
                        sh=d.sh if layout == "shared_sh" else d.sh.expand(b, *d.sh.shape),
                        viewmats=self._viewmat.expand(b, 1, 4, 4), Ks=self._K.expand(b, 1, 3, 3),
                        backgrounds=bgt.expand(b, 1, 3))
        colors, alphas, meta = rasterize(
            torch, d._rasterization, width=self.camera.width, height=self.camera.height,
            near=self.near, settings=d.settings, **args)
        if self._index is None and any(k is None for k in keeps):
            # gsplat >= 1.5 gives radii per axis ([..., C, N, 2]), older versions [..., C, N].
            n = d.num_gaussians
            radii, means2d = meta["radii"].detach(), meta["means2d"].detach()
            if b > 1:
                j = [k is None for k in keeps].index(True)
                radii, means2d = radii[j], means2d[j]
            per_axis = radii.ndim == means2d.ndim
            radii = radii.reshape(n, 2) if per_axis else radii.reshape(n)
            self._store_projection(means2d.reshape(n, 2).cpu().numpy(), radii.cpu().numpy())
        return _results(colors, alphas, self.camera.height, self.camera.width)

    def render(self, *, keep=None, background=(0.0, 0.0, 0.0)) -> RenderResult:
        """Render the view, optionally only the Gaussians where ``keep`` is True.

        Parameters
        ----------
        keep : (N,) bool, optional
            Gaussians to render (all by default); the others get opacity 0 on the device.
        background : 3 floats
            Colour behind the Gaussians.

        Returns
        -------
        RenderResult
            ``rgb`` (H, W, 3), ``alpha`` (H, W), ``depth`` (H, W), float32 NumPy arrays.
        """
        keep = _check_keep(keep, self.num_gaussians)
        bg = _check_background(background)
        return self._render_keeps([keep], bg)[0]

    def render_many(self, keeps: Sequence, *, background=(0.0, 0.0, 0.0),
                    batch_size: int | None = None) -> list[RenderResult]:
        """Render several subsets of this view; equal to calling :meth:`render` for each.

        Batches go through gsplat's leading batch dimension (one call per batch) where the
        installed gsplat has one (1.5.3 and later; earlier versions get one call per render).
        gsplat makes contiguous per-element copies of the Gaussians for it, so the default
        batch size keeps those under 1 GiB (about ``N * (160 + 12 K)`` bytes an element); for
        a large scene it is 1, a plain loop.

        Parameters
        ----------
        keeps : sequence of ((N,) bool or None)
        background : 3 floats
        batch_size : int, optional
            Renders per gsplat call (1: one call each).

        Returns
        -------
        list of RenderResult, one per keep.
        """
        keeps = [_check_keep(k, self.num_gaussians, f"keeps[{i}]") for i, k in enumerate(keeps)]
        bg = _check_background(background)
        return self._render_keeps(keeps, bg, batch_size)

    def render_layers(self, layers, *, tiles=None,
                      background=(0.0, 0.0, 0.0)) -> list[RenderResult]:
        """Each of ``layers`` (disjoint: (N,) bool masks, or (N,) int layer ids with -1 for
        none; at most 127) rendered on its own: one :meth:`render_many`, whole renders (so
        exact in any ``tiles`` asked for)."""
        return self.render_many(_layer_masks(*_check_layers(layers, self.num_gaussians)),
                                background=background)

    def render_pair(self, *, keep, first=None, tiles=None, start: RenderResult | None = None,
                    background=(0.0, 0.0, 0.0)) -> tuple[RenderResult, RenderResult]:
        """The renders with ``first`` (all Gaussians when None) and with ``keep``.

        Same results as ``PreparedView.render_pair``: both are full renders (one batched gsplat
        call when it fits, see :meth:`render_many`); with ``tiles``, the pixels outside those
        tiles hold ``start``'s values (zeros without ``start``), as on the CPU, although the
        renders are exact there too.

        Parameters
        ----------
        keep : (N,) bool
        first : (N,) bool, optional
        tiles : int array of tile ids, optional
        start : RenderResult, optional
        background : 3 floats

        Returns
        -------
        (RenderResult, RenderResult)
        """
        n = self.num_gaussians
        keep = _check_keep(keep, n)
        if keep is None:
            raise ClearsplatError("expected an (N,) bool mask", field="keep")
        first = _check_keep(first, n, "first")
        bg = _check_background(background)
        tiles = None if tiles is None else self._check_tiles(tiles)
        start = None if start is None else self._check_result(start, "start")
        h, w = self.camera.height, self.camera.width
        if tiles is not None and tiles.size == 0:
            return self._copy(start, h, w), self._copy(start, h, w)
        a, b = self._render_keeps([first, keep], bg)
        if tiles is None:
            return a, b
        pixels = self._tile_pixels(tiles)
        return self._paste(start, a, pixels), self._paste(start, b, pixels)

    def rerender(self, base: RenderResult, *, keep, tiles=None,
                 background=(0.0, 0.0, 0.0)) -> RenderResult:
        """A copy of ``base`` with the pixels of ``tiles`` from a render with ``keep``.

        A full render on the GPU; with ``tiles`` None it is returned as it is (``base`` is only
        checked), otherwise pasted into ``base`` at those tiles as ``PreparedView.rerender``
        does. Equals ``render(keep=keep)`` when ``tiles`` covers :meth:`tiles_touched` of every
        Gaussian whose keep differs from ``base``'s.

        Parameters
        ----------
        base : RenderResult
            A render of this view (with the same ``background``).
        keep : (N,) bool or None
        tiles : int array of tile ids, optional
        background : 3 floats

        Returns
        -------
        RenderResult
        """
        base = self._check_result(base, "base")
        keep = _check_keep(keep, self.num_gaussians)
        tiles = None if tiles is None else self._check_tiles(tiles)
        bg = _check_background(background)
        h, w = self.camera.height, self.camera.width
        if tiles is not None and tiles.size == 0:
            return self._copy(base, h, w)
        full = self._render_keeps([keep], bg)[0]
        if tiles is None:
            return full
        return self._paste(base, full, self._tile_pixels(tiles))

    def contributions(self, mask, *, keep=None) -> Contributions:
        """Every ``(pixel, gaussian, alpha * T)`` the compositing adds where ``mask`` is True.

        gsplat does not expose per-pixel contribution lists, so this runs on the CPU: the first
        call prepares this camera with :func:`clearsplat.render.prepare` (projection, binning
        and sort of the host Gaussians, about the cost of one CPU render, and the memory of a
        ``PreparedView``), kept for later calls. The weights are the CPU rasterizer's.

        Parameters
        ----------
        mask : (H, W) bool
        keep : (N,) bool, optional

        Returns
        -------
        Contributions, ordered by pixel, then front to back.
        """
        return self._cpu_view().contributions(mask, keep=keep)

    def _cpu_view(self) -> PreparedView:
        if self._cpu is None:
            self._cpu = prepare_view(self.gaussians.gaussians, self.camera, None, self.near,
                                     check_threads(None), self.gaussians.settings)
        return self._cpu


def prepare_gsplat(scene, camera: Camera, *, near: float = 0.01, device: str | None = None
                   ) -> GsplatView:
    """A camera of a scene ready for repeated subset renders through gsplat.

    Parameters
    ----------
    scene : Scene, Gaussians or DeviceGaussians
        A :class:`DeviceGaussians` (from :func:`upload_gaussians`) is used as it is, so views of
        one scene share one upload; a Scene or Gaussians is uploaded for this view alone.
    camera : Camera
    near : float
        Near plane (gsplat's ``near_plane``).
    device : str, optional
        Torch device for a Scene or Gaussians (``"cuda"`` by default); with a DeviceGaussians
        leave it None (or give its own device).

    Returns
    -------
    GsplatView

    Raises
    ------
    ImportError
        Without PyTorch, gsplat or a CUDA GPU (the message says what to install).
    ClearsplatError
        Bad ``camera``, ``near``, Gaussians or ``device``.
    """
    camera = _check_camera(camera)
    near = _check_near(near)
    if isinstance(scene, DeviceGaussians):
        if device is not None and str(device) != scene.device:
            raise ClearsplatError(f"the Gaussians are on {scene.device!r}, not {device!r}",
                                  field="device")
        uploaded = scene
    else:
        uploaded = upload_gaussians(scene, device="cuda" if device is None else device)
    return GsplatView(uploaded, camera, near=near)


def prepare_gsplat_views(scene, cameras: Sequence[Camera], *, near: float = 0.01,
                         device: str | None = None) -> list[GsplatView]:
    """One :class:`GsplatView` per camera, all sharing one upload of the Gaussians.

    Parameters
    ----------
    scene : Scene, Gaussians or DeviceGaussians
    cameras : sequence of Camera
    near : float
    device : str, optional
        As in :func:`prepare_gsplat`.

    Returns
    -------
    list of GsplatView
    """
    cameras = [_check_camera(c, f"cameras[{i}]") for i, c in enumerate(cameras)]
    near = _check_near(near)
    if not isinstance(scene, DeviceGaussians):
        scene = upload_gaussians(scene, device="cuda" if device is None else device)
    return [prepare_gsplat(scene, c, near=near, device=device) for c in cameras]
