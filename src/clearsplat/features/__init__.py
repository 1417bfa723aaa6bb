"""Feature extractors behind the distractor proposal, all with one interface.

``get_extractor(name, **options)`` returns a :class:`FeatureExtractor`:

``"local"`` (default)
    A weight-free descriptor (colour kernel, colour layout, gradient orientations, with
    a context ring); :mod:`clearsplat.features.local`.
``"rgb"``
    Per-patch RGB difference, the paper's ablation; :mod:`clearsplat.features.rgb`.
``"dinov2"``, ``"dinov3"``
    ViT patch tokens from a local checkpoint (needs ``pip install "clearsplat[dino]"``);
    :mod:`clearsplat.features.dino`. torch is imported only when one is built.

Each carries ``tau1 < tau2`` calibrated for its similarity scale (the paper's 0.50 / 0.70
for DINO; :mod:`clearsplat.features.calibrate` for the others). The patch grid and its
mapping to pixels are described in :mod:`clearsplat.features.base`.
"""

from __future__ import annotations

import inspect

from ..errors import ClearsplatError
from .base import (FeatureExtractor, cell_average, cell_edges, cell_slices,
                   cosine_similarity, grid_shape_for, upsample_nearest)
from .local import LocalDescriptor
from .rgb import RGBDifference

__all__ = [
    "DEFAULT_EXTRACTOR",
    "FeatureExtractor",
    "LocalDescriptor",
    "RGBDifference",
    "available_extractors",
    "cell_average",
    "cell_edges",
    "cell_slices",
    "cosine_similarity",
    "get_extractor",
    "grid_shape_for",
    "upsample_nearest",
]

DEFAULT_EXTRACTOR = "local"
_NAMES = ("local", "rgb", "dinov2", "dinov3")


def available_extractors() -> tuple[str, ...]:
    """Names accepted by :func:`get_extractor` (the DINO ones also need a checkpoint)."""
    return _NAMES


def get_extractor(name: str = DEFAULT_EXTRACTOR, **options) -> FeatureExtractor:
    """Build a feature extractor by name.

    Parameters
    ----------
    name : {"local", "rgb", "dinov2", "dinov3"}, default "local"
    **options
        Keyword options of the extractor class: ``patch_size``, ``tau1``, ``tau2`` for
        all but DINO's patch size; ``colour_sigma``, ``context`` for ``"local"``;
        ``checkpoint``, ``device``, ``batch_size`` for ``"dinov2"`` / ``"dinov3"``.

    Returns
    -------
    FeatureExtractor

    Raises
    ------
    ClearsplatError
        Unknown name or option, or (DINO) a checkpoint that cannot be loaded offline.
    ImportError
        (DINO) torch or transformers is not installed.
    """
    if name == "local":
        cls, args = LocalDescriptor, ()
    elif name == "rgb":
        cls, args = RGBDifference, ()
    elif name in ("dinov2", "dinov3"):
        from .dino import DinoExtractor
        cls, args = DinoExtractor, (name,)
    else:
        raise ClearsplatError(f"unknown feature extractor {name!r}; choose one of "
                              f"{', '.join(_NAMES)}", field="features")
    try:
        inspect.signature(cls).bind(*args, **options)
    except TypeError as exc:
        raise ClearsplatError(f"bad option for the {name!r} extractor: {exc}",
                              field="features") from exc
    return cls(*args, **options)
