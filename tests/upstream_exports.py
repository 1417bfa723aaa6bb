"""What each model's own PLY export writes, re-stated in NumPy for the import tests.

Each function takes a model's native prediction (the tensors its export function is called
with, as NumPy arrays) and writes the file the upstream function writes: the same vertex order,
border trim and cuts, frame change, opacity form (raw or ``torch.logit``), SH bands and
rotation handling (``scipy.spatial.transform.Rotation``, quaternions ``x y z w`` in, ``w x y z``
out). Sources (read, not copied) are named per function; ``docs/backbones.md`` has the table.

A prediction is a dict with, for ``G = V * H * W * spp`` Gaussians in the model's order
``(v, row, col, s)``: ``means (G, 3)`` in the model's frame, ``scales (G, 3)``,
``rotations (G, 4)`` (``x y z w``, camera frame unless said otherwise), ``harmonics (G, 3, d)``,
``opacities (G,)``, and ``extrinsics (V, 4, 4)`` camera-to-world of the context views.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["write_vertex_ply", "pixelsplat_export_ply", "noposplat_export_ply",
           "depthsplat_save_gaussian_ply", "mvsplat_figure_export", "pixelsplat_visualizer_export",
           "pixelsplat_figure_export",
           "yonosplat_test_step_export", "resplat_save_gaussian_ply", "anysplat_inference_export"]


def write_vertex_ply(path, columns):
    """A binary little-endian PLY with float32 properties in the given order (plyfile's)."""
    table = np.concatenate([np.asarray(c, dtype=np.float64).reshape(len(c), -1)
                            for _, c in columns], axis=1).astype("<f4")
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(table)}"]
    for k, c in columns:
        c = np.asarray(c)
        if c.ndim == 1:
            header.append(f"property float {k}")
        else:
            header += [f"property float {k}_{i}" for i in range(c.shape[1])]
    header.append("end_header")
    path.write_bytes(("\n".join(header) + "\n").encode() + table.tobytes())


def _cols(means, scales, rot_wxyz, f_dc, f_rest, opacity_column):
    cols = [("x", means[:, 0]), ("y", means[:, 1]), ("z", means[:, 2]),
            ("nx", np.zeros(len(means))), ("ny", np.zeros(len(means))),
            ("nz", np.zeros(len(means))), ("f_dc", f_dc)]
    if f_rest is not None and f_rest.shape[1]:
        cols.append(("f_rest", f_rest))
    cols += [("opacity", opacity_column), ("scale", np.log(scales)), ("rot", rot_wxyz)]
    return cols


def _turn(rotation, quats_xyzw):
    m = rotation @ Rotation.from_quat(quats_xyzw).as_matrix()
    return Rotation.from_matrix(m).as_quat()[:, [3, 0, 1, 2]]


def _logit(o):
    o = np.asarray(o, dtype=np.float32).astype(np.float64)
    return np.log(o / (1 - o))


def pixelsplat_export_ply(path, extrinsics0, means, scales, rotations, harmonics, opacities):
    """``export_ply`` of pixelSplat and MVSplat (``src/model/ply_export.py``): median shift,
    division by the largest 95 % quantile of ``|x|``, ``Rz(-45) @ swap @ C_0^-1`` turn of
    centres and rotations, DC band, raw opacity."""
    means = means - np.sort(means, axis=0)[(len(means) - 1) // 2]      # torch's lower median
    factor = np.quantile(np.abs(means), 0.95, axis=0).max()
    means, scales = means / factor, scales / factor
    swap = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=np.float64)
    adjust = Rotation.from_rotvec([0, 0, -45], True).as_matrix()
    rotation = adjust @ swap @ np.linalg.inv(extrinsics0[:3, :3])
    means = means @ rotation.T
    write_vertex_ply(path, _cols(means, scales, _turn(rotation, rotations), harmonics[..., 0],
                                 None, opacities))


def noposplat_export_ply(path, means, scales, rotations, harmonics, opacities, *,
                         shift_and_scale=False, save_sh_dc_only=True):
    """``export_ply`` of NoPoSplat, YoNoSplat and AnySplat: no frame change, rotations as given,
    DC band unless ``save_sh_dc_only=False`` (then ``harmonics[..., 1:]`` channel-major), raw
    opacity."""
    if shift_and_scale:
        means = means - np.sort(means, axis=0)[(len(means) - 1) // 2]
        factor = np.quantile(np.abs(means), 0.95, axis=0).max()
        means, scales = means / factor, scales / factor
    rot = Rotation.from_quat(rotations).as_quat()[:, [3, 0, 1, 2]]
    rest = None if save_sh_dc_only else harmonics[..., 1:].reshape(len(means), -1)
    write_vertex_ply(path, _cols(means, scales, rot, harmonics[..., 0], rest, opacities))


def _hwsv(x, v, h, w, trim, keep=None):
    """``"(v h w spp) ... -> h w spp v ..."`` then ``[mask]`` with the border trimmed."""
    x = np.asarray(x)
    x = x.reshape((v, h, w, -1) + x.shape[1:])
    x = np.moveaxis(x, 0, 3)                                     # h w spp v ...
    mask = np.zeros(x.shape[:4], dtype=bool)
    if trim:
        mask[trim:-trim, trim:-trim] = True
    else:
        mask[:] = True
    if keep is not None:
        mask &= keep
    return x[mask]


def depthsplat_save_gaussian_ply(path, pred, *, height, width):
    """DepthSplat's ``save_gaussian_ply``: 8-pixel trim, ``h w spp v`` order, camera rotations
    turned to world by their view, then centres and rotations turned by ``C_0^-1`` (no
    translation), DC band, ``torch.logit`` opacity."""
    ext = pred["extrinsics"]
    v = len(ext)
    t = lambda x: _hwsv(x, v, height, width, 8)                    # noqa: E731
    view = t(np.repeat(np.arange(v), len(pred["means"]) // v))
    world_rot = _turn_per_view(ext[view, :3, :3], t(pred["rotations"]))
    view_rotation = np.linalg.inv(ext[0, :3, :3])
    means = t(pred["means"]) @ view_rotation.T
    rot = _turn(view_rotation, world_rot)
    write_vertex_ply(path, _cols(means, t(pred["scales"]), rot, t(pred["harmonics"])[..., 0],
                                 None, _logit(t(pred["opacities"]))))


def _turn_per_view(c2w, quats_xyzw):
    m = c2w @ Rotation.from_quat(quats_xyzw).as_matrix()
    return Rotation.from_matrix(m).as_quat()


def mvsplat_figure_export(path, pred, *, height, width):
    """MVSplat's paper figure script: 8-pixel trim, ``h w spp v`` order, rotations turned to
    world by their view, then pixelSplat's ``export_ply`` (its far-plane cut keeps all here)."""
    ext = pred["extrinsics"]
    v = len(ext)
    t = lambda x: _hwsv(x, v, height, width, 8)                    # noqa: E731
    view = t(np.repeat(np.arange(v), len(pred["means"]) // v))
    world_rot = _turn_per_view(ext[view, :3, :3], t(pred["rotations"]))
    pixelsplat_export_ply(path, ext[0], t(pred["means"]), t(pred["scales"]), world_rot,
                          t(pred["harmonics"]), t(pred["opacities"]))


def pixelsplat_visualizer_export(path, pred):
    """pixelSplat's encoder visualizer (``export_ply: true``): the whole prediction in the
    model's order with the camera-frame ``visualization_dump["rotations"]``."""
    pixelsplat_export_ply(path, pred["extrinsics"][0], pred["means"], pred["scales"],
                          pred["rotations"], pred["harmonics"], pred["opacities"])


def pixelsplat_figure_export(path, pred, *, height, width):
    """pixelSplat's paper figure script (``src/paper/generate_point_cloud_figure.py``): 8-pixel
    trim, ``h w spp v`` order, the camera-frame ``visualization_dump["rotations"]`` as they
    are, then ``export_ply`` (its far-plane cut keeps all here)."""
    v = len(pred["extrinsics"])
    t = lambda x: _hwsv(x, v, height, width, 8)                    # noqa: E731
    pixelsplat_export_ply(path, pred["extrinsics"][0], t(pred["means"]), t(pred["scales"]),
                          t(pred["rotations"]), t(pred["harmonics"]), t(pred["opacities"]))


def yonosplat_test_step_export(path, pred, *, height, width):
    """YoNoSplat's ``test_step``: 8-pixel trim and ``opacity > 0.01``, ``h w spp v`` order,
    local (per-view camera) rotations, raw opacity, DC band."""
    v = len(pred["extrinsics"])
    op = np.moveaxis(np.asarray(pred["opacities"]).reshape(v, height, width, -1), 0, 3)
    keep = op > 0.01                                             # (h, w, spp, v)
    t = lambda x: _hwsv(x, v, height, width, 8, keep)            # noqa: E731
    noposplat_export_ply(path, t(pred["means"]), t(pred["scales"]), t(pred["rotations"]),
                         t(pred["harmonics"]), t(pred["opacities"]), save_sh_dc_only=True)


def resplat_save_gaussian_ply(path, pred):
    """ReSplat's ``save_gaussian_ply`` with its defaults (``save_all_gaussians=True``,
    aligned to the middle view): centres and camera-frame rotations turned by
    ``C_{V//2}^-1``, all SH bands unturned, ``torch.logit`` opacity."""
    ext = pred["extrinsics"]
    view_rotation = np.linalg.inv(ext[len(ext) // 2, :3, :3])
    means = pred["means"] @ view_rotation.T
    rot = _turn(view_rotation, pred["rotations"])
    harm = pred["harmonics"]
    write_vertex_ply(path, _cols(means, pred["scales"], rot, harm[..., 0],
                                 harm[..., 1:].reshape(len(means), -1),
                                 _logit(pred["opacities"])))


def anysplat_inference_export(path, pred):
    """AnySplat's ``inference.py``: ``export_ply(gaussians.means[0], ...)`` of the whole output
    (centres and rotations in the frame of the predicted poses), DC band, raw opacity."""
    noposplat_export_ply(path, pred["means"], pred["scales"], pred["rotations"],
                         pred["harmonics"], pred["opacities"])
