"""The view association of an export, recovered from geometry and the input images.

The filter needs each Gaussian's input view (``Scene.view_id``) and, for pixel-aligned
models, its pixel (``Scene.pixel_id``). When an export's vertex order no longer says which
view and pixel made each Gaussian, this module recovers them:

- :func:`associate_ordered`: per-pixel exports written view after view in the model's
  ``(view, row, col)`` order with an unknown number of vertices of each view cut (border
  trims, per-view depth-percentile cuts, masks, opacity cuts) and centres moved off their
  pixel's ray by sub-pixel offsets (Depth Anything 3's ``gs_ply``). The vertex sequence is cut
  into one run per view by a dynamic programme over the run boundaries; each vertex's pixel is
  the pixel its centre projects to in its view's camera.
- :func:`associate_centred`: per-pixel exports in no useful order (a pruned or subsampled
  file) whose centres lie on the ray through their pixel's centre (Long-LRM, WorldMirror):
  projected into its own camera a centre lands on a pixel centre, to float32 round-off, and
  into any other camera at a sub-pixel position that is near a centre only by chance. Each
  vertex goes to the camera that puts it nearest a pixel centre, and to that pixel.
- :func:`associate_fused`: Gaussians that mix pixels of several views (AnySplat's and
  WorldMirror's voxel fusion) or come from any trainer, in no useful order. From renders of
  every input camera: a Gaussian whose colour agrees with one view's image only (a transient)
  goes to that view; one that several views, most of those that see it, see agreeing (static
  content) is shared by them (``view_id = -1``); ``pixel_id = -1``, but a voxel of one pixel,
  its centre on that pixel's centre, takes that view and pixel.
- :func:`normalised_frame`: the frame Depth Anything 3 writes its Gaussians in when it is
  given poses (camera 0 the identity, median camera distance 1), as the similarity back to the
  cameras' frame.

Every function takes NumPy arrays, returns an :class:`Association` and reports bad input as
:class:`~clearsplat.errors.ClearsplatError` naming the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..render import prepare
from ..scene import SHARED, Gaussians, RenderSettings, Scene, sh_dc_to_rgb

__all__ = ["Association", "Similarity", "associate_centred", "associate_fused",
           "associate_ordered", "normalised_frame", "CENTRE_TOLERANCE", "CENTRE_RATIO",
           "COLOUR_SIGMA", "AGREE_RATIO", "SEEN_WEIGHT", "HIDDEN_DEPTH"]

#: Pixels a vertex's projection may lie off its pixel's centre, per axis, by default. Depth
#: Anything 3 moves centres by a predicted xy offset (unbounded in its code, sub-pixel in what
#: a trained head predicts; the tests use up to half a pixel); one pixel leaves room for
#: cameras that differ a little from the ones the model placed its Gaussians with (its own
#: predicted poses, a model frame undone only approximately).
MAX_OFFSET = 1.0
#: Cost of a break in row-major order inside one view's run (a step back by more than the
#: offsets can explain: two rows at the default ``MAX_OFFSET``), in units of the cost of one
#: vertex outside its view's image.
ORDER_WEIGHT = 2.0
#: Cost of a stall inside one view's run (the same pixel as the previous vertex, or a little
#: back), counted only with ``max_offset <= 0.5``: weak evidence, which tells apart cameras
#: that see a view's pixels without either of the costs above (a camera behind the view's own
#: sees them packed closer), but which a camera slightly off the model's also shows.
STALL_WEIGHT = 0.1
#: Step codes of :func:`_order_steps`.
STALL, BREAK = 1, 2
#: Pixels, per axis, within which :func:`associate_centred` takes a vertex's projection to lie
#: on a pixel centre. A centre the model put on its pixel's ray in float32 projects into its
#: own camera within round-off of that pixel's centre: measured at most 3e-4 px for Long-LRM's
#: computation at 960 x 540 (distances 0.3 to 5 in its normalised frame, cameras in a world
#: frame 130 units away) and 1.4e-3 px for WorldMirror's at 952 x 714 with points 70 times
#: nearer their camera than the camera is to the frame's origin; 1.4e-5 px on the 160 x 96
#: test worlds. Any other camera puts it this near a centre by chance, ``(2 tolerance)^2`` per
#: camera (0.16 %; 1.6 % for the neighbours in a video, whose shifts are small). Centres
#: computed at a lower precision miss it (Long-LRM under bfloat16 autocast: 0.9 px median).
CENTRE_TOLERANCE = 0.02
#: :func:`associate_centred` tells two cameras apart when the second one puts the vertex more
#: than this factor farther from a pixel centre than the first, and farther than
#: ``CENTRE_TOLERANCE / CENTRE_RATIO``.
CENTRE_RATIO = 10.0
#: :func:`associate_fused`: the colour difference (RGB in [0, 1], RMS over the channels) at
#: which a Gaussian's agreement with a view's image falls to ``exp(-1/2)``: a few levels of an
#: 8-bit image, so that a colour agrees where the image shows it and not where it shows
#: another surface.
COLOUR_SIGMA = 0.03
#: :func:`associate_fused`: a view sees a Gaussian agreeing when the share of its weight that
#: agrees is at least this share of the best view's.
AGREE_RATIO = 0.7
#: :func:`associate_fused`: the least blending weight, summed over a view's pixels, of a
#: Gaussian that view sees (the filter's rasterizer association takes 0.05 at one pixel).
SEEN_WEIGHT = 0.05
#: :func:`associate_fused`: in a view's blending weights, a Gaussian is hidden only by those in
#: front of it by more than this share of its depth: its own surface, a fusion's few
#: Gaussians deep, does not hide it (the filter's ``verify_hidden`` margin).
HIDDEN_DEPTH = 0.05


@dataclass(frozen=True, eq=False)
class Association:
    """Each Gaussian's input view and pixel, as recovered.

    Attributes
    ----------
    view_id : (N,) int64
        Input view of each Gaussian, in ``[0, V)``, or -1 (:data:`~clearsplat.scene.SHARED`)
        for static content several views see alike (:func:`associate_fused`).
    pixel_id : (N,) int64
        ``row * width + col`` in that view's image, or -1 where there is none (fused
        Gaussians, but for a voxel of one pixel; a vertex that does not project into its
        view's image).
    ambiguous : (N,) bool
        No view is clearly right: for :func:`associate_ordered` the vertex lies outside its
        view's image or breaks its run's row-major order; for :func:`associate_centred` no
        camera puts it on a pixel centre, or two do alike; for :func:`associate_fused` no view
        sees it with an agreeing colour (hidden everywhere, or a colour no image shows).
    source : str
        ``"geometry"`` or ``"images"``: what the association was recovered from.
    """

    view_id: np.ndarray
    pixel_id: np.ndarray
    ambiguous: np.ndarray
    source: str = "geometry"

    def __len__(self) -> int:
        return len(self.view_id)

    def summary(self) -> str:
        """One line: ``associated 123,456 Gaussians from geometry: 120,001 got a view, 3,455
        ambiguous`` (and, where there are any, ``..., 60,000 shared by several views``; from
        the images, ``120,001 got a view (50,000 with their pixel)``)."""
        n, amb = len(self), int(np.count_nonzero(self.ambiguous))
        shared = int(np.count_nonzero(self.view_id == SHARED))
        pixels = int(np.count_nonzero(self.pixel_id >= 0)) if self.source == "images" else 0
        return (f"associated {n:,} Gaussians from {self.source}: {n - amb - shared:,} got a "
                "view" + (f" ({pixels:,} with their pixel)" if pixels else "") + ", "
                + (f"{shared:,} shared by several views, " if shared else "")
                + f"{amb:,} ambiguous")

    def to_scene(self, gaussians: Gaussians, cameras, images=None, *,
                 render_settings: RenderSettings | None = None) -> Scene:
        """A validated :class:`~clearsplat.Scene` of ``gaussians`` with this association."""
        if len(gaussians) != len(self):
            raise ClearsplatError(f"{len(gaussians)} Gaussians for an association of "
                                  f"{len(self)}", field="gaussians")
        scene = Scene(gaussians, view_id=self.view_id, pixel_id=self.pixel_id,
                      cameras=list(cameras), images=images,
                      render_settings=render_settings or RenderSettings())
        scene.validate()
        return scene


class Similarity(NamedTuple):
    """``x -> scale * rotation @ x + translation``: a model frame to the cameras' frame.

    Attributes
    ----------
    scale : float
    rotation : (3, 3) float64
    translation : (3,) float64
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points) -> np.ndarray:
        """Points (M, 3) mapped to the cameras' frame, (M, 3) float64."""
        p = np.asarray(points, dtype=np.float64)
        return self.scale * p @ self.rotation.T + self.translation

    @classmethod
    def identity(cls) -> Similarity:
        return cls(1.0, np.eye(3), np.zeros(3))


# ------------------------------------------------------------------------------------------------
# input checks
# ------------------------------------------------------------------------------------------------
def _checked_means(means, field: str = "means") -> np.ndarray:
    """(N, 3) float64, finite."""
    try:
        m = np.asarray(means, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ClearsplatError(f"cannot read as numbers ({e})", field=field) from None
    if m.ndim != 2 or m.shape[1] != 3:
        raise ClearsplatError(f"expected shape (N, 3), got {m.shape}", field=field)
    bad = ~np.isfinite(m).all(axis=1)
    if bad.any():
        raise ClearsplatError(f"non-finite centre (first at vertex {int(np.argmax(bad))})",
                              field=field)
    return m


def _number(name: str, value) -> float:
    """``value`` as a float, or one line naming the option where it is none."""
    if isinstance(value, (bool, np.bool_)):
        raise ClearsplatError(f"expected a number, got {value!r}", field=name)
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ClearsplatError(f"expected a number, got {value!r}", field=name) from None


def _checked_share(min_seen) -> float:
    """``min_seen`` as a float in [0, 1], else one line naming it."""
    value = _number("min_seen", min_seen)
    if not 0 <= value <= 1:
        raise ClearsplatError(f"expected a share in [0, 1], got {value!r}", field="min_seen")
    return value


def _checked_cameras(cameras) -> list:
    cameras = list(cameras)
    if not cameras:
        raise ClearsplatError("no cameras", field="cameras")
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise ClearsplatError(f"expected a Camera, got {type(cam).__name__}",
                                  field=f"cameras[{i}]")
    return cameras


def _checked_views(views, num_cameras: int) -> np.ndarray:
    """The camera indices that may appear, in file order: (S,) int64."""
    if views is None:
        return np.arange(num_cameras, dtype=np.int64)
    v = np.asarray(list(views))
    if v.ndim != 1 or len(v) == 0 or v.dtype.kind not in "iu":
        raise ClearsplatError("expected a non-empty sequence of camera indices", field="views")
    v = v.astype(np.int64)
    if v.min() < 0 or v.max() >= num_cameras or len(np.unique(v)) != len(v):
        raise ClearsplatError(f"expected distinct camera indices in 0..{num_cameras - 1}, got "
                              f"{v.tolist()}", field="views")
    return v


def _checked_images(images, cameras) -> list:
    if images is None:
        raise ClearsplatError("the input images are needed", field="images")
    images = list(images)
    if len(images) != len(cameras):
        raise ClearsplatError(f"{len(images)} images for {len(cameras)} cameras",
                              field="images")
    out = []
    for i, (im, cam) in enumerate(zip(images, cameras)):
        a = np.asarray(im, dtype=np.float32)
        if a.shape != (cam.height, cam.width, 3):
            raise ClearsplatError(f"image {i} has shape {a.shape}, its camera expects "
                                  f"{(cam.height, cam.width, 3)}", field=f"images[{i}]")
        if not np.isfinite(a).all():
            raise ClearsplatError(f"image {i} has non-finite values", field=f"images[{i}]")
        out.append(a)
    return out


# ------------------------------------------------------------------------------------------------
# ordered exports
# ------------------------------------------------------------------------------------------------
def _projection(cam: Camera, means: np.ndarray, max_offset: float):
    """Pixel row, col (M,) int64 of each centre and whether it lies in front and inside the
    image (within ``max_offset - 0.5`` px of its border; such pixels are clipped in)."""
    uv, z = cam.project(means)
    tol = max(0.0, max_offset - 0.5)
    ok = z > 0
    x = np.where(ok, uv[:, 0], -np.inf)
    y = np.where(ok, uv[:, 1], -np.inf)
    ok &= (x >= -tol) & (x < cam.width + tol) & (y >= -tol) & (y < cam.height + tol)
    col = np.clip(np.floor(np.where(ok, x, 0.0)), 0, cam.width - 1).astype(np.int64)
    row = np.clip(np.floor(np.where(ok, y, 0.0)), 0, cam.height - 1).astype(np.int64)
    return row, col, ok


def _order_steps(row: np.ndarray, col: np.ndarray, ok: np.ndarray, width: int,
                 max_offset: float) -> np.ndarray:
    """(M,) uint8: how vertex ``n`` follows vertex ``n - 1`` in row-major order in one camera
    (both inside its image; vertex 0 always 0).

    0 forward; :data:`STALL` on the same pixel or back by up to a row (a run of one view never
    does this in its own camera with offsets below half a pixel: it shows a camera that sees
    the view's pixels closer together than its own does; not counted for larger offsets,
    which can reorder neighbours); :data:`BREAK` back by more than a row and more than
    ``max_offset`` offsets can explain (a new view starting over at the top of its image).
    """
    # A centre offset by less than m px from its pixel centre floors to a pixel that differs
    # from its own by -ceil(m - 1/2) .. ceil(m + 1/2) - 1 per axis, d values apart; consecutive
    # pixels of a row-major run step forward by at least 1. Stalls are told apart only where
    # d = 0 (m <= 1/2); a break always needs more than a row back.
    d = int(np.ceil(max_offset - 0.5) + np.ceil(max_offset + 0.5) - 1)
    step = np.diff(row * width + col)
    both = ok[1:] & ok[:-1]
    out = np.zeros(len(row), dtype=np.uint8)
    out[1:] = np.where(both & (step < 1 - d * (width + 1)), STALL, 0)
    out[1:][both & (step < 1 - max(d, 1) * (width + 1))] = BREAK
    return out


def _segment(outside: np.ndarray, steps: np.ndarray, weights) -> tuple[np.ndarray, float]:
    """Cut a sequence into consecutive runs, one per camera in order, at the least cost.

    Vertex ``n`` in the run of camera ``s`` costs ``outside[s, n] + weights[steps[s, n]]``,
    except that the step cost of a run's first vertex is free (a new view starts over at the
    top of its image). Runs may be empty. A dynamic programme over the run ends with prefix
    sums and running minima: O(S N) time, (S, N + 1) indices kept for the way back.

    Parameters
    ----------
    outside : (S, N) bool or float
        Cost of each vertex in each camera's run.
    steps : (S, N) int
        Step code of each vertex in each camera (indices into ``weights``).
    weights : (K,) array_like of float, >= 0
        Cost of each step code.

    Returns
    -------
    bounds : (S + 1,) int64
        Run ``s`` is ``[bounds[s], bounds[s + 1])``; ``bounds[0] = 0``, ``bounds[S] = N``.
    cost : float
        The least total cost.
    """
    s_count, n = outside.shape
    weights = np.asarray(weights, dtype=np.float64)
    idx = np.arange(n, dtype=np.int64)
    prev = np.full(n + 1, np.inf)
    prev[0] = 0.0
    choice = np.empty((s_count, n + 1), dtype=np.int32 if n < 2**31 - 1 else np.int64)
    for s in range(s_count):
        o = np.concatenate([[0.0], np.cumsum(outside[s], dtype=np.float64)])
        b = np.concatenate([[0.0], np.cumsum(weights[steps[s]])])
        # Run [a, e) with a < e costs o[e] - o[a] + b[e] - b[a + 1]; the best start for each end
        # is a running minimum over a < e (the latest start among equals).
        h = prev[:n] - o[:n] - b[1:]
        best = np.minimum.accumulate(h)
        arg = np.maximum.accumulate(np.where(h == best, idx, 0))
        run = np.full(n + 1, np.inf)
        run[1:] = best + o[1:] + b[1:]
        take = run < prev                              # ties: the run stays empty
        choice[s] = np.arange(n + 1)
        choice[s, 1:][take[1:]] = arg[take[1:]]
        prev = np.where(take, run, prev)
    bounds = np.empty(s_count + 1, dtype=np.int64)
    bounds[s_count] = n
    for s in range(s_count - 1, -1, -1):
        bounds[s] = choice[s, bounds[s + 1]]
    return bounds, float(prev[n])


def associate_ordered(means, cameras, *, views=None, max_offset: float = MAX_OFFSET,
                      min_seen: float = 0.5) -> Association:
    """The view and pixel of each vertex of a per-pixel export written view after view.

    The export holds one Gaussian per kept pixel, written in the model's ``(view, row, col)``
    order, with an unknown number of each view's pixels cut (border trims, depth-percentile
    cuts, masks, opacity cuts) and centres moved off their pixel's ray by sub-pixel offsets.

    Every vertex is projected into every camera. In the run of camera ``v`` a vertex costs 1
    when it is behind ``v`` or outside its image, :data:`ORDER_WEIGHT` when its row-major pixel
    key in ``v`` steps back from the previous vertex's by more than ``max_offset`` offsets
    explain (a break: the run of one view only moves forward), and :data:`STALL_WEIGHT` when it
    stays on the previous pixel or steps back less (:func:`_order_steps`). The sequence is cut
    into consecutive runs, one per camera of ``views`` in order (runs may be empty), at the
    least total cost by a dynamic programme over the run boundaries (:func:`_segment`, O(N V)).
    Where consecutive cameras are nearly identical (a video), the boundaries are the row
    resets from the bottom of one view to the top of the next, which every such camera shows.
    Each vertex's pixel is the one its centre projects to in its view's camera (floor).

    What stays ambiguous: a view none of whose pixels survived leaves no run, and when views
    are missing (an export of every k-th view) and ``views`` is not given, a camera close to a
    written one can take its run: only stalls tell them apart, counted with ``max_offset <=
    0.5`` when the export is in the cameras' exact frame; identical cameras cannot be told
    apart at all (give ``views``).

    Parameters
    ----------
    means : (N, 3) array_like
        Vertex centres, in the frame of ``cameras`` (for an export in Depth Anything 3's
        normalised frame, map them with :func:`normalised_frame` first).
    cameras : sequence of Camera
        The input cameras, in view-id order.
    views : sequence of int, optional
        The camera indices that may appear, in the order the export writes them (Depth
        Anything 3's ``gs_views_interval``: ``range(0, V, interval)``). Default: all, in order.
    max_offset : float
        Largest distance, in pixels per axis, of a centre's projection from its pixel centre.
    min_seen : float
        Least share of the vertices that must project into their view's image; fewer means
        the cameras do not fit the export (wrong frame, cameras or views).

    Returns
    -------
    Association
        ``source = "geometry"``; ``ambiguous`` where a vertex lies outside its view's image
        (``pixel_id = -1``) or breaks its run's order.

    Raises
    ------
    ClearsplatError
        Bad ``means`` (shape, NaN), ``cameras``, ``views`` or options; cameras that see fewer
        than ``min_seen`` of the vertices (``field="cameras"``).
    """
    means = _checked_means(means)
    cameras = _checked_cameras(cameras)
    views = _checked_views(views, len(cameras))
    max_offset, min_seen = _number("max_offset", max_offset), _checked_share(min_seen)
    if not (np.isfinite(max_offset) and max_offset > 0):
        raise ClearsplatError(f"expected a number > 0, got {max_offset!r}", field="max_offset")
    n = len(means)
    if n == 0:
        e = np.empty(0, dtype=np.int64)
        return Association(e, e.copy(), np.empty(0, dtype=bool))
    outside = np.empty((len(views), n), dtype=bool)
    steps = np.empty((len(views), n), dtype=np.uint8)
    for s, v in enumerate(views):
        row, col, ok = _projection(cameras[v], means, max_offset)
        outside[s] = ~ok
        steps[s] = _order_steps(row, col, ok, cameras[v].width, max_offset)
    bounds, _ = _segment(outside, steps, (0.0, STALL_WEIGHT, ORDER_WEIGHT))
    seg = np.repeat(np.arange(len(views)), np.diff(bounds))
    pick = np.arange(n)
    out, brk = outside[seg, pick], steps[seg, pick] == BREAK
    brk[bounds[:-1][bounds[:-1] < n]] = False           # a run's first vertex starts over
    seen = 1.0 - out.mean()
    if seen < min_seen:
        raise ClearsplatError(f"only {100 * seen:.1f} % of the vertices project into their "
                              "view's image: the cameras do not fit the export (another frame, "
                              "other cameras or views?)", field="cameras")
    view_id = views[seg]
    pixel_id = np.full(n, -1, dtype=np.int64)
    for s, v in enumerate(views):
        lo, hi = bounds[s], bounds[s + 1]
        if hi > lo:
            row, col, ok = _projection(cameras[v], means[lo:hi], max_offset)
            pixel_id[lo:hi] = np.where(ok, row * cameras[v].width + col, -1)
    return Association(view_id, pixel_id, out | brk, "geometry")


# ------------------------------------------------------------------------------------------------
# pixel-centred exports in no order
# ------------------------------------------------------------------------------------------------
def _centre_offsets(cam: Camera, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per centre, the pixel its projection falls in (``row * width + col``, -1 where none)
    and the distance, in pixels, of the projection from that pixel's centre along the axis
    where it is larger (inf where it is behind the camera or outside the image): (M,) int64,
    (M,) float64."""
    uv, z = cam.project(means)
    ok = z > 0
    x = np.where(ok, uv[:, 0], -1.0)
    y = np.where(ok, uv[:, 1], -1.0)
    ok &= (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
    col = np.floor(np.where(ok, x, 0.0))
    row = np.floor(np.where(ok, y, 0.0))
    off = np.maximum(np.abs(x - col - 0.5), np.abs(y - row - 0.5))
    pixel = np.where(ok, row.astype(np.int64) * cam.width + col.astype(np.int64), -1)
    return pixel, np.where(ok, off, np.inf)


def associate_centred(means, cameras, *, min_seen: float = 0.5) -> Association:
    """The view and pixel of each vertex of a per-pixel export whose centres lie on the rays
    through their pixels' centres, in any order.

    For exports that hold one Gaussian per pixel placed on the ray through the pixel's centre
    (Long-LRM: ``ray_o + t d`` through ``(col + 0.5, row + 0.5)``; WorldMirror: ``c2w ((col -
    W/2) z / f_x, (row - H/2) z / f_y, z)``, the pixel's centre once the principal point is
    moved by +0.5 px) but in no order that says which (pruning by opacity, a random subset).
    Projected into its own camera such a centre lands on its pixel's centre, to float32
    round-off; into another camera at a sub-pixel position unrelated to that camera's pixel
    grid, within ``tolerance`` (:data:`CENTRE_TOLERANCE`) of a centre with probability
    ``(2 tolerance)^2``.

    Every vertex is projected into every camera, one camera at a time; its *offset* in a
    camera is the distance of its projection from the centre of the pixel it falls in, along
    the axis where it is larger (:func:`_centre_offsets`). Its view is the camera with the
    smallest offset (the first of equals), its pixel the one it falls in there. It is
    ambiguous where that offset exceeds ``tolerance`` (no camera puts it on a pixel centre:
    the cameras do not fit, or the centres were computed at a lower precision; then its
    ``pixel_id`` is -1, as its pixel is a guess) or where the second smallest offset is at
    most ``max(ratio * smallest, tolerance / ratio)`` with ``ratio`` :data:`CENTRE_RATIO`
    (two cameras put it there alike: identical cameras, or ones a whole number of pixels
    apart).
    A vertex no camera sees goes to the camera whose image centre it projects nearest to (or
    that faces it most), with ``pixel_id = -1``.

    Parameters
    ----------
    means : (N, 3) array_like
        Vertex centres, in the frame of ``cameras``, as read (float64 preferably: a rounding
        to float32 far from the frame's origin moves them by more than the model did).
    cameras : sequence of Camera
        The input cameras, in view-id order, with the principal points in clearsplat's
        convention (pixel ``(row, col)`` centred at ``(col + 0.5, row + 0.5)``).
    min_seen : float
        Least share of the vertices that must project into some camera's image; fewer means
        the cameras do not fit the export.

    Returns
    -------
    Association
        ``source = "geometry"``.

    Raises
    ------
    ClearsplatError
        Bad ``means`` (shape, NaN), ``cameras`` or options; cameras that see fewer than
        ``min_seen`` of the vertices (``field="cameras"``).
    """
    means = _checked_means(means)
    cameras = _checked_cameras(cameras)
    min_seen = _checked_share(min_seen)
    tolerance = CENTRE_TOLERANCE
    n = len(means)
    view_id, pixel_id, best, second = _nearest_centres(means, cameras)
    seen = np.isfinite(best)
    if n and seen.mean() < min_seen:
        raise ClearsplatError(f"only {100 * seen.mean():.1f} % of the vertices project into an "
                              "input image: the cameras do not fit the export (another frame, "
                              "other cameras?)", field="cameras")
    if not seen.all():
        view_id[~seen] = _facing_view(means[~seen], cameras)
    ambiguous = ~(best <= tolerance) | _two_alike(best, second)
    # On no pixel centre (a merged voxel, a model run at a lower precision): the nearest
    # camera's view, but no pixel, which the filter would read as exact.
    pixel_id[~(best <= tolerance)] = -1
    return Association(view_id, pixel_id, ambiguous, "geometry")


def _nearest_centres(means: np.ndarray, cameras
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per centre, the camera that puts it nearest a pixel centre, that pixel, and the
    smallest and second smallest offsets over the cameras (:func:`_centre_offsets`; inf where
    fewer cameras see it): (M,) int64 each, then (M,) float64 each. Camera 0 where none sees
    it."""
    n = len(means)
    best, second = np.full(n, np.inf), np.full(n, np.inf)
    view_id, pixel_id = np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int64)
    for v, cam in enumerate(cameras):
        pixel, off = _centre_offsets(cam, means)
        nearer = off < best
        second = np.where(nearer, best, np.minimum(second, off))
        best = np.where(nearer, off, best)
        view_id[nearer] = v
        pixel_id[nearer] = pixel[nearer]
    return view_id, pixel_id, best, second


def _two_alike(best: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(M,) bool: the second camera puts the centre about as near a pixel centre as the first
    (:data:`CENTRE_RATIO`)."""
    return second <= np.maximum(CENTRE_RATIO * best, CENTRE_TOLERANCE / CENTRE_RATIO)


# ------------------------------------------------------------------------------------------------
# fused Gaussians
# ------------------------------------------------------------------------------------------------
def associate_fused(gaussians, cameras, images, *, settings: RenderSettings | None = None,
                    num_threads: int | None = None, progress=None) -> Association:
    """The view of each Gaussian from how it reproduces the input images.

    For Gaussians that mix pixels of several views (voxel fusion) or that come with no order
    information at all. Every input camera is rendered, one at a time, with the blending weight
    of every (pixel, Gaussian) pair: ``alpha * T``, where the transmittance ``T`` counts only
    the Gaussians in front of it by more than :data:`HIDDEN_DEPTH` of its depth
    (:func:`_unhidden_weights`). A fusion leaves a surface several Gaussians deep (a slanted
    or noisy one, voxels of a few pixels each); those of one surface do not hide each other,
    so a transient's Gaussians behind its front ones still agree with the view that saw it.
    Each pair's agreement ``exp(-e^2 / (2 sigma^2))`` (``sigma`` :data:`COLOUR_SIGMA`) says
    how well the Gaussian's colour (its SH DC term) matches that view's input image at the
    pixel (``e`` the RMS difference over the channels). Per Gaussian and view:
    ``W`` the summed weight (how large the view sees it), ``A`` the agreement-weighted sum and
    ``r = A / W`` the share of it that agrees (:func:`_view_sums`).

    The views that *see it agreeing* have ``W >=`` :data:`SEEN_WEIGHT` and ``r`` at least
    :data:`AGREE_RATIO` times the ``r`` of its best view, the one with the largest ``A * r``.

    - One such view: the Gaussian is what that view alone saw (a transient agrees with the
      image of the view that saw it only: from the others it covers what their images show
      behind it), or content that only one view sees. It goes to that view, as a per-pixel
      model would have it.
    - Several, and more than half of the views that see it (``W >= SEEN_WEIGHT``): static
      content. It is **shared** (``view_id`` :data:`~clearsplat.scene.SHARED`, -1): no single
      view made it. A per-pixel model predicts static content once from each view that sees
      it, so a view's render without its own Gaussians (the filter's exclusion render) still
      shows that content through the other views' copies; a fused Gaussian has no copy, and
      giving it to any one view would open a hole in that view's exclusion render, which the
      filter proposes as a region and, where the Gaussians there render a little off from the
      other views, removes. Shared, it stays in every view's exclusion render and no region
      maps to it. (Given to the view that sees it most instead, up to 1.71 % of the other
      voxels of the voxel-fused benchmark were removed, against at most 0.95 % shared:
      ``CHANGELOG.md``, 0.11.0.)
    - Several, but not most of those that see it: a transient that two frames caught at
      nearly the same place (each copy agrees with its own frame; the other views that look
      there see it disagreeing), or static content seen through other views' transients. It
      goes to the one of them (the views that see it agreeing) that sees it most, where the
      filter can judge it as a region.
    - None (no view sees it agreeing with a summed weight of ``SEEN_WEIGHT``): its best view;
      where no colour agrees anywhere, the view that sees it largest (where the filter can find
      it as a region that disagrees with the image); and if no camera renders it at all, the
      view whose image centre its centre projects nearest to (the one facing it most where
      none has it in front). Marked ambiguous.

    **One pixel's Gaussian.** A voxel that holds one pixel keeps that pixel's Gaussian, and a
    model that places its Gaussians on their pixels' rays (AnySplat, WorldMirror) leaves its
    centre on the ray through that pixel's centre: it is what a per-pixel model predicts, and
    it takes that view and pixel as :func:`associate_centred` finds them, whatever the renders
    say. Such hits are taken only where they are real, at least nine in ten of them, judged by
    the centres that chance puts just outside the tolerance (:func:`_one_pixel_gaussians`): a
    trained scene's Gaussians, or a fusion that moves every centre, lie on pixel centres by
    chance only, and none is taken.

    Every other Gaussian gets ``pixel_id`` -1: a fused Gaussian stands for pixels of several
    views, and one pixel of one view would misstate it. The filter then maps each image
    region to Gaussians through the rasterizer (compositing the view's own Gaussians from its
    camera; :func:`clearsplat.filter.association.region_gaussians`).

    Parameters
    ----------
    gaussians : Gaussians or Scene
    cameras : sequence of Camera
        The input cameras, in the frame of the Gaussians.
    images : sequence of (H, W, 3) array_like
        The input images, RGB in [0, 1], one per camera, of its size.
    settings : RenderSettings, optional
        How to rasterize; by default the scene's, or classic 3DGS for Gaussians.
    num_threads : int, optional
        Render threads (all cores by default).
    progress : callable(stage, done, total), optional
        Called with ``("associate", v, V)`` after each of the ``V`` cameras is rendered (the
        signature of the filter's ``progress=``).

    Returns
    -------
    Association
        ``source = "images"``; ``view_id = -1`` where shared; ``pixel_id = -1`` but for one
        pixel's Gaussians.
    """
    if isinstance(gaussians, Scene):
        settings = settings or gaussians.render_settings
        gaussians = gaussians.gaussians
    if not isinstance(gaussians, Gaussians):
        raise ClearsplatError(f"expected Gaussians or a Scene, got {type(gaussians).__name__}",
                              field="gaussians")
    gaussians.validate()
    cameras = _checked_cameras(cameras)
    images = _checked_images(images, cameras)
    n = len(gaussians)
    means = gaussians.means.astype(np.float64)
    total, agreeing = _view_sums(gaussians, means, cameras, images, settings=settings,
                                 num_threads=num_threads, progress=progress)
    view_id, ambiguous, unseen = _choose_views(total, agreeing)
    if unseen.any():
        view_id[unseen] = _facing_view(means[unseen], cameras)
    pixel_id = np.full(n, -1, dtype=np.int64)
    one, one_view, one_pixel = _one_pixel_gaussians(means, cameras)
    view_id[one], pixel_id[one], ambiguous[one] = one_view[one], one_pixel[one], False
    return Association(view_id, pixel_id, ambiguous, "images")


#: Largest summed weight held (float16).
_WEIGHT_CAP = 65504.0
#: Gaussians whose views are chosen at once (their float64 work: about 40 bytes per view).
_CHUNK = 1 << 18


def _view_sums(gaussians: Gaussians, means: np.ndarray, cameras, images, *, settings,
               num_threads, progress=None) -> tuple[np.ndarray, np.ndarray]:
    """Per Gaussian and view, rendering one camera at a time: ``W``, the summed blending
    weight (:func:`_unhidden_weights`), and ``A``, the agreement-weighted sum, each (N, V)
    float16 (capped at 65504; half precision keeps small sums' relative precision): 4 bytes
    per Gaussian and view. ``means``: the centres in float64."""
    n = len(gaussians)
    colour = np.clip(sh_dc_to_rgb(gaussians.sh[:, 0]), 0.0, 1.0)
    total = np.zeros((n, len(cameras)), dtype=np.float16)
    agreeing = np.zeros((n, len(cameras)), dtype=np.float16)
    for v, (cam, image) in enumerate(zip(cameras, images)):
        view = prepare(gaussians, cam, num_threads=num_threads, settings=settings)
        c = view.contributions(np.ones((cam.height, cam.width), dtype=bool))
        weight = _unhidden_weights(c.pixel, c.weight, cam.to_camera(means)[c.gaussian, 2])
        diff = colour[c.gaussian] - image.reshape(-1, 3)[c.pixel]
        agree = np.exp(np.einsum("ij,ij->i", diff, diff) / (-6.0 * COLOUR_SIGMA ** 2))
        total[:, v] = np.minimum(np.bincount(c.gaussian, weights=weight, minlength=n),
                                 _WEIGHT_CAP)
        agreeing[:, v] = np.minimum(np.bincount(c.gaussian, weights=weight * agree,
                                                minlength=n), _WEIGHT_CAP)
        if progress is not None:
            progress("associate", v + 1, len(cameras))
    return total, agreeing


def _unhidden_weights(pixel: np.ndarray, weight: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Each pair's blending weight with only what lies clearly in front counted as hiding it.

    Parameters
    ----------
    pixel, weight : (M,) arrays
        A render's ``(pixel, alpha * T)`` pairs, ordered by pixel, then front to back (a
        :class:`~clearsplat.render.Contributions`).
    depth : (M,) float64
        Each pair's Gaussian's camera depth (the compositing order within a pixel).

    Returns
    -------
    (M,) float64
        ``alpha * T'``: ``alpha = weight / T`` (``T`` one minus the weights before it in its
        pixel) and ``T'`` the product of ``1 - alpha`` over the Gaussians before it in its
        pixel whose depth is less than ``1 -`` :data:`HIDDEN_DEPTH` times its own. A Gaussian
        the compositing never reached at a pixel (the transmittance ran out before it) has no
        pair there.
    """
    w = np.asarray(weight, dtype=np.float64)
    if not len(w):
        return w
    pixel = np.asarray(pixel, dtype=np.int64)
    z = np.maximum(np.asarray(depth, dtype=np.float64), 0.0)
    starts = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
    first = np.repeat(starts, np.diff(np.r_[starts, len(w)]))
    summed = np.cumsum(w)
    trans = 1.0 - (summed - w - (summed[first] - w[first]))
    alpha = np.clip(w / np.maximum(trans, 1e-30), 0.0, _MAX_ALPHA)
    log_pass = np.log1p(-alpha)
    before = np.cumsum(log_pass) - log_pass          # summed log(1 - alpha) of all before
    # The first pair of each pair's pixel at a depth of at least (1 - HIDDEN_DEPTH) times its
    # own: the keys ``pixel + a depth share below 1/2`` rise along the list (made monotone
    # against ties the rasterizer's float32 sort may order otherwise); those before it hide it.
    unit = 0.5 / max(float(z.max()), 1e-30)
    key = np.maximum.accumulate(pixel + z * unit)
    front = np.searchsorted(key, pixel + z * ((1.0 - HIDDEN_DEPTH) * unit))
    front = np.clip(front, first, np.arange(len(w)))
    return alpha * np.exp(before[front] - before[first])


#: The largest opacity :func:`_unhidden_weights` reads back from a weight (3DGS clamps
#: opacity at 0.99; a little above leaves room for round-off).
_MAX_ALPHA = 0.999


def _one_pixel_gaussians(means: np.ndarray, cameras
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians whose centres lie on a pixel centre of one camera (see
    :func:`associate_fused`): (M,) bool, and each one's camera and pixel, (M,) int64 each.

    A centre is on a pixel centre where :func:`associate_centred` would give it a pixel
    unambiguously (within :data:`CENTRE_TOLERANCE`, no second camera alike). Chance puts a
    centre within ``t`` of some camera's pixel centre with a probability that grows as
    ``t^2`` (``(2 t)^2`` per camera), so as many centres fall within the tolerance by chance
    as a third of those between it and twice it. The hits are taken where they are at least
    ten times that count (nine in ten genuine), else none is.
    """
    view_id, pixel_id, best, second = _nearest_centres(means, cameras)
    hit = (best <= CENTRE_TOLERANCE) & ~_two_alike(best, second)
    near = (best > CENTRE_TOLERANCE) & (best <= 2 * CENTRE_TOLERANCE)
    if np.count_nonzero(hit) < max(10.0 * np.count_nonzero(near) / 3.0, 1.0):
        hit[:] = False
    return hit, view_id, pixel_id


def _choose_views(total: np.ndarray, agreeing: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The view of each Gaussian from ``_view_sums``' ``W`` and ``A`` (see
    :func:`associate_fused`).

    Returns
    -------
    view_id : (N,) int64
        :data:`~clearsplat.scene.SHARED` where several views and most of those that see it
        see it agreeing; where several do but not most, the one of them that sees it most;
        else the best view (the largest ``A * r``; where no colour agrees, the largest ``W``).
    ambiguous : (N,) bool
        No view sees it agreeing.
    unseen : (N,) bool
        No camera renders it at all: its view is to come from geometry.
    """
    n = total.shape[0]
    view_id = np.empty(n, dtype=np.int64)
    ambiguous, unseen = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
    for lo in range(0, n, _CHUNK):      # float64 work held for one chunk of rows at a time
        rows = slice(lo, min(lo + _CHUNK, n))
        w = total[rows].astype(np.float64)
        a = np.minimum(agreeing[rows].astype(np.float64), w)
        r = a / np.maximum(w, 1e-30)
        best = np.argmax(a * r, axis=1)
        r_best = r[np.arange(len(w)), best]
        seeing = w >= SEEN_WEIGHT
        ok = seeing & (r >= AGREE_RATIO * r_best[:, None]) & (r_best[:, None] > 0)
        c = ok.sum(axis=1)
        ambiguous[rows] = c == 0
        v = np.where(r_best > 0, best, np.argmax(w, axis=1))
        multi = c >= 2
        v[multi] = np.argmax(np.where(ok, w, -1.0)[multi], axis=1)
        v[multi & (2 * c > seeing.sum(axis=1))] = SHARED
        view_id[rows] = v
        unseen[rows] = w.max(axis=1, initial=0.0) <= 0
    return view_id, ambiguous, unseen


def _facing_view(means: np.ndarray, cameras) -> np.ndarray:
    """(M,) int64: per centre, the camera whose image centre it projects nearest to (in units
    of the half image size); where no camera has it in front, the one facing it most."""
    near = np.full((len(cameras), len(means)), np.inf)
    facing = np.empty((len(cameras), len(means)))
    for v, cam in enumerate(cameras):
        pc = cam.to_camera(means)
        front = pc[:, 2] > 0
        z = np.where(front, pc[:, 2], 1.0)
        dx = (cam.fx * pc[:, 0] / z + cam.cx - cam.width / 2) / (cam.width / 2)
        dy = (cam.fy * pc[:, 1] / z + cam.cy - cam.height / 2) / (cam.height / 2)
        near[v] = np.where(front, np.maximum(np.abs(dx), np.abs(dy)), np.inf)
        facing[v] = pc[:, 2] / np.maximum(np.linalg.norm(pc, axis=1), 1e-30)
    best = np.argmin(near, axis=0)
    none = ~np.isfinite(near.min(axis=0))
    best[none] = np.argmax(facing[:, none], axis=0)
    return best.astype(np.int64)


# ------------------------------------------------------------------------------------------------
# model frames
# ------------------------------------------------------------------------------------------------
def normalised_frame(cameras) -> Similarity:
    """Depth Anything 3's normalisation of given poses, as the map back to the cameras' frame.

    With input poses, Depth Anything 3 conditions on (and writes its Gaussians in) a frame where
    camera 0 is the identity and camera centres are divided by the (lower) median of their
    distances from camera 0, at least 0.1 (``DepthAnything3._normalize_extrinsics``). The model
    places its Gaussians with its own predicted poses, rescaled to that frame by an Umeyama
    scale, so the frame holds only approximately: associate with a ``max_offset`` of a pixel
    or more.

    Returns
    -------
    Similarity
        ``x_world = m C_0 x + t_0``: ``C_0``, ``t_0`` camera 0's rotation and centre, ``m`` the
        median distance.
    """
    cameras = _checked_cameras(cameras)
    c0 = cameras[0].camera_to_world
    dists = np.sort([np.linalg.norm(c.position - c0[:3, 3]) for c in cameras])
    m = max(float(dists[(len(dists) - 1) // 2]), 0.1)
    return Similarity(m, c0[:3, :3].copy(), c0[:3, 3].copy())
