"""clearsplat: remove transient distractors from feed-forward 3D Gaussian Splatting predictions.

Conventions (axes, matrices, quaternion order, pixel centres, SH layout) are on one page:
``docs/conventions.md``; the method and every option of the filter: ``docs/method.md``.
"""

from .cameras import Camera
from .errors import ClearsplatError
from .filter import Candidate, FilterConfig, FilterResult, filter_distractors
from .io import load_scene, read_ply, save_scene, write_ply
from .render import (Contributions, PreparedView, RenderResult, TilePatch, contributions,
                     prepare, render, render_batch)
from .scene import Gaussians, RenderSettings, Scene

#: The one place the version is written: pyproject.toml reads it (scikit-build-core's regex
#: provider), CHANGELOG.md's newest section names it (tests/test_release.py).
__version__ = "0.14.0"

__all__ = [
    "Camera", "ClearsplatError", "Gaussians", "Scene", "RenderSettings", "__version__",
    "load_scene", "read_ply", "save_scene", "write_ply",
    "render", "render_batch", "contributions", "prepare",
    "RenderResult", "Contributions", "PreparedView", "TilePatch",
    "filter_distractors", "FilterConfig", "FilterResult", "Candidate",
]
