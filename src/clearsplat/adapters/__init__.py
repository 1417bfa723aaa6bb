"""Adapters from feed-forward 3DGS models' native outputs to a :class:`clearsplat.Scene`.

One function per model family; each takes the model's tensors (PyTorch on any device, or
NumPy), its cameras and input images, and returns a validated scene with the view association
(``view_id``, ``pixel_id``) the layout implies. Layouts, sources and what each adapter does:
``docs/backbones.md``.

- :func:`from_depthsplat` (= :func:`from_mvsplat`, :func:`from_pixelsplat`): per-pixel,
  world frame, normalised intrinsics.
- :func:`from_noposplat` (= :func:`from_yonosplat`): per-pixel, first view's frame.
- :func:`from_resplat`: latent grid, ``pixel_id = -1``.
- :func:`from_anysplat`: per-pixel or voxel-fused; :func:`anysplat_voxel_inverse` recovers
  the voxel of every pixel from the encoder's outputs.
- :func:`from_pixel_aligned`: any other per-pixel model.
- :func:`covariance_to_scales_quats`, :func:`rotate_sh`: the conversions they use.
- :func:`associate_ordered`, :func:`associate_centred`, :func:`associate_fused`: the
  association recovered from geometry
  and the input images where an export's vertex order has lost it
  (:mod:`clearsplat.adapters.associate`).
"""

from ._common import (NEGATIVE_TOLERANCE, SCALE_FLOOR_ABS, SCALE_FLOOR_RATIO,
                      covariance_to_scales_quats, scales_quats_to_covariance)
from .anysplat import anysplat_voxel_inverse, from_anysplat
from .associate import (Association, Similarity, associate_centred, associate_fused,
                        associate_ordered, normalised_frame)
from .generic import from_pixel_aligned
from .noposplat import from_noposplat, from_yonosplat
from .pixelsplat import from_depthsplat, from_mvsplat, from_pixelsplat, from_resplat
from .sh_rotation import rotate_sh, sh_basis

__all__ = [
    "from_depthsplat", "from_mvsplat", "from_pixelsplat", "from_resplat", "from_noposplat",
    "from_yonosplat", "from_anysplat", "anysplat_voxel_inverse", "from_pixel_aligned",
    "covariance_to_scales_quats",
    "scales_quats_to_covariance", "rotate_sh", "sh_basis", "SCALE_FLOOR_RATIO",
    "SCALE_FLOOR_ABS", "NEGATIVE_TOLERANCE", "Association", "Similarity", "associate_ordered",
    "associate_fused", "associate_centred", "normalised_frame",
]
