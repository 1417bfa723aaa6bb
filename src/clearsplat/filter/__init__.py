"""The distractor filter, one module per stage of the paper's method.

- :mod:`.proposal`    exclusion renders compared with the inputs -> candidate regions
- :mod:`.association` regions -> Gaussians; verification views
- :mod:`.verify`      rendering-change-weighted error reduction
- :mod:`.pipeline`    the whole procedure (:func:`filter_distractors`)
- :mod:`.config`      :class:`FilterConfig` and its presets
"""

from .config import PRESETS, FilterConfig
from .pipeline import Candidate, FilterResult, filter_distractors

__all__ = ["PRESETS", "Candidate", "FilterConfig", "FilterResult", "filter_distractors"]
