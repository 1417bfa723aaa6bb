"""Drop the distractor filter into a DepthSplat-style inference loop.

The model, its checkpoint and its data loader are yours (DepthSplat's ``src/main.py`` builds
them from a Hydra config); this file shows only what changes around the encoder call:

1. run the encoder on a batch of context views, as DepthSplat's ``test_step`` does;
2. turn its native ``Gaussians`` into a :class:`clearsplat.Scene` with
   :func:`clearsplat.adapters.from_depthsplat` (cameras and images come from the batch);
3. run :func:`clearsplat.filter.filter_distractors` and apply the result (removed Gaussians get
   opacity zero);
4. save the filtered scene as a bundle (``cameras.json``, ``images/``, ``gaussians.ply``), or
   keep rendering with the model's decoder by writing the new opacities back into its tensors.

Run as ``python examples/depthsplat_inference.py --help``. Nothing from DepthSplat is imported
at module level, so the file imports (and its ``--dry-run`` runs) without PyTorch or the model.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import clearsplat
from clearsplat.adapters import from_depthsplat
from clearsplat.filter import FilterConfig, filter_distractors


def filter_batch(gaussians, context, *, out_dir: Path, batch: int = 0,
                 config: FilterConfig | None = None):
    """Filter one batch item of a DepthSplat prediction and save it.

    Parameters
    ----------
    gaussians : DepthSplat ``Gaussians``
        The encoder output (``means [B, G, 3]``, ``covariances``, ``harmonics``,
        ``opacities``), on any device.
    context : dict
        ``batch["context"]`` after the data shim: ``extrinsics [B, V, 4, 4]``, normalised
        ``intrinsics [B, V, 3, 3]``, ``image [B, V, 3, H, W]`` in [0, 1].
    out_dir : Path
        Where the scene bundle goes.

    Returns
    -------
    keep : (G,) bool NumPy array
        False for the Gaussians the filter removed (layout order, as in ``gaussians``).
    """
    _, _, _, height, width = context["image"].shape
    scene = from_depthsplat(gaussians, context["extrinsics"], context["intrinsics"],
                            context["image"], height=height, width=width, batch=batch)
    result = filter_distractors(scene, config=config or FilterConfig())
    print(f"removed {int(result.removed.sum())} of {len(scene)} Gaussians "
          f"({sum(c.accepted for c in result.candidates)} regions)")
    result.apply(scene).save(out_dir, overwrite=True)
    return result.keep


def write_back(gaussians, keep: np.ndarray, *, batch: int = 0):
    """Zero the opacities of removed Gaussians in the model's own tensors (for its decoder)."""
    import torch  # only needed here

    mask = torch.as_tensor(keep, device=gaussians.opacities.device)
    gaussians.opacities[batch] = torch.where(mask, gaussians.opacities[batch],
                                             torch.zeros_like(gaussians.opacities[batch]))
    return gaussians


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("filtered"))
    parser.add_argument("--dry-run", action="store_true",
                        help="run on synthetic arrays shaped like DepthSplat's output "
                             "(no model, no PyTorch)")
    args = parser.parse_args(argv)

    if args.dry_run:
        gaussians, context = _synthetic_prediction()
        filter_batch(gaussians, context, out_dir=args.out)
        return

    # ---- your model: replace with DepthSplat's own setup (see its src/main.py) ----
    try:
        import torch
        from src.config import load_typed_root_config          # DepthSplat repository
        from src.model.encoder import get_encoder               # noqa: F401
    except ImportError as e:
        raise SystemExit(f"run inside the DepthSplat repository with its environment ({e}); "
                         "or try --dry-run") from None
    encoder, data_loader = _build_depthsplat(load_typed_root_config)   # user code
    encoder.eval()
    with torch.no_grad():
        for i, batch in enumerate(data_loader):
            context = batch["context"]
            gaussians = encoder(context, global_step=0, deterministic=True)
            if isinstance(gaussians, dict):                         # return_depth=True
                gaussians = gaussians["gaussians"]
            keep = filter_batch(gaussians, context, out_dir=args.out / f"{i:05d}")
            write_back(gaussians, keep)                             # then render as usual


def _build_depthsplat(load_config):
    raise NotImplementedError("build DepthSplat's encoder and test data loader here "
                              "(model code is yours; see DepthSplat's src/main.py)")


def _synthetic_prediction():
    """Arrays laid out like DepthSplat's output, from clearsplat's synthetic benchmark."""
    from clearsplat.adapters import scales_quats_to_covariance
    from clearsplat.synth.backbone import reconstruct

    h, w, v = 48, 64, 3
    K = np.array([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]])
    cams, images, depths = [], [], []
    rows, cols = np.mgrid[0:h, 0:w]
    for i in range(v):
        c2w = np.eye(4)
        c2w[0, 3] = 0.2 * (i - 1)
        cams.append(clearsplat.Camera(K=K, camera_to_world=c2w, width=w, height=h))
        img = np.stack([0.5 + 0.3 * np.sin(0.2 * (cols + 8 * i)), 0.5 + 0.3 * np.cos(0.15 * rows),
                        np.full((h, w), 0.4)], -1)
        depth = np.full((h, w), 4.0)
        if i == 1:                                     # a transient object in one view only
            img[10:25, 20:35] = [0.9, 0.1, 0.1]
            depth[10:25, 20:35] = 2.5
        images.append(img)
        depths.append(depth)
    scene = reconstruct(cams, images, depths, seed=0)
    g = scene.gaussians
    gaussians = {"means": g.means[None], "covariances": scales_quats_to_covariance(
                     g.scales, g.quats)[None],
                 "harmonics": np.swapaxes(g.sh, 1, 2)[None], "opacities": g.opacities[None]}
    context = {"extrinsics": np.stack([c.camera_to_world for c in cams])[None],
               "intrinsics": np.stack([np.diag([1 / w, 1 / h, 1.0]) @ K] * v)[None],
               "image": np.moveaxis(np.stack(images), -1, 1)[None]}
    return gaussians, context


if __name__ == "__main__":
    main()
