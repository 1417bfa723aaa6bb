"""Filter a prediction inside an inference loop and get the keep mask on the model's device.

:func:`filter_prediction` is :func:`~clearsplat.filter.filter_distractors` with the torch
backend (``FilterConfig.backend="torch"``) on the device of the prediction, returning
:meth:`FilterResult.keep_tensor <clearsplat.filter.FilterResult.keep_tensor>`::

    scene = from_depthsplat(gaussians, extrinsics, intrinsics, images, height=h, width=w)
    keep = filter_prediction(scene, device=gaussians.means.device)   # (N,) bool, on the GPU
    opacities = gaussians.opacities.reshape(-1) * keep

What crosses the bus: the adapters convert a backbone's layout (covariances, SH, batches) in
NumPy, and the stages read the images, features and masks on the host, so the prediction
comes to the host once; the torch backend uploads the converted Gaussians once per round
(the views of a round share them) and every render and re-render runs on the device; the
keep mask goes back as one (N,) bool tensor.
"""

from __future__ import annotations

from ..scene import Scene
from .config import FilterConfig
from .pipeline import filter_distractors

__all__ = ["filter_prediction"]


def filter_prediction(scene: Scene, *, device="cuda", config: FilterConfig | None = None,
                      extractor=None, progress=None):
    """The keep mask of a prediction's Gaussians, computed and returned on ``device``.

    Parameters
    ----------
    scene : Scene
        The prediction (from an adapter, e.g. :func:`clearsplat.adapters.from_depthsplat`),
        with its input images.
    device : str or torch.device
        Where the renders run and the mask is returned (``"cuda"``, ``"cuda:1"``, ``"cpu"``).
    config : FilterConfig, optional
        Options (``FilterConfig()`` by default); ``backend`` and ``device`` are set here.
    extractor, progress
        As in :func:`~clearsplat.filter.filter_distractors`.

    Returns
    -------
    torch.Tensor
        (N,) bool on ``device``: False for the Gaussians to remove.

    Raises
    ------
    ClearsplatError
        Without PyTorch (or without CUDA for a CUDA device), naming the field ``backend``.
    """
    config = (config or FilterConfig()).replace(backend="torch", device=str(device))
    result = filter_distractors(scene, config=config, extractor=extractor, progress=progress)
    return result.keep_tensor(device)
