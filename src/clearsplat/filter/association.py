"""From image regions to Gaussians, and the choice of verification views.

Paper, end of "Distractor Proposal" and start of "Candidate Verification".
"""

from __future__ import annotations

import math

import numpy as np

from .._threads import thread_map
from ..render import PreparedView, contributions
from ..scene import Scene

#: With ``align_scale``: "in front" means beyond this many robust standard deviations of the
#: view's depth ratio to the reference.
_SPREAD_FACTOR = 2.5

__all__ = [
    "ViewIndex", "region_gaussians", "member_pixels", "revealing_gaussians", "pixels_of",
    "verification_views", "dilate",
]


class ViewIndex:
    """Per-view lists of Gaussian indices and their pixel ids, built once per scene."""

    def __init__(self, scene: Scene):
        order = np.argsort(scene.view_id, kind="stable")
        bounds = np.searchsorted(scene.view_id[order], np.arange(scene.num_views + 1))
        self.members = [order[bounds[i]:bounds[i + 1]] for i in range(scene.num_views)]
        self.pixels = [scene.pixel_id[m] for m in self.members]
        # Pixel -> Gaussians of each view as CSR (pixel-aligned Gaussians only): a region's
        # Gaussians are then gathered in time proportional to the region, not the view.
        self._by_pixel = []
        for i, cam in enumerate(scene.cameras):
            pid = self.pixels[i]
            aligned = np.flatnonzero(pid >= 0)
            by = aligned[np.argsort(pid[aligned], kind="stable")]
            starts = np.searchsorted(pid[by], np.arange(cam.width * cam.height + 1))
            self._by_pixel.append((self.members[i][by], starts))

    def at_pixels(self, view: int, flat_pixels: np.ndarray) -> np.ndarray:
        """Pixel-aligned Gaussians of ``view`` at the given flat pixel indices (unsorted)."""
        gaussians, starts = self._by_pixel[view]
        lo, hi = starts[flat_pixels], starts[flat_pixels + 1]
        counts = hi - lo
        if counts.sum() == 0:
            return np.empty(0, dtype=np.int64)
        # Concatenate the ranges [lo, hi) without a Python loop.
        offsets = np.repeat(lo - np.cumsum(counts) + counts, counts)
        return gaussians[offsets + np.arange(counts.sum())]

    def mask(self, view: int, n: int) -> np.ndarray:
        """(N,) bool mask of the Gaussians of ``view``."""
        out = np.zeros(n, dtype=bool)
        out[self.members[view]] = True
        return out


def region_gaussians(scene: Scene, view: int, pixels: np.ndarray, *, index: ViewIndex,
                     min_weight: float = 0.05, prepared: PreparedView | None = None) -> np.ndarray:
    """Gaussians of ``view`` that a pixel region maps to [C_k], sorted int64 indices.

    Pixel-aligned Gaussians map through their ``pixel_id`` (several per pixel allowed). The
    others (``pixel_id == -1``) map through the rasterizer association: compositing only the
    Gaussians of ``view`` from its own camera, those whose blending weight (alpha * T) reaches
    ``min_weight`` at some pixel of the region (the front surface of that view's prediction).

    Parameters
    ----------
    pixels : (H, W) bool
        The region in the image of ``view``.
    prepared : PreparedView, optional
        ``view``'s camera prepared from the whole scene; reused instead of projecting the
        scene again for every region.
    """
    members, pid = index.members[view], index.pixels[view]
    flat = pixels.ravel()
    chosen = np.sort(index.at_pixels(view, np.flatnonzero(flat)))
    aligned = pid >= 0
    if aligned.all() or not flat.any():
        return chosen
    own = np.zeros(len(scene), dtype=bool)
    own[members] = True
    if prepared is None:
        contrib = contributions(scene, scene.cameras[view], pixels, keep=own)
    else:
        contrib = prepared.contributions(pixels, keep=own)
    g = contrib.gaussian[(contrib.weight >= min_weight)]
    g = g[(scene.view_id[g] == view) & (scene.pixel_id[g] < 0)]
    return np.union1d(chosen, g).astype(np.int64)


def member_pixels(scene: Scene, index: ViewIndex, view: int) -> np.ndarray:
    """Flat pixel of each Gaussian of ``view`` in that view's image, (M,) int64, -1 if none.

    ``pixel_id`` where the model is pixel-aligned, otherwise the pixel its centre projects to.
    """
    members = index.members[view]
    pix = index.pixels[view].copy()
    loose = pix < 0
    if loose.any():
        cam = scene.cameras[view]
        uv, z = cam.project(scene.gaussians.means[members[loose]])
        with np.errstate(invalid="ignore"):
            col = np.floor(np.nan_to_num(uv[:, 0], nan=-1.0, posinf=-1.0, neginf=-1.0))
            row = np.floor(np.nan_to_num(uv[:, 1], nan=-1.0, posinf=-1.0, neginf=-1.0))
        ok = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        pix[loose] = np.where(ok, row * cam.width + col, -1).astype(np.int64)
    return pix


def revealing_gaussians(scene: Scene, index: ViewIndex, reference_depths: list[np.ndarray], *,
                        margin: float, reference_rgbs: list[np.ndarray] | None = None,
                        color_threshold: float | None = None, images: list | None = None,
                        align_scale: bool = False,
                        reference_rgbs_hi: list[np.ndarray] | None = None,
                        scale_reach: int = 0, color_grow: float | None = None,
                        workers: int | None = None) -> np.ndarray:
    """Gaussians in front of the surface that the other views show at their pixel, (N,) bool.

    The paper's depth condition asks, per patch, that excluding view i's Gaussians reveal a
    farther surface. This applies it per Gaussian: a Gaussian of view i qualifies when its
    camera-i depth is below ``(1 - margin)`` times the reference depth at its pixel (see
    :func:`member_pixels`). Where the reference shows nothing, nothing is revealed and it does
    not qualify.

    Parameters
    ----------
    reference_depths : list of (H, W) float
        Per input view, the expected depth of a render without that view's Gaussians (0 where
        empty).
    margin : float
        Relative depth gap that counts as "in front".
    reference_rgbs : list of (H, W, 3) float, optional
        Colours of the same reference renders; NaN where they should not be used.
    color_threshold : float, optional
        With ``reference_rgbs``: a Gaussian also qualifies when its view's input colour differs
        from the reference colour at its pixel by more than this (L1 over RGB) and it does not
        lie behind the reference surface (it touches it: the foot of an object on the floor).
    images : list of (H, W, 3) float, optional
        The input colours for the colour test (default: ``scene.images``).
    align_scale : bool
        Divide each view's depths by their median ratio to the reference depth first, and widen
        ``margin`` to 2.5 robust standard deviations of that ratio where the view's depth is
        noisier (:func:`clearsplat.filter.robust.view_depth_scales`): the test in the view's own
        depth scale and noise (``FilterConfig.depth_scale_align``).
    reference_rgbs_hi : list of (H, W, 3) float, optional
        Upper bounds of the reference colours; ``reference_rgbs`` are then the lower bounds and
        the colour difference is the L1 distance to that box (``FilterConfig.refine_tolerance``).
    scale_reach : int
        With ``align_scale``: 0 divides each view's depths by one scale; k > 0 by the median
        ratio within k 16-pixel cells around each Gaussian
        (:func:`clearsplat.filter.robust.local_depth_scales`, ``FilterConfig.depth_scale_reach``).
    color_grow : float, optional
        With ``color_threshold``: a lower threshold for the same colour test, applied with
        hysteresis. A Gaussian that touches the reference and differs from it by more than this
        also qualifies when its pixel is 8-connected through such pixels to the pixel of one
        that qualifies on its own (:func:`join_touching`, ``FilterConfig.refine_color_grow``).
    workers : int, optional
        Threads, one view at a time each (default: the cores, at most ``OMP_NUM_THREADS``); the
        result does not depend on it.
    """
    from .robust import local_depth_scales, view_depth_scales
    images = scene.images if images is None else images
    # Camera depths and pixels first, in this thread (matrix products, left to BLAS as they
    # are, whose own threads must not depend on ours).
    depths = [scene.cameras[view].to_camera(scene.gaussians.means[members])[:, 2]
              if members.size else None for view, members in enumerate(index.members)]
    pixels = [member_pixels(scene, index, view) if members.size else None
              for view, members in enumerate(index.members)]

    def view_front(view: int) -> np.ndarray | None:
        members = index.members[view]
        if members.size == 0:
            return None
        z, pix = depths[view], pixels[view]
        behind = np.zeros(members.size)
        valid = pix >= 0
        behind[valid] = reference_depths[view].ravel()[pix[valid]]
        view_margin = margin
        if align_scale and scale_reach > 0:
            cam = scene.cameras[view]
            scale, spread = local_depth_scales(z, behind, pix, cam.height, cam.width,
                                               reach=scale_reach)
            z = z / scale
            view_margin = max(margin, 1.0 - np.exp(-_SPREAD_FACTOR * spread))
        elif align_scale:
            scale, spread = view_depth_scales([z], [behind])[0]
            z = z / scale
            # "In front" beyond this view's own depth noise, not only beyond the fixed margin.
            view_margin = max(margin, 1.0 - np.exp(-_SPREAD_FACTOR * spread))
        front = (behind > 0) & (z > 0) & (z < (1.0 - view_margin) * behind)
        if color_threshold is not None and reference_rgbs is not None:
            image = images[view].reshape(-1, 3)
            ref = reference_rgbs[view].reshape(-1, 3)
            differ = np.zeros(members.size, dtype=bool)
            with np.errstate(invalid="ignore"):
                if reference_rgbs_hi is None:
                    diff = np.abs(image[pix[valid]] - ref[pix[valid]]).sum(-1)
                else:
                    x = image[pix[valid]]
                    hi = reference_rgbs_hi[view].reshape(-1, 3)[pix[valid]]
                    diff = (np.maximum(ref[pix[valid]] - x, 0) + np.maximum(x - hi, 0)).sum(-1)
            differ[valid] = diff > color_threshold       # False where the reference is NaN
            touching = (behind > 0) & (z > 0) & (z < (1.0 + margin) * behind)
            front |= differ & touching
            if color_grow is not None and color_grow < color_threshold:
                weak = np.zeros(members.size, dtype=bool)
                weak[valid] = diff > color_grow
                cam = scene.cameras[view]
                front |= join_touching(front, weak & touching & ~front, pix,
                                       cam.height, cam.width)
        return front

    out = np.zeros(len(scene), dtype=bool)
    # The views are independent (each writes its own Gaussians): one per core.
    fronts = thread_map(view_front, range(scene.num_views), workers=workers)
    for members, front in zip(index.members, fronts):
        if front is not None:
            out[members] = front
    return out


def join_touching(seeds: np.ndarray, weak: np.ndarray, pixels: np.ndarray, height: int,
                  width: int) -> np.ndarray:
    """The ``weak`` Gaussians joined to ``seeds`` through their pixels (hysteresis), (M,) bool.

    Parameters
    ----------
    seeds, weak : (M,) bool
        Over one view's Gaussians: those that qualify on their own, and those that qualify only
        when joined to them.
    pixels : (M,) int
        Each Gaussian's pixel (row-major index into the (height, width) image; negative: none).
    height, width : int

    Returns
    -------
    (M,) bool
        The weak Gaussians whose pixel lies in an 8-connected component of the pixels of
        seed and weak Gaussians that holds a seed pixel.
    """
    from .proposal import label8, touched_components
    joined = np.zeros(weak.shape, dtype=bool)
    seeds = seeds & (pixels >= 0)
    weak = weak & (pixels >= 0)
    if not (seeds.any() and weak.any()):
        return joined
    seed_px = np.zeros(height * width, dtype=bool)
    seed_px[pixels[seeds]] = True
    either = seed_px.copy()
    either[pixels[weak]] = True
    labels = label8(either.reshape(height, width))[0].ravel()
    joined[weak] = touched_components(labels, seed_px)[pixels[weak]]
    return joined


def pixels_of(scene: Scene, index: ViewIndex, view: int, selected: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of ``view`` holding one of its ``selected`` ((N,) bool) Gaussians."""
    cam = scene.cameras[view]
    out = np.zeros(cam.height * cam.width, dtype=bool)
    pix = member_pixels(scene, index, view)
    pix = pix[selected[index.members[view]] & (pix >= 0)]
    out[pix] = True
    return out.reshape(cam.height, cam.width)


def verification_views(scene: Scene, view: int, count: int, *, index: ViewIndex,
                       inside: list | None = None) -> list[int]:
    """The ``count`` other views that see the most centres of ``view``'s Gaussians [V_i].

    Centres count when they have positive depth and fall inside the image; ties go to the
    lower view index; ``view`` itself is never chosen.

    ``inside``, optional: per view, the (N,) bool :meth:`PreparedView.centres_inside
    <clearsplat.render.PreparedView.centres_inside>` of its prepared view. The counts then
    come from the projections already made (about 4x faster at 16 views) and leave out
    the Gaussians the rasterizer culls (alpha below 1/255, closer than its near plane).
    """
    others = [j for j in range(scene.num_views) if j != view]
    if not others:
        return []
    if inside is not None:
        members = index.members[view]
        counts = sorted((-int(np.count_nonzero(inside[j][members])), j) for j in others)
        return [j for _, j in counts[:count]]
    means = scene.gaussians.means[index.members[view]]
    # All cameras in one product: (M, 3) @ (3, 3V) plus translations, in float32.
    w2c = np.stack([scene.cameras[j].world_to_camera for j in others]).astype(np.float32)
    pc = means @ w2c[:, :3, :3].transpose(2, 0, 1).reshape(3, -1) + w2c[:, :3, 3].reshape(-1)
    pc = pc.reshape(len(means), len(others), 3)
    cams = [scene.cameras[j] for j in others]
    fx, fy, cx, cy, w, h = (np.array([getattr(c, a) for c in cams], dtype=np.float32)
                            for a in ("fx", "fy", "cx", "cy", "width", "height"))
    x, y, z = pc[..., 0], pc[..., 1], pc[..., 2]
    front = z > 0
    zf = np.where(front, z, np.float32(1.0))
    u = fx * x / zf + cx
    v = fy * y / zf + cy
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    counts = sorted(zip((-inside.sum(axis=0)).tolist(), others))
    return [j for _, j in counts[:count]]


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate a (H, W) bool mask by a disk of ``radius`` pixels (Euclidean)."""
    if radius <= 0 or not mask.any():
        return mask.copy()
    r = int(radius)
    # Dilate only the region's bounding box grown by r: same result, far less work.
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, mask.shape[0])
    c0, c1 = max(cols[0] - r, 0), min(cols[-1] + r + 1, mask.shape[1])
    out = np.zeros_like(mask, dtype=bool)
    out[r0:r1, c0:c1] = _dilate_disk(mask[r0:r1, c0:c1], r)
    return out


def _dilate_disk(mask: np.ndarray, r: int) -> np.ndarray:
    """Binary dilation by the disk ``dy^2 + dx^2 <= r^2`` with zeros outside ``mask``.

    Row by row: the disk's row at offset ``dy`` is the run ``|dx| <= k(dy)``, so the result is
    the union over ``dy`` of ``mask`` dilated horizontally by ``k(dy)`` (a difference of
    running sums) and shifted by ``dy``. Equal to ``scipy.ndimage.binary_dilation`` with that
    structure, without importing SciPy.
    """
    h, w = mask.shape
    run = np.zeros((h, w + 1), dtype=np.int32)
    np.cumsum(mask, axis=1, out=run[:, 1:])
    cols = np.arange(w)
    out = np.zeros((h, w), dtype=bool)
    rows: dict = {}
    for dy in range(-min(r, h - 1), min(r, h - 1) + 1):
        k = math.isqrt(r * r - dy * dy)
        if k not in rows:
            hi = np.minimum(cols + k + 1, w)
            lo = np.maximum(cols - k, 0)
            rows[k] = run[:, hi] > run[:, lo]
        wide = rows[k]
        # out[y] |= wide[y + dy]
        if dy >= 0:
            out[:h - dy] |= wide[dy:]
        else:
            out[-dy:] |= wide[:h + dy]
    return out
