"""A stand-in feed-forward backbone: pixel-aligned Gaussians from images and depths.

:func:`reconstruct` lays Gaussians out as DepthSplat does (one per input pixel, at the
predicted depth along the pixel ray) and gives them the imperfections of a learned
model, so that the filter sees realistic input without a network:

- depth is smoothed across object boundaries (a Gaussian blur of inverse depth), which
  leaves "flying" Gaussians between foreground and background;
- a smooth, low-frequency relative depth error (about 1 %) differs per view, so the views
  do not agree exactly;
- Gaussians are flat discs facing their camera, about one pixel footprint wide, thin
  along the optical axis, with opacity below one and a DC colour equal to the pixel's.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, Scene, rgb_to_sh_dc

__all__ = ["reconstruct", "clean_reference", "distractor_truth", "rotation_to_quat"]


def reconstruct(cameras, images, depths, *, seed: int = 0, depth_blur: float = 0.7,
                depth_noise: float = 0.01, noise_cells: int = 4, footprint: float = 0.6,
                thickness: float = 0.1, opacity: float = 0.9) -> Scene:
    """Pixel-aligned Gaussians from posed images and depth maps.

    Parameters
    ----------
    cameras : sequence of Camera
        The input cameras (view ``i`` is ``cameras[i]``).
    images : sequence of (H, W, 3) array_like
        RGB in [0, 1], one per camera.
    depths : sequence of (H, W) array_like
        Camera-z depth per pixel, positive and finite.
    seed : int
        Seeds the depth error fields; the same seed gives the same errors.
    depth_blur : float
        Standard deviation, in pixels, of the blur of inverse depth (boundary smoothing);
        0 disables it.
    depth_noise : float
        Standard deviation of the relative depth error; 0 disables it.
    noise_cells : int
        Number of random cells across the shorter image side of the smooth error field
        (larger is less smooth).
    footprint : float
        In-plane standard deviation of each Gaussian in pixels (``depth / f * footprint``).
    thickness : float
        Standard deviation along the optical axis relative to the in-plane one.
    opacity : float
        Opacity of every Gaussian, in (0, 1].

    Returns
    -------
    Scene
        ``N = sum(H * W)`` Gaussians ordered by view then pixel, with ``view_id``,
        ``pixel_id = row * W + col`` and ``images`` set; SH degree 0.
    """
    cameras = list(cameras)
    images = list(images)
    depths = list(depths)
    if not cameras:
        raise ClearsplatError("no input views", field="cameras")
    if len(images) != len(cameras) or len(depths) != len(cameras):
        raise ClearsplatError(f"{len(cameras)} cameras, {len(images)} images and "
                              f"{len(depths)} depth maps; expected one of each per view",
                              field="images/depths")
    if not 0.0 < opacity <= 1.0:
        raise ClearsplatError(f"opacity must be in (0, 1], got {opacity}", field="opacity")
    for name, value in (("footprint", footprint), ("thickness", thickness)):
        if not value > 0:
            raise ClearsplatError(f"must be positive, got {value}", field=name)
    for name, value in (("depth_blur", depth_blur), ("depth_noise", depth_noise)):
        if not value >= 0:
            raise ClearsplatError(f"must be >= 0, got {value}", field=name)
    if noise_cells < 1:
        raise ClearsplatError(f"must be >= 1, got {noise_cells}", field="noise_cells")
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(len(cameras))]
    parts = []
    for i, (cam, image, depth) in enumerate(zip(cameras, images, depths)):
        if not isinstance(cam, Camera):
            raise ClearsplatError(f"expected a Camera, got {type(cam).__name__}",
                                  field=f"cameras[{i}]")
        h, w = cam.height, cam.width
        image = np.asarray(image, dtype=np.float32)
        depth = np.asarray(depth, dtype=np.float64)
        if image.shape != (h, w, 3):
            raise ClearsplatError(f"expected shape {(h, w, 3)}, got {image.shape}",
                                  field=f"images[{i}]")
        if depth.shape != (h, w):
            raise ClearsplatError(f"expected shape {(h, w)}, got {depth.shape}",
                                  field=f"depths[{i}]")
        if not (np.isfinite(depth).all() and (depth > 0).all()):
            raise ClearsplatError("depth must be finite and positive", field=f"depths[{i}]")
        z = _imperfect_depth(depth, rngs[i], blur=depth_blur, noise=depth_noise,
                             cells=noise_cells)
        means = cam.unproject(z).reshape(-1, 3)
        zf = z.reshape(-1)
        scales = np.stack([zf / cam.fx * footprint, zf / cam.fy * footprint,
                           zf / np.sqrt(cam.fx * cam.fy) * footprint * thickness], axis=1)
        quat = rotation_to_quat(cam.camera_to_world[:3, :3])
        parts.append((means, scales, np.broadcast_to(quat, (h * w, 4)),
                      image.reshape(-1, 3), np.full(h * w, i), np.arange(h * w)))
    means, scales, quats, colours, view_id, pixel_id = (np.concatenate(p) for p in zip(*parts))
    n = len(means)
    gaussians = Gaussians(means=means, scales=scales, quats=quats,
                          opacities=np.full(n, opacity, dtype=np.float32),
                          sh=rgb_to_sh_dc(colours)[:, None, :])
    return Scene(gaussians, view_id=view_id, pixel_id=pixel_id, cameras=cameras, images=images)


def _imperfect_depth(depth, rng, *, blur, noise, cells):
    """Blur inverse depth across boundaries, then apply a smooth relative error field."""
    h, w = depth.shape
    z = depth
    if blur > 0:
        z = 1.0 / ndimage.gaussian_filter(1.0 / depth, blur, mode="nearest", truncate=3.0)
    if noise > 0:
        step = min(h, w) / cells
        gh, gw = int(np.ceil(h / step)) + 3, int(np.ceil(w / step)) + 3
        grid = rng.standard_normal((gh, gw))
        rows = (np.arange(h) + 0.5) / step + 1.0
        cols = (np.arange(w) + 0.5) / step + 1.0
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        field = ndimage.map_coordinates(grid, [rr, cc], order=3, mode="nearest")
        field /= max(field.std(), 1e-12)
        z = z * (1.0 + noise * field)
    return z


def rotation_to_quat(R) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` of a 3x3 rotation matrix, ``w >= 0``.

    Parameters
    ----------
    R : (3, 3) array_like, orthonormal with determinant +1.

    Returns
    -------
    (4,) float64
    """
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def clean_reference(world, *, seed: int = 0, **options) -> Scene:
    """The stand-in prediction from the clean twin (same cameras, no transients).

    With the same ``seed`` and options as the cluttered :func:`reconstruct` call, the two
    scenes differ only at (and, through the depth blur, right next to) transient pixels.
    """
    return reconstruct(world.cameras, world.clean_images, world.clean_depths, seed=seed,
                       **options)


def distractor_truth(scene: Scene, world) -> np.ndarray:
    """Which Gaussians of a pixel-aligned prediction come from transient pixels.

    Parameters
    ----------
    scene : Scene
        A prediction over ``world.cameras`` with ``pixel_id`` set for every Gaussian.
    world : World

    Returns
    -------
    (N,) bool
        ``world.transient_masks[view_id][pixel_id]``.
    """
    if len(scene) and not scene.is_pixel_aligned:
        raise ClearsplatError("distractor truth needs a pixel index for every Gaussian",
                              field="pixel_id")
    if scene.num_views != len(world.transient_masks):
        raise ClearsplatError(f"the scene has {scene.num_views} views, the world "
                              f"{len(world.transient_masks)}", field="view_id")
    flat = np.concatenate([np.asarray(m, dtype=bool).reshape(-1) for m in world.transient_masks])
    offsets = np.concatenate([[0], np.cumsum([m.size for m in world.transient_masks])[:-1]])
    sizes = np.array([m.size for m in world.transient_masks])
    if len(scene) and (scene.pixel_id >= sizes[scene.view_id]).any():
        raise ClearsplatError("pixel index outside its view's transient mask", field="pixel_id")
    return flat[offsets[scene.view_id] + scene.pixel_id]
