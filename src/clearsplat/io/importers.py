"""Scenes from the PLY exports of feed-forward models, with the view association recovered.

A model's ``export_ply`` writes no ``view_id``, but the order of its vertices follows the
model's per-pixel layout, so the association is implied by the vertex order, the image grid
and the export's options (border trim, Gaussians per pixel, view order, cuts). This module
recomputes it, undoes the export's change of frame, turns camera-frame rotations to world, and
returns a :class:`clearsplat.Scene` the filter takes.

What each export does (read from the upstream code, listed in ``docs/backbones.md``) is held
in :data:`EXPORT_FORMATS`:

========== ======= ==== ======= ========== =================== ================
format     order   trim opacity cut        frame               rotations
========== ======= ==== ======= ========== =================== ================
depthsplat h w s v 8    logit   --         first-rotation      world
mvsplat    h w s v 8    raw     (far)      viewer              world
pixelsplat v h w s 0    raw     --         viewer              camera
noposplat  v h w s 0    raw     --         first-camera        frame
yonosplat  h w s v 8    raw     <= 0.01    first-camera        camera
resplat    v h w s 0    logit   --         middle-rotation     camera
anysplat   v h w s 0    raw     (voxels)   world (predicted)   frame
3dgs       v h w s 0    logit   --         world               frame
========== ======= ==== ======= ========== =================== ================

Orders: ``"vhws"`` is the model's own flattening (view slowest); ``"hwsv"`` the
``"() (v h w spp) ... -> h w spp v ..."`` rearrangement of the ``save_gaussian_ply``-style
exports (view fastest), taken after the border trim (``mask[trim:-trim, trim:-trim]``).

Frames (file coordinates ``x`` to world ``s A x + b``; ``C_v``, ``t_v`` the rotation and
centre of input camera ``v``, camera-to-world):

- ``world``: ``A = I``.
- ``first-rotation``: the export turned the scene by the inverse of ``C_0`` (no translation):
  ``A = C_0``.
- ``middle-rotation``: the same with the middle view ``C_{V//2}``.
- ``viewer``: pixelSplat's ``export_ply``: centres minus their median, divided by the largest
  95 % quantile of ``|x|``, turned by ``Rz(-45 deg) @ [[0,0,1],[-1,0,0],[0,-1,0]] @ C_0^T``.
  The rotation is known; the median and scale are not, and are recovered by aligning the
  pixel-aligned vertices to the rays of their pixels (``align="scale-shift"``).
- ``first-camera``: the camera frame of view 0 (pose-free models): ``A = C_0``, ``b = t_0``.
  ``align="scale"`` recovers the scale when the cameras are metric and the model's are not.
  AnySplat's Gaussians are in the frame of its predicted poses (``pred_context_pose``, whose
  first camera is the identity only as far as the camera head learned it): ``world``, to be
  imported with those poses as the cameras.

Rotations: ``world``/``frame`` rotations are in the file's frame and turn with ``A``;
``camera`` rotations are each vertex's own camera frame (the encoders' un-rotated
``rotations``), turned only by the export's frame rotation, so the world rotation is
``C_v @ F^T @ R_file`` with ``F`` the rotation the export applied (``A^T`` for ``viewer`` and
``middle-rotation``, none for ``first-camera``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, Scene
from .exports import read_export

__all__ = ["EXPORT_FORMATS", "ExportFormat", "ImportReport", "import_export", "export_slots",
           "viewer_rotation", "load_views", "NEAR_FRACTION", "MIN_NEAR_SHARE"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

#: A vertex is *near* its pixel when its projection lies within this fraction of the image's
#: larger side (at least 1 px) of the pixel centre along each axis: 3.2 px at 160 pixels wide.
NEAR_FRACTION = 0.02
#: An import with fewer pixel-aligned vertices near their pixel is refused (unless
#: ``allow_misaligned``): correct imports of every format put 100 % there with the model's
#: cameras and >= 68 % with cameras off by 0.5 degrees, a wrong format <= 3.4 %
#: (``docs/backbones.md``, "Wrong formats are refused"; ``python tests/export_matrix.py``).
MIN_NEAR_SHARE = 0.5


@dataclass(frozen=True)
class ExportFormat:
    """How one model's export lays out its vertices (see the module docstring).

    Attributes
    ----------
    order : {"vhws", "hwsv"}
    trim : int
        Border cells dropped on every side of each view's grid.
    spp : int
        Gaussians per pixel (per grid cell).
    opacity : {"raw", "logit"}
    opacity_cut : float
        The export dropped vertices with opacity ``<= opacity_cut`` (0: no cut).
    frame : {"world", "first-rotation", "middle-rotation", "viewer", "first-camera"}
    rotations : {"frame", "world", "camera"}
    sh_frame : {"file", "world"}
        ``"file"``: higher SH bands are expressed in the file's frame and turn with ``A``;
        ``"world"``: they were written as the model renders them and stay.
    grid : {"pixel", "latent"}
        ``"latent"``: one Gaussian per cell of a grid coarser than the image (no pixel id).
    half_pixel : bool
        The model puts pixel ``(row, col)`` at image coordinates ``(col, row)`` (VGGT's
        integer convention), half a pixel from ours: the cameras' principal points are moved
        by +0.5 px so that every vertex projects into its own pixel.
    voxelized : bool
        The upstream default fuses pixels into voxels: the file holds no association.
    cut_note : str
        A cut the export may apply that drops vertices without a record.
    source : str
        Where the upstream export lives.
    """

    order: str
    trim: int
    spp: int
    opacity: str
    frame: str
    rotations: str
    opacity_cut: float = 0.0
    sh_frame: str = "file"
    grid: str = "pixel"
    half_pixel: bool = False
    voxelized: bool = False
    cut_note: str = ""
    source: str = ""
    adapter: str = "from_pixel_aligned"


#: The export of each model as its upstream code writes it (details: ``docs/backbones.md``).
EXPORT_FORMATS = {
    "depthsplat": ExportFormat(
        order="hwsv", trim=8, spp=1, opacity="logit", frame="first-rotation", rotations="world",
        source="cvg/depthsplat src/model/ply_export.py (save_gaussian_ply)",
        adapter="from_depthsplat"),
    "mvsplat": ExportFormat(
        order="hwsv", trim=8, spp=1, opacity="raw", frame="viewer", rotations="world",
        cut_note="the paper figure script also drops Gaussians beyond twice the far plane",
        source="donydchen/mvsplat src/paper/generate_point_cloud_figure_mvsplat.py + "
               "src/model/ply_export.py (export_ply)", adapter="from_mvsplat"),
    "pixelsplat": ExportFormat(
        order="vhws", trim=0, spp=1, opacity="raw", frame="viewer", rotations="camera",
        source="dcharatan/pixelsplat src/model/encoder/visualization/"
               "encoder_visualizer_epipolar.py + src/model/ply_export.py (export_ply)",
        adapter="from_pixelsplat"),
    "noposplat": ExportFormat(
        order="vhws", trim=0, spp=1, opacity="raw", frame="first-camera", rotations="frame",
        source="cvg/NoPoSplat src/model/ply_export.py (export_ply)", adapter="from_noposplat"),
    "yonosplat": ExportFormat(
        order="hwsv", trim=8, spp=1, opacity="raw", frame="first-camera", rotations="camera",
        opacity_cut=0.01,
        source="YoNoSplat src/model/model_wrapper.py (test_step) + src/model/ply_export.py",
        adapter="from_yonosplat"),
    "resplat": ExportFormat(
        order="vhws", trim=0, spp=1, opacity="logit", frame="middle-rotation",
        rotations="camera", sh_frame="world", grid="latent",
        source="cvg/resplat src/model/ply_export.py (save_gaussian_ply, "
               "save_all_gaussians=True)", adapter="from_resplat"),
    "anysplat": ExportFormat(
        order="vhws", trim=0, spp=1, opacity="raw", frame="world", rotations="frame",
        half_pixel=True, voxelized=True,
        source="InternRobotics/AnySplat inference.py + src/model/ply_export.py (export_ply)",
        adapter="from_anysplat"),
    "3dgs": ExportFormat(
        order="vhws", trim=0, spp=1, opacity="logit", frame="world", rotations="frame"),
}

_ORDERS = ("vhws", "hwsv")
_FRAMES = ("world", "first-rotation", "middle-rotation", "viewer", "first-camera")
_ALIGN = ("auto", "none", "scale", "scale-shift")

#: pixelSplat's fixed viewer rotation: +Z up, then -45 degrees about z (Polycam's start view).
_SWAP = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def viewer_rotation(first_camera_to_world) -> np.ndarray:
    """The rotation pixelSplat's ``export_ply`` applies: ``Rz(-45 deg) @ swap @ C_0^T`` (3, 3)."""
    c = np.radians(-45.0)
    rz = np.array([[np.cos(c), -np.sin(c), 0.0], [np.sin(c), np.cos(c), 0.0], [0, 0, 1.0]])
    c0 = np.asarray(first_camera_to_world, dtype=np.float64)[:3, :3]
    return rz @ _SWAP @ c0.T


@dataclass
class ImportReport:
    """What :func:`import_export` recovered and how well it fits.

    Attributes
    ----------
    format : str
    num_vertices : int
    scale : float
        ``s`` of the file-to-world map ``s A x + b``.
    shift : (3,) list of float
        ``b``.
    aligned : str
        Which unknowns were fitted (``"none"``, ``"scale"``, ``"scale-shift"``).
    inside_pixel : float
        Fraction of pixel-aligned vertices that project into their own pixel in their own view.
    median_px, p99_px : float
        Distance, in pixels, from each such projection to its pixel centre.
    grid : (rows, cols)
    notes : list of str
    near_pixel : float
        Fraction of pixel-aligned vertices whose projection lies within ``near_px`` of their
        pixel centre along each axis; below :data:`MIN_NEAR_SHARE` the import is refused.
    near_px : float
        ``max(1, NEAR_FRACTION * max(height, width))``.
    """

    format: str
    num_vertices: int
    scale: float
    shift: list
    aligned: str
    inside_pixel: float
    median_px: float
    p99_px: float
    grid: tuple
    notes: list = field(default_factory=list)
    near_pixel: float = 0.0
    near_px: float = 1.0

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def summary(self) -> str:
        """One line for the command line."""
        fit = "" if self.aligned == "none" else (
            f"; fitted {self.aligned}: scale {self.scale:.6g}, shift "
            f"({', '.join(f'{x:.4g}' for x in self.shift)})")
        return (f"{self.num_vertices:,} vertices; {100 * self.inside_pixel:.2f} % project into "
                f"their pixel (median {self.median_px:.3f} px, 99th percentile "
                f"{self.p99_px:.3f} px), {100 * self.near_pixel:.2f} % within "
                f"{self.near_px:.3g} px{fit}")


# ------------------------------------------------------------------------------------------------
# layout
# ------------------------------------------------------------------------------------------------
def export_slots(num_views: int, rows: int, cols: int, *, order: str = "vhws", trim: int = 0,
                 spp: int = 1):
    """``(view, cell)`` of every vertex an export writes, in the export's order.

    Parameters
    ----------
    num_views, rows, cols : int
        Views and the per-view grid (the image size for per-pixel models).
    order : {"vhws", "hwsv"}
        ``"vhws"``: view slowest, then row, column, sample; ``"hwsv"``: row, column, sample,
        then view fastest (the ``"h w spp v"`` rearrangement).
    trim : int
        Cells dropped on each border (``mask[trim:-trim, trim:-trim]``; 0 keeps all).
    spp : int
        Gaussians per cell.

    Returns
    -------
    view_id : (M,) int32
    cell_id : (M,) int64
        ``row * cols + col``.
    """
    v, h, w, s, t = int(num_views), int(rows), int(cols), int(spp), int(trim)
    if order not in _ORDERS:
        raise ClearsplatError(f"must be one of {_ORDERS}, got {order!r}", field="order")
    if min(v, h, w, s) < 1 or t < 0:
        raise ClearsplatError(f"views, rows, cols and spp must be positive and trim >= 0, got "
                              f"{v}, {h}, {w}, {s}, {t}", field="layout")
    rr = np.arange(t, h - t)
    cc = np.arange(t, w - t)
    if not len(rr) or not len(cc):
        raise ClearsplatError(f"a trim of {t} leaves nothing of a {h}x{w} grid", field="trim")
    if order == "vhws":
        vv, r, c, _ = np.meshgrid(np.arange(v), rr, cc, np.arange(s), indexing="ij")
    else:
        r, c, _, vv = np.meshgrid(rr, cc, np.arange(s), np.arange(v), indexing="ij")
    return vv.reshape(-1).astype(np.int32), (r * w + c).reshape(-1).astype(np.int64)


def _latent_grid(n_full: int, v: int, h: int, w: int, spp: int) -> tuple:
    """ReSplat's rule: ``f = int(sqrt(V H W / N))``, grid ``(H // f, W // f)``."""
    f = int(np.sqrt(v * h * w * spp / max(n_full, 1)))
    return (h // f, w // f) if f >= 1 else (h, w)


# ------------------------------------------------------------------------------------------------
# frames
# ------------------------------------------------------------------------------------------------
def _frame(fmt: ExportFormat, cameras) -> tuple:
    """``A`` (3, 3), ``b`` (3,), and ``F^T`` for camera-frame rotations."""
    c0 = cameras[0].camera_to_world
    eye = np.eye(3)
    if fmt.frame == "world":
        return eye, np.zeros(3), eye
    if fmt.frame == "first-rotation":
        return c0[:3, :3], np.zeros(3), c0[:3, :3]
    if fmt.frame == "middle-rotation":
        cm = cameras[len(cameras) // 2].camera_to_world
        return cm[:3, :3], np.zeros(3), cm[:3, :3]
    if fmt.frame == "viewer":
        a = viewer_rotation(c0).T
        return a, np.zeros(3), a
    if fmt.frame == "first-camera":
        return c0[:3, :3], c0[:3, 3].copy(), eye
    raise ClearsplatError(f"unknown frame {fmt.frame!r} (known: {_FRAMES})", field="frame")


def _pixel_rays(cameras, view_id, pixel_id):
    """Origins (M, 3) and unit directions (M, 3) through the pixel centres."""
    origins = np.empty((len(view_id), 3))
    dirs = np.empty((len(view_id), 3))
    for v, cam in enumerate(cameras):
        sel = view_id == v
        if not sel.any():
            continue
        pid = pixel_id[sel]
        x = (pid % cam.width + 0.5 - cam.cx) / cam.fx
        y = (pid // cam.width + 0.5 - cam.cy) / cam.fy
        d = np.stack([x, y, np.ones_like(x)], axis=1) @ cam.camera_to_world[:3, :3].T
        dirs[sel] = d / np.linalg.norm(d, axis=1, keepdims=True)
        origins[sel] = cam.position
    return origins, dirs


def _fit(a_pts, b0, origins, dirs, mode: str):
    """Least-squares ``s`` (and ``b``) putting ``s a + b`` on the rays ``o + t d``.

    Minimises ``sum w_i |P_i (s a_i + b - o_i)|^2`` with ``P_i = I - d_i d_i^T`` (the part off
    the ray) and ``w_i = 1 / depth_i^2`` (angular error), re-weighted three times with the
    vertices beyond five median residuals left out (occlusion edges, bad depths).
    """
    n = len(a_pts)
    proj = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]          # (n, 3, 3)
    pa = np.einsum("nij,nj->ni", proj, a_pts)
    po = np.einsum("nij,nj->ni", proj, origins)
    w = np.ones(n)
    s, b = 1.0, np.asarray(b0, dtype=np.float64)
    for _ in range(4):
        if mode == "scale":
            rhs = po - np.einsum("nij,j->ni", proj, b)
            den = np.sum(w * np.einsum("ni,ni->n", pa, pa))
            if not den > 0:
                raise ClearsplatError("cannot fit a scale: the vertices lie on their rays' "
                                      "origins", field="align")
            s = float(np.sum(w * np.einsum("ni,ni->n", pa, rhs)) / den)
        else:
            jt = np.concatenate([pa[:, :, None], proj], axis=2)                # (n, 3, 4)
            lhs = np.einsum("n,nij,nik->jk", w, jt, jt)
            rhs = np.einsum("n,nij,ni->j", w, jt, po)
            try:
                u = np.linalg.solve(lhs, rhs)
            except np.linalg.LinAlgError:
                raise ClearsplatError("cannot fit a scale and shift: the rays are degenerate "
                                      "(one view, or parallel rays)", field="align") from None
            s, b = float(u[0]), u[1:]
        pts = s * a_pts + b
        depth = np.einsum("ni,ni->n", pts - origins, dirs)
        off = np.linalg.norm(np.einsum("nij,nj->ni", proj, pts - origins), axis=1)
        ang = off / np.maximum(np.abs(depth), 1e-12)
        keep = (depth > 0) & (ang <= 5 * np.median(ang) + 1e-12)
        w = np.where(keep, 1.0 / np.maximum(depth, 1e-12) ** 2, 0.0)
        if not w.any():
            break
    if not s > 0:
        raise ClearsplatError(f"the fitted scale is {s:.3g}: the cameras do not see these "
                              "vertices (wrong cameras, views or order?)", field="align")
    return s, np.asarray(b, dtype=np.float64)


def _residuals(means, cameras, view_id, pixel_id):
    """Offset (M, 2) of each vertex's projection from its pixel centre, in pixels."""
    out = np.full((len(means), 2), np.inf)
    for v, cam in enumerate(cameras):
        sel = (view_id == v) & (pixel_id >= 0)
        if not sel.any():
            continue
        uv, z = cam.project(means[sel])
        pid = pixel_id[sel]
        centre = np.stack([pid % cam.width + 0.5, pid // cam.width + 0.5], axis=1)
        d = uv - centre
        d[~(z > 0)] = np.inf
        out[np.flatnonzero(sel)] = d
    return out


# ------------------------------------------------------------------------------------------------
# the import
# ------------------------------------------------------------------------------------------------
def import_export(path, format: str, cameras, images=None, *, trim: int | None = None,
                  spp: int | None = None, opacity_cut: float | None = None,
                  order: str | None = None, grid: tuple | None = None, align: str = "auto",
                  voxelized: bool | None = None, half_pixel: bool | None = None,
                  allow_misaligned: bool = False):
    """Read a model's PLY export as a scene with ``view_id`` and ``pixel_id``.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.ply`` the model's export function wrote.
    format : str
        One of :data:`EXPORT_FORMATS`.
    cameras : sequence of Camera
        The model's context views, in its view order, at the resolution the model saw (all
        the same size). Their frame is the world of the result.
    images : sequence of (H, W, 3) arrays, optional
        Those views' images in [0, 1] (the filter needs them).
    trim, spp, opacity_cut, order : optional
        Override the format's defaults (``trim=0`` for an untrimmed export, ...).
    grid : (rows, cols), optional
        Per-view grid of a latent-grid model (``resplat``); inferred when left out.
    align : {"auto", "none", "scale", "scale-shift"}
        Which unknowns of the file-to-world map ``s A x + b`` to fit by aligning the
        pixel-aligned vertices to their pixel rays. ``"auto"``: ``"scale-shift"`` for the
        ``viewer`` frame (whose median and scale are not recorded), ``"none"`` otherwise.
    voxelized : bool, optional
        Whether the model fused pixels into voxels (AnySplat's released configs do); such a
        file holds no association and is refused.
    half_pixel : bool, optional
        Move the cameras' principal points by +0.5 px (VGGT's pixel convention, AnySplat).
    allow_misaligned : bool
        Return the scene even when fewer than :data:`MIN_NEAR_SHARE` of the pixel-aligned
        vertices project near their pixel (``ImportReport.near_pixel``); by default such an
        import, whose association is wrong, is refused.

    Returns
    -------
    scene : Scene
        Gaussians in the cameras' world, ``view_id`` and ``pixel_id`` from the layout
        (``pixel_id = -1`` on a latent grid), the (possibly shifted) cameras, the images, and
        the model's render settings (those of the adapter: ReSplat's antialiased mode,
        AnySplat's radius clip).
    report : ImportReport

    Raises
    ------
    ClearsplatError
        In one line, naming the file: the vertex count does not fit the layout (with the
        layouts that would fit, or why the association is lost: an opacity cut, voxels);
        the opacity column does not hold what the format says; the vertices do not project
        near their pixels (field ``format`` with the formats whose frame fits, else
        ``vertex``); bad cameras or images.
    """
    if format not in EXPORT_FORMATS:
        raise ClearsplatError(f"unknown format {format!r} (known: "
                              f"{', '.join(EXPORT_FORMATS)})", field="format")
    given = list(cameras)
    fmt = EXPORT_FORMATS[format]
    fmt = replace(fmt, **{k: v for k, v in dict(
        trim=trim, spp=spp, opacity_cut=opacity_cut, order=order, voxelized=voxelized,
        half_pixel=half_pixel).items() if v is not None})
    if align not in _ALIGN:
        raise ClearsplatError(f"must be one of {_ALIGN}, got {align!r}", field="align")
    if not 0 <= float(fmt.opacity_cut) < 1:       # also refuses NaN
        raise ClearsplatError(f"must lie in [0, 1), got {fmt.opacity_cut}", field="opacity_cut")
    if int(fmt.trim) < 0:
        raise ClearsplatError(f"must be >= 0, got {fmt.trim}", field="trim")
    if int(fmt.spp) < 1:
        raise ClearsplatError(f"must be >= 1, got {fmt.spp}", field="spp")
    cams = _checked_cameras(given)
    v, h, w = len(cams), cams[0].height, cams[0].width
    if fmt.half_pixel:
        cams = [_shift_principal_point(c, 0.5) for c in cams]
    if images is not None:
        images = _checked_images(images, v, h, w)

    g, _, _ = read_export(path, opacity=fmt.opacity, color="sh")
    n = len(g)
    if fmt.voxelized:
        raise ClearsplatError(
            f"{format} fuses pixels into voxels by default (voxelize: true): vertex k is voxel "
            "k, mixed from pixels of several views, and the file does not say which; build the "
            f"scene with clearsplat.adapters.{fmt.adapter} and voxel_inverse from "
            "clearsplat.adapters.anysplat_voxel_inverse (examples/anysplat_inference.py), or "
            "pass voxelized=False (--no-voxels) for a model run with voxelize: false",
            path=path, field="vertex")
    if fmt.grid == "latent":
        gh, gw = (int(grid[0]), int(grid[1])) if grid is not None else \
            _latent_grid(n + _trimmed(fmt, v, h, w, n), v, h, w, fmt.spp)
    else:
        gh, gw = h, w
    view_id, cell_id = export_slots(v, gh, gw, order=fmt.order, trim=fmt.trim, spp=fmt.spp)
    if len(view_id) != n:
        raise ClearsplatError(_count_message(fmt, format, n, v, gh, gw), path=path,
                              field="vertex")
    if fmt.opacity_cut > 0 and n and g.opacities.min() <= fmt.opacity_cut:
        raise ClearsplatError(
            f"{format} exports drop opacities <= {fmt.opacity_cut:g}, but this file has "
            f"{g.opacities.min():.3g}: it was not written with that cut (pass opacity_cut=0)",
            path=path, field="opacity")
    pixel_id = cell_id if (gh, gw) == (h, w) else np.full(n, -1, dtype=np.int64)

    # the frame: s A x + b, with s and b fitted where the export did not record them
    a, b, ft = _frame(fmt, cams)
    a_pts = g.means.astype(np.float64) @ a.T
    mode = ("scale-shift" if fmt.frame == "viewer" else "none") if align == "auto" else align
    s = 1.0
    notes = []
    if mode != "none":
        aligned = pixel_id >= 0
        if aligned.sum() < 4:
            raise ClearsplatError(f"cannot align: {int(aligned.sum())} pixel-aligned vertices",
                                  path=path, field="align")
        o, d = _pixel_rays(cams, view_id[aligned], pixel_id[aligned])
        s, b = _fit(a_pts[aligned], b, o, d, mode)
    means = s * a_pts + b
    scales = (g.scales.astype(np.float64) * s).astype(np.float32)

    # rotations to world
    from ..adapters._common import matrices_to_quats, quats_to_matrices
    rot = quats_to_matrices(g.quats) if n else np.zeros((0, 3, 3))
    if fmt.rotations == "camera":
        c2w = np.stack([c.camera_to_world[:3, :3] for c in cams])
        rot = c2w[view_id] @ (ft @ rot)
    else:
        rot = a @ rot
    quats = matrices_to_quats(rot).astype(np.float32) if n else g.quats
    sh = g.sh
    if sh.shape[1] > 1 and fmt.sh_frame == "file" and not np.allclose(a, np.eye(3)):
        from ..adapters.sh_rotation import rotate_sh
        try:
            sh = rotate_sh(sh, a)
        except ClearsplatError as e:
            raise ClearsplatError(
                f"the f_rest bands are in the export's frame and must turn to the cameras' "
                f"({e.reason}); export the DC band only, or give cameras in the export's frame",
                path=path, field="f_rest") from None
    out = Gaussians(means=means.astype(np.float32), scales=scales, quats=quats,
                    opacities=g.opacities, sh=sh)
    scene = Scene(out, view_id=view_id, pixel_id=pixel_id, cameras=cams, images=images,
                  render_settings=_render_settings(format))
    scene.validate(path=path)

    res = _residuals(means, cams, view_id, pixel_id)
    fin = res[np.isfinite(res).all(axis=1)]
    aligned_n = int((pixel_id >= 0).sum())
    inside = float((np.abs(fin) <= 0.5 + 1e-3).all(axis=1).sum() / aligned_n) if aligned_n \
        else 0.0
    dist = np.linalg.norm(fin, axis=1) if len(fin) else np.array([np.nan])
    near_px = max(1.0, NEAR_FRACTION * max(h, w))
    near = float((np.abs(res) <= near_px).all(axis=1).sum() / aligned_n) if aligned_n else 0.0
    if not aligned_n:
        notes.append("no vertex is pixel-aligned (latent grid): the filter associates them "
                     "through the rasterizer")
    if fmt.cut_note:
        notes.append(fmt.cut_note + "; the vertex count matched, so none were dropped")
    report = ImportReport(format=format, num_vertices=n, scale=float(s),
                          shift=[float(x) for x in b], aligned=mode, inside_pixel=inside,
                          median_px=float(np.median(dist)) if aligned_n else float("nan"),
                          p99_px=float(np.percentile(dist, 99)) if aligned_n else float("nan"),
                          grid=(gh, gw), notes=notes, near_pixel=near, near_px=near_px)
    if aligned_n and near < MIN_NEAR_SHARE and not allow_misaligned:
        raise _misaligned(path, format, fmt, given, report)
    return scene, report


def _misaligned(path, format, fmt, cameras, report) -> ClearsplatError:
    """The refusal of an import whose vertices miss their pixels, naming the formats that fit.

    Every other format is tried with its own defaults and with the layout (order, trim,
    spp) this import used; those that put at least :data:`MIN_NEAR_SHARE` of the vertices
    near their pixel are named with the command line that imports them.
    """
    share = (f"only {100 * report.near_pixel:.1f} % of the pixel-aligned vertices project "
             f"within {report.near_px:.3g} px of their pixel (at least "
             f"{100 * MIN_NEAR_SHARE:.0f} % needed)")
    keep = "allow_misaligned=True (--allow-misaligned) keeps it anyway"
    fits = []
    for name, other in EXPORT_FORMATS.items():
        if name == format:
            continue
        layouts = [{}]
        mine = dict(order=fmt.order, trim=fmt.trim, spp=fmt.spp)
        if any(getattr(other, k) != v for k, v in mine.items()):
            layouts.append(mine)
        for layout in layouts:
            extra = dict(voxelized=False) if other.voxelized else {}
            try:
                _, rep = import_export(path, name, cameras, align="auto",
                                       allow_misaligned=True, **layout, **extra)
            except ClearsplatError:
                continue
            if rep.near_pixel >= MIN_NEAR_SHARE:
                flags = "".join(f" --{k} {v}" for k, v in layout.items()
                                if getattr(other, k) != v)
                flags += " --no-voxels" if extra else ""
                fits.append((-rep.near_pixel, bool(flags), name, other.frame, flags))
                break
    if not fits:
        return ClearsplatError(
            f"{share}: the association is wrong; the cameras (their order, --views), the "
            f"image size or the format's options do not match the export, and no other "
            f"format's frame fits the pixel rays; {keep}", path=path, field="vertex")
    fits.sort()
    named = " or ".join(f"{name}'s {frame} frame: clearsplat import {name}{flags} ... "
                        f"({100 * -s:.0f} % near)" for s, _, name, frame, flags in fits)
    return ClearsplatError(f"read as {format} ({fmt.frame} frame), {share}: the file is not "
                           f"{format}'s export; the vertices fit {named}; {keep}",
                           path=path, field="format")


def _render_settings(format: str):
    """How the model renders (the adapters' settings), so the filter renders the same way."""
    if format == "resplat":
        from ..adapters.pixelsplat import RESPLAT_RENDER_SETTINGS
        return RESPLAT_RENDER_SETTINGS
    if format == "anysplat":
        from ..adapters.anysplat import RENDER_SETTINGS
        return RENDER_SETTINGS
    return None


def _trimmed(fmt, v, h, w, n) -> int:
    """Vertices a trim removes from a latent grid with ``n`` kept (for inferring the grid)."""
    if fmt.trim == 0:
        return 0
    for f in range(1, 65):
        gh, gw = h // f, w // f
        if gh > 2 * fmt.trim and gw > 2 * fmt.trim and \
                v * (gh - 2 * fmt.trim) * (gw - 2 * fmt.trim) * fmt.spp == n:
            return v * gh * gw * fmt.spp - n
    return 0


def _count_message(fmt, name, n, v, gh, gw) -> str:
    m = len(export_slots(v, gh, gw, order=fmt.order, trim=fmt.trim, spp=fmt.spp)[0])
    what = (f"{n:,} vertices, but {v} views of a {gh}x{gw} grid with trim {fmt.trim} and "
            f"{fmt.spp} per pixel make {m:,}")
    if fmt.opacity_cut > 0 and n < m:
        return (f"{what}: the export dropped the Gaussians of opacity <= {fmt.opacity_cut:g} "
                "without recording which, so the association cannot be recovered; re-export "
                "without that cut (opacity_cut=0 here) or build the scene from the model's "
                f"tensors with clearsplat.adapters.{fmt.adapter}")
    fits = [f"trim={t} spp={s}" for t in (0, 2, 4, 8, 16) for s in (1, 2, 3)
            if gh > 2 * t and gw > 2 * t and v * (gh - 2 * t) * (gw - 2 * t) * s == n]
    hint = (f"; it fits {' or '.join(fits)}" if fits else
            "; check the views (--views), the image size the model saw and the options")
    if fmt.cut_note and n < m:
        hint += f" ({fmt.cut_note}: then the association is lost; use " \
                f"clearsplat.adapters.{fmt.adapter} on the model's tensors)"
    return what + hint


def _checked_cameras(cameras) -> list:
    cams = list(cameras)
    if not cams:
        raise ClearsplatError("no cameras", field="cameras")
    for i, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise ClearsplatError(f"expected a Camera, got {type(c).__name__}",
                                  field=f"cameras[{i}]")
        if (c.height, c.width) != (cams[0].height, cams[0].width):
            raise ClearsplatError(f"camera is {c.width}x{c.height}, camera 0 is "
                                  f"{cams[0].width}x{cams[0].height}: the model saw one size",
                                  field=f"cameras[{i}]")
    return cams


def _checked_images(images, v, h, w) -> list:
    ims = [np.asarray(im, dtype=np.float32) for im in images]
    if len(ims) != v:
        raise ClearsplatError(f"{len(ims)} images for {v} cameras", field="images")
    for i, im in enumerate(ims):
        if im.shape != (h, w, 3):
            raise ClearsplatError(f"expected {(h, w, 3)}, got {im.shape}",
                                  field=f"images[{i}]")
    return ims


def _shift_principal_point(cam: Camera, px: float) -> Camera:
    k = cam.K.copy()
    k[0, 2] += px
    k[1, 2] += px
    return Camera(K=k, camera_to_world=cam.camera_to_world, width=cam.width, height=cam.height)


# ------------------------------------------------------------------------------------------------
# cameras and images from files
# ------------------------------------------------------------------------------------------------
def load_views(cameras_path, images_dir, *, views=None):
    """The context cameras and images of a model run, from files.

    Parameters
    ----------
    cameras_path : str or os.PathLike
        A ``cameras.json`` / nerfstudio ``transforms.json`` (or a folder holding one), or a
        COLMAP model folder (``cameras.bin``/``images.bin`` or ``.txt``, or a dataset folder
        with ``sparse/0``).
    images_dir : str or os.PathLike
        The images the model saw. Matched to the cameras by file name (the cameras' image
        names, without their folders); when the names do not match, by sorted order if there
        are as many images as (selected) cameras.
    views : sequence of int or str, optional
        Which cameras are the model's context views, in the model's order: indices into the
        camera file's order (COLMAP: sorted by image name) or image names. Default: all.

    Returns
    -------
    cameras : list of Camera
        At the images' resolution: a camera whose size differs from its image by one exact
        factor is scaled to it (``Camera.scaled``); any other mismatch is refused.
    images : list of (H, W, 3) float32
    names : list of str
        The image files used.

    Raises
    ------
    ClearsplatError
        Naming the file or option: unreadable cameras or images, an unknown view, too few
        images, a size that is not a uniform scaling (a crop: write the cropped cameras).
    """
    from pathlib import Path

    from .bundle import CAMERAS_FILE, TRANSFORMS_FILE, load_cameras
    from .colmap import read_colmap
    from .images import read_image

    cpath = Path(cameras_path)
    colmap = cpath.is_dir() and not any((cpath / f).is_file()
                                        for f in (CAMERAS_FILE, TRANSFORMS_FILE))
    if colmap:
        cams, names = read_colmap(cpath)
    else:
        cams, paths = load_cameras(cpath)
        names = [None if p is None else Path(p).name for p in paths]
    names = [None if n is None else Path(n).name for n in names]
    if views is not None:
        picked = []
        for item in views:
            key = str(item).strip()
            if key.lstrip("-").isdigit():
                i = int(key)
                if not 0 <= i < len(cams):
                    raise ClearsplatError(f"view {i} out of range 0..{len(cams) - 1}",
                                          path=cpath, field="--views")
            elif key in names:
                i = names.index(key)
            else:
                raise ClearsplatError(f"no camera for image {key!r}", path=cpath,
                                      field="--views")
            picked.append(i)
        cams, names = [cams[i] for i in picked], [names[i] for i in picked]
    folder = Path(images_dir)
    if not folder.is_dir():
        raise ClearsplatError("not a folder", path=folder, field="--images")
    files = sorted(p.name for p in folder.iterdir()
                   if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file())
    if all(n is not None and n in files for n in names):
        chosen = list(names)
    elif len(files) == len(cams):
        chosen = files
    else:
        raise ClearsplatError(f"{len(files)} images and {len(cams)} cameras, and the cameras' "
                              "image names are not all in the folder: pass --views or a folder "
                              "holding exactly the model's input images", path=folder,
                              field="--images")
    images, out = [], []
    for i, (cam, name) in enumerate(zip(cams, chosen)):
        img = read_image(folder / name)
        h, w = img.shape[:2]
        if (h, w) != (cam.height, cam.width):
            f = w / cam.width
            if abs(h - cam.height * f) > 1e-9 * h or round(cam.width * f) != w:
                raise ClearsplatError(
                    f"image is {w}x{h}, its camera {cam.width}x{cam.height}: not a uniform "
                    "scaling (a crop, such as DepthSplat's centre crop, changes the principal "
                    "point; write the cameras of the cropped images)", path=folder / name,
                    field="size")
            cam = cam.scaled(f)
        images.append(img)
        out.append(cam)
    return out, images, chosen
