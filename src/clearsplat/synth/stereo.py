"""A real-image check: the Middlebury "Motorcycle" stereo pair with a pasted distractor.

scikit-image ships the left and right images of Middlebury 2014 *Motorcycle* (perfect
rectification, down-sampled 4x to 741 x 500) with the left view's ground-truth disparity.
:func:`stereo_motorcycle_scene` turns it into a two-view pixel-aligned prediction with the
stand-in backbone (:func:`clearsplat.synth.reconstruct`), after pasting a real object cut
from another sample image into one view; :func:`real_image_check` runs the filter on it and
measures what it removed.

Construction (every choice, in the order it is made):

- **Calibration** (from the ``stereo_motorcycle`` docstring, valid for the 741 x 500 images):
  f = 994.978 px, principal point (311.193, 254.877) px, doffs = 31.086 px (the right
  camera's principal point lies doffs to the right of the left one's), baseline 193.001 mm.
  Middlebury puts pixel centres at integers; the 4x block-mean down-sampling maps a full
  resolution coordinate ``x`` to ``(x + 0.5) / 4`` in clearsplat's convention (centres at
  +0.5), so ``cx = 311.193 + 0.125`` and ``cy = 254.877 + 0.125``. doffs, a difference, is
  unchanged.
- **Cameras**: the left camera is the world frame (identity pose); the right camera is
  translated by the baseline along +x (metres). Both share f and cy; the right camera's cx is
  the left one's plus doffs (the rectified pair of Middlebury does not share cx). Then the
  camera depth of a left pixel is ``Z = f B / (d + doffs)``.
- **Invalid disparities** (``inf`` in the shipped map, 7 % of the pixels, mostly regions the
  right camera does not see) are filled per scan line with the smaller (farther) of the
  nearest valid disparities to the left and to the right: an occlusion hole belongs to the
  background next to it.
- **Right view depth**: the filled left disparity is forward-warped to the right image
  (each left pixel centre ``x`` lands at ``x - d``; it is splatted to the two nearest right
  pixel centres, the larger disparity wins). Right pixels nothing lands on (the right
  camera's own occlusions and its right border) are filled as the left holes are. The right
  pixels that received a warped left pixel are the *co-visible* pixels.
- **Size**: the images are cropped (centred) and block-averaged by an integer factor to
  ``height`` rows and a multiple-of-16 width (240 x 368 by default, factor 2); disparities
  are block-averaged and divided by the factor, K is scaled and shifted consistently.
- **Paste**: an ellipse cut from a sample image (the face of Chelsea the cat, or the cup and
  saucer of ``coffee()``) is resampled (anti-aliased by a Gaussian pre-blur) into an ellipse
  of one view. Its pixels get one depth: ``paste_depth`` (0.7) times a low percentile (5th)
  of the scene depth behind the ellipse, a fronto-parallel surface clearly in front of
  everything it covers, as a learned model would place a pasted object on its own surface.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import ndimage

from ..cameras import Camera
from ..errors import ClearsplatError
from .backbone import reconstruct

__all__ = ["stereo_motorcycle_scene", "real_image_check", "motorcycle_views", "PASTES"]

# Calibration of the shipped (4x down-sampled) images, from the stereo_motorcycle docstring.
_FOCAL = 994.978
_CX = 311.193 + 0.125          # Middlebury integer-centre coordinate to +0.5 centres
_CY = 254.877 + 0.125
_DOFFS = 31.086
_BASELINE = 0.193001           # metres

#: Ellipse cuts of the objects that can be pasted: sample image name and
#: ``(centre_row, centre_col, radius_rows, radius_cols)`` in its pixels.
PASTES = {
    "chelsea": ("chelsea", (160.0, 200.0, 135.0, 165.0)),
    "coffee": ("coffee", (235.0, 278.0, 150.0, 200.0)),
}


def _skimage_data():
    try:
        from skimage import data
    except ImportError as exc:  # pragma: no cover - exercised only without scikit-image
        raise ImportError("the real-image check needs scikit-image: pip install "
                          "\"clearsplat[bench]\"") from exc
    return data


def _fill_scanlines(disp: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fill invalid entries with the smaller of the nearest valid values left and right.

    Rows without any valid entry take the median of all valid entries.
    """
    h, w = disp.shape
    cols = np.broadcast_to(np.arange(w), (h, w))
    left = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(valid, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    big = np.float64(np.inf)
    from_left = np.where(left >= 0, disp[rows, np.clip(left, 0, w - 1)], big)
    from_right = np.where(right < w, disp[rows, np.clip(right, 0, w - 1)], big)
    fill = np.minimum(from_left, from_right)
    fill = np.where(np.isfinite(fill), fill, np.median(disp[valid]) if valid.any() else 1.0)
    return np.where(valid, disp, fill)


def _warp_to_right(disp_left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward-warp a (filled) left disparity map to the right view.

    Returns the right disparity (holes filled) and the mask of right pixels that received a
    warped left pixel.
    """
    h, w = disp_left.shape
    x = np.arange(w)[None, :] + 0.5 - disp_left                 # right image coordinate
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    out = np.full((h, w), -np.inf)
    for col in (np.floor(x - 0.5), np.floor(x - 0.5) + 1):     # two nearest pixel centres
        col = col.astype(np.int64)
        ok = (col >= 0) & (col < w)
        np.maximum.at(out, (rows[ok], col[ok]), disp_left[ok])
    hit = np.isfinite(out)
    # Left pixels on depth edges (mixed disparities) land as isolated specks inside the right
    # camera's occlusion holes; runs of fewer than 3 hits along a row are dropped.
    # A 3 x 3 median then removes the remaining specks of the fill.
    hit = ndimage.binary_opening(hit, structure=np.ones((1, 3), bool))
    filled = _fill_scanlines(np.where(hit, out, 0.0), hit)
    return ndimage.median_filter(filled, size=3, mode="nearest"), hit


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    h, w = a.shape[0] // k, a.shape[1] // k
    a = a[:h * k, :w * k]
    return a.reshape(h, k, w, k, *a.shape[2:]).mean(axis=(1, 3))


def motorcycle_views(*, height: int = 240):
    """The Motorcycle pair as two posed views with depth, without any paste.

    Parameters
    ----------
    height : int
        Image rows, 16 to 500; the images are cropped (centred) and block-averaged by
        ``500 // height``, the width is the largest multiple of 16 that fits (240 gives
        240 x 368).

    Returns
    -------
    cameras : list of 2 Camera
        Left (identity pose) and right (translated by the baseline along +x), metres.
    images : list of 2 (H, W, 3) float32
    depths : list of 2 (H, W) float64
        Camera-z depth in metres, finite and positive everywhere (holes filled).
    covisible : list of 2 (H, W) bool
        Left: pixels with a ground-truth disparity that land inside the right image;
        right: pixels that a warped left pixel landed on.
    """
    height = int(height)
    if not 16 <= height <= 500:
        raise ClearsplatError(f"must be between 16 and 500, got {height}", field="height")
    data = _skimage_data()
    left, right, disp = data.stereo_motorcycle()
    disp = np.asarray(disp, dtype=np.float64)
    if disp.ndim == 3:
        disp = disp[..., 0]
    full_h, full_w = disp.shape
    valid = np.isfinite(disp)
    disp_l = _fill_scanlines(np.where(valid, disp, 0.0), valid)
    disp_r, hit_r = _warp_to_right(disp_l)
    vis_l = valid & (np.arange(full_w)[None, :] + 0.5 - disp_l >= 0)

    k = full_h // height
    width = full_w // k
    width = width // 16 * 16 if width >= 16 else width
    r0, c0 = (full_h - height * k) // 2, (full_w - width * k) // 2
    crop = (slice(r0, r0 + height * k), slice(c0, c0 + width * k))
    cameras, images, depths, covis = [], [], [], []
    for i, (img, d, vis) in enumerate(((left, disp_l, vis_l), (right, disp_r, hit_r))):
        images.append(_block_mean(np.asarray(img, np.float32)[crop] / 255.0, k)
                      .astype(np.float32))
        d = _block_mean(d[crop], k)                       # full-res units, like doffs
        depths.append(_FOCAL * _BASELINE / (d + _DOFFS))  # Z = f B / (d + doffs)
        covis.append(_block_mean(vis[crop].astype(np.float64), k) > 0.5)
        cx = _CX + (_DOFFS if i == 1 else 0.0)
        K = np.array([[_FOCAL / k, 0.0, (cx - c0) / k],
                      [0.0, _FOCAL / k, (_CY - r0) / k],
                      [0.0, 0.0, 1.0]])
        c2w = np.eye(4)
        c2w[0, 3] = _BASELINE * i
        cameras.append(Camera(K=K, camera_to_world=c2w, width=width, height=height))
    return cameras, images, depths, covis


def _ellipse(h, w, cy, cx, ry, rx):
    rr, cc = np.mgrid[0:h, 0:w]
    return ((rr + 0.5 - cy) / ry) ** 2 + ((cc + 0.5 - cx) / rx) ** 2 <= 1.0


def _paste(image, depth, *, paste, center, size, paste_depth):
    """Paste the cut of ``paste`` into a copy of ``image``; return image, depth, mask."""
    if paste not in PASTES:
        raise ClearsplatError(f"unknown paste {paste!r}; choose from {sorted(PASTES)}",
                              field="paste")
    name, (scy, scx, sry, srx) = PASTES[paste]
    source = np.asarray(getattr(_skimage_data(), name)(), dtype=np.float32)[..., :3] / 255.0
    h, w = depth.shape
    ry = 0.5 * size * h
    rx = ry * srx / sry
    cy, cx = center[0] * h, center[1] * w
    mask = _ellipse(h, w, cy, cx, ry, rx)
    if not mask.any():
        raise ClearsplatError("the pasted ellipse falls outside the image", field="center")
    scale = sry / ry                                   # source pixels per target pixel
    sigma = max(0.0, 0.5 * (scale - 1.0))
    rr, cc = np.nonzero(mask)
    src_r = scy + (rr + 0.5 - cy) * scale - 0.5
    src_c = scx + (cc + 0.5 - cx) * scale - 0.5
    out = image.copy()
    for ch in range(3):
        band = ndimage.gaussian_filter(source[..., ch], sigma) if sigma > 0 else source[..., ch]
        out[rr, cc, ch] = ndimage.map_coordinates(band, [src_r, src_c], order=1,
                                                  mode="nearest")
    behind = depth[mask]
    z = paste_depth * float(np.percentile(behind, 5))
    new_depth = depth.copy()
    new_depth[mask] = z
    return np.clip(out, 0.0, 1.0).astype(np.float32), new_depth, mask, z


def stereo_motorcycle_scene(*, height: int = 240, paste: str = "chelsea", seed: int = 0,
                            view: int = 1, center=(0.42, 0.3), size: float = 0.4,
                            paste_depth: float = 0.7, backbone: dict | None = None):
    """The Motorcycle pair with a real object pasted into one view, as a prediction.

    Parameters
    ----------
    height : int
        Image rows (see :func:`motorcycle_views`); 240 gives 240 x 368.
    paste : {"chelsea", "coffee"}
        What to paste: the cat's face or the cup and saucer (:data:`PASTES`).
    seed : int
        Seed of the backbone's depth errors.
    view : {0, 1}
        The view that gets the paste (1: right).
    center : (float, float)
        Ellipse centre as fractions of (height, width).
    size : float
        Ellipse height as a fraction of the image height (the width follows the cut).
    paste_depth : float
        Depth of the pasted surface as a fraction of the 5th percentile of the scene depth
        behind it, in (0, 1).
    backbone : dict, optional
        Options of :func:`clearsplat.synth.reconstruct` (``depth_blur``, ``depth_noise``...);
        its defaults otherwise.

    Returns
    -------
    scene : Scene
        Two views, ``H * W`` Gaussians each, pixel-aligned, with the pasted image as input.
    info : dict
        ``"mask"``: (H, W) bool, the pasted pixels; ``"view"``: the pasted view;
        ``"clean_images"``: the two images without the paste; ``"depths"``: the clean depth
        maps (metres); ``"paste_depth"``: depth of the pasted surface (metres);
        ``"covisible"``: per view, (H, W) bool, pixels the other view also sees;
        ``"seed"``, ``"backbone"``: the backbone's seed and options.

    Examples
    --------
    >>> scene, info = stereo_motorcycle_scene(height=120)
    >>> scene.num_views, info["mask"].shape, info["view"]
    (2, (120, 176), 1)
    """
    if view not in (0, 1):
        raise ClearsplatError(f"must be 0 or 1, got {view!r}", field="view")
    if not 0.0 < paste_depth < 1.0:
        raise ClearsplatError(f"must be in (0, 1), got {paste_depth}", field="paste_depth")
    if not 0.0 < size <= 1.0:
        raise ClearsplatError(f"must be in (0, 1], got {size}", field="size")
    cameras, images, depths, covis = motorcycle_views(height=height)
    pasted_img, pasted_depth, mask, z = _paste(images[view], depths[view], paste=paste,
                                               center=center, size=size,
                                               paste_depth=paste_depth)
    imgs = list(images)
    deps = list(depths)
    imgs[view], deps[view] = pasted_img, pasted_depth
    backbone = dict(backbone or {})
    scene = reconstruct(cameras, imgs, deps, seed=seed, **backbone)
    info = {"mask": mask, "view": view, "clean_images": images, "depths": depths,
            "paste_depth": z, "covisible": covis, "seed": seed, "backbone": backbone}
    return scene, info


def real_image_check(config=None, *, extractor=None, **scene_options) -> dict:
    """Run the filter on the pasted Motorcycle pair and measure what it removed.

    Parameters
    ----------
    config : FilterConfig, optional
        Filter options (``FilterConfig()`` by default).
    extractor : FeatureExtractor, optional
        A ready feature extractor, passed to :func:`clearsplat.filter_distractors`.
    **scene_options
        Options of :func:`stereo_motorcycle_scene`.

    Returns
    -------
    dict
        ``iou``: IoU of the pasted view's removed pixels (pixels with a removed Gaussian)
        and the pasted mask; ``recall``, ``precision``: the same pixels' recall and
        precision; ``psnr_before``, ``psnr_after``: PSNR of the other view's rendering
        (all Gaussians, then the kept ones) against its input image; ``psnr_clean``: the
        same for the prediction without the paste (the target); ``other_removed``: share of
        the Gaussians not on the pasted mask that were removed; ``removed_count``,
        ``pasted_gaussians``; ``timings`` (seconds: ``"scene"``, the filter's stages);
        ``result``: the :class:`FilterResult`; ``scene``, ``info``.
    """
    from ..filter import FilterConfig, filter_distractors
    from ..metrics import psnr
    from ..render import render

    config = config or FilterConfig()
    t0 = time.perf_counter()
    scene, info = stereo_motorcycle_scene(**scene_options)
    t_scene = time.perf_counter() - t0
    result = filter_distractors(scene, config=config, extractor=extractor)
    v, mask = info["view"], info["mask"]
    other = 1 - v
    in_view = scene.view_id == v
    pasted = np.zeros(len(scene), dtype=bool)
    pasted[in_view] = mask.reshape(-1)[scene.pixel_id[in_view]]
    removed_px = np.zeros(mask.size, dtype=bool)
    removed_px[scene.pixel_id[in_view & result.removed]] = True
    removed_px = removed_px.reshape(mask.shape)
    inter = float((removed_px & mask).sum())
    union = float((removed_px | mask).sum())
    cam, target = scene.cameras[other], scene.images[other]
    before = render(scene, cam).rgb
    after = render(scene, cam, keep=result.keep).rgb
    # The same backbone (seed and options) on the images without the paste: the target.
    clean = reconstruct(scene.cameras, info["clean_images"], info["depths"],
                        seed=info["seed"], **info["backbone"])
    clean_render = render(clean, cam).rgb
    others = ~pasted
    return {
        "iou": inter / union if union else float("nan"),
        "recall": inter / float(mask.sum()),
        "precision": inter / float(removed_px.sum()) if removed_px.any() else float("nan"),
        "psnr_before": psnr(before, target),
        "psnr_after": psnr(after, target),
        "psnr_clean": psnr(clean_render, target),
        "other_removed": float((result.removed & others).sum() / others.sum()),
        "removed_count": int(result.removed.sum()),
        "pasted_gaussians": int(pasted.sum()),
        "timings": {"scene": t_scene, **result.timings},
        "result": result, "scene": scene, "info": info,
        "renders": {"before": before, "after": after, "clean": clean_render},
        "removed_pixels": removed_px,
    }
