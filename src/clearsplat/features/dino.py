"""DINOv2 / DINOv3 patch features through Hugging Face ``transformers`` (the paper's Phi).

The model is loaded only from a local checkpoint directory or the local Hugging Face
cache (``local_files_only=True``): nothing is downloaded at run time. ``torch`` and
``transformers`` are imported when an extractor is built, not when
``clearsplat.features`` is imported.

The grid: an ``H x W`` image is resized (bilinear, antialiased when shrinking) to
``(h * p, w * p)`` with ``(h, w) = grid_shape(H, W)`` (the multiple of the model's patch
size ``p`` nearest to the input size), normalised with the checkpoint's image mean and
standard deviation (``preprocessor_config.json``; ImageNet's when absent), and passed
through the model. The patch tokens of the last hidden state (after the final layer
norm), without the CLS token and the register tokens (DINOv3 and DINOv2-with-registers
have 4), form the ``(h, w, C)`` grid. Similarity is their cosine; the thresholds are the
paper's ``tau1 = 0.50``, ``tau2 = 0.70``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError
from .base import FeatureExtractor, check_images

__all__ = ["DEFAULT_CHECKPOINTS", "DinoExtractor"]

DEFAULT_CHECKPOINTS = {
    "dinov2": "facebook/dinov2-small",
    "dinov3": "facebook/dinov3-vits16-pretrain-lvd1689m",
}
_MODEL_TYPES = {
    "dinov2": ("dinov2", "dinov2_with_registers"),
    "dinov3": ("dinov3_vit",),
}
_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


def _how_to(name: str) -> str:
    # Written for both doors: the Python API (FilterConfig) and the command line.
    return (f"give a local checkpoint, a directory written by save_pretrained (e.g. a download "
            f"of {DEFAULT_CHECKPOINTS[name]}): FilterConfig(features={name!r}, "
            f"checkpoint='/path/to/{name}') in Python, or --features {name} --checkpoint "
            f"/path/to/{name} on the command line; or put {DEFAULT_CHECKPOINTS[name]} in the "
            f"Hugging Face cache; clearsplat never downloads weights")


def _import_backend(name: str):
    try:
        import torch
        import transformers
    except ImportError as exc:
        raise ImportError(
            f"the {name!r} features need torch and transformers: pip install "
            f"\"clearsplat[dino]\" (or use the weight-free features='local', e.g. "
            f"FilterConfig.preset('paper-local'), --preset paper-local on the command line); "
            f"then {_how_to(name)}"
        ) from exc
    return torch, transformers


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _looks_like_path(checkpoint: str) -> bool:
    return (os.path.isabs(checkpoint) or checkpoint.startswith((".", "~"))
            or os.path.exists(checkpoint) or checkpoint.count("/") > 1
            or os.sep != "/" and os.sep in checkpoint)


class DinoExtractor(FeatureExtractor):
    """Patch tokens of a DINOv2 or DINOv3 ViT, compared by cosine similarity.

    Parameters
    ----------
    name : {"dinov2", "dinov3"}
        Model family; the checkpoint's ``model_type`` must match it.
    checkpoint : str or os.PathLike, optional
        A local directory written by ``save_pretrained`` or a model id already in the
        Hugging Face cache. Default: :data:`DEFAULT_CHECKPOINTS` ``[name]``.
    device : {"cpu", "cuda"}, optional
        Where to run the model; default ``"cuda"`` when available, else ``"cpu"``.
    batch_size : int, default 8
        Images per forward pass.
    tau1, tau2 : float, optional
        Override the paper's thresholds.

    Raises
    ------
    ImportError
        torch or transformers is missing.
    ClearsplatError
        The checkpoint is missing, cannot be loaded offline, or is not a ViT of the
        requested family.
    """

    tau1 = 0.50
    tau2 = 0.70

    def __init__(self, name: str = "dinov3", *, checkpoint: str | os.PathLike | None = None,
                 device: str | None = None, batch_size: int = 8,
                 tau1: float | None = None, tau2: float | None = None):
        if name not in _MODEL_TYPES:
            raise ClearsplatError(f"unknown DINO family {name!r}; choose one of "
                                  f"{sorted(_MODEL_TYPES)}", field="features")
        self.name = name
        self._set_thresholds(tau1, tau2)
        if int(batch_size) < 1:
            raise ClearsplatError(f"batch_size must be >= 1, got {batch_size}",
                                  field="batch_size")
        self.batch_size = int(batch_size)
        torch, transformers = _import_backend(name)
        self._torch = torch

        if device is None:
            device = "cuda" if torch.cuda.is_available() else "cpu"
        if device not in ("cpu", "cuda") and not str(device).startswith("cuda:"):
            raise ClearsplatError(f"device must be 'cpu' or 'cuda', got {device!r}",
                                  field="device")
        if str(device).startswith("cuda") and not torch.cuda.is_available():
            raise ClearsplatError("device 'cuda' requested but torch sees no CUDA device",
                                  field="device")
        self.device = str(device)

        ckpt = os.fspath(checkpoint) if checkpoint is not None else DEFAULT_CHECKPOINTS[name]
        if checkpoint is not None and _looks_like_path(ckpt):
            ckpt = os.path.expanduser(ckpt)
            if not os.path.isdir(ckpt):
                raise ClearsplatError(f"no checkpoint directory here; {_how_to(name)}",
                                      path=ckpt, field="checkpoint")
        self.checkpoint = ckpt
        try:
            config = transformers.AutoConfig.from_pretrained(ckpt, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise ClearsplatError(f"cannot load a {name} checkpoint offline "
                                  f"({_first_line(exc)}); "
                                  f"{_how_to(name)}", path=ckpt, field="checkpoint") from exc
        if config.model_type not in _MODEL_TYPES[name]:
            raise ClearsplatError(f"checkpoint is a {config.model_type!r} model, expected "
                                  f"one of {_MODEL_TYPES[name]} for --features {name}",
                                  path=ckpt, field="checkpoint")
        try:
            model = transformers.AutoModel.from_pretrained(ckpt, local_files_only=True)
        except (OSError, ValueError) as exc:
            raise ClearsplatError(f"cannot load the {name} weights offline "
                                  f"({_first_line(exc)}); "
                                  f"{_how_to(name)}", path=ckpt, field="checkpoint") from exc
        self._model = model.to(self.device).eval()
        self.patch_size = int(config.patch_size)
        self.num_register_tokens = int(getattr(config, "num_register_tokens", 0) or 0)
        self._mean, self._std = self._normalisation(ckpt)

    @staticmethod
    def _normalisation(ckpt: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Image mean/std from the checkpoint's preprocessor config, else ImageNet's."""
        cfg = Path(ckpt) / "preprocessor_config.json"
        if cfg.is_file():
            try:
                data = json.loads(cfg.read_text())
                mean, std = data["image_mean"], data["image_std"]
                if len(mean) == 3 and len(std) == 3 and min(std) > 0:
                    return tuple(map(float, mean)), tuple(map(float, std))
            except (OSError, ValueError, KeyError, TypeError):
                pass
        return _IMAGENET_MEAN, _IMAGENET_STD

    def features(self, images) -> np.ndarray:
        """Patch-token grid of a batch of images.

        Parameters
        ----------
        images : (B, H, W, 3) float32 in [0, 1]

        Returns
        -------
        features : (B, h, w, C) float32
            ``(h, w) = self.grid_shape(H, W)``, ``C`` the model's hidden size.
        """
        torch = self._torch
        x = check_images(images)
        B, H, W, _ = x.shape
        h, w = self.grid_shape(H, W)
        p = self.patch_size
        mean = torch.tensor(self._mean, dtype=torch.float32).view(1, 3, 1, 1)
        std = torch.tensor(self._std, dtype=torch.float32).view(1, 3, 1, 1)
        out = []
        with torch.inference_mode():
            for start in range(0, B, self.batch_size):
                t = torch.from_numpy(x[start:start + self.batch_size]).permute(0, 3, 1, 2)
                if (H, W) != (h * p, w * p):
                    t = torch.nn.functional.interpolate(
                        t, size=(h * p, w * p), mode="bilinear", align_corners=False,
                        antialias=h * p < H or w * p < W)
                t = ((t - mean) / std).to(self.device)
                hidden = self._model(pixel_values=t).last_hidden_state
                n_prefix = hidden.shape[1] - h * w
                if n_prefix != 1 + self.num_register_tokens:
                    raise ClearsplatError(
                        f"model returned {hidden.shape[1]} tokens for a {h}x{w} patch grid; "
                        f"expected 1 CLS + {self.num_register_tokens} register tokens before "
                        f"the patches", path=self.checkpoint, field="checkpoint")
                patches = hidden[:, n_prefix:, :].reshape(hidden.shape[0], h, w, -1)
                out.append(patches.float().cpu().numpy())
        return np.ascontiguousarray(np.concatenate(out, axis=0), dtype=np.float32)
