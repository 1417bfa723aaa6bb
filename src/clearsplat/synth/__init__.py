"""Synthetic distractor benchmark: procedural worlds with analytic ground truth.

- :func:`make_world` builds an ``"object"`` (RobustNeRF-like) or ``"street"``
  (NeRF On-the-go-like) capture: cluttered inputs, their clean twins, depths, transient
  masks and held-out test views, all ray cast analytically.
- :func:`reconstruct` is a stand-in feed-forward backbone: one Gaussian per input pixel
  with the imperfections of a learned model; :func:`clean_reference` runs it on the clean
  twin and :func:`distractor_truth` says which Gaussians are distractors.
- :func:`realistic_reconstruction` gives that backbone the artifacts of real models (soft
  opacities, depth scale bias, several Gaussians per pixel, exposure, pose error, coarse
  grids), each a named scenario (:data:`SCENARIOS`).
"""

from .backbone import clean_reference, distractor_truth, reconstruct
from .realism import SCENARIOS, realistic_reconstruction
from .worlds import FAMILIES, OCCLUSION_LEVELS, World, make_world

__all__ = ["World", "make_world", "reconstruct", "clean_reference", "distractor_truth",
           "FAMILIES", "OCCLUSION_LEVELS", "realistic_reconstruction", "SCENARIOS"]
