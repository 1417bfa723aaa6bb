"""Every format's export of one prediction, imported as every format: how many vertices land
near their pixel when the format is right, and when it is wrong.

The figures behind ``MIN_NEAR_SHARE`` (``clearsplat.io.importers``; ``docs/backbones.md``,
"Wrong formats are refused"). Each file is written by the NumPy re-statement of the model's
export (``upstream_exports.py``) from a synthetic prediction (``clearsplat.synth``), then
imported with ``allow_misaligned=True``. ``pose`` hands the import cameras off by a multiple of
the realism scenario's pose error (0.25 degrees, 0.4 % of the depth) from those that made the
Gaussians, as a pose estimate would be::

    python tests/export_matrix.py --sizes 96x160,192x320 --pose 0,1,2,4

prints, per size and pose error, the smallest share of a correct import and the largest of a
wrong one that the layout and opacity checks let through.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

import upstream_exports as up  # noqa: E402
from clearsplat import Camera  # noqa: E402
from clearsplat.adapters._common import quats_to_matrices  # noqa: E402
from clearsplat.errors import ClearsplatError  # noqa: E402
from clearsplat.io.importers import EXPORT_FORMATS, import_export  # noqa: E402

__all__ = ["prediction", "write_every_export", "cross_import", "half_pixel_cameras"]

#: Formats whose files hold the same frame and layout, apart from the opacity form: an
#: anysplat file read as 3dgs fits the pixel rays (its raw opacities are read as logits).
SAME_FRAME = {frozenset({"anysplat", "3dgs"})}


def half_pixel_cameras(cameras, px=-0.5):
    """The cameras with the principal point moved by ``px`` (VGGT's convention: -0.5)."""
    out = []
    for c in cameras:
        k = c.K.copy()
        k[0, 2] += px
        k[1, 2] += px
        out.append(Camera(K=k, camera_to_world=c.camera_to_world, width=c.width,
                          height=c.height))
    return out


def prediction(scene) -> dict:
    """The native prediction (``upstream_exports.py``) of a pixel-aligned scene in view order:
    world centres, camera-frame rotations, the DC band, opacities kept off 0 and 1."""
    g = scene.gaussians
    c2w = np.stack([c.camera_to_world for c in scene.cameras])
    rot_world = quats_to_matrices(g.quats).astype(np.float64)
    rot_cam = np.swapaxes(c2w[scene.view_id, :3, :3], 1, 2) @ rot_world
    return dict(means=g.means.astype(np.float64), scales=g.scales.astype(np.float64),
                rotations=Rotation.from_matrix(rot_cam).as_quat(),
                harmonics=np.swapaxes(g.sh, 1, 2).astype(np.float64)[..., :1],
                opacities=np.clip(g.opacities, 0.02, 0.98), extrinsics=c2w)


def write_every_export(root, scene) -> dict:
    """``{format: path}``: the export of each format of the pixel-aligned ``scene``.

    The scene's Gaussians, in view order with every pixel, are the model's prediction in the
    world of its cameras; pose-free formats get it in the first camera's frame, ``anysplat``
    in the frame of cameras half a pixel before ours (:func:`half_pixel_cameras`).
    """
    root = Path(root)
    h, w = scene.cameras[0].height, scene.cameras[0].width
    pred = prediction(scene)
    c2w = pred["extrinsics"]
    rot_world = quats_to_matrices(scene.gaussians.quats).astype(np.float64)
    inv = np.linalg.inv(c2w[0])
    rel_means = pred["means"] @ inv[:3, :3].T + inv[:3, 3]
    world_xyzw = Rotation.from_matrix(rot_world).as_quat()
    rel_xyzw = Rotation.from_matrix(inv[:3, :3] @ rot_world).as_quat()
    local = dict(pred, means=rel_means, extrinsics=inv[None] @ c2w)
    files = {name: root / f"{name}.ply" for name in EXPORT_FORMATS}
    up.depthsplat_save_gaussian_ply(files["depthsplat"], pred, height=h, width=w)
    up.mvsplat_figure_export(files["mvsplat"], pred, height=h, width=w)
    up.pixelsplat_visualizer_export(files["pixelsplat"], pred)
    up.noposplat_export_ply(files["noposplat"], rel_means, pred["scales"], rel_xyzw,
                            pred["harmonics"], pred["opacities"])
    up.yonosplat_test_step_export(files["yonosplat"], local, height=h, width=w)
    up.resplat_save_gaussian_ply(files["resplat"], pred)
    up.anysplat_inference_export(files["anysplat"], dict(pred, rotations=world_xyzw))
    up.write_vertex_ply(files["3dgs"], up._cols(
        pred["means"], pred["scales"], world_xyzw[:, [3, 0, 1, 2]], pred["harmonics"][..., 0],
        None, up._logit(pred["opacities"])))
    return files


def cross_import(files: dict, cameras) -> dict:
    """``{(written, read): near_pixel}`` for every pair the layout and opacity checks pass."""
    out = {}
    for written, path in files.items():
        cams = half_pixel_cameras(cameras) if written == "anysplat" else cameras
        for read in EXPORT_FORMATS:
            extra = dict(voxelized=False) if read == "anysplat" else {}
            try:
                _, report = import_export(path, read, cams, allow_misaligned=True, **extra)
            except ClearsplatError:
                continue
            out[written, read] = report.near_pixel
    return out


def _measure(size, pose_multiple, root):
    import clearsplat.synth.realism as realism
    from clearsplat.synth.backbone import reconstruct
    from clearsplat.synth.worlds import make_world

    h, w = size
    world = make_world("object", num_views=4, seed=1, height=h, width=w)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    cams = scene.cameras
    if pose_multiple:
        saved = realism._POSE_DEG, realism._POSE_SHIFT
        realism._POSE_DEG, realism._POSE_SHIFT = saved[0] * pose_multiple, \
            saved[1] * pose_multiple
        try:
            cams = [realism.estimated_camera(c, d, seed=1, view=i)
                    for i, (c, d) in enumerate(zip(world.cameras, world.depths))]
        finally:
            realism._POSE_DEG, realism._POSE_SHIFT = saved
    return cross_import(write_every_export(root, scene), cams)


def main(argv=None) -> int:
    import tempfile

    from clearsplat.io.importers import MIN_NEAR_SHARE, NEAR_FRACTION

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="96x160,192x320", help="HxW,...")
    p.add_argument("--pose", default="0,1,2,4",
                   help="multiples of the realism pose error given to the import's cameras")
    args = p.parse_args(argv)
    print(f"share of pixel-aligned vertices within {NEAR_FRACTION:g} x the larger image side "
          f"of their pixel; refused below {MIN_NEAR_SHARE:g}")
    print("| size | pose error | correct: smallest | wrong: largest (pairs) |")
    print("|---|---|---|---|")
    ok = True
    for size in args.sizes.split(","):
        h, w = (int(x) for x in size.lower().split("x"))
        for m in (float(x) for x in args.pose.split(",")):
            with tempfile.TemporaryDirectory() as tmp:
                shares = _measure((h, w), m, Path(tmp))
            right = {k: v for k, v in shares.items() if k[0] == k[1]}
            wrong = {k: v for k, v in shares.items()
                     if k[0] != k[1] and frozenset(k) not in SAME_FRAME}
            lo, hi = min(right, key=right.get), max(wrong, key=wrong.get)
            print(f"| {h}x{w} | {m:g} x (0.25 deg) | {100 * right[lo]:.1f} % ({lo[0]}) | "
                  f"{100 * wrong[hi]:.1f} % ({hi[0]} as {hi[1]}) ({len(wrong)}) |")
            ok &= wrong[hi] < MIN_NEAR_SHARE
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
