"""A messier stand-in backbone: the artifacts of real feed-forward predictions, one by one.

:func:`clearsplat.synth.reconstruct` is a clean pixel-aligned model (one opaque-ish Gaussian
per pixel, exact colours, exact cameras, mildly noisy depth). Real models are messier, and
:func:`realistic_reconstruction` adds their artifacts, each a named option seeded from the
scene seed:

``"soft"``
    Learned-looking opacities (spread between about 0.35 and 1, lower at depth edges), colours
    from a slightly blurred image plus noise, footprints 1-1.6x wider, SH degree 1 with a small
    view-dependent term.
``"depth"``
    A per-view global depth scale bias (a few percent), stronger low-frequency depth noise and
    stronger flying pixels at depth edges.
``"multi"``
    Three Gaussians per pixel along the ray (pixelSplat's ``gaussians_per_pixel = 3``), their
    opacities compounding to the single Gaussian's.
``"exposure"``
    A per-view, per-channel gain (white balance and exposure changes between shots): the input
    images handed to the filter disagree in colour, and each view's Gaussians carry its colours.
``"pose"``
    The cameras handed to the filter are off by a fraction of a degree and a fraction of a
    percent of the scene depth from those that took the images (estimated poses), and each
    view's Gaussians are unprojected with its estimated camera.
``"coarse"``
    Gaussians on a grid of 2x2 pixel cells, without ``pixel_id`` (ReSplat-like); the filter
    must associate them through the rasterizer.

``"all"`` is ``soft``, ``depth``, ``exposure`` and ``pose`` together; ``"plain"`` none. The
random draws of each artifact depend only on the seed, the artifact and the view, so the clean
twin (``clean=True``) gets the same gains, biases and pose errors as the cluttered scene.
"""

from __future__ import annotations

import zlib

import numpy as np
from scipy import ndimage

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import Gaussians, Scene, rgb_to_sh_dc
from .backbone import _imperfect_depth, rotation_to_quat

__all__ = ["ARTIFACTS", "SCENARIOS", "parse_realism", "realistic_reconstruction",
           "reproduction_psnr", "estimated_camera"]

#: The single artifacts, each a scenario of ``clearsplat bench --realism``.
ARTIFACTS = ("soft", "depth", "multi", "exposure", "pose", "coarse")
#: What ``"all"`` stands for (``multi`` and ``coarse`` are other layouts, kept apart).
ALL = ("soft", "depth", "exposure", "pose")
#: Every scenario name: no artifact, each alone, and several together.
SCENARIOS = ("plain",) + ARTIFACTS + ("all",)

# Strengths, chosen so that inputs are reproduced at about 25-32 dB by their own Gaussians and
# test views at about 17-25 dB (docs/benchmarks.md measures both).
_DEPTH_SCALE_SD = 0.02        # per-view global depth scale bias (relative)
_DEPTH_NOISE = 0.02           # low-frequency relative depth noise
_DEPTH_BLUR = 1.2             # inverse-depth blur (pixels): flying pixels at edges
_GAIN_SD = 0.06               # per-view exposure (log gain)
_WB_SD = 0.03                 # per-view, per-channel white balance (log gain)
_POSE_DEG = 0.25              # rotation error, degrees (standard deviation per axis)
_POSE_SHIFT = 0.004           # translation error relative to the median scene depth
_MULTI = 3                    # Gaussians per pixel
_MULTI_SPREAD = 0.01          # their relative spacing along the ray
_COARSE = 2                   # cell size in pixels


def parse_realism(spec) -> tuple[str, ...]:
    """The artifacts of a scenario name or list: ``"plain"``, ``"all"``, ``"soft+depth"``...

    Returns the artifacts in :data:`ARTIFACTS` order; ``()`` for ``"plain"``.
    """
    if isinstance(spec, str):
        items = [s.strip() for s in spec.replace(",", "+").split("+") if s.strip()]
    else:
        items = [str(s) for s in spec]
    out = set()
    for s in items:
        if s == "plain":
            continue
        if s == "all":
            out.update(ALL)
        elif s in ARTIFACTS:
            out.add(s)
        else:
            raise ClearsplatError(f"unknown realism {s!r}; expected one of {SCENARIOS}",
                                  field="realism")
    if "multi" in out and "coarse" in out:
        raise ClearsplatError("'multi' and 'coarse' are different layouts; choose one",
                              field="realism")
    return tuple(a for a in ARTIFACTS if a in out)


def _rng(seed: int, artifact: str, view: int) -> np.random.Generator:
    """One generator per (seed, artifact, view): the same draws for the clean twin."""
    return np.random.default_rng([int(seed), zlib.crc32(artifact.encode()), int(view)])


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(axis_angle))
    if theta == 0:
        return np.eye(3)
    k = axis_angle / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def estimated_camera(camera: Camera, depth: np.ndarray, *, seed: int, view: int) -> Camera:
    """``camera`` off by a small rotation and shift, as a pose estimator would give it."""
    rng = _rng(seed, "pose", view)
    rot = _rotation(np.deg2rad(_POSE_DEG) * rng.standard_normal(3))
    shift = _POSE_SHIFT * float(np.median(depth)) * rng.standard_normal(3)
    c2w = camera.camera_to_world.copy()
    c2w[:3, :3] = c2w[:3, :3] @ rot
    c2w[:3, 3] = c2w[:3, 3] + shift
    return Camera(K=camera.K, camera_to_world=c2w, width=camera.width, height=camera.height)


def _gain(seed: int, view: int) -> np.ndarray:
    rng = _rng(seed, "exposure", view)
    return np.exp(_GAIN_SD * rng.standard_normal() + _WB_SD * rng.standard_normal(3))


def _depth_edges(z: np.ndarray) -> np.ndarray:
    """0..1: how strongly a pixel sits on a depth edge (log-depth gradient)."""
    lz = np.log(z)
    g = np.hypot(ndimage.sobel(lz, 0), ndimage.sobel(lz, 1)) / 8.0
    return np.clip((g - 0.02) / 0.1, 0.0, 1.0)


def realistic_reconstruction(world, realism="plain", *, seed: int = 0,
                             clean: bool = False) -> tuple[Scene, np.ndarray]:
    """The stand-in prediction of ``world`` with the artifacts of ``realism``.

    Parameters
    ----------
    world : World
        From :func:`clearsplat.synth.make_world`.
    realism : str or sequence of str
        A scenario of :data:`SCENARIOS` or artifacts joined by ``+`` or ``,``.
    seed : int
        Seeds every artifact (and the depth noise).
    clean : bool
        Reconstruct the clean twin (same cameras, gains and errors, no transients).

    Returns
    -------
    scene : Scene
        Gaussians ordered by view; ``cameras`` are the (possibly estimated) cameras of the
        prediction and ``images`` the images the model saw (with the exposure gains).
    truth : (N,) bool
        Which Gaussians come from transient pixels (for ``coarse``, cells that are mostly
        transient); all False for the clean twin.
    """
    artifacts = parse_realism(realism)
    images = world.clean_images if clean else world.images
    depths = world.clean_depths if clean else world.depths
    soft, multi, coarse = "soft" in artifacts, "multi" in artifacts, "coarse" in artifacts
    rngs = [np.random.default_rng(s)
            for s in np.random.SeedSequence(int(seed)).spawn(len(world.cameras))]
    parts, cameras, inputs = [], [], []
    for i, cam in enumerate(world.cameras):
        image = np.asarray(images[i], dtype=np.float32)
        depth = np.asarray(depths[i], dtype=np.float64)
        transient = (np.zeros(depth.shape, bool) if clean
                     else np.asarray(world.transient_masks[i], dtype=bool))
        if "exposure" in artifacts:
            image = np.clip(image * _gain(seed, i).astype(np.float32), 0.0, 1.0)
        if "depth" in artifacts:
            z = _imperfect_depth(depth, rngs[i], blur=_DEPTH_BLUR, noise=_DEPTH_NOISE, cells=3)
            bias = _rng(seed, "depth", i).standard_normal()
            z = z * (1.0 + _DEPTH_SCALE_SD * float(np.clip(bias, -2.0, 2.0)))
        else:
            z = _imperfect_depth(depth, rngs[i], blur=0.7, noise=0.01, cells=4)
        given = estimated_camera(cam, depth, seed=seed, view=i) if "pose" in artifacts else cam
        cameras.append(given)
        inputs.append(image)
        parts.append(_view_gaussians(given, image, z, transient, seed=seed, view=i, soft=soft,
                                     multi=multi, coarse=coarse))
    means, scales, quats, opac, sh, view_id, pixel_id, truth = (
        np.concatenate(p) for p in zip(*parts))
    g = Gaussians(means=means, scales=scales, quats=quats, opacities=opac, sh=sh)
    return Scene(g, view_id=view_id, pixel_id=pixel_id, cameras=cameras, images=inputs), truth


def _view_gaussians(cam, image, z, transient, *, seed, view, soft, multi, coarse):
    """Gaussians of one view: (means, scales, quats, opacities, sh, view_id, pixel_id, truth)."""
    h, w = z.shape
    rng = _rng(seed, "soft", view)
    footprint = np.full((h, w), 0.6)
    opacity = np.full((h, w), 0.9)
    colour = image.astype(np.float64)
    if soft:
        colour = ndimage.gaussian_filter(colour, (1.0, 1.0, 0), mode="nearest")
        colour = colour + 0.045 * rng.standard_normal(colour.shape)
        footprint = footprint * rng.uniform(1.0, 1.6, (h, w))
        opacity = 0.35 + 0.65 * rng.beta(2.5, 1.2, (h, w))
        opacity = opacity * (1.0 - 0.5 * _depth_edges(z))
    if coarse:
        c = _COARSE
        hc, wc = h // c, w // c
        def pool(a):
            a = a[:hc * c, :wc * c]
            return a.reshape(hc, c, wc, c, *a.shape[2:]).mean(axis=(1, 3))
        zc = np.exp(pool(np.log(z)))
        colour, opacity, footprint = pool(colour), pool(opacity), pool(footprint) * c
        truth = (pool(transient.astype(np.float64)) >= 0.5).reshape(-1)
        # Cell centres: the camera with its pixel grid scaled by 1/c.
        K = cam.K.copy()
        K[:2] /= c
        grid = Camera(K=K, camera_to_world=cam.camera_to_world, width=wc, height=hc)
        means = grid.unproject(zc).reshape(-1, 3)
        zf, fx, fy = zc.reshape(-1), grid.fx, grid.fy
        footprint = footprint / c        # in cell units of the scaled camera
        pixel_id = np.full(hc * wc, -1, dtype=np.int64)
    else:
        means = cam.unproject(z).reshape(-1, 3)
        zf, fx, fy = z.reshape(-1), cam.fx, cam.fy
        truth = transient.reshape(-1)
        pixel_id = np.arange(h * w, dtype=np.int64)
    fp = footprint.reshape(-1)
    scales = np.stack([zf / fx * fp, zf / fy * fp, zf / np.sqrt(fx * fy) * fp * 0.1], axis=1)
    colour = np.clip(colour.reshape(-1, 3), 0.0, 1.0)
    opacity = np.clip(opacity.reshape(-1), 0.02, 1.0)
    m = len(means)
    k = 4 if soft else 1
    sh = np.zeros((m, k, 3), dtype=np.float32)
    sh[:, 0] = rgb_to_sh_dc(colour)
    if soft:  # a small view-dependent term (about 0.02 in colour)
        sh[:, 1:] = (0.02 / 0.4886 / np.sqrt(3)) * rng.standard_normal((m, 3, 3))
    quat = np.broadcast_to(rotation_to_quat(cam.camera_to_world[:3, :3]), (m, 4))
    if multi:
        centre = cam.position
        layers = []
        for offset in np.linspace(-_MULTI_SPREAD, _MULTI_SPREAD, _MULTI):
            layers.append(centre + (means - centre) * (1.0 + offset))
        means = np.concatenate(layers)
        scales = np.concatenate([scales * (1.0 + o) for o in
                                 np.linspace(-_MULTI_SPREAD, _MULTI_SPREAD, _MULTI)])
        # Three layers of opacity a' compound to the single Gaussian's a.
        opacity = np.tile(1.0 - (1.0 - opacity) ** (1.0 / _MULTI), _MULTI)
        sh = np.concatenate([sh] * _MULTI)
        quat = np.concatenate([quat] * _MULTI)
        pixel_id = np.tile(pixel_id, _MULTI)
        truth = np.tile(truth, _MULTI)
    n = len(means)
    return (means, scales, np.asarray(quat), opacity.astype(np.float32), sh,
            np.full(n, view, dtype=np.int32), pixel_id, truth)


def reproduction_psnr(scene: Scene) -> np.ndarray:
    """PSNR of each input image against the render of its own view's Gaussians, (V,)."""
    from ..metrics import psnr
    from ..render import render
    out = []
    for i, cam in enumerate(scene.cameras):
        r = render(scene, cam, keep=scene.view_id == i)
        out.append(psnr(r.rgb, scene.images[i]))
    return np.array(out)
