"""The public rendering functions; each picks a backend and returns the same types.

- :func:`render` / :func:`render_batch`: images, alpha and expected depth of a camera.
- :func:`contributions`: the blending weight of every Gaussian the compositing adds at the
  pixels of a mask (the rasterizer association).
- :func:`prepare` -> :class:`~clearsplat.render.native.PreparedView`: projection, binning and
  sorting done once, then any subset rendered.
"""

from __future__ import annotations

from typing import Sequence

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import RenderSettings
from .base import (Contributions, RenderResult, _check_background, _check_camera,
                   _check_gaussians, _check_keep, _check_near, _check_settings, _gaussians)
from .gsplat import render_gsplat
from .native import PreparedView, check_threads, prepare_view

__all__ = ["render", "render_batch", "contributions", "prepare"]


def prepare(scene, camera: Camera, *, keep=None, near: float = 0.01,
            num_threads: int | None = None,
            settings: RenderSettings | None = None) -> PreparedView:
    """Project, bin and depth-sort a scene for one camera, for repeated (subset) renders.

    Parameters
    ----------
    scene : Scene or Gaussians
    camera : Camera
    keep : (N,) bool, optional
        Prepare only these Gaussians: every render of the view then holds at most them (its
        ``keep`` masks still index the whole scene). None: all.
    near : float
        Gaussians with camera z below this are culled.
    num_threads : int, optional
        Threads for this view's kernels (all cores by default); results do not depend on it.
    settings : RenderSettings, optional
        How to rasterize (classic or antialiased, eps2d, radius clip, SH degree); by default
        the scene's :attr:`~clearsplat.Scene.render_settings` (classic 3DGS for Gaussians).

    Returns
    -------
    PreparedView
    """
    g = _gaussians(scene)
    _check_gaussians(g)
    return prepare_view(g, _check_camera(camera), _check_keep(keep, len(g)), _check_near(near),
                        check_threads(num_threads), _check_settings(settings, scene))


def render(scene, camera: Camera, *, keep=None, background=(0.0, 0.0, 0.0), near: float = 0.01,
           num_threads: int | None = None, device: str = "cpu",
           settings: RenderSettings | None = None) -> RenderResult:
    """Render a scene from a camera.

    Parameters
    ----------
    scene : Scene or Gaussians
    camera : Camera
    keep : (N,) bool, optional
        Render only these Gaussians (no copy of the scene); equal to rendering the subset.
    background : 3 floats
        Colour behind the Gaussians, RGB.
    near : float
        Near plane: Gaussians with camera z below it are culled.
    num_threads : int, optional
        Threads (all cores by default); results do not depend on it.
    device : str
        ``"cpu"`` (the native rasterizer) or a CUDA device such as ``"cuda"``, rendered through
        ``gsplat.rasterization`` (needs PyTorch with CUDA and gsplat; see
        :func:`clearsplat.render.gsplat.render_gsplat` for the small differences).
    settings : RenderSettings, optional
        How to rasterize (classic or antialiased, eps2d, radius clip, SH degree); by default
        the scene's :attr:`~clearsplat.Scene.render_settings` (classic 3DGS for Gaussians).

    Returns
    -------
    RenderResult
        ``rgb`` (H, W, 3), ``alpha`` (H, W), ``depth`` (H, W), float32.

    Examples
    --------
    >>> out = render(scene, scene.cameras[0])  # doctest: +SKIP
    >>> out.rgb.shape  # doctest: +SKIP
    (H, W, 3)
    """
    if str(device) != "cpu":
        if not str(device).startswith("cuda"):
            raise ClearsplatError(f"unknown device {device!r}; expected 'cpu' or 'cuda[:N]'",
                                  field="device")
        return render_gsplat(scene, camera, keep=keep, background=background, near=near,
                             device=device, settings=settings)
    g = _gaussians(scene)
    _check_gaussians(g)
    camera = _check_camera(camera)
    keep = _check_keep(keep, len(g))
    bg = _check_background(background)
    view = prepare_view(g, camera, keep, _check_near(near), check_threads(num_threads),
                        _check_settings(settings, scene))
    return view.render(background=bg)


def render_batch(scene, cameras: Sequence[Camera], keeps: Sequence | None = None, *,
                 background=(0.0, 0.0, 0.0), near: float = 0.01,
                 num_threads: int | None = None,
                 settings: RenderSettings | None = None) -> list[RenderResult]:
    """Render many (camera, keep) pairs; equal to calling :func:`render` for each.

    Parameters
    ----------
    scene : Scene or Gaussians
    cameras : sequence of Camera
    keeps : sequence of ((N,) bool or None), optional
        One per camera.
    background, near, num_threads, settings
        As in :func:`render`.

    Returns
    -------
    list of RenderResult, one per camera.
    """
    g = _gaussians(scene)
    _check_gaussians(g)
    cameras = [_check_camera(c, f"cameras[{i}]") for i, c in enumerate(cameras)]
    if keeps is None:
        keeps = [None] * len(cameras)
    keeps = list(keeps)
    if len(keeps) != len(cameras):
        raise ClearsplatError(f"{len(keeps)} keep masks for {len(cameras)} cameras", field="keeps")
    keeps = [_check_keep(k, len(g), f"keeps[{i}]") for i, k in enumerate(keeps)]
    bg = _check_background(background)
    near, threads = _check_near(near), check_threads(num_threads)
    settings = _check_settings(settings, scene)
    return [prepare_view(g, c, k, near, threads, settings).render(background=bg)
            for c, k in zip(cameras, keeps)]


def contributions(scene, camera: Camera, mask, *, keep=None, near: float = 0.01,
                  num_threads: int | None = None,
                  settings: RenderSettings | None = None) -> Contributions:
    """Every ``(pixel, gaussian, alpha * T)`` the compositing adds at the pixels of ``mask``.

    Parameters
    ----------
    scene : Scene or Gaussians
    camera : Camera
    mask : (H, W) bool
    keep : (N,) bool, optional
    near : float
    num_threads : int, optional
    settings : RenderSettings, optional
        How to rasterize (classic or antialiased, eps2d, radius clip, SH degree); by default
        the scene's :attr:`~clearsplat.Scene.render_settings` (classic 3DGS for Gaussians).

    Returns
    -------
    Contributions
        ``pixel`` (M,) int64, ``gaussian`` (M,) int64, ``weight`` (M,) float32, ordered by
        pixel, then front to back.
    """
    g = _gaussians(scene)
    _check_gaussians(g)
    camera = _check_camera(camera)
    keep = _check_keep(keep, len(g))
    view = prepare_view(g, camera, keep, _check_near(near), check_threads(num_threads),
                        _check_settings(settings, scene))
    return view.contributions(mask)

