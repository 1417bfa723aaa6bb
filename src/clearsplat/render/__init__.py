"""Rendering: one interface, three backends.

Layers, each importing only those below it::

    api.py         render, render_batch, contributions, prepare: the public functions
    gsplat.py      gsplat on a CUDA GPU (GsplatView, render_gsplat)      |  backends, same
    torch_view.py  the native math in torch, any device (TorchView)      |  results and
    native.py      the native CPU rasterizer (PreparedView)               |  checks
    base.py        RenderResult, Contributions, TilePatch, input checks, the tile grid
    _kernels.py    one thin wrapper per native kernel (``clearsplat._core``)
    _torch_*.py    the torch twins of the kernels (projection, compositing, patches)

Every convention is on one page, ``docs/conventions.md`` ("Rasterization").
"""

from ..scene import RenderSettings
from .api import contributions, prepare, render, render_batch
from .base import TILE, Contributions, RenderResult, TilePatch
from .native import PreparedView

__all__ = ["RenderResult", "Contributions", "TilePatch", "PreparedView", "render",
           "render_batch", "contributions", "prepare", "TILE", "RenderSettings"]
