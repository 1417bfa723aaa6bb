"""Camera paths: smooth interpolation through cameras, and output sizes.

A path passes through its key cameras in order: positions on a centripetal Catmull-Rom
spline (no overshoot or cusps between unevenly spaced cameras), rotations by spherical linear
interpolation (slerp) of their quaternions, intrinsics linearly. Frames that fall between two
key cameras are novel views: no input image was taken there.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .cameras import Camera
from .errors import ClearsplatError

__all__ = ["interpolate_cameras", "resize_camera", "parse_size"]


def _catmull_rom(points: np.ndarray, seg: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Centripetal Catmull-Rom through ``points`` (K, 3) at segment ``seg``, local ``u`` in [0, 1].

    The end segments use mirrored ghost points, so the curve starts and ends at the first and
    last point and passes through every point.
    """
    p = np.concatenate([2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]])
    p0, p1, p2, p3 = p[seg], p[seg + 1], p[seg + 2], p[seg + 3]

    def knot(a, b):
        return np.sqrt(np.maximum(np.linalg.norm(b - a, axis=-1), 1e-12))[:, None]

    t0 = np.zeros((len(seg), 1))
    t1 = t0 + knot(p0, p1)
    t2 = t1 + knot(p1, p2)
    t3 = t2 + knot(p2, p3)
    t = t1 + u[:, None] * (t2 - t1)
    a1 = ((t1 - t) * p0 + (t - t0) * p1) / (t1 - t0)
    a2 = ((t2 - t) * p1 + (t - t1) * p2) / (t2 - t1)
    a3 = ((t3 - t) * p2 + (t - t2) * p3) / (t3 - t2)
    b1 = ((t2 - t) * a1 + (t - t0) * a2) / (t2 - t0)
    b2 = ((t3 - t) * a2 + (t - t1) * a3) / (t3 - t1)
    return ((t2 - t) * b1 + (t - t1) * b2) / (t2 - t1)


def interpolate_cameras(cameras: Sequence[Camera], num_frames: int, *,
                        width: int | None = None, height: int | None = None) -> list[Camera]:
    """A smooth path of ``num_frames`` cameras through ``cameras``, in their order.

    Parameters
    ----------
    cameras : sequence of Camera
        The key cameras (at least one). The path starts at the first and ends at the last.
    num_frames : int
        Number of cameras on the path (at least 1). Key camera ``k`` of ``K`` sits at path
        parameter ``k / (K - 1)``; frames are spaced evenly in that parameter, so every key
        camera is on the path when ``num_frames - 1`` is a multiple of ``K - 1``.
    width, height : int, optional
        Image size of the path's cameras (see :func:`resize_camera`); default the first key
        camera's.

    Returns
    -------
    list of Camera
        Positions on a centripetal Catmull-Rom spline through the key positions, rotations
        slerped between consecutive key rotations, intrinsics (in the first camera's pixel
        size) interpolated linearly.

    Raises
    ------
    ClearsplatError
        On an empty camera list or a non-positive ``num_frames``.
    """
    cameras = list(cameras)
    if not cameras:
        raise ClearsplatError("no cameras to interpolate", field="cameras")
    if isinstance(num_frames, bool) or int(num_frames) != num_frames or num_frames < 1:
        raise ClearsplatError(f"must be a positive whole number, got {num_frames}",
                              field="frames")
    num_frames = int(num_frames)
    base = cameras[0]
    # intrinsics in the first camera's size, so that they interpolate
    Ks = np.stack([resize_camera(c, base.width, base.height).K for c in cameras])
    if len(cameras) == 1:
        out = [Camera(K=Ks[0], camera_to_world=base.camera_to_world, width=base.width,
                      height=base.height)] * num_frames
    else:
        k = len(cameras)
        s = np.linspace(0.0, k - 1.0, num_frames)
        seg = np.minimum(np.floor(s).astype(int), k - 2)
        u = s - seg
        pos = _catmull_rom(np.stack([c.position for c in cameras]), seg, u)
        rots = Rotation.from_matrix(np.stack([c.camera_to_world[:3, :3] for c in cameras]))
        rot = Slerp(np.arange(k, dtype=float), rots)(s).as_matrix()
        K = Ks[seg] * (1 - u)[:, None, None] + Ks[seg + 1] * u[:, None, None]
        out = []
        for i in range(num_frames):
            c2w = np.eye(4)
            c2w[:3, :3] = rot[i]
            c2w[:3, 3] = pos[i]
            out.append(Camera(K=K[i], camera_to_world=c2w, width=base.width,
                              height=base.height))
    if width is not None or height is not None:
        out = [resize_camera(c, width or c.width, height) for c in out]
    return out


def resize_camera(camera: Camera, width: int, height: int | None = None) -> Camera:
    """The camera at another image size, same viewpoint, without stretching.

    The image is scaled uniformly by ``width / camera.width``; ``height`` defaults to the
    scaled height (rounded). A different ``height`` shows more or less above and below (the
    principal point moves with the centre), never a squeezed picture.

    Raises
    ------
    ClearsplatError
        If a size is not a positive whole number.
    """
    for name, v in (("width", width), ("height", height)):
        if v is not None and (isinstance(v, bool) or int(v) != v or v < 1):
            raise ClearsplatError(f"must be a positive whole number, got {v}", field=name)
    width = int(width)
    s = width / camera.width
    scaled_h = camera.height * s
    height = max(1, round(scaled_h)) if height is None else int(height)
    K = camera.K.copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 2] *= s
    K[1, 2] = K[1, 2] * s + 0.5 * (height - scaled_h)
    return Camera(K=K, camera_to_world=camera.camera_to_world, width=width, height=height)


def parse_size(text: str) -> tuple[int, int | None]:
    """``"640"`` -> (640, None), ``"640x360"`` -> (640, 360); a ClearsplatError otherwise."""
    parts = str(text).lower().split("x")
    try:
        nums = [int(p) for p in parts]
    except ValueError:
        nums = []
    if len(nums) not in (1, 2) or min(nums) < 1 or max(nums) > 16384:
        raise ClearsplatError(f"expected WIDTH or WIDTHxHEIGHT in pixels (1..16384), got "
                              f"{text!r}", field="--size")
    return nums[0], (nums[1] if len(nums) == 2 else None)
