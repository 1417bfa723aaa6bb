"""clearsplat: remove transient distractors from feed-forward 3D Gaussian Splatting predictions.

Conventions (axes, matrices, quaternion order, pixel centres, SH layout) are on one page:
``docs/conventions.md``.
"""

from .cameras import Camera
from .errors import ClearsplatError
from .io import load_scene, read_ply, save_scene, write_ply
from .scene import Gaussians, Scene

__version__ = "0.1.0"

__all__ = [
    "Camera", "ClearsplatError", "Gaussians", "Scene", "__version__",
    "load_scene", "read_ply", "save_scene", "write_ply",
]
