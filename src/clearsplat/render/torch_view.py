"""The native rasterizer's prepared views in torch, on any torch device (``cpu``, ``cuda``).

:class:`TorchView` implements the methods of :class:`clearsplat.render.native.PreparedView`
that the filter's stages use, with the same signatures, results and checks (NumPy in, NumPy
out; keep masks may also be torch bool tensors): :meth:`~TorchView.render`,
:meth:`~TorchView.render_pair`, :meth:`~TorchView.rerender`, :meth:`~TorchView.rerender_tiles`,
:meth:`~TorchView.tiles_touched`, :meth:`~TorchView.centres_inside`,
:meth:`~TorchView.tile_pixels`, :meth:`~TorchView.contributions`, and ``camera``,
``tile_size``, ``grid``, ``num_visible``, ``visible``. Not implemented: ``pruned``, ``restrict``,
``subset``, ``gather``, ``scatter`` (the torch backend neither prunes nor hands views on).

A scene's Gaussians are uploaded once (:func:`upload_torch`, :class:`TorchGaussians`) and
shared by the views of its cameras; each view projects, sorts and bins them once, in torch
(:mod:`clearsplat.render._torch_raster`), and composites any batch of (tile, keep, removal)
tasks in a fixed number of torch calls (:mod:`clearsplat.render._torch_composite`): all the
removals of :meth:`~TorchView.rerender_tiles` go through one batch. The math is the CPU
rasterizer's (``docs/conventions.md``, "Rasterization"): the visible sets, boxes, tiles and
depth order are equal; colours, alpha and depth agree to float32 rounding (the products and
sums run in another order).

Needs PyTorch (``pip install clearsplat[gpu]``); imported lazily.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import RenderSettings
from . import _torch_composite as tc
from . import _torch_raster as tr
from .base import (TILE, Contributions, RenderResult, TilePatch, _check_background,
                   _check_camera, _check_gaussians, _check_indices, _check_keep, _check_near,
                   _check_settings, _gaussians, _TiledView, sh_to_evaluate)

__all__ = ["import_torch", "TorchGaussians", "upload_torch", "TorchView", "prepare_torch",
           "prepare_torch_views"]

_PIX = TILE * TILE


def import_torch(device="cpu"):
    """The torch module, or ImportError saying what to install."""
    try:
        import torch
    except ImportError as e:
        raise ImportError("clearsplat's torch backend needs PyTorch: pip install "
                          f"clearsplat[gpu] ({e})") from None
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        raise ImportError("clearsplat's torch backend on a CUDA device needs PyTorch with CUDA "
                          "and a GPU: torch.cuda.is_available() is False")
    return torch


class TorchGaussians:
    """A scene's Gaussians as float32 tensors on one torch device, uploaded once.

    Attributes
    ----------
    device : torch.device
    num_gaussians : int
    settings : RenderSettings
    means, scales, quats, opacities, sh : torch.Tensor
        (N, 3), (N, 3), (N, 4), (N,), (N, K, 3) float32 (SH cut to ``settings.sh_degree``).
    """

    def __init__(self, torch, device, *, means, scales, quats, opacities, sh,
                 settings: RenderSettings):
        self.torch, self.device, self.settings = torch, device, settings
        self.means, self.scales, self.quats = means, scales, quats
        self.opacities, self.sh = opacities, sh
        self.num_gaussians = int(means.shape[0])

    def __repr__(self) -> str:
        return f"TorchGaussians({self.num_gaussians} Gaussians on {self.device})"


def _tensor(torch, a, device):
    if isinstance(a, torch.Tensor):
        return a.detach().to(device=device, dtype=torch.float32).contiguous()
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not a.flags.writeable:       # torch.from_numpy warns on read-only arrays
        a = a.copy()
    return torch.from_numpy(a).to(device)


def upload_torch(scene, *, device="cpu", settings: RenderSettings | None = None
                 ) -> TorchGaussians:
    """Upload a scene's Gaussians to a torch device once (no copy on the CPU).

    Parameters
    ----------
    scene : Scene or Gaussians
    device : str or torch.device
    settings : RenderSettings, optional
        By default the scene's (classic 3DGS for Gaussians).

    Returns
    -------
    TorchGaussians
    """
    g = _gaussians(scene)
    _check_gaussians(g)
    settings = _check_settings(settings, scene)
    torch = import_torch(device)
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError) as e:
        raise ClearsplatError(f"not a torch device: {device!r} ({e})", field="device") from None
    t = {name: _tensor(torch, getattr(g, name), dev)
         for name in ("means", "scales", "quats", "opacities")}
    return TorchGaussians(torch, dev, sh=_tensor(torch, sh_to_evaluate(g, settings), dev),
                          settings=settings, **t)


class TorchView(_TiledView):
    """One camera projected, sorted and binned in torch: the twin of ``PreparedView``.

    Made by :func:`prepare_torch` or :func:`prepare_torch_views`; see the module docstring.

    Attributes
    ----------
    camera : Camera
    gaussians : TorchGaussians
    tile_size : int
        16.
    grid : (int, int)
        Rows and columns of tiles.
    num_gaussians, num_visible : int
    visible : (V,) int64
        Visible Gaussians, front to back (NumPy).
    """

    def __init__(self, gaussians: TorchGaussians, camera: Camera, *, near: float, keep=None):
        torch = gaussians.torch
        self._torch, self.gaussians, self.camera = torch, gaussians, camera
        self.num_gaussians = gaussians.num_gaussians
        rec, box, rect, index = tr.project(torch, gaussians, camera, near=near,
                                           settings=gaussians.settings, keep=keep)
        rows, cols = self.grid
        offsets, lists = tr.bin_tiles(torch, rect, rows, cols)
        self._t = tc.ViewTensors(rec[:, :6].contiguous(), rec[:, 6:].contiguous(), box, offsets,
                                 lists, camera.width, camera.height, cols)
        self._rect, self._index = rect, index
        self.visible = index.cpu().numpy()
        self._vid = None            # (N,) int64 Gaussian -> visible id or -1, on demand

    @property
    def num_visible(self) -> int:
        return int(self.visible.shape[0])

    @property
    def device(self):
        return self.gaussians.device

    @property
    def memory_bytes(self) -> int:
        """Bytes of this view's tensors and arrays (the shared Gaussians not counted)."""
        ts = [*self._t[:5], self._rect, self._index] + ([self._vid] if self._vid is not None
                                                         else [])
        return int(sum(t.numel() * t.element_size() for t in ts) + self.visible.nbytes)

    def __repr__(self) -> str:
        return (f"TorchView({self.camera.width}x{self.camera.height} on {self.device}, "
                f"{self.num_visible} of {self.num_gaussians} Gaussians visible)")

    # -- inputs ----------------------------------------------------------------------------
    def _mask(self, mask, field: str):
        """An (N,) bool mask (NumPy or torch) as a tensor on the device, or None."""
        torch = self._torch
        if isinstance(mask, torch.Tensor):
            if mask.dtype != torch.bool or tuple(mask.shape) != (self.num_gaussians,):
                raise ClearsplatError(f"expected a ({self.num_gaussians},) bool tensor, got "
                                      f"{mask.dtype} {tuple(mask.shape)}", field=field)
            return mask.to(self.device)
        mask = _check_keep(mask, self.num_gaussians, field)
        return None if mask is None else torch.from_numpy(mask).to(self.device)

    def _keep(self, keep, field: str = "keep"):
        """(V,) bool over the visible Gaussians, or None."""
        k = self._mask(keep, field)
        return None if k is None else k[self._index]

    def _visible_ids(self):
        if self._vid is None:
            torch = self._torch
            vid = torch.full((self.num_gaussians,), -1, dtype=torch.long, device=self.device)
            vid[self._index] = torch.arange(self.num_visible, device=self.device)
            self._vid = vid
        return self._vid

    def _ids(self, gaussians, field: str):
        """Sorted unique visible ids of Gaussians (index array or (N,) bool mask), a tensor."""
        torch = self._torch
        if isinstance(gaussians, torch.Tensor) and gaussians.dtype == torch.bool:
            return torch.nonzero(self._keep(gaussians, field)).squeeze(1)
        a = np.asarray(gaussians.cpu() if isinstance(gaussians, torch.Tensor) else gaussians)
        idx = torch.from_numpy(_check_indices(a, self.num_gaussians, field)).to(self.device)
        ids = self._visible_ids()[idx]
        return torch.unique(ids[ids >= 0])

    def _tiles(self, tiles, field: str = "tiles"):
        return self._torch.from_numpy(self._check_tiles(tiles, field).astype(np.int64)
                                      ).to(self.device)

    # -- outputs ---------------------------------------------------------------------------
    def _pixels(self, tiles):
        """Flat image indices (T, 256) of the pixels of ``tiles`` and which exist."""
        torch = self._torch
        p = torch.arange(_PIX, device=self.device)
        rows = (tiles // self.grid[1])[:, None] * TILE + p // TILE
        cols = (tiles % self.grid[1])[:, None] * TILE + p % TILE
        inside = (rows < self.camera.height) & (cols < self.camera.width)
        return torch.where(inside, rows * self.camera.width + cols, 0), inside

    @staticmethod
    def _finish(torch, sums, trans, bg):
        """rgb = C + T bg, alpha = 1 - T, depth = D / alpha (0 where alpha is 0)."""
        alpha = 1.0 - trans
        rgb = sums[..., :3] + trans[..., None] * bg
        depth = torch.where(alpha > 0, sums[..., 3] / torch.where(alpha > 0, alpha, 1.0), 0.0)
        return rgb, alpha, depth

    def _images(self, start, tiles, sums, trans, bg):
        """``start`` (zeros when None) with the composited ``tiles`` written in; NumPy."""
        torch = self._torch
        h, w = self.camera.height, self.camera.width
        if start is None:
            rgb = torch.zeros((h * w, 3), device=self.device)
            alpha = torch.zeros(h * w, device=self.device)
            depth = torch.zeros(h * w, device=self.device)
        else:
            start = self._check_result(start, "start")
            rgb, alpha, depth = (torch.from_numpy(np.array(a, np.float32)).to(self.device)
                                 .reshape(h * w, -1).squeeze(1) for a in start)
        flat, inside = self._pixels(tiles)
        flat = flat[inside]
        r, a, d = self._finish(torch, sums, trans, bg)
        rgb[flat], alpha[flat], depth[flat] = r[inside], a[inside], d[inside]
        return RenderResult(rgb.reshape(h, w, 3).cpu().numpy(),
                            alpha.reshape(h, w).cpu().numpy(), depth.reshape(h, w).cpu().numpy())

    def _bg(self, background):
        return self._torch.from_numpy(_check_background(background)).to(self.device)

    def _all_tiles(self):
        return self._torch.arange(self.num_tiles, device=self.device)

    # -- rendering -------------------------------------------------------------------------
    def render(self, *, keep=None, background=(0.0, 0.0, 0.0)) -> RenderResult:
        """Render the view, optionally only the Gaussians where ``keep`` is True (as
        ``PreparedView.render``)."""
        keep_v = self._keep(keep)
        bg = self._bg(background)
        tiles = self._all_tiles()
        zero = self._torch.zeros_like(tiles)
        sums, trans = tc.composite(self._torch, self._t, tiles,
                                   keeps=None if keep_v is None else keep_v[None], keep_of=zero)
        return self._images(None, tiles, sums, trans, bg)

    def render_pair(self, *, keep, first=None, tiles=None, start: RenderResult | None = None,
                    background=(0.0, 0.0, 0.0)) -> tuple[RenderResult, RenderResult]:
        """The renders with ``first`` (all Gaussians when None) and with ``keep``, in one batch
        (as ``PreparedView.render_pair``: with ``tiles``, only those are composited and the
        other pixels hold ``start``, zeros without it)."""
        torch = self._torch
        keep_v = self._keep(keep)
        if keep_v is None:
            raise ClearsplatError("expected an (N,) bool mask", field="keep")
        first_v = self._keep(first, "first")
        if first_v is None:
            first_v = torch.ones_like(keep_v)
        bg = self._bg(background)
        tiles = self._all_tiles() if tiles is None else self._tiles(tiles)
        n = tiles.shape[0]
        which = torch.cat([torch.zeros(n, dtype=torch.long, device=self.device),
                           torch.ones(n, dtype=torch.long, device=self.device)])
        sums, trans = tc.composite(torch, self._t, torch.cat([tiles, tiles]),
                                   keeps=torch.stack([first_v, keep_v]), keep_of=which)
        return (self._images(start, tiles, sums[:n], trans[:n], bg),
                self._images(start, tiles, sums[n:], trans[n:], bg))

    def rerender(self, base: RenderResult, *, keep, tiles,
                 background=(0.0, 0.0, 0.0)) -> RenderResult:
        """A copy of ``base`` with only ``tiles`` composited again using ``keep`` (as
        ``PreparedView.rerender``)."""
        base = self._check_result(base)
        keep_v = self._keep(keep)
        tiles = self._tiles(tiles)
        bg = self._bg(background)
        zero = self._torch.zeros_like(tiles)
        sums, trans = tc.composite(self._torch, self._t, tiles,
                                   keeps=None if keep_v is None else keep_v[None], keep_of=zero)
        return self._images(base, tiles, sums, trans, bg)

    def tiles_touched(self, gaussians) -> np.ndarray:
        """(T,) int32 sorted unique tiles whose lists hold any of ``gaussians`` (as
        ``PreparedView.tiles_touched``)."""
        ids = self._ids(gaussians, "gaussians")
        _, tiles = tr.rect_tiles(self._torch, self._rect[ids], self.grid[1])
        return self._torch.unique(tiles).cpu().numpy().astype(np.int32)

    def centres_inside(self) -> np.ndarray:
        """(N,) bool: the visible Gaussians whose projected centre lies inside the image."""
        torch = self._torch
        u, v = self._t.geom[:, 0], self._t.geom[:, 1]
        on = (u >= 0) & (u < float(self.camera.width)) & (v >= 0) & (v < float(self.camera.height))
        out = torch.zeros(self.num_gaussians, dtype=torch.bool, device=self.device)
        out[self._index[on]] = True
        return out.cpu().numpy()

    def contributions(self, mask, *, keep=None) -> Contributions:
        """Every ``(pixel, gaussian, alpha * T)`` the compositing adds where ``mask`` is True,
        ordered by pixel, then front to back (as ``PreparedView.contributions``)."""
        torch = self._torch
        h, w = self.camera.height, self.camera.width
        mask = np.asarray(mask)
        if mask.dtype != np.bool_ or mask.shape != (h, w):
            raise ClearsplatError(f"expected a ({h}, {w}) bool mask, got {mask.dtype} "
                                  f"{mask.shape}", field="mask")
        keep_v = self._keep(keep)
        tiles = self._all_tiles()
        flat, inside = self._pixels(tiles)
        on = torch.from_numpy(np.ascontiguousarray(mask).ravel()).to(self.device)[flat] & inside
        task, p, ids, weight = tc.composite(
            torch, self._t, tiles, keeps=None if keep_v is None else keep_v[None],
            keep_of=torch.zeros_like(tiles), pixel_ok=on, record=True)
        pixel = flat[task, p]
        pixel, order = torch.sort(pixel, stable=True)
        return Contributions(pixel.cpu().numpy(), self._index[ids[order]].cpu().numpy(),
                             weight[order].cpu().numpy())

    def rerender_tiles(self, *, keep, removals: Sequence, tiles_list: Sequence | None = None,
                       background=(0.0, 0.0, 0.0), base: RenderResult | None = None
                       ) -> list[TilePatch]:
        """Exact incremental renders, one per removal, of only the tiles it changes (as
        ``PreparedView.rerender_tiles``), every (removal, tile) task in one batch."""
        from ._torch_patches import rerender_tiles
        return rerender_tiles(self, keep=keep, removals=removals, tiles_list=tiles_list,
                              background=background, base=base)


def prepare_torch(scene, camera: Camera, *, near: float = 0.01, keep=None, device=None,
                  settings: RenderSettings | None = None) -> TorchView:
    """A camera of a scene projected, sorted and binned in torch.

    Parameters
    ----------
    scene : Scene, Gaussians or TorchGaussians
        A :class:`TorchGaussians` is used as it is (views of one scene share one upload).
    camera : Camera
    near : float
    keep : (N,) bool, optional
        Prepare only these Gaussians (as :func:`clearsplat.render.prepare`).
    device : str or torch.device, optional
        For a Scene or Gaussians (``"cpu"`` by default).
    settings : RenderSettings, optional
        For a Scene or Gaussians (the scene's by default).

    Returns
    -------
    TorchView
    """
    camera = _check_camera(camera)
    near = _check_near(near)
    g = scene if isinstance(scene, TorchGaussians) else upload_torch(
        scene, device="cpu" if device is None else device, settings=settings)
    if keep is not None:
        keep = _check_keep(keep, g.num_gaussians)
        keep = g.torch.from_numpy(keep).to(g.device)
    return TorchView(g, camera, near=near, keep=keep)


def prepare_torch_views(scene, cameras: Sequence[Camera], *, near: float = 0.01,
                        device=None) -> list[TorchView]:
    """One :class:`TorchView` per camera, sharing one upload of the Gaussians."""
    g = scene if isinstance(scene, TorchGaussians) else upload_torch(
        scene, device="cpu" if device is None else device)
    return [prepare_torch(g, c, near=near) for c in cameras]

