"""Filter an AnySplat prediction, voxels included.

AnySplat's released configs fuse pixels into voxels (``voxelize: true``), and its
``inference()`` returns only ``(gaussians, pred_context_pose)``: the pixel -> voxel index that
says which views made each Gaussian is not among the outputs. This example calls the encoder
itself, which also returns ``pred_pose_enc_list`` and ``depth_dict``, and recomputes that index:

1. run ``model.encoder(images, global_step=0)`` (what ``inference()`` does inside);
2. ``voxel_inverse``: either :func:`clearsplat.adapters.anysplat_voxel_inverse` (NumPy; agrees
   with the encoder up to float32 round-off at voxel boundaries) or :func:`exact_voxel_inverse`
   (the encoder's own PyTorch functions on the same tensors: the same indices);
3. :func:`clearsplat.adapters.from_anysplat` with the predicted poses (its default
   ``vggt_pixels=True`` moves the principal points half a pixel to clearsplat's pixel centres);
4. :func:`clearsplat.filter.filter_distractors`, apply, save a bundle.

Run as ``python examples/anysplat_inference.py --help``; ``--dry-run`` runs steps 2-4 on
synthetic arrays shaped like AnySplat's outputs (no model, no PyTorch).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clearsplat.adapters import anysplat_voxel_inverse, from_anysplat
from clearsplat.filter import FilterConfig, filter_distractors


def exact_voxel_inverse(encoder_output, image_hw, voxel_size: float, batch: int = 0):
    """The encoder's own computation (inside the AnySplat repository, with PyTorch)."""
    import torch
    from src.model.encoder.vggt.utils.geometry import batchify_unproject_depth_map_to_point_map
    from src.model.encoder.vggt.utils.pose_enc import pose_encoding_to_extri_intri

    extrinsic, intrinsic = pose_encoding_to_extri_intri(
        encoder_output.pred_pose_enc_list[-1], image_hw)
    pts = batchify_unproject_depth_map_to_point_map(
        encoder_output.depth_dict["depth"], extrinsic, intrinsic)
    voxels = (pts[batch].reshape(-1, 3) / voxel_size).round().int()
    _, inverse = torch.unique(voxels, dim=0, return_inverse=True)
    return inverse.cpu().numpy()


def filter_prediction(gaussians, pose, pose_encoding, depth, images, *, voxel_size: float,
                      out_dir: Path, inverse=None, config: FilterConfig | None = None):
    """Filter one AnySplat prediction (batch item 0) and save it as a bundle.

    Parameters
    ----------
    gaussians : AnySplat ``Gaussians``
        ``means [1, N, 3]``, ``covariances``, ``harmonics``, ``opacities``.
    pose : dict
        ``pred_context_pose``: ``extrinsic [1, V, 4, 4]`` camera-to-world, ``intrinsic``
        normalised.
    pose_encoding : [1, V, 9]
        ``encoder_output.pred_pose_enc_list[-1]``.
    depth : [1, V, H, W(, 1)]
        ``encoder_output.depth_dict["depth"]``.
    images : [1, V, 3, H, W]
        The input images in [0, 1] (before AnySplat's normalisation).
    voxel_size : float
        The encoder's ``voxel_size`` (0.002 in the released configs).
    inverse : (V*H*W,) int, optional
        From :func:`exact_voxel_inverse`; recomputed with NumPy when left out.
    """
    v, h, w = np.shape(images)[1], np.shape(images)[3], np.shape(images)[4]
    n = np.shape(gaussians["means"] if isinstance(gaussians, dict) else gaussians.means)[1]
    if inverse is None:
        inverse = anysplat_voxel_inverse(pose_encoding, depth, voxel_size=voxel_size,
                                         num_gaussians=n)
    scene = from_anysplat(gaussians, pose["extrinsic"], pose["intrinsic"], images,
                          height=h, width=w, voxel_inverse=inverse)
    result = filter_distractors(scene, config=config or FilterConfig())
    print(f"{v} views, {len(scene)} voxels: removed {int(result.removed.sum())} "
          f"({sum(c.accepted for c in result.candidates)} regions)")
    result.apply(scene).save(out_dir, overwrite=True)
    return result


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("filtered"))
    parser.add_argument("--images", type=Path, help="folder of input images (real run)")
    parser.add_argument("--voxel-size", type=float, default=0.002)
    parser.add_argument("--dry-run", action="store_true",
                        help="synthetic arrays shaped like AnySplat's outputs (no model)")
    parser.add_argument("--backend", choices=("native", "torch"), default="native",
                        help="the filter's renderer: the native CPU rasterizer, or the torch "
                             "backend on --device (docs/method.md, 'The torch backend')")
    parser.add_argument("--device", default="cuda", help="the torch backend's device")
    args = parser.parse_args(argv)
    config = (FilterConfig(backend="torch", device=args.device) if args.backend == "torch"
              else None)
    if args.dry_run:
        g, pose, enc, depth, images, voxel = _synthetic_prediction()
        filter_prediction(g, pose, enc, depth, images, voxel_size=voxel, out_dir=args.out,
                          config=config)
        return
    try:
        import torch
        from src.model.model.anysplat import AnySplat          # AnySplat repository
        from src.utils.image import process_image
    except ImportError as e:
        raise SystemExit(f"run inside the AnySplat repository with its environment ({e}); "
                         "or try --dry-run") from None
    model = AnySplat.from_pretrained("lhjiang/anysplat").eval()
    files = sorted(p for p in args.images.iterdir() if p.suffix.lower() in (".png", ".jpg"))
    images = torch.stack([process_image(str(p)) for p in files])[None]     # [-1, 1]
    images = (images + 1) * 0.5
    with torch.no_grad():
        model.encoder.distill = False
        out = model.encoder(images, global_step=0, visualization_dump=None)
    inverse = exact_voxel_inverse(out, images.shape[-2:], model.encoder.voxel_size)
    filter_prediction(out.gaussians, out.pred_context_pose, out.pred_pose_enc_list[-1],
                      out.depth_dict["depth"], images, voxel_size=model.encoder.voxel_size,
                      out_dir=args.out, inverse=inverse, config=config)


def _synthetic_prediction():
    """AnySplat-shaped arrays from clearsplat's synthetic world, fused into voxels."""
    from scipy.spatial.transform import Rotation

    from clearsplat.scene import rgb_to_sh_dc
    from clearsplat.synth import make_world

    world = make_world("object", num_views=3, seed=2, height=48, width=64)
    h, w = 48, 64
    enc, c2w, intr = [], [], []
    for cam in world.cameras:
        w2c = cam.world_to_camera
        fov_h = 2 * np.arctan((h / 2) / cam.fy)
        fov_w = 2 * np.arctan((w / 2) / cam.fx)
        enc.append(np.concatenate([w2c[:3, 3], Rotation.from_matrix(w2c[:3, :3]).as_quat(),
                                   [fov_h, fov_w]]))
        c2w.append(cam.camera_to_world)
        fx = (w / 2) / (np.tan(fov_w / 2) + 1e-3)                # as the encoder decodes it
        fy = (h / 2) / (np.tan(fov_h / 2) + 1e-3)
        intr.append(np.array([[fx / w, 0, 0.5], [0, fy / h, 0.5], [0, 0, 1]]))
    enc = np.array(enc, dtype=np.float32)[None]
    depth = np.stack(world.depths).astype(np.float32)[None]
    voxel = float(np.median(depth)) * 0.01
    inverse = anysplat_voxel_inverse(enc, depth, voxel_size=voxel)
    # the fusion: mean point and colour per voxel (the encoder weights by confidence)
    pts = []
    for i, cam in enumerate(world.cameras):
        rows, cols = np.mgrid[0:h, 0:w]
        pc = np.stack([(cols - w / 2) / intr[i][0, 0] / w, (rows - h / 2) / intr[i][1, 1] / h,
                       np.ones((h, w))], -1) * depth[0, i][..., None]
        pts.append(pc.reshape(-1, 3) @ cam.camera_to_world[:3, :3].T + cam.position)
    pts = np.concatenate(pts)
    colours = np.concatenate([im.reshape(-1, 3) for im in world.images])
    n = int(inverse.max()) + 1
    count = np.bincount(inverse, minlength=n)[:, None]
    means = np.zeros((n, 3))
    rgb = np.zeros((n, 3))
    np.add.at(means, inverse, pts)
    np.add.at(rgb, inverse, colours)
    means, rgb = means / count, rgb / count
    s = (voxel * 0.7) ** 2
    g = {"means": means[None], "covariances": np.broadcast_to(s * np.eye(3), (1, n, 3, 3)),
         "harmonics": rgb_to_sh_dc(rgb)[None, :, :, None], "opacities": np.full((1, n), 0.9)}
    pose = {"extrinsic": np.array(c2w)[None], "intrinsic": np.array(intr)[None]}
    images = np.moveaxis(np.stack(world.images), -1, 1)[None]
    return g, pose, enc, depth, images, voxel


if __name__ == "__main__":
    main()
