"""An interactive 3D viewer in the browser (viser): the scene before and after filtering.

:func:`serve` starts a viser server showing

- the original Gaussians, the filtered ones, or the removed ones alone in a highlight colour,
  switched with the "Show" control;
- the input cameras as frustums carrying their images; clicking one moves the browser's
  camera to it (same position, orientation and vertical field of view), so the scene is seen
  through that input view;
- with a filter output that keeps its candidates (``filtered=``), a "Review" panel: the
  candidates listed by score and filtered by verdict and view; selecting one (in the list, or
  by clicking one of its splats) highlights its Gaussians, looks through its input view and
  shows the input crop beside the render before and after its removal; its verdict toggles
  and the scene follows at once; "Save" writes an edited folder exactly as ``clearsplat edit``
  does (:func:`clearsplat.review.edit_filter_output`) and prints that command.

viser renders the Gaussians in WebGL with their DC colour (view-independent) and opacity;
it follows the same OpenCV camera axes as clearsplat (``docs/conventions.md``). Needs the
``viewer`` extra: ``pip install "clearsplat[viewer]"``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .errors import ClearsplatError
from .scene import SH_C0

__all__ = ["serve", "Viewer", "covariances", "SHOW_MODES", "REMOVED_COLOUR",
           "SELECTED_COLOUR"]

#: The choices of the "Show" control.
SHOW_MODES = ("original", "filtered", "removed")
#: Colour of the removed Gaussians when shown alone (RGB in [0, 1]).
REMOVED_COLOUR = (1.0, 0.1, 0.75)
#: Colour of the selected candidate's Gaussians in the review panel (RGB in [0, 1]).
SELECTED_COLOUR = (0.1, 1.0, 0.25)


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
        splat set it holds, hidden or not, so a change replaces the set).
    keep : (N,) bool or None
        The Gaussians kept now (the review panel's toggles change it).
    highlight : (M,) int64
        The Gaussians drawn in :data:`SELECTED_COLOUR` (the selected candidate's).
    review : clearsplat._review_panel.Review or None
        The review panel, with a filter output that holds its candidates.
    """

    server: object
    url: str
    show: object
    modes: tuple
    arrays: dict = field(default_factory=dict, repr=False)
    splats: object = None
    frustums: list = field(default_factory=list)
    current: str = ""
    keep: np.ndarray | None = None
    highlight: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    review: object = None
    scene: object = field(default=None, repr=False)

    def set_show(self, mode: str) -> None:
        """Show the ``"original"``, ``"filtered"`` or ``"removed"`` Gaussians."""
        if mode not in self.modes:
            raise ClearsplatError(f"expected one of {', '.join(self.modes)}, got {mode!r}",
                                  field="show")
        if mode == self.current and self.splats is not None:
            return
        self.current = mode
        self.refresh()
        if self.show.value != mode:
            self.show.value = mode

    def shown(self) -> np.ndarray:
        """(N,) bool: the Gaussians in the scene now (the mode's, and the highlighted ones)."""
        n = len(self.arrays["centers"])
        mask = np.ones(n, bool)
        if self.current == "filtered":
            mask = self.keep.copy()
        elif self.current == "removed":
            mask = ~self.keep
        mask[self.highlight] = True
        return mask

    def refresh(self) -> None:
        """Replace the splat set by what the mode, the verdicts and the selection ask for."""
        mask = self.shown()
        rgb = self.arrays["rgbs"].copy()
        if self.current == "removed":
            rgb[:] = REMOVED_COLOUR
        rgb[self.highlight] = SELECTED_COLOUR
        if self.splats is not None:
            self.splats.remove()
        a = self.arrays
        self.splats = self.server.scene.add_gaussian_splats(
            "/gaussians", centers=a["centers"][mask], covariances=a["covariances"][mask],
            rgbs=rgb[mask], opacities=a["opacities"][mask])

    def look_through(self, view: int) -> None:
        """Put every connected browser (and those that connect later) at input camera ``view``."""
        cam = self.scene.cameras[view]
        fov = 2 * math.atan(0.5 * cam.height / cam.fy)
        callback = _look_through(cam, fov, view, self.frustums)
        for client in self.server.get_clients().values():
            callback(_Event(client))
        for j, handle in enumerate(self.frustums):
            handle.visible = j != view
        _initial_camera(self.server, cam, self.scene)

    def stop(self) -> None:
        """Stop the server (its port is free again)."""
        with _quiet(True):
            self.server.stop()


@dataclass
class _Event:
    client: object


def serve(scene, *, keep=None, filtered=None, host: str = "127.0.0.1", port: int = 8080,
          show: str | None = None, select: int | None = None, image_width: int = 160,
          verbose: bool = False) -> Viewer:
    """Start the viewer on ``host:port`` and return at once (the server runs in threads).

    Parameters
    ----------
    scene : Scene
        Images, where present, are shown on the camera frustums.
    keep : (N,) bool, optional
        The Gaussians the filter kept (``result.keep``, or ``~removed.npy``). Without it (and
        without ``filtered``) only the original Gaussians are shown.
    filtered : str or os.PathLike, optional
        The filter output folder of ``scene``: ``keep`` is read from it (when not given), and
        where it holds its candidates (``candidates.npz``) the review panel is added.
    host : str, default "127.0.0.1"
        Only this machine can connect; ``"0.0.0.0"`` shares the viewer on the network.
    port : int, default 8080
        A port in use gives the next free one (viser's behaviour); ``Viewer.url`` tells.
    show : {"original", "filtered", "removed"}, optional
        What is shown first; default ``"filtered"`` with ``keep``, else ``"original"``.
    select : int, optional
        A candidate selected from the start (needs the review panel).
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
        On a ``keep`` of the wrong shape, an unknown ``show``, a ``filtered`` folder of
        another scene or an unknown ``select``.
    """
    try:
        import viser
    except ImportError:
        raise ImportError("the viewer needs viser: pip install 'clearsplat[viewer]'") from None
    g = scene.gaussians
    n = len(g)
    output, note = None, None
    if filtered is not None:
        from .review import load_filter_output
        try:
            output = load_filter_output(filtered)
        except ClearsplatError as e:
            note = str(e)
        if output is not None and output.removed.size != n:
            raise ClearsplatError(f"{output.removed.size} entries for the scene's {n} "
                                  "Gaussians: this filter output belongs to another scene",
                                  path=output.folder / "removed.npy", field="removed")
        if keep is None and output is not None:
            keep = ~output.removed
        elif keep is None:              # no candidate data: the removal alone
            try:
                keep = ~np.load(os.path.join(filtered, "removed.npy"), allow_pickle=False)
            except (OSError, ValueError) as e:
                raise ClearsplatError(f"cannot read ({e})", path=os.path.join(
                    filtered, "removed.npy"), field="removed") from None
    if keep is not None:
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != (n,):
            raise ClearsplatError(f"expected {n} values, got shape {keep.shape}", field="keep")
    modes = SHOW_MODES if keep is not None else SHOW_MODES[:1]
    show = show or ("filtered" if keep is not None else "original")
    if show not in modes:
        raise ClearsplatError(f"expected one of {', '.join(modes)}, got {show!r}", field="show")
    if select is not None and (output is None or not 0 <= select < len(output.sets)):
        raise ClearsplatError(f"no candidate {select} to select", field="select")

    with _quiet(not verbose):           # viser prints a banner of its own
        server = viser.ViserServer(host=host, port=port, verbose=verbose)
    try:
        viewer = _populate(server, scene, keep, modes, show, image_width)
        if output is not None:
            from ._review_panel import Review
            viewer.review = Review(viewer, output, keep)
            if select is not None:
                viewer.review.select(select)
        elif note is not None:
            with server.gui.add_folder("Review"):
                server.gui.add_markdown(f"No review: {note}")
    except BaseException:
        server.stop()
        raise
    return viewer


def _initial_camera(server, cam, scene) -> None:
    """Where a browser that connects starts: looking through ``cam``."""
    g = scene.gaussians
    pos = np.stack([c.position for c in scene.cameras])
    centre = np.median(g.means, axis=0) if len(g) else pos.mean(0)
    dist = float(np.linalg.norm(cam.position - centre)) or 1.0
    server.initial_camera.position = tuple(float(v) for v in cam.position)
    server.initial_camera.look_at = tuple(float(v) for v in
                                          cam.position + dist * cam.camera_to_world[:3, 2])
    server.initial_camera.up = tuple(float(v) for v in -cam.camera_to_world[:3, 1])
    server.initial_camera.fov = 2 * math.atan(0.5 * cam.height / cam.fy)


def _populate(server, scene, keep, modes, show, image_width) -> Viewer:
    g = scene.gaussians
    cams = scene.cameras
    server.gui.configure_theme(show_share_button=False, dark_mode=True)
    # world up: the mean of the input cameras' up directions (-y in OpenCV camera axes)
    up = -np.mean([c.camera_to_world[:3, 1] for c in cams], axis=0)
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-9 else np.array([0.0, 0.0, 1.0])
    server.scene.set_up_direction(tuple(float(v) for v in up))

    arrays = dict(centers=g.means, covariances=covariances(g),
                  rgbs=np.clip(SH_C0 * g.sh[:, 0] + 0.5, 0.0, 1.0).astype(np.float32),
                  opacities=g.opacities[:, None].astype(np.float32))

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
    frustums[0].visible = False
    _initial_camera(server, cams[0], scene)

    n_removed = 0 if keep is None else int((~keep).sum())
    server.gui.add_markdown(
        f"**clearsplat** — {len(g):,} Gaussians, {len(cams)} input views"
        + (f", {n_removed:,} removed by the filter" if keep is not None else "")
        + ". Click a camera to look through it.")
    control = server.gui.add_dropdown("Show", list(modes), initial_value=show)
    viewer = Viewer(server=server, url=f"http://{_display_host(server.get_host())}:"
                                        f"{server.get_port()}",
                    show=control, modes=tuple(modes), arrays=arrays, frustums=frustums,
                    keep=None if keep is None else keep.copy(), scene=scene)
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
