"""An interactive 3D viewer in the browser (viser): the scene before and after filtering.

:func:`serve` starts a viser server showing

- the original Gaussians, the filtered ones, or the removed ones alone in a highlight colour,
  switched with the "Show" control;
- the input cameras as frustums carrying their images; clicking one moves the browser's
  camera to it (same position, orientation and vertical field of view), so the scene is seen
  through that input view.

viser renders the Gaussians in WebGL with their DC colour (view-independent) and opacity;
it follows the same OpenCV camera axes as clearsplat (``docs/conventions.md``). Needs the
``viewer`` extra: ``pip install "clearsplat[viewer]"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import ClearsplatError
from .scene import SH_C0

__all__ = ["serve", "Viewer", "covariances", "SHOW_MODES", "REMOVED_COLOUR"]

#: The choices of the "Show" control.
SHOW_MODES = ("original", "filtered", "removed")
#: Colour of the removed Gaussians when shown alone (RGB in [0, 1]).
REMOVED_COLOUR = (1.0, 0.1, 0.75)


def covariances(gaussians) -> np.ndarray:
    """World-space covariances ``R diag(s^2) R^T``, shape (N, 3, 3) float32.

    ``R`` from the normalised quaternion ``w, x, y, z``, ``s`` the scales.
    """
    q = np.asarray(gaussians.quats, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)
    s2 = np.asarray(gaussians.scales, np.float64) ** 2
    return ((R * s2[:, None, :]) @ R.transpose(0, 2, 1)).astype(np.float32)


def _rotation_to_wxyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


@dataclass
class Viewer:
    """A running viewer: ``url``, the viser ``server``, :meth:`set_show` and :meth:`stop`.

    Attributes
    ----------
    server : viser.ViserServer
    url : str
        ``http://host:port``.
    show : viser GUI handle
        The "Show" control.
    modes : tuple of str
        What the control offers (``"original"``, and with a filter result ``"filtered"``,
        ``"removed"``).
    splats : viser GaussianSplatHandle
        The Gaussians on show. Only one set is in the scene at a time (viser draws every
        splat set it holds, hidden or not, so switching replaces the set).
    """

    server: object
    url: str
    show: object
    modes: tuple
    parts: dict = field(default_factory=dict, repr=False)
    splats: object = None
    frustums: list = field(default_factory=list)
    current: str = ""

    def set_show(self, mode: str) -> None:
        """Show the ``"original"``, ``"filtered"`` or ``"removed"`` Gaussians."""
        if mode not in self.modes:
            raise ClearsplatError(f"expected one of {', '.join(self.modes)}, got {mode!r}",
                                  field="show")
        if mode == self.current and self.splats is not None:
            return
        if self.splats is not None:
            self.splats.remove()
        self.splats = self.server.scene.add_gaussian_splats("/gaussians", **self.parts[mode])
        self.current = mode
        if self.show.value != mode:
            self.show.value = mode

    def stop(self) -> None:
        """Stop the server (its port is free again)."""
        with _quiet(True):
            self.server.stop()


def serve(scene, *, keep=None, host: str = "127.0.0.1", port: int = 8080,
          show: str | None = None, image_width: int = 160, verbose: bool = False) -> Viewer:
    """Start the viewer on ``host:port`` and return at once (the server runs in threads).

    Parameters
    ----------
    scene : Scene
        Images, where present, are shown on the camera frustums.
    keep : (N,) bool, optional
        The Gaussians the filter kept (``result.keep``, or ``~removed.npy``). Without it only
        the original Gaussians are shown.
    host : str, default "127.0.0.1"
        Only this machine can connect; ``"0.0.0.0"`` shares the viewer on the network.
    port : int, default 8080
        A port in use gives the next free one (viser's behaviour); ``Viewer.url`` tells.
    show : {"original", "filtered", "removed"}, optional
        What is shown first; default ``"filtered"`` with ``keep``, else ``"original"``.
    image_width : int, default 160
        Width of the images on the frustums (downscaled, to keep the page light).
    verbose : bool
        viser's own log lines.

    Returns
    -------
    Viewer

    Raises
    ------
    ImportError
        Without viser (``pip install "clearsplat[viewer]"``).
    ClearsplatError
        On a ``keep`` of the wrong shape or an unknown ``show``.
    """
    try:
        import viser
    except ImportError:
        raise ImportError("the viewer needs viser: pip install 'clearsplat[viewer]'") from None
    g = scene.gaussians
    n = len(g)
    if keep is not None:
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != (n,):
            raise ClearsplatError(f"expected {n} values, got shape {keep.shape}", field="keep")
    modes = SHOW_MODES if keep is not None else SHOW_MODES[:1]
    show = show or ("filtered" if keep is not None else "original")
    if show not in modes:
        raise ClearsplatError(f"expected one of {', '.join(modes)}, got {show!r}", field="show")

    with _quiet(not verbose):           # viser prints a banner of its own
        server = viser.ViserServer(host=host, port=port, verbose=verbose)
    try:
        viewer = _populate(server, scene, keep, modes, show, image_width)
    except BaseException:
        server.stop()
        raise
    return viewer


def _populate(server, scene, keep, modes, show, image_width) -> Viewer:
    g = scene.gaussians
    cams = scene.cameras
    server.gui.configure_theme(show_share_button=False, dark_mode=True)
    # world up: the mean of the input cameras' up directions (-y in OpenCV camera axes)
    up = -np.mean([c.camera_to_world[:3, 1] for c in cams], axis=0)
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-9 else np.array([0.0, 0.0, 1.0])
    server.scene.set_up_direction(tuple(float(v) for v in up))

    centres = g.means
    colour = np.clip(SH_C0 * g.sh[:, 0] + 0.5, 0.0, 1.0).astype(np.float32)
    cov = covariances(g)
    opac = g.opacities[:, None].astype(np.float32)
    masks = {"original": np.ones(len(g), bool)}
    if keep is not None:
        masks["filtered"] = keep
        masks["removed"] = ~keep
    parts = {}
    for name in modes:
        m = masks[name]
        rgb = colour[m]
        if name == "removed":
            rgb = np.broadcast_to(np.asarray(REMOVED_COLOUR, np.float32), rgb.shape).copy()
        parts[name] = dict(centers=centres[m], covariances=cov[m], rgbs=rgb, opacities=opac[m])

    # frustum size: a twentieth of the cameras' distance to the scene's centre
    pos = np.stack([c.position for c in cams])
    centre = np.median(g.means, axis=0) if len(g) else pos.mean(0)
    dist = float(np.median(np.linalg.norm(pos - centre, axis=1)))
    scale = 0.06 * dist if dist > 0 else 0.1
    frustums = []
    for i, cam in enumerate(cams):
        image = None
        if scene.images is not None:
            from PIL import Image
            im = (np.clip(scene.images[i], 0, 1) * 255 + 0.5).astype(np.uint8)
            w = min(image_width, cam.width)
            h = max(1, round(cam.height * w / cam.width))
            image = np.asarray(Image.fromarray(im).resize((w, h), Image.BILINEAR))
        fov = 2 * math.atan(0.5 * cam.height / cam.fy)
        handle = server.scene.add_camera_frustum(
            f"/cameras/view_{i:03d}", fov=fov, aspect=cam.width / cam.height, scale=scale,
            image=image, wxyz=_rotation_to_wxyz(cam.camera_to_world[:3, :3]),
            position=cam.position, color=(255, 200, 40))
        handle.on_click(_look_through(cam, fov, i, frustums))
        frustums.append(handle)

    # the browser starts looking through input view 0 (as if its frustum had been clicked):
    # pixel-aligned Gaussians look right from the input views
    c0 = cams[0]
    forward = c0.camera_to_world[:3, 2]
    dist = float(np.linalg.norm(c0.position - centre)) or 1.0
    eye = c0.position
    target = c0.position + dist * forward
    frustums[0].visible = False
    server.initial_camera.position = tuple(float(v) for v in eye)
    server.initial_camera.look_at = tuple(float(v) for v in target)
    server.initial_camera.up = tuple(float(v) for v in -c0.camera_to_world[:3, 1])
    server.initial_camera.fov = 2 * math.atan(0.5 * c0.height / c0.fy)

    n_removed = 0 if keep is None else int((~keep).sum())
    server.gui.add_markdown(
        f"**clearsplat** — {len(g):,} Gaussians, {len(cams)} input views"
        + (f", {n_removed:,} removed by the filter" if keep is not None else "")
        + ". Click a camera to look through it.")
    control = server.gui.add_dropdown("Show", list(modes), initial_value=show)
    viewer = Viewer(server=server, url=f"http://{_display_host(server.get_host())}:"
                                        f"{server.get_port()}",
                    show=control, modes=tuple(modes), parts=parts, frustums=frustums)
    viewer.set_show(show)

    @control.on_update
    def _(_event) -> None:
        viewer.set_show(control.value)

    return viewer


def _look_through(cam, fov, index, frustums):
    wxyz = _rotation_to_wxyz(cam.camera_to_world[:3, :3])
    position = cam.position

    def callback(event) -> None:
        client = event.client
        if client is None:
            return
        # the camera's own frustum (and its image) would fill the view: hide it until
        # another camera is chosen
        for j, handle in enumerate(frustums):
            handle.visible = j != index
        with client.atomic():
            client.camera.fov = fov
            client.camera.wxyz = wxyz
            client.camera.position = position
    return callback


def _quiet(on: bool):
    import contextlib
    import io
    return contextlib.redirect_stdout(io.StringIO()) if on else contextlib.nullcontext()


def _display_host(host: str) -> str:
    return "127.0.0.1" if host in ("0.0.0.0", "", "::") else host
