"""Image metrics (PSNR, SSIM, LPIPS) and filter accuracy.

Images are (H, W, 3) or (H, W) float arrays with data range 1 (RGB in [0, 1]).
"""

from __future__ import annotations

import importlib.util
import os

import numpy as np
from scipy import ndimage

from .errors import ClearsplatError

__all__ = ["psnr", "ssim", "lpips", "lpips_available", "LpipsUnavailable", "removal_stats"]


class LpipsUnavailable(ClearsplatError):
    """LPIPS was asked for but the ``lpips`` package or its weights are not installed."""


def _pair(a, b):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ClearsplatError(f"images differ in shape: {a.shape} and {b.shape}", field="b")
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (1, 3)):
        raise ClearsplatError(f"expected an (H, W) or (H, W, 3) image, got shape {a.shape}",
                              field="a")
    return a, b


def psnr(a, b, *, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: ``10 log10(data_range**2 / mean((a - b)**2))``.

    Parameters
    ----------
    a, b : (H, W, 3) or (H, W) array_like
        Images of the same shape.
    data_range : float
        Difference between the largest and smallest possible values.

    Returns
    -------
    float
        ``inf`` for identical images.
    """
    a, b = _pair(a, b)
    mse = float(np.mean((a - b) ** 2))
    if mse == 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range ** 2 / mse))


def ssim(a, b, *, data_range: float = 1.0) -> float:
    """Structural similarity as in the 3DGS evaluation (Wang et al. 2004).

    An 11x11 Gaussian window (sigma 1.5, truncated at 3.5 sigma), ``C1 = (0.01 L)^2``,
    ``C2 = (0.03 L)^2``, population (co)variances, computed per channel and averaged.
    Borders are reflected and the 5-pixel margin is left out of the mean, which matches
    ``skimage.metrics.structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=-1)``. (The 3DGS code pads
    with zeros and keeps the margin; values differ slightly near the borders.)

    Parameters
    ----------
    a, b : (H, W, 3) or (H, W) array_like
        Images of the same shape, at least 11 pixels on each side.
    data_range : float

    Returns
    -------
    float
    """
    a, b = _pair(a, b)
    if min(a.shape[:2]) < 11:
        raise ClearsplatError(f"SSIM needs at least 11x11 pixels, got {a.shape[:2]}", field="a")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    pad = 5

    def blur(x):
        return ndimage.gaussian_filter(x, 1.5, mode="reflect", truncate=3.5)

    scores = []
    for c in range(a.shape[2]):
        x, y = a[..., c], b[..., c]
        mx, my = blur(x), blur(y)
        vx = blur(x * x) - mx * mx
        vy = blur(y * y) - my * my
        cxy = blur(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        scores.append(s[pad:-pad, pad:-pad].mean())
    return float(np.mean(scores))


def _lpips_weights_present() -> bool:
    """Whether LPIPS could run offline: package, torch and the AlexNet weights on disk."""
    if importlib.util.find_spec("lpips") is None or importlib.util.find_spec("torch") is None:
        return False
    spec = importlib.util.find_spec("lpips")
    root = os.path.dirname(spec.origin or "")
    if not os.path.isfile(os.path.join(root, "weights", "v0.1", "alex.pth")):
        return False
    import torch  # only now: it is heavy, and only needed when lpips is installed

    checkpoints = os.path.join(torch.hub.get_dir(), "checkpoints")
    return os.path.isdir(checkpoints) and any(
        f.startswith("alexnet-") and f.endswith(".pth") for f in os.listdir(checkpoints))


_LPIPS_MODEL = None


def lpips_available() -> bool:
    """True when :func:`lpips` can run: the ``lpips`` package and its weights are local.

    Nothing is downloaded; without them LPIPS is reported as unavailable, never
    approximated.
    """
    return _lpips_weights_present()


def lpips(a, b) -> float:
    """LPIPS (AlexNet, v0.1) between two RGB images in [0, 1]; lower is closer.

    Raises
    ------
    LpipsUnavailable
        When the ``lpips`` package, ``torch`` or the AlexNet weights are not installed
        locally (see :func:`lpips_available`).
    """
    if not lpips_available():
        raise LpipsUnavailable("LPIPS is unavailable: install the `lpips` package and its "
                               "AlexNet weights (nothing is downloaded at run time)",
                               field="lpips")
    a, b = _pair(a, b)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ClearsplatError(f"LPIPS needs (H, W, 3) images, got {a.shape}", field="a")
    global _LPIPS_MODEL
    import lpips as lpips_pkg
    import torch

    if _LPIPS_MODEL is None:
        _LPIPS_MODEL = lpips_pkg.LPIPS(net="alex", verbose=False).eval()

    def tensor(x):
        return torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)[None] * 2 - 1)).float()

    with torch.no_grad():
        return float(_LPIPS_MODEL(tensor(a), tensor(b)).item())


def removal_stats(removed, truth) -> dict:
    """How well a filter removed the distractor Gaussians.

    Parameters
    ----------
    removed : (N,) array_like of bool
        Gaussians the filter removed.
    truth : (N,) array_like of bool
        Gaussians that are distractors (from :func:`clearsplat.synth.distractor_truth`).

    Returns
    -------
    dict
        ``recall``: share of distractor Gaussians removed (nan without distractors);
        ``precision``: share of removed Gaussians that are distractors (nan if none removed);
        ``static_removed``: share of the other Gaussians removed (nan if there are none);
        ``removed_share``: share of all Gaussians removed;
        counts ``n``, ``n_distractor``, ``n_static``, ``n_removed``,
        ``n_removed_distractor``, ``n_removed_static``, ``n_missed``.
    """
    removed = np.asarray(removed)
    truth = np.asarray(truth)
    for name, arr in (("removed", removed), ("truth", truth)):
        if arr.dtype != bool or arr.ndim != 1:
            raise ClearsplatError(f"expected a 1-D bool array, got {arr.dtype} of shape "
                                  f"{arr.shape}", field=name)
    if removed.shape != truth.shape:
        raise ClearsplatError(f"{removed.shape[0]} removal flags for {truth.shape[0]} "
                              "Gaussians", field="removed")
    n = int(truth.size)
    n_dis = int(truth.sum())
    n_rem = int(removed.sum())
    tp = int((removed & truth).sum())
    fp = n_rem - tp

    def share(k, total):
        return k / total if total else float("nan")

    return {
        "recall": share(tp, n_dis),
        "precision": share(tp, n_rem),
        "static_removed": share(fp, n - n_dis),
        "removed_share": share(n_rem, n),
        "n": n,
        "n_distractor": n_dis,
        "n_static": n - n_dis,
        "n_removed": n_rem,
        "n_removed_distractor": tp,
        "n_removed_static": fp,
        "n_missed": n_dis - tp,
    }
