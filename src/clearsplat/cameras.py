"""Pinhole cameras in OpenCV axes.

Conventions (see ``docs/conventions.md``): camera axes are x right, y down,
z forward; ``camera_to_world`` is a 4x4 rigid transform; ``K`` is in pixels and
the centre of pixel ``(row, col)`` sits at ``(col + 0.5, row + 0.5)`` in image
coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ClearsplatError

__all__ = ["Camera", "OPENGL_TO_OPENCV", "look_at"]

#: Flips y and z: converts camera axes between OpenGL (x right, y up, z back)
#: and OpenCV (x right, y down, z forward). It is its own inverse.
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world matrix (4, 4) in OpenCV axes, at ``eye``, looking at ``target``.

    ``up`` is the world direction that appears upwards in the image (``-y`` in camera axes);
    it must not be parallel to the viewing direction.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    c2w[:3, 3] = eye
    return c2w


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera.

    Parameters
    ----------
    K : (3, 3) array_like
        Intrinsics in pixels: ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    camera_to_world : (4, 4) array_like
        Rigid transform from OpenCV camera axes to world coordinates.
    width, height : int
        Image size in pixels.
    """

    K: np.ndarray
    camera_to_world: np.ndarray
    width: int
    height: int
    world_to_camera: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        K = np.array(self.K, dtype=np.float64)
        c2w = np.array(self.camera_to_world, dtype=np.float64)
        if K.shape != (3, 3):
            raise ClearsplatError(f"expected a 3x3 matrix, got shape {K.shape}", field="K")
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4):
            raise ClearsplatError(f"expected a 4x4 matrix, got shape {c2w.shape}",
                                  field="camera_to_world")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(c2w))):
            raise ClearsplatError("non-finite value", field="K/camera_to_world")
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ClearsplatError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}",
                                  field="K")
        R = c2w[:3, :3]
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or not np.allclose(R.T @ R, np.eye(3), atol=1e-3):
            raise ClearsplatError("rotation part is not orthonormal with det +1 "
                                  "(singular, scaled or mirrored camera)", field="camera_to_world")
        width, height = int(self.width), int(self.height)
        if width <= 0 or height <= 0:
            raise ClearsplatError(f"image size must be positive, got {width}x{height}",
                                  field="width/height")
        w2c = np.eye(4)
        w2c[:3, :3] = R.T
        w2c[:3, 3] = -R.T @ c2w[:3, 3]
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "camera_to_world", c2w)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        object.__setattr__(self, "world_to_camera", w2c)

    # -- convenience -------------------------------------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates, shape (3,)."""
        return self.camera_to_world[:3, 3].copy()

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @classmethod
    def from_opengl(cls, *, K, camera_to_world_gl, width: int, height: int) -> "Camera":
        """Build from a camera-to-world matrix in OpenGL axes (nerfstudio, Blender)."""
        c2w = np.asarray(camera_to_world_gl, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        return cls(K=K, camera_to_world=c2w @ OPENGL_TO_OPENCV, width=width, height=height)

    def camera_to_world_opengl(self) -> np.ndarray:
        """The camera-to-world matrix in OpenGL axes, shape (4, 4)."""
        return self.camera_to_world @ OPENGL_TO_OPENCV

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (M, 3) to camera coordinates (M, 3)."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points.

        Parameters
        ----------
        points : (M, 3) array_like
            World coordinates.

        Returns
        -------
        uv : (M, 2) float64
            Image coordinates ``(x, y)``; pixel ``(row, col)`` covers
            ``col <= x < col + 1`` and ``row <= y < row + 1``.
            Undefined (inf or nan) where ``z <= 0``.
        z : (M,) float64
            Depth along the optical axis.
        """
        pc = self.to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K[0, 0] * pc[:, 0] / z + self.K[0, 2]
            v = self.K[1, 1] * pc[:, 1] / z + self.K[1, 2]
        return np.stack([u, v], axis=1), z

    def flat_pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pixel of this camera's image that each world point falls in.

        Parameters
        ----------
        points : (M, 3) array_like
            World coordinates.

        Returns
        -------
        pixels : (M,) int64
            Flat pixel index ``row * width + col``; -1 behind the camera or outside the image.
        z : (M,) float64
            Depth along the optical axis.
        """
        uv, z = self.project(points)
        with np.errstate(invalid="ignore"):
            col = np.floor(np.nan_to_num(uv[:, 0], nan=-1.0, posinf=-1.0, neginf=-1.0))
            row = np.floor(np.nan_to_num(uv[:, 1], nan=-1.0, posinf=-1.0, neginf=-1.0))
        ok = (z > 0) & (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return np.where(ok, row * self.width + col, -1).astype(np.int64), z

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through every pixel centre.

        Returns
        -------
        origin : (3,) float64
        directions : (H, W, 3) float64
            Not normalised: ``origin + t * d`` has camera depth ``t``.
        """
        cols = np.arange(self.width) + 0.5
        rows = np.arange(self.height) + 0.5
        x = (cols[None, :] - self.cx) / self.fx
        y = (rows[:, None] - self.cy) / self.fy
        d_cam = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1)
        d_world = d_cam @ self.camera_to_world[:3, :3].T
        return self.position, d_world

    def unproject(self, depth: np.ndarray) -> np.ndarray:
        """Pixel-centre points at the given camera depth.

        Parameters
        ----------
        depth : (H, W) array_like
            Depth along the optical axis (camera z), not ray length.

        Returns
        -------
        points : (H, W, 3) float64, world coordinates.
        """
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (self.height, self.width):
            raise ClearsplatError(f"expected depth of shape {(self.height, self.width)}, "
                                  f"got {depth.shape}", field="depth")
        o, d = self.pixel_rays()
        return o + d * depth[..., None]

    def scaled(self, factor: float) -> "Camera":
        """The same camera at ``factor`` times the resolution (rounded)."""
        w, h = round(self.width * factor), round(self.height * factor)
        sx, sy = w / self.width, h / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        return Camera(K=K, camera_to_world=self.camera_to_world, width=w, height=h)

    def __eq__(self, other) -> bool:
        return (isinstance(other, Camera) and self.width == other.width
                and self.height == other.height and np.array_equal(self.K, other.K)
                and np.array_equal(self.camera_to_world, other.camera_to_world))

    __hash__ = None
