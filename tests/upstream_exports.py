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

The exports whose vertex order no longer gives each vertex's view and pixel (Depth Anything 3,
AnySplat's voxels, WorldMirror v1 and 2.0, Long-LRM, VolSplat) take the prediction their
model hands its export (raw head channels, depths and offsets, fusion weights: each says
which) and (all but VolSplat's) return where every pixel or vertex went, so that a test knows
the association the file no longer holds.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["write_vertex_ply", "pixelsplat_export_ply", "noposplat_export_ply",
           "depthsplat_save_gaussian_ply", "mvsplat_figure_export", "pixelsplat_visualizer_export",
           "pixelsplat_figure_export",
           "yonosplat_test_step_export", "resplat_save_gaussian_ply", "anysplat_inference_export",
           "da3_export_to_gs_ply", "anysplat_voxel_export", "worldmirror_v1_save_gs_ply",
           "worldmirror2_save_results", "longlrm_save_gaussian_ply",
           "volsplat_save_gaussian_ply"]


def write_vertex_ply(path, columns, *, uchar=()):
    """A binary little-endian PLY with float32 properties in the given order (plyfile's);
    the columns named in ``uchar`` are written as ``uchar`` (Long-LRM's normals)."""
    names, types, values = [], [], []
    for k, c in columns:
        c = np.asarray(c, dtype=np.float64)
        flat = c.reshape(len(c), -1)
        sub = [k] if c.ndim == 1 else [f"{k}_{i}" for i in range(flat.shape[1])]
        names += sub
        types += ["u1" if k in uchar else "<f4"] * len(sub)
        values += list(flat.T)
    table = np.empty(len(values[0]), dtype=list(zip(names, types)))
    for name, v in zip(names, values):
        table[name] = v
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(table)}"]
    header += [f"property {'uchar' if t == 'u1' else 'float'} {n}" for n, t in zip(names, types)]
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


# ------------------------------------------------------------------------------------------------
# exports whose vertex order no longer gives each vertex's view and pixel
# ------------------------------------------------------------------------------------------------
def _unit_rays(intrinsics, c2w_rotation, u, v):
    """World directions of unit length through image points ``(u, v)`` of one camera."""
    d = np.stack([(u - intrinsics[0, 2]) / intrinsics[0, 0],
                  (v - intrinsics[1, 2]) / intrinsics[1, 1], np.ones_like(u)], axis=-1)
    d = d @ c2w_rotation.T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def da3_normalisation(extrinsics, pose_scale=1.0):
    """Depth Anything 3's frame when poses are given (``api.py`` ``_normalize_extrinsics``,
    then the Umeyama scale of ``model/gs_adapter.py`` ``GaussianAdapter.forward``): world
    ``x`` -> ``s R_0^T (x - t_0)`` with ``s = pose_scale / m``, ``m`` the lower median
    (``torch.median``) of the camera centres' distances to camera 0 (itself included),
    at least 0.1. Returns ``(s, R_0^T, t_0)``."""
    ext = np.asarray(extrinsics, dtype=np.float64)
    dist = np.sort(np.linalg.norm(ext[:, :3, 3] - ext[0, :3, 3], axis=1))
    m = max(dist[(len(dist) - 1) // 2], 0.1)
    return pose_scale / m, ext[0, :3, :3].T, ext[0, :3, 3].copy()


def da3_export_to_gs_ply(path, pred, *, gs_views_interval=1, poses_given=True,
                         pose_scale=1.0):
    """Depth Anything 3's ``inference(infer_gs=True, export_format="gs_ply")``:
    ``utils/export/gs.py`` ``export_to_gs_ply`` -> ``utils/gsply_helpers.py``
    ``save_gaussian_ply`` (``prune_by_depth_percent=0.9``, ``prune_border_gs=True``,
    ``inv_opacity=True``, DC only), of Gaussians built as ``model/gs_adapter.py``
    ``GaussianAdapter.forward`` builds them.

    ``pred`` (order ``(v, row, col)``): ``extrinsics (V, 4, 4)`` camera-to-world and
    ``intrinsics (V, 3, 3)`` in pixels (the world); ``depth (V, H, W)`` (``prediction.depth``,
    which the adapter takes as a distance along the unit ray); ``offset_xy (G, 2)`` pixels and
    ``offset_depth (G,)`` (the head's offsets); ``scales (G, 3)`` linear, world units;
    ``rotations (G, 4)`` the head's camera-frame quaternions, ``x y z w``; ``harmonics``;
    ``opacities``.

    Centres are ``o + d * (depth + offset_depth)`` with ``d`` the unit ray through
    ``(col + 0.5 + dx, row + 0.5 + dy)``. With ``poses_given`` everything is in the
    normalised frame (:func:`da3_normalisation`). Rotations follow
    ``cam_quat_xyzw_to_world_quat_wxyz``: the ``x y z w`` vector is reordered to ``w x y z``
    and read back as ``x y z w`` by ``quat_to_mat`` (as upstream), turned by the camera, and
    ``mat_to_quat`` writes the result ``x y z w`` with ``w >= 0`` into ``rot_0..3``. The mask:
    rows ``int(8/256 H)`` and columns ``int(8/256 W)`` off each border, and per view
    ``depth <= torch.quantile(depth, 0.9)`` (linear, as ``np.quantile``); views
    ``[::gs_views_interval]``.

    Returns the prediction index of every written vertex, in file order.
    """
    ext = np.asarray(pred["extrinsics"], dtype=np.float64)
    ks = np.asarray(pred["intrinsics"], dtype=np.float64)
    depth = np.asarray(pred["depth"], dtype=np.float64)
    v, h, w = depth.shape
    s, r0t, t0 = da3_normalisation(ext, pose_scale) if poses_given else (1.0, np.eye(3),
                                                                       np.zeros(3))
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    off = np.asarray(pred["offset_xy"], dtype=np.float64).reshape(v, h, w, 2)
    dist = (depth + np.asarray(pred["offset_depth"]).reshape(v, h, w)) * s
    means, rot = np.empty((v, h, w, 3)), np.empty((v, h, w, 4))
    raw = np.asarray(pred["rotations"], dtype=np.float64).reshape(v, h * w, 4)
    raw = raw / np.linalg.norm(raw, axis=-1, keepdims=True)
    for i in range(v):
        c2w_rot = r0t @ ext[i, :3, :3]
        centre = s * r0t @ (ext[i, :3, 3] - t0)
        rays = _unit_rays(ks[i], c2w_rot, cols + 0.5 + off[i, ..., 0],
                          rows + 0.5 + off[i, ..., 1])
        means[i] = centre + rays * dist[i, ..., None]
        cam = Rotation.from_quat(raw[i][:, [3, 0, 1, 2]]).as_matrix()       # (sic)
        q = Rotation.from_matrix(c2w_rot @ cam).as_quat()
        rot[i] = np.where(q[:, 3:] < 0, -q, q).reshape(h, w, 4)
    th, tw = int(8 / 256 * h), int(8 / 256 * w)
    mask = np.zeros((v, h, w), dtype=bool)
    mask[:, th:h - th, tw:w - tw] = True            # upstream's [th:-th] is empty when th is 0
    if th == 0 or tw == 0:
        mask[:] = False
    mask &= depth <= np.quantile(depth.reshape(v, -1), 0.9, axis=1)[:, None, None]
    keep = np.zeros((v, h, w), dtype=bool)
    keep[::gs_views_interval] = mask[::gs_views_interval]
    idx = np.flatnonzero(keep)
    write_vertex_ply(path, _cols(means.reshape(-1, 3)[idx],
                                 np.asarray(pred["scales"])[idx] * s, rot.reshape(-1, 4)[idx],
                                 np.asarray(pred["harmonics"])[idx, :, 0], None,
                                 _logit(np.asarray(pred["opacities"])[idx])))
    return idx


def _softplus(x):
    return np.logaddexp(0.0, x)


def anysplat_voxel_export(path, pred, *, voxel_size=0.002):
    """AnySplat with ``voxelize: true`` (every ``config/experiment/*.yaml``; 0.002 there) and
    ``inference.py``'s ``export_ply(..., save_sh_dc_only=True)``
    (``src/model/encoder/anysplat.py`` ``voxelizaton_with_fusion``,
    ``common/gaussian_adapter.py`` ``UnifiedGaussianAdapter.forward``,
    ``src/model/ply_export.py`` ``export_ply``).

    ``pred`` per pixel, order ``(v, row, col)``: ``means (G, 3)`` (the depth head's points in
    the predicted poses' frame), and the head's raw channels: ``opacity_logit (G,)``,
    ``scale_raw (G, 3)``, ``rotations (G, 4)`` (``x y z w``, any length), ``harmonics (G, 3,
    d)``, ``conf (G,)``. Key ``round(p / voxel_size)``; ``torch.unique(dim=0)`` sorts the keys
    lexicographically; weights ``exp(c - max_voxel c) / (sum + 1e-6)``; centres and all raw
    channels averaged before activation; opacity ``sigmoid`` written as it is (no logit),
    scale ``min(0.001 softplus, 0.3)`` as log, quaternion normalised, through scipy, ``w x y
    z``.

    Returns the voxel (vertex) of every pixel, ``(G,)``.
    """
    p = np.asarray(pred["means"], dtype=np.float64)
    key = np.round(p / voxel_size).astype(np.int32)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    k = inv.max() + 1
    conf = np.asarray(pred["conf"], dtype=np.float64)
    top = np.full(k, -np.inf)
    np.maximum.at(top, inv, conf)
    e = np.exp(conf - top[inv])
    wgt = e / (np.bincount(inv, e, minlength=k)[inv] + 1e-6)

    def fuse(x):
        x = np.asarray(x, dtype=np.float64).reshape(len(inv), -1)
        return np.stack([np.bincount(inv, wgt * c, minlength=k) for c in x.T], axis=1)

    means = fuse(p)
    opacity = 1 / (1 + np.exp(-fuse(pred["opacity_logit"])[:, 0]))
    scales = np.minimum(0.001 * _softplus(fuse(pred["scale_raw"])), 0.3)
    q = fuse(pred["rotations"])
    q = q / (np.linalg.norm(q, axis=1, keepdims=True) + 1e-8)
    harm = fuse(pred["harmonics"]).reshape(k, 3, -1)
    noposplat_export_ply(path, means, scales, q, harm, opacity)
    return inv


def _wm_voxels(means, voxel_size):
    """WorldMirror's voxel of each splat: ``floor(p / s) - min``, flattened
    ``kx My Mz + ky Mz + kz``, ``torch.unique`` (sorted) inverse."""
    key = np.floor(np.asarray(means, dtype=np.float64) / voxel_size).astype(np.int64)
    key -= key.min(axis=0)
    dims = key.max(axis=0) + 1
    flat = key[:, 0] * dims[1] * dims[2] + key[:, 1] * dims[2] + key[:, 2]
    _, inv = np.unique(flat, return_inverse=True)
    return inv.reshape(-1)


def _wm_merge(splats, inv):
    """``prune_gs`` / ``_voxel_prune_gaussians``: weighted means of centres, DC, linear
    scales and quaternions (then normalised), opacity ``sum w^2 / sum w``."""
    w = np.asarray(splats["weights"], dtype=np.float64)
    k = inv.max() + 1
    wsum = np.maximum(np.bincount(inv, w, minlength=k), 1e-8)

    def avg(x):
        x = np.asarray(x, dtype=np.float64).reshape(len(inv), -1)
        return np.stack([np.bincount(inv, w * c, minlength=k) for c in x.T], axis=1) / \
            wsum[:, None]

    q = avg(splats["quats"])
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-8)
    return dict(means=avg(splats["means"]), dc=avg(splats["dc"]), scales=avg(splats["scales"]),
                quats=q, opacities=np.bincount(inv, w * w, minlength=k) / wsum)


def _wm_splats(pred):
    """WorldMirror's per-pixel splats (``prepare_splats``): ``w x y z`` quaternions, the DC
    band, opacities, and the fusion weights."""
    q = np.asarray(pred["rotations"], dtype=np.float64)
    return dict(means=np.asarray(pred["means"], dtype=np.float64),
                scales=np.asarray(pred["scales"], dtype=np.float64),
                quats=q[:, [3, 0, 1, 2]], dc=np.asarray(pred["harmonics"])[:, :, 0],
                opacities=np.asarray(pred["opacities"], dtype=np.float64),
                weights=np.asarray(pred["weights"], dtype=np.float64))


def _wm_write(path, s, keep):
    write_vertex_ply(path, _cols(s["means"][keep], s["scales"][keep], s["quats"][keep],
                                 s["dc"][keep], None, s["opacities"][keep]))


def _provenance(inv, keep):
    """Vertex of every pixel after ``keep`` (bool over voxels), -1 where dropped."""
    out = np.full(keep.shape, -1, dtype=np.int64)
    out[keep] = np.arange(int(keep.sum()))
    return np.where(inv >= 0, out[np.maximum(inv, 0)], -1)


def worldmirror_v1_save_gs_ply(path, pred, *, voxel_size=0.002):
    """HunyuanWorld-Mirror v1 ``infer.py`` (``--save_gs``): the renderer's ``prune_gs``
    (``src/models/models/rasterization.py``, ``voxel_size=0.002`` from ``worldmirror.py``,
    applied to every splat) and ``src/utils/save_utils.py`` ``save_gs_ply`` (keep largest
    scale ``<= np.quantile(., 0.95)``, order kept; opacity written as it is, log scales,
    ``w x y z``).

    ``pred`` per pixel, order ``(v, row, col)``, in the predicted cameras' frame: ``means``,
    ``scales`` (linear), ``rotations`` (``x y z w``, world), ``harmonics (G, 3, 1)`` (the SH
    DC), ``opacities`` (unused by the export), ``weights (G,)`` (``sigmoid``, the fusion
    weights).

    Returns the vertex of every pixel, ``-1`` where the scale cut dropped its voxel.
    """
    inv = _wm_voxels(pred["means"], voxel_size)
    merged = _wm_merge(_wm_splats(pred), inv)
    big = merged["scales"].max(axis=1).astype(np.float32)
    keep = big <= np.float32(np.quantile(big, 0.95))
    _wm_write(path, merged, keep)
    return _provenance(inv, keep)


def worldmirror2_save_results(path, pred, *, keep=None, voxel_size=0.002,
                              max_points=5_000_000):
    """WorldMirror 2.0 (HY-World-2.0) ``hyworld2/worldrecon/hyworldmirror/utils/
    inference_utils.py`` ``save_results`` with its defaults: splats of the pixels in
    ``keep`` (``gs_filter_mask``: not sky, not a depth/normal edge; given here), order kept;
    ``_voxel_prune_gaussians``: if no voxel (as v1's) holds two splats nothing changes,
    otherwise every splat is merged as in v1; above ``max_points`` (5,000,000 upstream) a
    ``np.random.default_rng(42).choice(N, max_points, replace=False)`` subset in that
    (unsorted) order; then ``save_utils.py`` ``_build_gs_ply_data``: largest scale
    ``<= torch.quantile(., 0.98)`` (linear, as ``np.quantile``).

    ``pred`` as for :func:`worldmirror_v1_save_gs_ply`. Returns the vertex of every pixel,
    ``-1`` where dropped.
    """
    s = _wm_splats(pred)
    g = len(s["means"])
    kept = np.ones(g, dtype=bool) if keep is None else np.asarray(keep, dtype=bool).reshape(-1)
    s = {k: x[kept] for k, x in s.items()}
    inv = _wm_voxels(s["means"], voxel_size)
    if inv.max() + 1 < len(inv):
        s = _wm_merge(s, inv)
    else:
        inv = np.arange(len(inv))
    order = np.arange(len(s["means"]))
    if len(order) > max_points:
        order = np.random.default_rng(42).choice(len(order), size=max_points, replace=False)
    s = {k: s[k][order] for k in ("means", "scales", "quats", "dc", "opacities")}
    big = s["scales"].max(axis=1).astype(np.float32)
    cut = big <= np.quantile(big, 0.98)
    _wm_write(path, s, cut)
    slot = np.full(inv.max() + 1, -1, dtype=np.int64)
    slot[order] = np.arange(len(order))
    pixel = np.full(g, -1, dtype=np.int64)
    pixel[kept] = slot[inv]
    return _provenance(pixel, cut)


def longlrm_normalisation(extrinsics, scene_scale=1.0):
    """Long-LRM's input normalisation (``data/dataset.py`` ``__getitem__``): ``pos_avg`` =
    [right, down, forward, mean centre] by Gram-Schmidt from the mean camera axes, ``c2w <-
    pos_avg^-1 c2w``, translations times ``1 / (scene_scale * max |t|)``: world ``x`` ->
    ``s R^T (x - p)``. Returns ``(s, R^T, p)``."""
    ext = np.asarray(extrinsics, dtype=np.float64)
    pos = ext[:, :3, 3].mean(0)
    fwd = ext[:, :3, 2].mean(0)
    fwd = fwd / np.linalg.norm(fwd)
    down = ext[:, :3, 1].mean(0)
    down = down - down.dot(fwd) * fwd
    down = down / np.linalg.norm(down)
    rot = np.stack([np.cross(down, fwd), down, fwd], axis=1)
    centres = (ext[:, :3, 3] - pos) @ rot
    return 1.0 / (scene_scale * np.abs(centres).max()), rot.T, pos


def _bf16(x):
    """``x`` rounded to bfloat16 (to nearest, ties to even), as float32."""
    bits = np.ascontiguousarray(x, dtype=np.float32).view(np.uint32)
    bits = (bits + np.uint32(0x7FFF) + ((bits >> np.uint32(16)) & np.uint32(1))) \
        & np.uint32(0xFFFF0000)
    return bits.view(np.float32)


def _longlrm_bf16_means(means, c2w):
    """Long-LRM's centres as ``LongLRM.forward`` computes them under bfloat16 autocast (its
    configs' ``use_amp: true``, ``amp_dtype: bf16``; ``main.py`` evaluates under it), in its
    normalised frame: the unit pixel ray (float32) times the camera rotation by a matmul in
    bfloat16 (inputs rounded, output rounded), the distance in bfloat16, their product rounded
    to bfloat16, plus the camera centre in float32. ``means (G, 3)`` in the model's order on
    their pixels' rays, ``c2w (V, 4, 4)``: the ray of each is the direction from its camera."""
    v = len(c2w)
    view = np.repeat(np.arange(v), len(means) // v)
    origin = c2w[view, :3, 3]
    d = means - origin
    dist = np.linalg.norm(d, axis=1, keepdims=True)
    cam = np.einsum("nij,ni->nj", c2w[view, :3, :3], d / dist).astype(np.float32)
    rot = _bf16(c2w[:, :3, :3]).astype(np.float64)[view]
    ray = _bf16(np.einsum("nij,nj->ni", rot, _bf16(cam).astype(np.float64)))
    step = _bf16(_bf16(dist) * ray)
    return (origin.astype(np.float32) + step).astype(np.float64)


def longlrm_save_gaussian_ply(path, pred, *, prune_ratio=0.0, random_ratio=0.0,
                              opacity_threshold=0.001, seed=1111, bf16=False):
    """Long-LRM's ``model/llrm.py``: the ``LongLRM.forward`` prune block (``prune_ratio``,
    ``random_ratio``: 0.6 and 0.1 in ``configs/dl3dv_i540_32input_8target.yaml``, 0
    elsewhere) and ``save_gaussian_ply(opacity_threshold=0.001)`` as
    ``save_evaluation_results`` calls it.

    ``pred`` per pixel, order ``(v, row, col)`` (``"b (v hh ph ww pw) d"``): ``extrinsics``
    (the input cameras, world), ``means`` (world), ``scales`` (linear), ``rotations``
    (``x y z w``, world), ``harmonics (G, 3, d)`` with ``d <= 16`` (the model's, in its
    frame), ``opacities``. Everything is moved to the normalised frame
    (:func:`longlrm_normalisation`) the model predicts in. Written: 62 properties, ``nx ny
    nz`` as ``uchar``, 45 ``f_rest`` (channel-major, zero-padded), the logit opacity, log
    scales, ``w x y z`` rotations not normalised (the raw head output; here each quaternion
    times ``1 + (i mod 7) / 3``). Pruning keeps the ``int(G (1-p)(1-r))`` most opaque
    (``argsort`` descending) and ``int(G (1-p) r)`` of the rest by a random permutation
    (``torch.randperm`` on the process seed; NumPy's generator seeded with ``seed`` here);
    then rows with ``sigmoid(opacity) <= opacity_threshold`` are dropped, order kept. With
    ``bf16`` the centres are moved along their rays as bfloat16 autocast computes them
    (:func:`_longlrm_bf16_means`); otherwise as in float32.

    Returns the prediction index of every written vertex, in file order.
    """
    s, rt, p = longlrm_normalisation(pred["extrinsics"])
    means = s * (np.asarray(pred["means"], dtype=np.float64) - p) @ rt.T
    if bf16:
        c2w = np.array(pred["extrinsics"], dtype=np.float64)
        c2w[:, :3, :3] = rt @ c2w[:, :3, :3]
        c2w[:, :3, 3] = s * (c2w[:, :3, 3] - p) @ rt.T
        means = _longlrm_bf16_means(means, c2w)
    g = len(means)
    rot = Rotation.from_matrix(rt @ Rotation.from_quat(pred["rotations"]).as_matrix()).as_quat()
    rot = rot[:, [3, 0, 1, 2]] * (1 + (np.arange(g) % 7) / 3)[:, None]
    logit = _logit(pred["opacities"]).astype(np.float32)
    order = np.arange(g)
    if prune_ratio > 0:
        keep_ratio = 1 - prune_ratio
        rnd_ratio = keep_ratio * random_ratio
        keep_ratio = keep_ratio - rnd_ratio
        n_keep, n_rnd = int(g * keep_ratio), int(g * rnd_ratio)
        ranked = np.argsort(-logit, kind="stable")
        order = ranked[:n_keep]
        if n_rnd > 0:
            rest = ranked[n_keep:]
            perm = np.random.default_rng(seed).permutation(len(rest))[:n_rnd]
            order = np.concatenate([order, rest[perm]])
    order = order[1 / (1 + np.exp(-logit[order])) > opacity_threshold]
    harm = np.asarray(pred["harmonics"], dtype=np.float64)
    rest = np.zeros((g, 45))
    rest[:, :3 * (harm.shape[2] - 1)] = harm[..., 1:].reshape(g, -1)
    cols = [("x", means[order, 0]), ("y", means[order, 1]), ("z", means[order, 2]),
            ("nx", np.zeros(len(order))), ("ny", np.zeros(len(order))),
            ("nz", np.zeros(len(order))), ("f_dc", harm[order, :, 0]), ("f_rest", rest[order]),
            ("opacity", logit[order]),
            ("scale", np.log(np.asarray(pred["scales"])[order] * s)), ("rot", rot[order])]
    write_vertex_ply(path, cols, uchar=("nx", "ny", "nz"))
    return order


def volsplat_save_gaussian_ply(path, pred, *, height, width):
    """VolSplat's ``src/model/ply_export.py`` ``save_gaussian_ply`` (``test.save_gaussian``),
    whose encoder (``encoder_volsplat.py``) hands over voxel Gaussians without scales or
    rotations.

    ``pred``: ``means (N, 3)``, ``harmonics (N, 3, d)``, ``opacities (N,)`` of the ``N``
    voxels, and ``extrinsics (V, 4, 4)``. Every tensor is padded (centres 0, harmonics 0.1,
    opacity 0.01) or truncated to ``E = V H W``; scales are the constant 0.01 and rotations
    the identity ``(0, 0, 0, 1)``; flat index ``n`` is read as ``(v, h, w)``, rearranged
    ``"h w spp v"`` and trimmed by 8 pixels; rotations turned by ``C_v``; then ``export_ply``
    turns centres and rotations by ``C_0^-1`` (no translation), writes the DC band, the logit
    opacity, log scales, ``w x y z``.
    """
    ext = np.asarray(pred["extrinsics"], dtype=np.float64)
    v, e = len(ext), len(ext) * height * width

    def fit(x, value):
        x = np.asarray(x, dtype=np.float64)[:e]
        pad = np.full((e - len(x),) + x.shape[1:], value)
        return np.concatenate([x, pad])

    means, harm = fit(pred["means"], 0.0), fit(pred["harmonics"], 0.1)
    opac = fit(pred["opacities"], 0.01)
    t = lambda x: _hwsv(x, v, height, width, 8)                    # noqa: E731
    view = t(np.repeat(np.arange(v), height * width))
    view_rotation = np.linalg.inv(ext[0, :3, :3])
    rot = Rotation.from_matrix(view_rotation @ ext[view, :3, :3]).as_quat()[:, [3, 0, 1, 2]]
    kept = t(means)
    write_vertex_ply(path, _cols(kept @ view_rotation.T, np.full((len(kept), 3), 0.01), rot,
                                 t(harm)[..., 0], None, _logit(t(opac))))
