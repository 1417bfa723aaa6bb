"""Drop the distractor filter into DepthSplat's inference loop.

Run inside a checkout of DepthSplat (https://github.com/cvg/depthsplat) with its environment::

    python /path/to/clearsplat/examples/depthsplat_inference.py \\
        --checkpoint pretrained/depthsplat-gs-small-re10kdl3dv-448x768-randview4-10-c08188db.pth \\
        --out filtered -- +experiment=re10k dataset/view_sampler=evaluation \\
        dataset.view_sampler.index_path=assets/evaluation_index_re10k.json

(the words after ``--`` are DepthSplat's own Hydra overrides, as in its README's test commands).
Per test batch this does what DepthSplat's ``ModelWrapper.test_step`` does up to the encoder,
then filters:

1. load the encoder: DepthSplat's checkpoints hold the whole ``ModelWrapper``'s state_dict, so
   the encoder's weights are the ``encoder.``-prefixed entries (:func:`encoder_state_dict`);
2. move the batch to the encoder's device (Lightning does this for DepthSplat;
   :func:`to_device`) and apply the data shim, ``apply_patch_shim``, which centre-crops the
   images to a multiple of the encoder's patch size and rescales the intrinsics;
3. run the encoder on ``batch["context"]``;
4. turn its native ``Gaussians`` into a :class:`clearsplat.Scene` with
   :func:`clearsplat.adapters.from_depthsplat` (cameras and the cropped images from the batch),
   run :func:`clearsplat.filter_distractors` and save the filtered scene as a bundle
   (``cameras.json``, ``images/``, ``gaussians.ply``);
5. write the new opacities back into the model's tensors (:func:`write_back`) to keep rendering
   with its decoder.

``--backend torch`` runs the filter's renders through the torch backend on ``--device`` (the
native rasterizer's math in torch; ``docs/method.md``, "The torch backend"), and the keep mask
comes back as a bool tensor there (``FilterResult.keep_tensor``).

``--dry-run`` runs steps 4 and 5 without DepthSplat or PyTorch, on a prediction laid out like
DepthSplat's: four views of a textured wall, consistent with their cameras, and an object that
stands in front of the wall in one view only (a distractor). The filter removes the object and
keeps the wall. Nothing from DepthSplat is imported at module level.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import clearsplat
from clearsplat.adapters import from_depthsplat
from clearsplat.filter import FilterConfig, filter_distractors

#: The planted distractor of the dry run: view, rows, columns.
DRY_RUN_OBJECT = (1, slice(30, 62), slice(50, 82))


def filter_batch(gaussians, context, *, out_dir: Path, batch: int = 0,
                 config: FilterConfig | None = None, overwrite: bool = False):
    """Filter one batch item of a DepthSplat prediction and save it as a bundle.

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
    overwrite : bool
        Replace an earlier bundle at ``out_dir`` (never a folder that is not a bundle).

    Returns
    -------
    result : FilterResult
        ``result.keep`` is False for the Gaussians the filter removed, in the layout order of
        ``gaussians``.
    """
    _, _, _, height, width = context["image"].shape
    scene = from_depthsplat(gaussians, context["extrinsics"], context["intrinsics"],
                            context["image"], height=height, width=width, batch=batch)
    result = filter_distractors(scene, config=config or FilterConfig())
    print(f"removed {int(result.removed.sum()):,} of {len(scene):,} Gaussians "
          f"({sum(c.accepted for c in result.candidates)} regions); wrote {out_dir}")
    result.apply(scene).save(out_dir, overwrite=overwrite)
    return result


def write_back(gaussians, keep, *, batch: int = 0):
    """Zero the opacities of removed Gaussians in the model's own tensors (for its decoder)."""
    import torch  # only needed here

    mask = torch.as_tensor(keep, device=gaussians.opacities.device)
    gaussians.opacities[batch] = torch.where(mask, gaussians.opacities[batch],
                                             torch.zeros_like(gaussians.opacities[batch]))
    return gaussians


def encoder_state_dict(checkpoint: dict) -> dict:
    """The encoder's weights from a DepthSplat checkpoint.

    DepthSplat saves the ``ModelWrapper`` (a LightningModule holding ``encoder``, ``decoder``
    and the losses), optionally under ``"state_dict"``; the encoder's entries are the keys
    starting with ``encoder.``, which this strips.
    """
    state = checkpoint.get("state_dict", checkpoint)
    prefix = "encoder."
    out = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
    if not out:
        raise SystemExit("no 'encoder.' weights in the checkpoint: expected a DepthSplat "
                         "ModelWrapper state_dict (the released .pth files or a training .ckpt)")
    return out


def to_device(obj, device):
    """``obj`` with every tensor inside (nested dicts, lists, tuples) moved to ``device``."""
    if hasattr(obj, "to") and hasattr(obj, "device"):
        return obj.to(device)
    if isinstance(obj, dict):
        return {k: to_device(v, device) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_device(v, device) for v in obj)
    return obj


def load_depthsplat(checkpoint: Path, overrides: list, device: str):
    """DepthSplat's encoder (with the checkpoint's weights, on ``device``), its data shim and
    its test data loader, built from its Hydra config as its ``src/main.py`` does."""
    import torch
    from hydra import compose, initialize_config_dir

    from src.config import load_typed_root_config          # DepthSplat repository
    from src.dataset.data_module import DataModule, get_data_shim
    from src.global_cfg import set_cfg
    from src.model.encoder import get_encoder

    with initialize_config_dir(config_dir=str(Path("config").resolve()), version_base=None):
        cfg_dict = compose(config_name="main", overrides=["mode=test", *overrides])
    set_cfg(cfg_dict)
    cfg = load_typed_root_config(cfg_dict)
    encoder, _ = get_encoder(cfg.model.encoder)
    encoder.load_state_dict(encoder_state_dict(torch.load(checkpoint, map_location="cpu")))
    encoder = encoder.to(device).eval()
    shim = get_data_shim(encoder)         # apply_patch_shim, as ModelWrapper.test_step applies
    loader = DataModule(cfg.dataset, cfg.data_loader, None, global_rank=0).test_dataloader()
    return encoder, shim, loader


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("filtered"),
                        help="folder for the filtered bundles, one per batch item")
    parser.add_argument("--force", action="store_true",
                        help="replace bundles that an earlier run wrote")
    parser.add_argument("--dry-run", action="store_true",
                        help="run on a synthetic prediction laid out like DepthSplat's (no "
                             "model, no PyTorch)")
    parser.add_argument("--checkpoint", type=Path, help="DepthSplat checkpoint (.pth / .ckpt)")
    parser.add_argument("--device", default="cuda", help="the encoder's device")
    parser.add_argument("--backend", choices=("native", "torch"), default="native",
                        help="the filter's renderer: the native CPU rasterizer, or the torch "
                             "backend on --device (docs/method.md, 'The torch backend')")
    parser.add_argument("overrides", nargs="*", help="DepthSplat's Hydra overrides")
    args = parser.parse_args(argv)
    config = (FilterConfig(backend="torch", device=args.device) if args.backend == "torch"
              else None)

    if args.dry_run:
        gaussians, context = synthetic_prediction()
        filter_batch(gaussians, context, out_dir=args.out, overwrite=args.force, config=config)
        return
    if args.checkpoint is None:
        parser.error("--checkpoint is required (or try --dry-run)")
    try:
        import torch
        encoder, shim, loader = load_depthsplat(args.checkpoint, args.overrides, args.device)
    except ImportError as e:
        raise SystemExit(f"run inside the DepthSplat repository with its environment ({e}); "
                         "or try --dry-run") from None
    with torch.no_grad():
        for i, batch in enumerate(loader):
            batch = shim(to_device(batch, args.device))
            prediction = encoder(batch["context"], 0, deterministic=False)
            gaussians = prediction["gaussians"] if isinstance(prediction, dict) else prediction
            for b in range(batch["context"]["image"].shape[0]):
                result = filter_batch(gaussians, batch["context"], batch=b, config=config,
                                      out_dir=args.out / f"{i:05d}_{b}", overwrite=args.force)
                keep = result.keep_tensor(gaussians.opacities.device)  # (N,) bool there
                write_back(gaussians, keep, batch=b)     # then render as usual


def _wall_colour(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The colours painted on the dry run's wall, at world coordinates (x, y)."""
    r = 0.5 + 0.25 * np.sin(7.0 * x) * np.cos(5.0 * y) + 0.1 * np.sign(np.sin(19.0 * x + 3 * y))
    g = 0.5 + 0.25 * np.cos(6.0 * y + 2.0 * x)
    b = 0.45 + 0.2 * np.sin(11.0 * (x + y))
    return np.clip(np.stack([r, g, b], -1), 0.0, 1.0)


def synthetic_prediction(*, height: int = 96, width: int = 128, views: int = 4):
    """A prediction laid out like DepthSplat's output, consistent with its cameras.

    The cameras (focal length 100 px, OpenCV axes) look along +z at a textured wall at z = 4,
    side by side 0.25 apart: the wall shifts 6.25 px between neighbouring views, in the images
    as in the geometry. View 1 also sees a red object at depth 2.5 (:data:`DRY_RUN_OBJECT`) that
    the other views do not: a distractor. Gaussians come from clearsplat's stand-in backbone
    (one per pixel at the depth of what the pixel sees).
    """
    from clearsplat.adapters import scales_quats_to_covariance
    from clearsplat.synth.backbone import reconstruct

    h, w, f, wall = height, width, 100.0, 4.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    rows, cols = np.mgrid[0:h, 0:w] + 0.5            # pixel centres
    cams, images, depths = [], [], []
    view, box_rows, box_cols = DRY_RUN_OBJECT
    for i in range(views):
        c2w = np.eye(4)
        c2w[0, 3] = 0.25 * (i - (views - 1) / 2)
        cams.append(clearsplat.Camera(K=K, camera_to_world=c2w, width=w, height=h))
        # The wall point each pixel sees: camera centre + depth * ray.
        img = _wall_colour(c2w[0, 3] + (cols - w / 2) / f * wall, (rows - h / 2) / f * wall)
        depth = np.full((h, w), wall)
        if i == view:
            img[box_rows, box_cols] = [0.85, 0.12, 0.10]
            depth[box_rows, box_cols] = 2.5
        images.append(img.astype(np.float32))
        depths.append(depth)
    scene = reconstruct(cams, images, depths, seed=0)
    g = scene.gaussians
    gaussians = {"means": g.means[None], "covariances": scales_quats_to_covariance(
                     g.scales, g.quats)[None],
                 "harmonics": np.swapaxes(g.sh, 1, 2)[None], "opacities": g.opacities[None]}
    context = {"extrinsics": np.stack([c.camera_to_world for c in cams])[None],
               "intrinsics": np.stack([np.diag([1 / w, 1 / h, 1.0]) @ K] * views)[None],
               "image": np.moveaxis(np.stack(images), -1, 1)[None]}
    return gaussians, context


if __name__ == "__main__":
    main()
