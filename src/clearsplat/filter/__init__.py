"""The distractor filter, one module per stage of the paper's method.

- :mod:`.pipeline`    the whole procedure (:func:`filter_distractors`, :func:`run_round`)
- :mod:`.backend`     the one interface to the renderer (native CPU, gsplat on CUDA, torch)
- :mod:`.exclusion`   exclusion renders R_i and R_i^-i
- :mod:`.proposal`    exclusion renders compared with the inputs -> candidate regions
- :mod:`.association` regions -> Gaussians; verification views
- :mod:`.refine`      the Gaussians in front of the (static) reference
- :mod:`.verify`      the scores; individual, additional and joint tests
- :mod:`.expansion`   verified candidates grown to their surroundings
- :mod:`.rounds`      what a round hands to the next
- :mod:`.masks`       connected components and dilation, shared by the stages
- :mod:`.config`      :class:`FilterConfig` and its presets
- :mod:`.result`      :class:`Candidate`, :class:`FilterResult`
- :mod:`.on_device`   :func:`filter_prediction`: the keep mask on the model's device
"""

from .config import PRESETS, FilterConfig
from .on_device import filter_prediction
from .pipeline import filter_distractors
from .result import Candidate, FilterResult

__all__ = ["PRESETS", "Candidate", "FilterConfig", "FilterResult", "filter_distractors",
           "filter_prediction"]
