"""Procedural distractor worlds with analytic ground truth.

Two families imitate the paper's benchmarks:

``"object"`` (RobustNeRF-like)
    A cluster of static objects on a rug in a room, seen by inward-facing cameras on an
    arc (90 degrees by default, slightly above the objects). Every cluttered input view
    holds 1-3 small toys on the floor at places that change from view to view.
``"street"`` (NeRF On-the-go-like)
    Forward-facing cameras walking down a street (facades, sidewalks, parked car, lamp
    posts, trees, sky) with a little yaw. Passers-by 2-7 m away appear in a fraction of the
    input views; ``occlusion`` sets their number, size and distance.

Each input view's transients exist in that view only. The clean twin has the same cameras
and static scene without any transient. Test views sit halfway between consecutive input
cameras (pose parameters interpolated) and never contain transients. Everything is
ray cast analytically (:mod:`clearsplat.synth.raycast`), never rasterised, and is
deterministic from ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import Camera, look_at
from ..errors import ClearsplatError
from . import raycast as rc
from .textures import Texture, random_texture

__all__ = ["World", "make_world", "FAMILIES", "OCCLUSION_LEVELS", "TRANSIENT_MODES"]

FAMILIES = ("object", "street")
OCCLUSION_LEVELS = ("low", "medium", "high")
#: ``"shots"``: each view's transients exist in that view only (photos taken apart);
#: ``"video"`` (street): each passer-by stays for 2-5 consecutive views, walking 0.15-0.4 m
#: between them, as in the frames of a video.
TRANSIENT_MODES = ("shots", "video")
#: Video passers-by: consecutive views each stays for, and metres walked between two.
_VIDEO_STAY = (2, 5)
_VIDEO_STEP = (0.15, 0.4)

#: Passers-by per occlusion level: number range, distance range (m), size factor,
#: share of the input views that contain any.
_STREET_LEVELS = {
    "low": dict(count=(1, 1), distance=(4.5, 7.0), size=(0.9, 1.0), share=0.5),
    "medium": dict(count=(1, 2), distance=(3.0, 6.0), size=(0.95, 1.05), share=0.625),
    "high": dict(count=(2, 4), distance=(2.0, 4.5), size=(1.0, 1.1), share=0.75),
}
#: Toys per occlusion level in the object family: number range and size factor.
_OBJECT_LEVELS = {
    "low": dict(count=(1, 2), size=0.8),
    "medium": dict(count=(1, 3), size=1.0),
    "high": dict(count=(2, 3), size=1.3),
}


@dataclass(eq=False)
class World:
    """A synthetic capture with its ground truth.

    Attributes
    ----------
    family : str
        ``"object"`` or ``"street"``.
    seed : int
    occlusion : str
        ``"low"``, ``"medium"`` or ``"high"``.
    cameras : list of Camera
        The input cameras.
    images : list of (H, W, 3) float32
        The cluttered input images, RGB in [0, 1].
    clean_images : list of (H, W, 3) float32
        The same views without any transient.
    depths, clean_depths : list of (H, W) float32
        Camera-z depth of the first surface hit (cluttered / clean).
    transient_masks : list of (H, W) bool
        True where the first surface hit in the cluttered input is a transient.
    test_cameras : list of Camera
        Held-out views between consecutive input cameras.
    test_images : list of (H, W, 3) float32
        Static scene only.
    test_depths : list of (H, W) float32
    static : list of primitives
        The static scene.
    transients : list of list of primitives
        The transients of each input view (empty lists for views without any).
    params : dict
        Layout parameters (field of view, arc span or step, ...).
    """

    family: str
    seed: int
    occlusion: str
    cameras: list
    images: list
    clean_images: list
    depths: list
    clean_depths: list
    transient_masks: list
    test_cameras: list
    test_images: list
    test_depths: list
    static: list = field(repr=False)
    transients: list = field(repr=False)
    params: dict = field(default_factory=dict)

    @property
    def num_views(self) -> int:
        return len(self.cameras)

    @property
    def height(self) -> int:
        return self.cameras[0].height

    @property
    def width(self) -> int:
        return self.cameras[0].width

    def render(self, camera: Camera, *, view: int | None = None):
        """Ray cast the static scene (plus input ``view``'s transients) from ``camera``.

        Returns
        -------
        rgb : (H, W, 3) float32
        depth : (H, W) float32, camera z.
        transient : (H, W) bool, where a transient is the first hit.
        """
        extra = [] if view is None else self.transients[view]
        return _render(camera, self.static, extra)[0:3]


# ------------------------------------------------------------------------------------------
# public entry point


def make_world(family: str, *, num_views: int = 8, seed: int = 0, height: int = 256,
               width: int = 448, num_test_views: int = 3, occlusion: str = "medium",
               transients: str = "shots") -> World:
    """Build a synthetic world and ray cast all its views.

    Parameters
    ----------
    family : {"object", "street"}
    num_views : int
        Number of cluttered input views, at least 2 (the benchmark uses 4, 8, 16).
    seed : int
        Everything (layout, textures, cameras, transients) follows from it.
    height, width : int
        Image size in pixels (at least 16 each; multiples of 16 suit the backbones).
    num_test_views : int
        Held-out views, at least 1; halfway between consecutive input cameras.
    occlusion : {"low", "medium", "high"}
        How much the transients cover: their number, size and (street) distance.
    transients : {"shots", "video"}
        ``"shots"``: each input view's transients are its own. ``"video"`` (street family):
        each passer-by stays for 2-5 consecutive views, walking 0.15-0.4 m between them; a
        view's transients are then also in its neighbours' (:data:`TRANSIENT_MODES`).

    Returns
    -------
    World

    Examples
    --------
    >>> w = make_world("street", num_views=4, height=64, width=112)
    >>> len(w.images), w.images[0].shape, w.transient_masks[0].dtype
    (4, (64, 112, 3), dtype('bool'))
    """
    if family not in FAMILIES:
        raise ClearsplatError(f"unknown family {family!r}; expected one of {FAMILIES}",
                              field="family")
    if occlusion not in OCCLUSION_LEVELS:
        raise ClearsplatError(f"unknown occlusion level {occlusion!r}; expected one of "
                              f"{OCCLUSION_LEVELS}", field="occlusion")
    if transients not in TRANSIENT_MODES or (transients == "video" and family != "street"):
        raise ClearsplatError(f"unknown transients {transients!r} for the {family} family; "
                              "expected 'shots', or 'video' for the street family",
                              field="transients")
    for name, value, low in (("num_views", num_views, 2), ("num_test_views", num_test_views, 1),
                             ("height", height, 16), ("width", width, 16)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ClearsplatError(f"expected an integer >= {low}, got {value!r}", field=name)
    ss = np.random.SeedSequence([int(seed), FAMILIES.index(family)])
    layout_rng, camera_rng, transient_rng = (np.random.default_rng(s) for s in ss.spawn(3))
    if family == "object":
        return _object_world(layout_rng, camera_rng, transient_rng, seed=int(seed),
                             n=int(num_views), h=int(height), w=int(width),
                             n_test=int(num_test_views), occlusion=occlusion)
    return _street_world(layout_rng, camera_rng, transient_rng, seed=int(seed), n=int(num_views),
                         h=int(height), w=int(width), n_test=int(num_test_views),
                         occlusion=occlusion, video=transients == "video")


# ------------------------------------------------------------------------------------------
# cameras


def _intrinsics(h: int, w: int, hfov_deg: float) -> np.ndarray:
    f = 0.5 * w / np.tan(np.radians(hfov_deg) / 2)
    return np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])


def _test_positions(n: int, n_test: int) -> np.ndarray:
    """Fractional input-view indices of the test views: midpoints of spread-out gaps."""
    if n_test <= n - 1:
        gaps = np.unique(np.round(np.linspace(0, n - 2, n_test)).astype(int))
        if len(gaps) == n_test:
            return gaps + 0.5
    return (np.arange(n_test) + 0.5) / n_test * (n - 1)


def _interp(params: np.ndarray, s: float) -> np.ndarray:
    i = min(int(np.floor(s)), len(params) - 2)
    a = s - i
    return (1 - a) * params[i] + a * params[i + 1]


# ------------------------------------------------------------------------------------------
# rendering


def _render(camera: Camera, static, transients, clean_pass=None):
    """Ray cast one view. Returns rgb, depth, transient mask, clean rgb, clean depth, hits."""
    o, d = camera.pixel_rays()
    h, w = camera.height, camera.width
    d = d.reshape(-1, 3)
    pixel_angle = 1.0 / np.sqrt(camera.fx * camera.fy)
    if clean_pass is None:
        hits = rc.cast(static, o, d, camera=camera)
        rgb = rc.shade(static, hits, o, d, pixel_angle=pixel_angle)
    else:
        rgb, hits = clean_pass
    depth = hits.t.copy()
    mask = np.zeros(len(d), dtype=bool)
    out = rgb
    if transients:
        th = rc.cast(transients, o, d, camera=camera)
        mask = th.t < hits.t
        if mask.any():
            sub = rc.Hits(th.t[mask], th.index[mask], th.face[mask])
            out = rgb.copy()
            out[mask] = rc.shade(transients, sub, o, d[mask], pixel_angle=pixel_angle)
            depth = np.where(mask, th.t, hits.t)
    if not np.isfinite(depth).all():  # every world is closed; a miss is a layout bug
        raise RuntimeError("a ray escaped the synthetic world")
    img = out.reshape(h, w, 3).astype(np.float32)
    return (img, depth.reshape(h, w).astype(np.float32), mask.reshape(h, w),
            rgb.reshape(h, w, 3).astype(np.float32),
            hits.t.reshape(h, w).astype(np.float32), (rgb, hits))


def _assemble(family, seed, occlusion, cameras, test_cameras, static, place, params):
    """Render every view; ``place(i, camera, clean_hits)`` returns view i's transients."""
    images, clean_images, depths, clean_depths, masks, transients = [], [], [], [], [], []
    for i, cam in enumerate(cameras):
        _, _, _, crgb, cdepth, clean = _render(cam, static, [])
        prims = place(i, cam, clean[1])
        rgb, depth, mask = _render(cam, static, prims, clean_pass=clean)[:3]
        images.append(rgb)
        depths.append(depth)
        masks.append(mask)
        clean_images.append(crgb)
        clean_depths.append(cdepth)
        transients.append(prims)
    test_images, test_depths = [], []
    for cam in test_cameras:
        rgb, depth = _render(cam, static, [])[:2]
        test_images.append(rgb)
        test_depths.append(depth)
    return World(family=family, seed=seed, occlusion=occlusion, cameras=cameras, images=images,
                 clean_images=clean_images, depths=depths, clean_depths=clean_depths,
                 transient_masks=masks, test_cameras=test_cameras, test_images=test_images,
                 test_depths=test_depths, static=static, transients=transients, params=params)


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _free(xy, r, footprints, margin=0.03) -> bool:
    return all(np.hypot(xy[0] - fx, xy[1] - fy) > r + fr + margin for fx, fy, fr in footprints)


# ------------------------------------------------------------------------------------------
# object family


def _object_world(rng, cam_rng, tr_rng, *, seed, n, h, w, n_test, occlusion) -> World:
    static = [
        rc.Box(random_texture(rng, scale=3.0, saturation=(0.1, 0.35), value=(0.55, 0.85)),
               center=(0, 0, 2.45), half=(6.0, 6.0, 2.5), inside=True, name="room"),
        rc.Plane(random_texture(rng, scale=2.0, saturation=(0.1, 0.4), value=(0.35, 0.6)),
                 point=(0, 0, 0), normal=(0, 0, 1), half_size=(5.9, 5.9), name="floor"),
        rc.Plane(random_texture(rng, scale=0.8, saturation=(0.3, 0.7), value=(0.45, 0.8)),
                 point=(0, 0, 0.002), normal=(0, 0, 1), axis_u=(np.cos(0.3), np.sin(0.3), 0),
                 half_size=(1.3, 1.3), name="rug"),
    ]
    floors = (1, 2)
    footprints = []
    for k in range(int(rng.integers(4, 7))):
        for _ in range(100):
            r = rng.uniform(0.12, 0.25)
            xy = rng.uniform(-0.75, 0.75, size=2)
            if np.hypot(*xy) < 0.85 and _free(xy, r, footprints, margin=0.08):
                break
        footprints.append((xy[0], xy[1], r))
        static.append(_solid(rng, xy, r, kind=k % 3, tall=rng.uniform(0.8, 2.6),
                             tex=random_texture(rng, scale=2 * r), name=f"object{k}"))
    hfov = 60.0
    span = np.radians(90.0)
    a0 = cam_rng.uniform(0, 2 * np.pi)
    s = np.linspace(-0.5, 0.5, n)
    pose = np.stack([a0 + span * s, 2.4 + cam_rng.normal(0, 0.05, n),
                     1.0 + cam_rng.normal(0, 0.04, n),
                     cam_rng.normal(0, 0.03, n), cam_rng.normal(0, 0.03, n)], axis=1)
    K = _intrinsics(h, w, hfov)

    def camera(p):
        a, radius, height, tx, ty = p
        c2w = look_at((radius * np.cos(a), radius * np.sin(a), height), (tx, ty, 0.18))
        return Camera(K=K, camera_to_world=c2w, width=w, height=h)

    cameras = [camera(p) for p in pose]
    test_cameras = [camera(_interp(pose, t)) for t in _test_positions(n, n_test)]
    level = _OBJECT_LEVELS[occlusion]

    def place(i, cam, hits):
        o, d = cam.pixel_rays()
        rows, cols = np.divmod(np.arange(h * w), w)
        x = o + d.reshape(-1, 3) * np.where(np.isfinite(hits.t), hits.t, 0)[:, None]
        ok = (np.isin(hits.index, floors) & (np.hypot(x[:, 0], x[:, 1]) < 1.25)
              & (rows > 0.25 * h) & (rows < 0.95 * h) & (cols > 0.08 * w) & (cols < 0.92 * w))
        cand = np.flatnonzero(ok)
        toys, taken = [], list(footprints)
        for k in range(int(tr_rng.integers(level["count"][0], level["count"][1] + 1))):
            r = tr_rng.uniform(0.05, 0.1) * level["size"]
            for _ in range(200):
                if not len(cand):
                    break
                xy = x[cand[tr_rng.integers(len(cand))], :2]
                if _free(xy, r, taken):
                    break
            else:
                continue
            taken.append((xy[0], xy[1], r))
            tex = random_texture(tr_rng, scale=3 * r, saturation=(0.7, 1.0), value=(0.7, 1.0))
            toys.append(_solid(tr_rng, xy, r, kind=int(tr_rng.integers(3)),
                               tall=tr_rng.uniform(1.0, 2.5), tex=tex, name=f"toy{i}.{k}"))
        return toys

    return _assemble("object", seed, occlusion, cameras, test_cameras, static, place,
                     dict(hfov_deg=hfov, arc_deg=90.0, radius=2.4))


def _solid(rng, xy, r, *, kind, tall, tex, name):
    """A box, sphere or cylinder of footprint radius ``r`` standing on the floor at ``xy``."""
    if kind == 0:
        half = np.array([r / np.sqrt(2), r / np.sqrt(2) * rng.uniform(0.6, 1.0), r * tall / 2])
        return rc.Box(tex, center=(xy[0], xy[1], half[2]), half=tuple(half),
                      rotation=_rot_z(rng.uniform(0, np.pi)), name=name)
    if kind == 1:
        return rc.Sphere(tex, center=(xy[0], xy[1], r), radius=r,
                         rotation=_rot_z(rng.uniform(0, 2 * np.pi)), name=name)
    return rc.Cylinder(tex, base=(xy[0], xy[1], 0.0), radius=r * 0.9, height=r * tall,
                       rotation=_rot_z(rng.uniform(0, 2 * np.pi)), name=name)


# ------------------------------------------------------------------------------------------
# street family


def _street_world(rng, cam_rng, tr_rng, *, seed, n, h, w, n_test, occlusion,
                  video: bool = False) -> World:
    road, walk_out = 3.2, 5.5
    sky = Texture(base=(0.45, 0.62, 0.88), alt=(0.93, 0.95, 0.98), noise_period=40.0,
                  noise_weight=0.9, grain_weight=0.0, seed=int(rng.integers(2**31 - 1)))
    static = [
        rc.Sphere(sky, center=(0, 30, 0), radius=300.0, inside=True, emissive=True, name="sky"),
        rc.Plane(random_texture(rng, scale=2.0, saturation=(0.0, 0.12), value=(0.3, 0.45)),
                 point=(0, 0, 0), normal=(0, 0, 1), name="road"),
    ]
    footprints = []  # (x, y, r) of everything standing on the street
    for side in (-1, 1):
        static.append(rc.Box(random_texture(rng, scale=1.5, saturation=(0.05, 0.3),
                                            value=(0.5, 0.75)),
                             center=(side * (road + walk_out) / 2, 30, 0.06),
                             half=((walk_out - road) / 2, 55, 0.06), name="sidewalk"))
        y = -25.0
        while y < 85:
            length = rng.uniform(6, 14)
            height = rng.uniform(5, 16)
            tex = random_texture(rng, scale=6.0, saturation=(0.1, 0.5), value=(0.45, 0.85))
            tex = replace(tex, checker_period=rng.uniform(1.2, 2.0),
                          checker_weight=rng.uniform(0.6, 0.9))
            static.append(rc.Box(tex, center=(side * (walk_out + 3), y + length / 2, height / 2),
                                 half=(3.0, length / 2 - 0.05, height / 2), name="building"))
            y += length
        for y in np.arange(rng.uniform(2, 8), 60, rng.uniform(8, 11)):
            x = side * rng.uniform(3.5, 3.8)
            static.append(rc.Cylinder(Texture(base=(0.2, 0.22, 0.25), alt=(0.35, 0.36, 0.4),
                                              stripe_period=0.3, stripe_weight=0.4),
                                      base=(x, y, 0.12), radius=0.07, height=4.3, name="lamp"))
            static.append(rc.Sphere(Texture(base=(0.95, 0.9, 0.7), alt=(1.0, 1.0, 0.9)),
                                    center=(x, y, 4.55), radius=0.16, name="lamp"))
            footprints.append((x, y, 0.1))
        for y in np.arange(rng.uniform(4, 12), 60, rng.uniform(12, 18)):
            x = side * rng.uniform(4.6, 4.9)
            if not _free((x, y), 0.2, footprints, margin=1.0):
                continue
            static.append(rc.Cylinder(Texture(base=(0.3, 0.2, 0.12), alt=(0.45, 0.33, 0.2),
                                              noise_period=0.1, seed=int(rng.integers(1000))),
                                      base=(x, y, 0.12), radius=0.16, height=2.6, name="trunk"))
            static.append(rc.Sphere(random_texture(rng, scale=1.5, hue=rng.uniform(0.2, 0.4),
                                                   saturation=(0.4, 0.7), value=(0.3, 0.6)),
                                    center=(x, y, 3.4), radius=rng.uniform(1.0, 1.3),
                                    name="crown"))
            footprints.append((x, y, 0.2))
    for k in range(2):  # parked cars at the kerb
        side = 1 if k == 0 else -1
        y = rng.uniform(8, 25) + 15 * k
        tex = random_texture(rng, scale=2.0, saturation=(0.5, 0.9), value=(0.4, 0.8))
        static.append(rc.Box(tex, center=(side * 2.3, y, 0.75), half=(0.85, 2.1, 0.6),
                             name="car"))
        static.append(rc.Box(Texture(base=(0.15, 0.18, 0.22), alt=(0.4, 0.45, 0.5),
                                     stripe_period=0.4, stripe_weight=0.5, noise_weight=0.3),
                             center=(side * 2.3, y - 0.2, 1.55), half=(0.75, 1.1, 0.25),
                             name="car"))
        footprints.append((side * 2.3, y, 2.2))
    static.append(rc.Box(random_texture(rng, scale=6.0, saturation=(0.1, 0.4), value=(0.5, 0.8)),
                         center=(0, 88, 9), half=(14, 3, 9), name="end building"))

    hfov = 70.0
    step = 0.35
    x0 = cam_rng.uniform(-1.0, 1.0)
    phase = cam_rng.uniform(0, 2 * np.pi)
    i = np.arange(n)
    yaw = np.radians(8.0) * np.sin(phase + 0.6 * i) + cam_rng.normal(0, np.radians(1.5), n)
    pose = np.stack([x0 + cam_rng.normal(0, 0.08, n), i * step + cam_rng.normal(0, 0.05, n),
                     1.6 + cam_rng.normal(0, 0.03, n), yaw,
                     np.radians(-4.0) + cam_rng.normal(0, np.radians(1.0), n)], axis=1)
    K = _intrinsics(h, w, hfov)

    def camera(p):
        x, y, z, yw, pitch = p
        fwd = np.array([np.sin(yw) * np.cos(pitch), np.cos(yw) * np.cos(pitch), np.sin(pitch)])
        return Camera(K=K, camera_to_world=look_at((x, y, z), (x, y, z) + fwd),
                      width=w, height=h)

    cameras = [camera(p) for p in pose]
    test_cameras = [camera(_interp(pose, t)) for t in _test_positions(n, n_test)]
    level = _STREET_LEVELS[occlusion]
    n_busy = min(n, max(1, int(round(level["share"] * n))))
    busy = set(tr_rng.choice(n, size=n_busy, replace=False).tolist())

    def spots(i, taken, person=None):
        """Where view i's new passers-by stand: (xy, size) each, in front of camera i; with
        ``person``, the parts of ``person(xy, size, k)`` for each, drawn as it is found."""
        out = []
        for k in range(int(tr_rng.integers(level["count"][0], level["count"][1] + 1))):
            size = tr_rng.uniform(*level["size"])
            for _ in range(200):
                dist = tr_rng.uniform(*level["distance"])
                ang = pose[i, 3] + tr_rng.uniform(-0.75, 0.75) * np.radians(hfov / 2)
                xy = pose[i, :2] + dist * np.array([np.sin(ang), np.cos(ang)])
                if abs(xy[0]) < road + 1.5 and _free(xy, 0.3 * size, taken, margin=0.3):
                    break
            else:
                continue
            taken.append((xy[0], xy[1], 0.3 * size))
            out += [(xy, size)] if person is None else person(xy, size, k)
        return out

    tracks = []     # video: (first view, views, start xy, step per view (2,), size, seed)
    if video:
        for i in sorted(busy):
            if any(t[0] <= i < t[0] + t[1] for t in tracks):
                continue        # someone from an earlier view is still here
            for xy, size in spots(i, list(footprints)):
                heading = tr_rng.uniform(0, 2 * np.pi)
                step = tr_rng.uniform(*_VIDEO_STEP) * np.array([np.cos(heading), np.sin(heading)])
                tracks.append((i, int(tr_rng.integers(_VIDEO_STAY[0], _VIDEO_STAY[1] + 1)), xy,
                               step, size, int(tr_rng.integers(2**31 - 1))))

    def place(i, cam, hits):
        if video:   # the same person (same draw of its look) a step further in each view
            return [part for k, (first, stay, xy, step, size, s) in enumerate(tracks)
                    if first <= i < first + stay
                    for part in _person(np.random.default_rng(s), xy + (i - first) * step,
                                        size, name=f"person{k}")]
        if i not in busy:
            return []
        return spots(i, list(footprints),
                     lambda xy, size, k: _person(tr_rng, xy, size, name=f"person{i}.{k}"))

    return _assemble("street", seed, occlusion, cameras, test_cameras, static, place,
                     dict(hfov_deg=hfov, step=step, busy_views=sorted(busy)))


def _person(rng, xy, s, *, name):
    """A passer-by (legs, arms, torso, head) standing at ``xy``, about 1.7 * s m tall."""
    R = _rot_z(rng.uniform(0, 2 * np.pi))
    shirt = random_texture(rng, scale=0.6, saturation=(0.5, 1.0), value=(0.5, 0.95))
    trousers = random_texture(rng, scale=0.5, saturation=(0.1, 0.6), value=(0.15, 0.45))
    skin = Texture(base=tuple(rng.uniform([0.45, 0.3, 0.2], [0.95, 0.75, 0.6])),
                   alt=(0.25, 0.17, 0.1), noise_period=0.08, noise_weight=0.3,
                   seed=int(rng.integers(1000)))
    base = np.array([xy[0], xy[1], 0.0])

    def at(local):
        return tuple(base + R @ (np.asarray(local) * s))

    parts = []
    for side in (-1, 1):
        parts.append(rc.Cylinder(trousers, base=at((side * 0.1, 0, 0)), radius=0.075 * s,
                                 height=0.86 * s, rotation=R, name=name))
        parts.append(rc.Cylinder(shirt, base=at((side * 0.28, 0, 0.78)), radius=0.055 * s,
                                 height=0.66 * s, rotation=R, name=name))
    parts.append(rc.Box(shirt, center=at((0, 0, 1.17)), half=(0.22 * s, 0.13 * s, 0.32 * s),
                        rotation=R, name=name))
    parts.append(rc.Sphere(skin, center=at((0, 0, 1.61)), radius=0.11 * s, rotation=R,
                           name=name))
    return parts
