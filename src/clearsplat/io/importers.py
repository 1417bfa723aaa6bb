"""Scenes from the PLY exports of feed-forward models, with the view association recovered.

A model's ``export_ply`` writes no ``view_id``, but the order of its vertices follows the
model's per-pixel layout, so the association is implied by the vertex order, the image grid
and the export's options (border trim, Gaussians per pixel, view order, cuts). This module
recomputes it, undoes the export's change of frame, turns camera-frame rotations to world, and
returns a :class:`clearsplat.Scene` the filter takes. The scene keeps the file's vertex order,
so a mask over it (the filter's ``removed.npy``) indexes the file.

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
anysplat   voxels  0    raw     --         world (predicted)   frame
3dgs       v h w s 0    logit   --         world               frame
========== ======= ==== ======= ========== =================== ================

AnySplat fuses pixels into voxels by default (``voxelize: true``): each voxel's view is
recovered from the images (``voxelized=False``, ``--no-voxels``: per-pixel ``v h w s``).

Other exports no longer give each vertex's view and pixel by their order
(:data:`MODEL_FORMATS`); the association is recovered from the geometry or the images
(:mod:`clearsplat.adapters.associate`). Per-pixel vertices in pixel order get theirs from the
runs of the order; those in no order (Long-LRM pruned, WorldMirror 2.0 subsampled) from the
camera that puts each centre on a pixel centre, where the model placed them there in float32
(else from the images); voxels from the images:

=========== ========================================= ======= =========================
format      order of the vertices                     opacity frame
=========== ========================================= ======= =========================
da3         v h w, border trim and per-view depth cut logit   normalised (poses given),
                                                               or the cameras'; fitted
worldmirror voxel key (v1; 2.0 when voxels merge),    raw     predicted cameras'
            v h w after masks (2.0, no merge), or
            a seeded subsample (2.0, > 5M)
longlrm     v h w minus opacity <= 0.001, or ranked   logit   normalised (from cameras)
            by opacity plus random picks (pruned)
volsplat    refused: constant 0.01 scales, padded/truncated to V H W
=========== ========================================= ======= =========================

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
- Depth Anything 3: with given poses, its frame has camera 0 the identity and the camera
  centres divided by their median distance from it, then rescaled by the model (an Umeyama
  scale): undone from the cameras, then fitted to the pixel rays together with the
  association; without, the frame of its own predicted cameras (fitted the same way).
- Long-LRM: its input normalisation (mean camera axes and centre, largest coordinate 1),
  computed from the cameras (:func:`longlrm_frame`).
- WorldMirror: the frame of its predicted cameras (``camera_params.json``, whose
  ``extrinsics`` are camera-to-world: :func:`read_camera_params`).

Rotations: ``world``/``frame`` rotations are in the file's frame and turn with ``A``;
``camera`` rotations are each vertex's own camera frame (the encoders' un-rotated
``rotations``), turned only by the export's frame rotation, so the world rotation is
``C_v @ F^T @ R_file`` with ``F`` the rotation the export applied (``A^T`` for ``viewer`` and
``middle-rotation``, none for ``first-camera``). Depth Anything 3 writes ``mat_to_quat``'s
``x y z w`` into ``rot_0..3`` and renders that vector as ``w x y z`` (gsplat): it is read as
written, which reproduces the model's renders.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, Scene
from .exports import read_export

__all__ = ["EXPORT_FORMATS", "ExportFormat", "MODEL_FORMATS", "ModelExport", "ImportReport",
           "import_export", "export_slots", "viewer_rotation", "longlrm_frame", "load_views",
           "read_camera_params", "NEAR_FRACTION", "MIN_NEAR_SHARE", "MIN_SEEN_SHARE",
           "MAX_ORDER_AMBIGUOUS", "MIN_CENTRED_SHARE", "VOXEL_ORDER_SHARE"]

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
        The upstream default fuses pixels into voxels: the file holds no association, and
        each voxel's view is recovered from the images
        (:func:`clearsplat.adapters.associate.associate_fused`; a pixel only for a
        voxel of one pixel).
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

@dataclass(frozen=True)
class ModelExport:
    """An export whose vertex order no longer gives each vertex's view and pixel.

    Attributes
    ----------
    association : {"ordered", "voxels-or-ordered", "ranked-or-ordered", "refused"}
        ``"ordered"``: one Gaussian per kept pixel, view after view in ``(view, row, col)``
        order with unknown cuts; views and pixels from the geometry
        (:func:`~clearsplat.adapters.associate.associate_ordered`). ``"voxels-or-ordered"``:
        voxel-merged when the vertices are sorted by voxel key, then each Gaussian's view from
        the images (:func:`~clearsplat.adapters.associate.associate_fused`, a pixel only for a
        voxel of one pixel); else ordered; in neither order (a subsample), views and pixels
        from the pixel centre each centre lies on
        (:func:`~clearsplat.adapters.associate.associate_centred`), or from the images where
        the centres are not on pixel centres. ``"ranked-or-ordered"``: where
        the export ranked its vertices by opacity (pruning), as the subsample; else ordered.
        ``"refused"``: the file cannot be filtered.
    opacity : {"logit", "raw"}
    frame : {"world", "da3", "longlrm", "first-rotation"}
        ``"world"``: the cameras' frame (the model's predicted cameras). ``"da3"``: the
        cameras' frame or Depth Anything 3's normalised frame of their poses, fitted to the
        pixel rays. ``"longlrm"``: Long-LRM's normalised frame of the cameras
        (:func:`longlrm_frame`).
    bands : int
        SH coefficients per channel the export writes.
    half_pixel : bool
        The model puts pixel ``(row, col)`` at image coordinates ``(col, row)``: the
        cameras' principal points are moved by +0.5 px (as :class:`ExportFormat`).
    centred : bool
        A per-pixel vertex lies on the ray through its pixel's centre (no offsets): with the
        right cameras it projects there, within :data:`CENTRE_PX`; an ordered import where
        fewer than :data:`MIN_NEAR_SHARE` do is refused, and one in no order is associated
        from those centres (:data:`MIN_CENTRED_SHARE`).
    source : str
    """

    association: str
    opacity: str
    frame: str
    bands: int = 1
    half_pixel: bool = False
    centred: bool = False
    source: str = ""


#: Exports whose vertex order no longer gives each vertex's view and pixel (details:
#: ``docs/backbones.md``): the association is recovered from the geometry
#: (:func:`clearsplat.adapters.associate.associate_ordered`,
#: :func:`clearsplat.adapters.associate.associate_centred`) or the images
#: (:func:`clearsplat.adapters.associate.associate_fused`).
MODEL_FORMATS = {
    "da3": ModelExport(
        association="ordered", opacity="logit", frame="da3",
        source="ByteDance-Seed/Depth-Anything-3 src/depth_anything_3/utils/export/gs.py "
               "(export_to_gs_ply) + utils/gsply_helpers.py (save_gaussian_ply)"),
    "worldmirror": ModelExport(
        association="voxels-or-ordered", opacity="raw", frame="world", half_pixel=True,
        centred=True,
        source="Tencent-Hunyuan/HunyuanWorld-Mirror infer.py + src/utils/save_utils.py "
               "(save_gs_ply); Tencent-Hunyuan/HY-World-2.0 hyworld2/worldrecon/hyworldmirror/"
               "utils/inference_utils.py (save_results)"),
    "longlrm": ModelExport(
        association="ranked-or-ordered", opacity="logit", frame="longlrm", bands=16,
        centred=True,
        source="arthurhero/Long-LRM model/llrm.py (LongLRM.forward, save_gaussian_ply)"),
    "volsplat": ModelExport(
        association="refused", opacity="logit", frame="first-rotation",
        source="ziplab/VolSplat src/model/ply_export.py (save_gaussian_ply)"),
}

#: Least share of the Gaussians whose recovered view sees them (unambiguous): below it the
#: cameras do not fit the export and the import is refused (unless ``allow_misaligned``).
MIN_SEEN_SHARE = 0.5
#: A WorldMirror export in neither voxel nor pixel order (its seeded subsample above 5 million
#: Gaussians) breaks the per-pixel order at about every other vertex; one in pixel order at
#: almost none. More ambiguous vertices than this share and the order is taken as lost.
MAX_ORDER_AMBIGUOUS = 0.1
#: Scales tried on Depth Anything 3's normalised frame, nearest first, when it does not fit as
#: it is. The model rescales its own poses to the given (normalised) ones by their Umeyama
#: scale, so its frame is off only by its pose errors (unless that scale hit its clamp, [1/3,
#: 3]): steps of 10 % (a fit converges from within about 10 %) up to about 50 %.
DA3_SCALES = tuple(k for j in range(1, 5) for k in (1.1 ** j, 1.1 ** -j))
#: Pixels a DA3 vertex's projection may fall back within one image row (offsets, a frame not
#: yet fitted) before it is taken as the start of the next row.
DA3_ROW_TOLERANCE = 4.0
#: Pixels (per axis) within which a vertex of a ``centred`` export projects onto its pixel's
#: centre with the right cameras (they put it there up to float32 round-off); with other
#: cameras the projections spread over the pixel, 4 % of them this near.
CENTRE_PX = 0.1
#: Least share of the vertices of a ``centred`` export in no order (Long-LRM pruned,
#: WorldMirror 2.0 subsampled) that a camera must put unambiguously on a pixel centre
#: (:func:`clearsplat.adapters.associate.associate_centred`) for that association to be taken;
#: below it each Gaussian's view is recovered from the images. Exports computed in float32
#: have over 99.9 % on the test worlds (video-like captures included); Long-LRM's under
#: bfloat16 autocast 0.5 to 3.6 %; centres on no pixel centre about ``V (2 tolerance)^2`` by
#: chance (5 % with 32 views).
MIN_CENTRED_SHARE = 0.5
#: Voxel order: ``x`` falls back below its running maximum by at most a voxel; taken as such
#: when the 99th percentile of that fall-back is within this share of the ``x`` extent.
VOXEL_ORDER_SHARE = 0.02

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
    association : str
        For a recovered association (:data:`MODEL_FORMATS`, voxels): its one-line summary
        (how many Gaussians got a view, how many are ambiguous); empty otherwise. The pixel
        of a recovered vertex is the one its centre projects to, so ``inside_pixel`` then
        says only where the centres sit in their pixels.
    ambiguous : int
        Gaussians whose recovered view is not clearly right.
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
    association: str = ""
    ambiguous: int = 0

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    def summary(self) -> str:
        """One line for the command line."""
        fit = "" if self.aligned == "none" else (
            f"; fitted {self.aligned}: scale {self.scale:.6g}, shift "
            f"({', '.join(f'{x:.4g}' for x in self.shift)})")
        if self.association:
            return f"{self.num_vertices:,} vertices; {self.association}{fit}"
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
                  allow_misaligned: bool = False, progress=None):
    """Read a model's PLY export as a scene with ``view_id`` and ``pixel_id``.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.ply`` the model's export function wrote.
    format : str
        One of :data:`EXPORT_FORMATS` (the association follows from the vertex order) or
        :data:`MODEL_FORMATS` (it is recovered from the geometry or the images).
    cameras : sequence of Camera
        The model's context views, in its view order, at the resolution the model saw (all
        the same size). Their frame is the world of the result.
    images : sequence of (H, W, 3) arrays, optional
        Those views' images in [0, 1] (the filter needs them; so does the association of
        fused Gaussians: voxels, and the exports in no order whose centres are not on their
        pixels' centres).
    trim, spp, opacity_cut, order : optional
        Override the format's defaults (``trim=0`` for an untrimmed export, ...); not for
        :data:`MODEL_FORMATS`.
    grid : (rows, cols), optional
        Per-view grid of a latent-grid model (``resplat``); inferred when left out.
    align : {"auto", "none", "scale", "scale-shift"}
        Which unknowns of the file-to-world map ``s A x + b`` to fit by aligning the
        pixel-aligned vertices to their pixel rays. ``"auto"``: ``"scale-shift"`` for the
        ``viewer`` frame (whose median and scale are not recorded), ``"none"`` otherwise.
    voxelized : bool, optional
        Whether the model fused pixels into voxels (``anysplat``: its released configs do,
        the default); each voxel's view is then recovered from the images
        (:func:`clearsplat.adapters.associate.associate_fused`; a pixel only for a
        voxel of one pixel).
        ``False``: a per-pixel export in the model's order.
    half_pixel : bool, optional
        Move the cameras' principal points by +0.5 px (VGGT's pixel convention, AnySplat).
    allow_misaligned : bool
        Return the scene even when fewer than :data:`MIN_NEAR_SHARE` of the pixel-aligned
        vertices project near their pixel (``ImportReport.near_pixel``), or, for
        :data:`MODEL_FORMATS` and voxels, when the cameras see fewer than
        :data:`MIN_SEEN_SHARE` of them; by default such an import, whose association is
        wrong, is refused.
    progress : callable(stage, done, total), optional
        Told of the association from the images, one camera at a time (stage
        ``"associate"``; :func:`clearsplat.adapters.associate.associate_fused`).

    Returns
    -------
    scene : Scene
        Gaussians in the cameras' world, in the file's vertex order (so a mask over the
        scene indexes the file), ``view_id`` and ``pixel_id`` (``-1`` on a latent grid, for
        fused Gaussians and for recovered vertices outside their view's image), the
        (possibly shifted) cameras, the images, and the model's render settings (those of
        the adapter: ReSplat's antialiased mode, AnySplat's radius clip).
    report : ImportReport

    Raises
    ------
    ClearsplatError
        In one line, naming the file: the vertex count does not fit the layout (with the
        layouts that would fit, or why the association is lost: an opacity cut); the opacity
        column does not hold what the format says; the vertices do not project near their
        pixels (field ``format`` with the formats whose frame fits, else ``vertex``); the
        cameras do not fit a recovered association (field ``cameras``); an export that
        cannot be imported (``volsplat``); missing images where they are needed; bad
        cameras or images.
    """
    if format in MODEL_FORMATS:
        given = dict(trim=trim, spp=spp, opacity_cut=opacity_cut, order=order, grid=grid,
                     voxelized=voxelized, half_pixel=half_pixel)
        for name, value in list(given.items()) + [("align", None if align == "auto" else 1)]:
            if value is not None:
                raise ClearsplatError(f"does not apply to {format}, whose association is "
                                      "recovered from the geometry or the images", field=name)
        cams = _checked_cameras(cameras)
        if images is not None:
            images = _checked_images(images, len(cams), cams[0].height, cams[0].width)
        return _import_model(path, format, cams, images, allow_misaligned=allow_misaligned,
                             progress=progress)
    fmt = _format_with_options(format, dict(
        trim=trim, spp=spp, opacity_cut=opacity_cut, order=order, voxelized=voxelized,
        half_pixel=half_pixel), align)
    given = list(cameras)
    cams = _checked_cameras(given)
    v, h, w = len(cams), cams[0].height, cams[0].width
    if fmt.half_pixel:
        cams = [_shift_principal_point(c, 0.5) for c in cams]
    if images is not None:
        images = _checked_images(images, v, h, w)
    g, _, _ = read_export(path, opacity=fmt.opacity, color="sh")
    if fmt.voxelized:
        return _import_fused(path, format, g, cams, images, allow_misaligned=allow_misaligned,
                             notes=["voxel-fused export: each voxel's view recovered from the "
                                    "images"], progress=progress)
    view_id, pixel_id, (gh, gw) = _layout(path, format, fmt, g, cams, grid)

    # the frame: s A x + b, with s and b fitted where the export did not record them
    a, b, ft = _frame(fmt, cams)
    a_pts = g.means.astype(np.float64) @ a.T
    mode = ("scale-shift" if fmt.frame == "viewer" else "none") if align == "auto" else align
    s = 1.0
    if mode != "none":
        aligned = pixel_id >= 0
        if aligned.sum() < 4:
            raise ClearsplatError(f"cannot align: {int(aligned.sum())} pixel-aligned vertices",
                                  path=path, field="align")
        o, d = _pixel_rays(cams, view_id[aligned], pixel_id[aligned])
        s, b = _fit(a_pts[aligned], b, o, d, mode)
    means = s * a_pts + b
    out = _turned(path, fmt, g, means, s, a, ft, cams, view_id)
    scene = Scene(out, view_id=view_id, pixel_id=pixel_id, cameras=cams, images=images,
                  render_settings=_render_settings(format))
    scene.validate(path=path)
    notes = [] if (pixel_id >= 0).any() else \
        ["no vertex is pixel-aligned (latent grid): the filter associates them through the "
         "rasterizer"]
    if fmt.cut_note:
        notes.append(fmt.cut_note + "; the vertex count matched, so none were dropped")
    report = ImportReport(format=format, num_vertices=len(g), scale=float(s),
                          shift=[float(x) for x in b], aligned=mode, grid=(gh, gw), notes=notes,
                          **_pixel_stats(means, cams, view_id, pixel_id))
    if (pixel_id >= 0).any() and report.near_pixel < MIN_NEAR_SHARE and not allow_misaligned:
        raise _misaligned(path, format, fmt, given, report)
    return scene, report


def _format_with_options(format: str, options: dict, align: str) -> ExportFormat:
    """The format's layout with the options given, checked."""
    if format not in EXPORT_FORMATS:
        raise ClearsplatError(f"unknown format {format!r} (known: "
                              f"{', '.join(list(EXPORT_FORMATS) + list(MODEL_FORMATS))})",
                              field="format")
    fmt = replace(EXPORT_FORMATS[format], **{k: v for k, v in options.items() if v is not None})
    if align not in _ALIGN:
        raise ClearsplatError(f"must be one of {_ALIGN}, got {align!r}", field="align")
    if not 0 <= float(fmt.opacity_cut) < 1:       # also refuses NaN
        raise ClearsplatError(f"must lie in [0, 1), got {fmt.opacity_cut}", field="opacity_cut")
    if int(fmt.trim) < 0:
        raise ClearsplatError(f"must be >= 0, got {fmt.trim}", field="trim")
    if int(fmt.spp) < 1:
        raise ClearsplatError(f"must be >= 1, got {fmt.spp}", field="spp")
    return fmt


def _layout(path, format, fmt, g, cams, grid):
    """``view_id``, ``pixel_id`` and the per-view grid of a layout format's vertices."""
    n = len(g)
    v, h, w = len(cams), cams[0].height, cams[0].width
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
    return view_id, pixel_id, (gh, gw)


def _turned(path, fmt, g, means, s, a, ft, cams, view_id) -> Gaussians:
    """The Gaussians at ``means`` with scales times ``s``, rotations and SH bands to world."""
    from ..adapters._common import matrices_to_quats, quats_to_matrices
    n = len(g)
    scales = (g.scales.astype(np.float64) * s).astype(np.float32)
    rot = quats_to_matrices(g.quats) if n else np.zeros((0, 3, 3))
    if fmt.rotations == "camera":
        c2w = np.stack([c.camera_to_world[:3, :3] for c in cams])
        rot = c2w[view_id] @ (ft @ rot)
    else:
        rot = a @ rot
    quats = matrices_to_quats(rot).astype(np.float32) if n else g.quats
    sh = g.sh if fmt.sh_frame != "file" else _turned_sh(path, g.sh, a)
    return Gaussians(means=means.astype(np.float32), scales=scales, quats=quats,
                     opacities=g.opacities, sh=sh)


def _turned_sh(path, sh, a):
    """SH bands in the file's frame turned by ``A`` to the cameras' (the DC band stays)."""
    if sh.shape[1] == 1 or np.allclose(a, np.eye(3)):
        return sh
    from ..adapters.sh_rotation import rotate_sh
    try:
        return rotate_sh(sh, a)
    except ClearsplatError as e:
        raise ClearsplatError(
            f"the f_rest bands are in the export's frame and must turn to the cameras' "
            f"({e.reason}); export the DC band only, or give cameras in the export's frame",
            path=path, field="f_rest") from None


def _pixel_stats(means, cams, view_id, pixel_id) -> dict:
    """The report's measures of how the pixel-aligned vertices sit on their pixels."""
    h, w = cams[0].height, cams[0].width
    res = _residuals(means.astype(np.float64), cams, view_id, pixel_id)
    fin = res[np.isfinite(res).all(axis=1)]
    aligned_n = int((pixel_id >= 0).sum())
    inside = float((np.abs(fin) <= 0.5 + 1e-3).all(axis=1).sum() / aligned_n) if aligned_n \
        else 0.0
    dist = np.linalg.norm(fin, axis=1) if len(fin) else np.array([np.nan])
    near_px = max(1.0, NEAR_FRACTION * max(h, w))
    near = float((np.abs(res) <= near_px).all(axis=1).sum() / aligned_n) if aligned_n else 0.0
    return dict(inside_pixel=inside,
                median_px=float(np.median(dist)) if aligned_n else float("nan"),
                p99_px=float(np.percentile(dist, 99)) if aligned_n else float("nan"),
                near_pixel=near, near_px=near_px)


# ------------------------------------------------------------------------------------------------
# exports whose vertex order no longer gives the association
# ------------------------------------------------------------------------------------------------
def _import_model(path, format: str, cams, images, *, allow_misaligned: bool, progress=None):
    """A :data:`MODEL_FORMATS` export: its frame, the recovered association, the scene."""
    spec = MODEL_FORMATS[format]
    if spec.association == "refused":
        raise _refusal(path, format, spec)
    # Depth Anything 3 writes log(p / (1 - p)) unclamped: a saturated confidence is infinite.
    g, _, _ = read_export(path, opacity=spec.opacity, color="sh",
                          saturated_logits=format == "da3")
    if g.sh.shape[1] != spec.bands:
        raise ClearsplatError(f"{format}'s export writes {_bands(spec.bands)}, this file "
                              f"{_bands(g.sh.shape[1])}: it is not {format}'s export",
                              path=path, field="f_rest")
    if spec.half_pixel:
        cams = [_shift_principal_point(c, 0.5) for c in cams]
    min_seen = 0.0 if allow_misaligned else MIN_SEEN_SHARE
    if spec.frame == "da3":
        assoc, frame, notes = _da3_association(path, g.means, cams, min_seen)
        return _recovered(path, format, _similar(path, g, frame), assoc, cams, images, frame,
                          notes, aligned="scale-shift")
    frame = longlrm_frame(cams) if spec.frame == "longlrm" else _identity()
    moved = _similar(path, g, frame)
    if spec.association == "voxels-or-ordered" and _voxel_sorted(g.means):
        return _import_fused(path, format, moved, cams, images,
                             allow_misaligned=allow_misaligned, frame=frame, progress=progress,
                             notes=["vertices in voxel order (voxel-merged): each voxel's view "
                                    "recovered from the images"])
    if spec.association == "ranked-or-ordered" and _opacity_ranked(g.opacities):
        order = "ranked by opacity (pruned)"
    else:
        assoc = _ordered(path, format, spec, moved.means, cams, min_seen,
                         fallback=spec.association == "voxels-or-ordered")
        if assoc is not None:
            return _recovered(path, format, moved, assoc, cams, images, frame,
                              ["vertices in pixel order, view after view: each one's view and "
                               "pixel recovered from where its centre projects"])
        order = "in neither voxel nor pixel order (subsampled)"
    assoc = _centred(frame.apply(g.means), cams)
    if assoc is not None:
        return _recovered(path, format, moved, assoc, cams, images, frame,
                          [f"vertices {order}: each one's view and pixel recovered from the "
                           "camera that puts its centre on a pixel centre"])
    return _import_fused(path, format, moved, cams, images, allow_misaligned=allow_misaligned,
                         notes=[f"vertices {order}, centres not on pixel centres (computed at a "
                                "lower precision, or other cameras): each Gaussian's view "
                                "recovered from the images"], frame=frame,
                         progress=progress)


def _bands(k: int) -> str:
    return "the DC band only" if k == 1 else f"{k} SH coefficients per channel"


def _identity():
    from ..adapters.associate import Similarity
    return Similarity.identity()


def _refusal(path, format: str, spec) -> ClearsplatError:
    """Why VolSplat's export cannot be imported, naming the file and the field at fault."""
    g, _, _ = read_export(path, opacity=spec.opacity, color="sh")
    constant = bool(len(g)) and np.allclose(g.scales, 0.01, rtol=1e-4)
    found = f"all {len(g):,} of this file's are" if constant else \
        "this file's are not, so it may not be its export either"
    return ClearsplatError(
        f"{format}'s save_gaussian_ply writes every scale as 0.01 ({found}) and pads or "
        "truncates the voxels to views x height x width Gaussians, so renders of the file are "
        "not the model's and its vertex order names no view: filtering it would judge "
        "Gaussians the model did not predict; take the encoder's Gaussians in the model "
        "instead (means, covariances through clearsplat.adapters.covariance_to_scales_quats, "
        "harmonics, opacities) and clearsplat.adapters.associate.associate_fused(gaussians, "
        "cameras, images).to_scene(gaussians, cameras, images)", path=path, field="scale_0")


def _da3_association(path, means, cams, min_seen):
    """Depth Anything 3's frame and association.

    With given poses its export is in its normalised frame of them
    (:func:`clearsplat.adapters.associate.normalised_frame`), rescaled by the model only
    approximately (an Umeyama scale, clamped to [1/3, 3]); without, in the frame of its own
    predicted cameras (the cameras to give). Both are tried, and the scale and shift fitted
    (:func:`_da3_fit`); of those whose fit puts at least :data:`MIN_NEAR_SHARE` of the pinned
    vertices near their pixel, the one whose pinned vertices lie nearest their pixels' centres
    (median) is kept, the cameras' frame on a tie: a model frame close to the normalised one
    also fits it, a little off. Where neither fits, the normalised frame rescaled by
    :data:`DA3_SCALES` is tried, the first that fits kept (with ``min_seen = 0``,
    ``allow_misaligned``: the best).
    """
    from ..adapters.associate import Similarity, associate_ordered, normalised_frame
    norm = normalised_frame(cams)
    tries = [("the cameras' frame", Similarity.identity()),
             ("DA3's normalised frame of the cameras' poses", norm)]
    tries += [(f"DA3's normalised frame of the cameras' poses, rescaled by {k:.3g}",
               Similarity(norm.scale * k, norm.rotation, norm.translation)) for k in DA3_SCALES]
    means = np.asarray(means, dtype=np.float64)
    best = None
    for k, (name, init) in enumerate(tries):
        fitted = _da3_fit(means, cams, init)
        if fitted is not None and (best is None or _da3_better(fitted, best[1:])):
            best = (name, *fitted)
        if k >= 1 and best is not None and best[2] >= MIN_NEAR_SHARE:
            break
    if best is None or (best[2] < MIN_NEAR_SHARE and min_seen > 0):
        share = 0.0 if best is None else best[2]
        raise ClearsplatError(
            f"the vertices fit neither the cameras' frame nor DA3's normalised frame of their "
            f"poses: {100 * share:.1f} % of the vertices whose pixel the order pins project "
            f"near it (at least {100 * MIN_NEAR_SHARE:.0f} % needed); the cameras (their order, "
            "--views), the image size or the format do not match the export; "
            "allow_misaligned=True (--allow-misaligned) keeps it", path=path, field="cameras")
    name, frame, share, _ = best
    try:
        assoc = associate_ordered(frame.apply(means), cams, min_seen=min_seen)
    except ClearsplatError as e:
        raise ClearsplatError(e.reason, path=path, field=e.field) from None
    return assoc, frame, [f"frame: {name}; scale and shift fitted to the rays of the "
                          f"pixels the order pins ({100 * share:.1f} % near them)"]


def _da3_fit(means, cams, init):
    """Scale and shift of a DA3 frame (``s A x + b``, ``A`` the rotation of ``init``) fitted to
    the pixel rays of the vertices whose pixel the order pins (:func:`_da3_pinned`), three
    times, re-associating in between. Returns ``(frame, share of those vertices near their
    pixel, their median distance from their pixel's centre in px)``, or None when too few are
    pinned."""
    from ..adapters.associate import Similarity, associate_ordered
    frame = init
    for _ in range(3):
        pts = frame.apply(means)
        assoc = associate_ordered(pts, cams, min_seen=0.0)
        pinned = _da3_pinned(pts, cams, assoc.view_id)
        use = pinned >= 0
        if use.sum() < 2 * cams[0].width:
            return None
        o, d = _pixel_rays(cams, assoc.view_id[use], pinned[use])
        try:
            s, b = _fit(means[use] @ frame.rotation.T, frame.translation, o, d, "scale-shift")
        except ClearsplatError:
            return None
        frame = Similarity(s, frame.rotation, b)
    res = _residuals(frame.apply(means[use]), cams, assoc.view_id[use], pinned[use])
    near = max(1.0, NEAR_FRACTION * max(cams[0].height, cams[0].width))
    return (frame, float((np.abs(res) <= near).all(axis=1).mean()),
            float(np.median(np.linalg.norm(res, axis=1))))


def _da3_better(fitted: tuple, best: tuple) -> bool:
    """Whether a fit ``(frame, share, median)`` beats ``best``: the first to reach
    :data:`MIN_NEAR_SHARE`, then the lower median distance, else the higher share."""
    fits, best_fits = fitted[1] >= MIN_NEAR_SHARE, best[1] >= MIN_NEAR_SHARE
    if fits != best_fits:
        return fits
    return fitted[2] < best[2] if fits else fitted[1] > best[1]


def _da3_pinned(pts, cams, view_id) -> np.ndarray:
    """(N,) pixel of each vertex that DA3's order pins, else -1.

    Within a view's run the kept pixels follow in row-major order between the border trims
    (``int(8/256 H)`` rows, ``int(8/256 W)`` columns); the depth cut leaves gaps. A row that
    kept every pixel between the trims (as many vertices as the trimmed width, its first and
    last near the trims' columns) pins its vertices' columns exactly; its row is counted up
    from the last row above the bottom trim (the ground is rarely cut), a gap of rows showing
    as a jump in the projected rows. Rows are told apart where the projected column falls back
    by more than :data:`DA3_ROW_TOLERANCE` px.
    """
    tol = DA3_ROW_TOLERANCE
    out = np.full(len(pts), -1, dtype=np.int64)
    for v, cam in enumerate(cams):
        idx = np.flatnonzero(view_id == v)
        h, w = cam.height, cam.width
        th, tw = int(8 / 256 * h), int(8 / 256 * w)
        if len(idx) < 2 or not th or not tw:
            continue
        uv, z = cam.project(pts[idx])
        uv[~(z > 0)] = -1e6                  # behind the camera: its segment pins nothing
        segs = np.split(np.arange(len(idx)), np.flatnonzero(np.diff(uv[:, 0]) < -tol) + 1)
        approx = np.array([np.median(uv[s, 1]) for s in segs])
        jumps = np.maximum(1, np.round(np.diff(approx)).astype(np.int64))
        rows = h - th - 1 - np.concatenate([np.cumsum(jumps[::-1])[::-1], [0]])
        for seg, r in zip(segs, rows):
            u = uv[seg]
            if len(seg) == w - 2 * tw and r >= th and abs(u[0, 0] - tw - 0.5) <= tol and \
                    abs(u[-1, 0] - (w - tw - 0.5)) <= tol and np.ptp(u[:, 1]) <= tol:
                out[idx[seg]] = r * w + tw + np.arange(w - 2 * tw)
    return out


def longlrm_frame(cameras):
    """Long-LRM's normalisation of its input cameras, as the map back to them.

    ``data/dataset.py`` (``__getitem__``) turns the cameras by ``pos_avg^-1``, with ``pos_avg``
    = [right, down, forward, mean centre] from the mean camera axes (Gram-Schmidt), and
    divides their translations by the largest absolute coordinate of the turned centres; the
    Gaussians are predicted in that frame. Computed from the cameras given (the same either
    way when they are already normalised).

    Returns
    -------
    clearsplat.adapters.associate.Similarity
        ``x_world = m R x + p``.
    """
    from ..adapters.associate import Similarity
    c2w = np.stack([c.camera_to_world for c in cameras])
    pos = c2w[:, :3, 3].mean(0)
    fwd = c2w[:, :3, 2].mean(0)
    down = c2w[:, :3, 1].mean(0)
    fwd = fwd / np.linalg.norm(fwd)
    down = down - down.dot(fwd) * fwd
    down = down / np.linalg.norm(down)
    rot = np.stack([np.cross(down, fwd), down, fwd], axis=1)
    m = float(np.abs((c2w[:, :3, 3] - pos) @ rot).max())
    if not (m > 0 and np.isfinite(rot).all()):
        raise ClearsplatError("the cameras share one centre or cancel out each other's axes: "
                              "Long-LRM's normalisation is undefined", field="cameras")
    return Similarity(m, rot, pos)


def _similar(path, g, frame) -> Gaussians:
    """The Gaussians mapped by a similarity (centres, scales, rotations, SH bands)."""
    from ..adapters._common import matrices_to_quats, quats_to_matrices
    rot = np.asarray(frame.rotation, dtype=np.float64)
    if frame.scale == 1.0 and np.array_equal(rot, np.eye(3)) and not np.any(frame.translation):
        return Gaussians(means=g.means, scales=g.scales, quats=g.quats, opacities=g.opacities,
                         sh=g.sh)
    quats = matrices_to_quats(rot @ quats_to_matrices(g.quats)).astype(np.float32) \
        if len(g) else g.quats
    return Gaussians(means=frame.apply(g.means).astype(np.float32),
                     scales=(g.scales.astype(np.float64) * frame.scale).astype(np.float32),
                     quats=quats, opacities=g.opacities, sh=_turned_sh(path, g.sh, rot))


def _voxel_sorted(means) -> bool:
    """Whether the centres (in the file's frame) are sorted by a voxel key, ``x`` major, as
    WorldMirror's voxel merge writes them (``torch.unique`` of ``floor(p / 0.002)``,
    flattened): ``x`` then never falls back by more than a voxel. Told by the 99th percentile
    of the fall-back below the running maximum, within :data:`VOXEL_ORDER_SHARE` of the
    ``x`` extent (whatever the voxel size); in pixel order ``x`` falls back a whole image
    width at every row."""
    x = np.asarray(means, dtype=np.float64)[:, 0]
    if len(x) < 2 or not np.ptp(x) > 0:
        return False
    back = np.maximum.accumulate(x) - x
    return bool(np.quantile(back, 0.99) <= VOXEL_ORDER_SHARE * np.ptp(x))


def _opacity_ranked(opacities) -> bool:
    """Whether the vertices start with a run of non-increasing opacity over half the file:
    Long-LRM's pruning writes the most opaque first, ranked (``argsort`` descending), and its
    random picks after them; a per-pixel order is not ranked."""
    op = np.asarray(opacities)
    if len(op) < 2:
        return False
    rise = np.flatnonzero(np.diff(op) > 0)
    run = rise[0] + 1 if len(rise) else len(op)
    return bool(run >= 0.5 * len(op))


def _ordered(path, format, spec, means, cams, min_seen, *, fallback: bool):
    """:func:`clearsplat.adapters.associate.associate_ordered`, checked: the cameras must see
    at least ``min_seen`` of the vertices and, for a ``centred`` export, put at least
    :data:`MIN_NEAR_SHARE` of them within :data:`CENTRE_PX` of their pixel's centre (both
    unless ``min_seen`` is 0). With ``fallback``, None instead of a refusal, and also when more
    than :data:`MAX_ORDER_AMBIGUOUS` of the vertices break the order (no per-pixel order)."""
    from ..adapters.associate import associate_ordered
    try:
        assoc = associate_ordered(means, cams, min_seen=min_seen)
    except ClearsplatError as e:
        if fallback:
            return None
        raise ClearsplatError(f"{e.reason}; or the file is not {format}'s export", path=path,
                              field=e.field) from None
    if fallback and len(assoc) and assoc.ambiguous.mean() > MAX_ORDER_AMBIGUOUS:
        return None
    has = assoc.pixel_id >= 0
    if spec.centred and min_seen > 0 and has.any():
        res = _residuals(means[has], cams, assoc.view_id[has], assoc.pixel_id[has])
        share = float((np.abs(res) <= CENTRE_PX).all(axis=1).mean())
        if share < MIN_NEAR_SHARE:
            if fallback:
                return None
            raise ClearsplatError(
                f"only {100 * share:.1f} % of the vertices project within {CENTRE_PX:g} px of "
                f"their pixel's centre, where {format} places them (at least "
                f"{100 * MIN_NEAR_SHARE:.0f} % needed): the cameras (their order, size, poses) "
                f"do not fit the export, or the file is not {format}'s export; "
                "allow_misaligned=True (--allow-misaligned) keeps it", path=path, field="cameras")
    return assoc


def _centred(means, cams):
    """:func:`clearsplat.adapters.associate.associate_centred` of the centres in the cameras'
    frame (float64, as mapped from the file), or None where fewer than
    :data:`MIN_CENTRED_SHARE` of them get a view unambiguously: the centres are not on their
    pixels' centres to float32 round-off (a model run at a lower precision: Long-LRM under
    its configs' bfloat16 autocast) or the cameras do not fit."""
    from ..adapters.associate import associate_centred
    try:
        assoc = associate_centred(means, cams, min_seen=0.0)
    except ClearsplatError:
        return None
    if len(assoc) and 1.0 - float(assoc.ambiguous.mean()) < MIN_CENTRED_SHARE:
        return None
    return assoc


def _import_fused(path, format, g, cams, images, *, allow_misaligned, notes, frame=None,
                  progress=None):
    """Gaussians that mix views or carry no order: each one's view from the images."""
    from ..adapters.associate import associate_fused
    if images is None:
        raise ClearsplatError(f"{format}: the input images are needed (each Gaussian's view "
                              "is recovered from how it reproduces them)", path=path,
                              field="images")
    settings = _render_settings(format)
    assoc = associate_fused(g, cams, images, settings=settings, progress=progress)
    seen = 1.0 - float(assoc.ambiguous.mean()) if len(assoc) else 1.0
    if seen < MIN_SEEN_SHARE and not allow_misaligned:
        raise ClearsplatError(
            f"only {100 * seen:.1f} % of the Gaussians are seen by an input view with a colour "
            f"that agrees with its image (at least {100 * MIN_SEEN_SHARE:.0f} % needed): the "
            f"cameras or images do not fit the export (frame, order, size), or the file is not "
            f"{format}'s export; allow_misaligned=True (--allow-misaligned) keeps it",
            path=path, field="cameras")
    return _recovered(path, format, g, assoc, cams, images, frame or _identity(), notes)


def _recovered(path, format, g, assoc, cams, images, frame, notes, *, aligned="none"):
    """The scene and report of an import whose association was recovered."""
    scene = Scene(g, view_id=assoc.view_id, pixel_id=assoc.pixel_id, cameras=cams,
                  images=images, render_settings=_render_settings(format))
    scene.validate(path=path)
    report = ImportReport(
        format=format, num_vertices=len(g), scale=float(frame.scale),
        shift=[float(x) for x in frame.translation], aligned=aligned,
        grid=(cams[0].height, cams[0].width), notes=list(notes),
        association=assoc.summary(), ambiguous=int(np.count_nonzero(assoc.ambiguous)),
        **_pixel_stats(g.means, cams, assoc.view_id, assoc.pixel_id))
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
    """The cameras as a list (checked as the association checks them), all of one size."""
    from ..adapters.associate import _checked_cameras as checked
    cams = checked(cameras)
    for i, c in enumerate(cams):
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
        A ``cameras.json`` / nerfstudio ``transforms.json`` (or a folder holding one), a
        COLMAP model folder (``cameras.bin``/``images.bin`` or ``.txt``, or a dataset folder
        with ``sparse/0``), or WorldMirror's ``camera_params.json`` (or a folder holding it;
        :func:`read_camera_params`: no image size or names, so each camera takes the size of
        its image, and the images are matched by sorted order).
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
        images, a size that is not a uniform scaling (a crop: write the cropped cameras),
        WorldMirror intrinsics whose principal point is not the centre of their image.
    """
    from pathlib import Path

    from .images import read_image

    cpath = Path(cameras_path)
    cams, names = _view_cameras(cpath)
    if views is not None:
        picked = [_view_index(item, names, len(cams), cpath) for item in views]
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
    for cam, name in zip(cams, chosen):
        img = read_image(folder / name)
        images.append(img)
        out.append(_sized(cam, img.shape[:2], folder / name))
    return out, images, chosen


def _view_cameras(cpath):
    """The cameras of a camera file or folder and their image names (None where unknown);
    WorldMirror's come as ``(K, camera_to_world)`` pairs, sized by their images later."""
    from pathlib import Path

    from .bundle import CAMERAS_FILE, TRANSFORMS_FILE, load_cameras
    from .colmap import read_colmap

    ours = cpath.is_dir() and any((cpath / f).is_file() for f in (CAMERAS_FILE, TRANSFORMS_FILE))
    params = cpath / CAMERA_PARAMS_FILE if cpath.is_dir() else cpath
    if not ours and params.is_file() and _is_camera_params(params):
        ks, c2w = read_camera_params(params)
        return list(zip(ks, c2w)), [None] * len(ks)
    if cpath.is_dir() and not ours:
        cams, names = read_colmap(cpath)
    else:
        cams, paths = load_cameras(cpath)
        names = [None if p is None else Path(p).name for p in paths]
    return cams, [None if n is None else Path(n).name for n in names]


def _view_index(item, names, count, cpath) -> int:
    """A ``--views`` entry (an index or an image name) as a camera index."""
    key = str(item).strip()
    if key.lstrip("-").isdigit():
        i = int(key)
        if not 0 <= i < count:
            raise ClearsplatError(f"view {i} out of range 0..{count - 1}", path=cpath,
                                  field="--views")
        return i
    if key in names:
        return names.index(key)
    raise ClearsplatError(f"no camera for image {key!r}", path=cpath, field="--views")


def _sized(cam, size, image_path) -> Camera:
    """The camera at its image's size: scaled by one exact factor; a WorldMirror camera
    (``(K, c2w)``) takes the size, its principal point being the image centre (within a
    pixel either way)."""
    h, w = size
    if not isinstance(cam, Camera):
        k, c2w = cam
        if abs(2 * k[0, 2] - w) > 2 or abs(2 * k[1, 2] - h) > 2:
            raise ClearsplatError(
                f"the camera's principal point ({k[0, 2]:.6g}, {k[1, 2]:.6g}) is not the centre "
                f"of its {w}x{h} image: WorldMirror's intrinsics are at the resolution it "
                "processed; pass the images it saw at that size", path=image_path,
                field="size")
        return Camera(K=k, camera_to_world=c2w, width=w, height=h)
    if (h, w) == (cam.height, cam.width):
        return cam
    f = w / cam.width
    if abs(h - cam.height * f) > 1e-9 * h or round(cam.width * f) != w:
        raise ClearsplatError(
            f"image is {w}x{h}, its camera {cam.width}x{cam.height}: not a uniform "
            "scaling (a crop, such as DepthSplat's centre crop, changes the principal "
            "point; write the cameras of the cropped images)", path=image_path, field="size")
    return cam.scaled(f)


#: The camera file WorldMirror writes (``save_camera_params``).
CAMERA_PARAMS_FILE = "camera_params.json"


def _is_camera_params(path) -> bool:
    """Whether a JSON file has WorldMirror's ``camera_params.json`` layout."""
    from .bundle import _read_json
    if path.suffix.lower() != ".json":
        return False
    doc = _read_json(path)
    return isinstance(doc, dict) and "frames" not in doc and \
        isinstance(doc.get("extrinsics"), list) and isinstance(doc.get("intrinsics"), list)


def read_camera_params(path):
    """WorldMirror's ``camera_params.json`` (``save_camera_params`` in
    ``src/utils/save_utils.py`` of HunyuanWorld-Mirror and HY-World-2.0).

    ``{"num_cameras": N, "extrinsics": [{"camera_id": i, "matrix": 4x4}], "intrinsics":
    [{"camera_id": i, "matrix": 3x3}]}``, where the "extrinsics" are the predicted
    ``camera_poses``: OpenCV **camera-to-world**; intrinsics in pixels at the resolution the
    model processed (principal point at its centre). Cameras are ordered by ``camera_id``.

    Returns
    -------
    intrinsics : (N, 3, 3) float64
    camera_to_world : (N, 4, 4) float64

    Raises
    ------
    ClearsplatError
        Naming the file and the entry: missing keys, ids that are not 0..N-1 in both lists, a
        matrix of the wrong shape or with non-finite values.
    """
    from .bundle import _read_json
    doc = _read_json(path)
    out = []
    for key, shape in (("extrinsics", (4, 4)), ("intrinsics", (3, 3))):
        entries = doc.get(key) if isinstance(doc, dict) else None
        if not isinstance(entries, list) or not entries:
            raise ClearsplatError("expected a non-empty list", path=path, field=key)
        mats = {}
        for i, e in enumerate(entries):
            try:
                cid, m = int(e["camera_id"]), np.asarray(e["matrix"], dtype=np.float64)
            except (TypeError, KeyError, ValueError):
                raise ClearsplatError("expected {'camera_id': int, 'matrix': [[...]]}",
                                      path=path, field=f"{key}[{i}]") from None
            if m.shape != shape or not np.isfinite(m).all():
                raise ClearsplatError(f"expected a finite {shape[0]}x{shape[1]} matrix, got "
                                      f"shape {m.shape}", path=path, field=f"{key}[{i}]")
            mats[cid] = m
        if sorted(mats) != list(range(len(entries))):
            raise ClearsplatError(f"camera ids must be 0..{len(entries) - 1}, got "
                                  f"{sorted(mats)}", path=path, field=key)
        out.append(np.stack([mats[i] for i in range(len(entries))]))
    if len(out[0]) != len(out[1]):
        raise ClearsplatError(f"{len(out[0])} extrinsics and {len(out[1])} intrinsics",
                              path=path, field="intrinsics")
    return out[1], out[0]
