"""File input and output: scene bundles, 3DGS PLY files, cameras and images.

Formats are described in the module docstrings of :mod:`clearsplat.io.bundle` (bundle folder,
``cameras.json``, nerfstudio ``transforms.json``), :mod:`clearsplat.io.ply` (Gaussians) and
:mod:`clearsplat.io.images`; every error they raise is listed in ``docs/errors.md``.
"""

from .bundle import (load_cameras, load_render_settings, load_scene, save_bundle_cameras,
                     save_cameras, save_scene,
                     swap_into_place)
from .colmap import read_colmap
from .exports import EXPORT_PRESETS, read_export
from .images import read_image, write_image
from .ply import read_ply, write_ply

__all__ = ["load_scene", "save_scene", "load_cameras", "save_cameras", "save_bundle_cameras",
           "read_ply", "write_ply", "read_image", "write_image", "read_colmap",
           "read_export", "EXPORT_PRESETS", "swap_into_place", "load_render_settings"]
