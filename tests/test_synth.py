"""Synthetic worlds, analytic ray casting and the stand-in backbone."""

import numpy as np
import pytest

from clearsplat import Camera, ClearsplatError
from clearsplat.synth import raycast as rc
from clearsplat.synth.backbone import (clean_reference, distractor_truth, reconstruct,
                                       rotation_to_quat)
from clearsplat.synth.textures import Texture, value_noise
from clearsplat.cameras import look_at
from clearsplat.synth.worlds import make_world

H, W = 64, 112
FAMILIES = ("object", "street")


@pytest.fixture(scope="module")
def worlds():
    return {f: make_world(f, num_views=4, seed=3, height=H, width=W) for f in FAMILIES}


def _arrays(world):
    return (world.images + world.clean_images + world.depths + world.clean_depths
            + world.transient_masks + world.test_images + world.test_depths)


# -- shapes and determinism ----------------------------------------------------------------

@pytest.mark.parametrize("family", FAMILIES)
def test_shapes_and_dtypes(worlds, family):
    w = worlds[family]
    assert w.family == family and w.num_views == 4 and len(w.test_cameras) == 3
    for im in w.images + w.clean_images + w.test_images:
        assert im.shape == (H, W, 3) and im.dtype == np.float32
        assert im.min() >= 0 and im.max() <= 1
    for d in w.depths + w.clean_depths + w.test_depths:
        assert d.shape == (H, W) and d.dtype == np.float32 and (d > 0).all()
    for m in w.transient_masks:
        assert m.shape == (H, W) and m.dtype == bool
    for cam in w.cameras + w.test_cameras:
        assert (cam.height, cam.width) == (H, W)


@pytest.mark.parametrize("family", FAMILIES)
def test_same_seed_same_world_other_seed_differs(worlds, family):
    again = make_world(family, num_views=4, seed=3, height=H, width=W)
    for a, b in zip(_arrays(worlds[family]), _arrays(again)):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(worlds[family].cameras, again.cameras):
        assert a == b
    other = make_world(family, num_views=4, seed=4, height=H, width=W)
    assert not np.array_equal(worlds[family].clean_images[0], other.clean_images[0])
    assert worlds[family].cameras[0] != other.cameras[0]


@pytest.mark.parametrize("n", [2, 4, 8, 16])
def test_view_counts(n):
    w = make_world("object", num_views=n, seed=0, height=16, width=32, num_test_views=3)
    assert len(w.cameras) == len(w.images) == len(w.transient_masks) == n
    assert len(w.test_cameras) == len(w.test_images) == 3


@pytest.mark.parametrize("kwargs, field", [
    (dict(family="forest"), "family"), (dict(occlusion="extreme"), "occlusion"),
    (dict(num_views=1), "num_views"), (dict(num_views=2.5), "num_views"),
    (dict(num_test_views=0), "num_test_views"), (dict(height=8), "height"),
    (dict(width=True), "width")])
def test_bad_arguments(kwargs, field):
    args = dict(family="object", num_views=2, height=16, width=16)
    args.update(kwargs)
    family = args.pop("family")
    with pytest.raises(ClearsplatError) as err:
        make_world(family, **args)
    assert err.value.field == field


# -- ground truth ----------------------------------------------------------------------------

@pytest.mark.parametrize("family", FAMILIES)
def test_clean_twin_differs_only_on_transients(worlds, family):
    w = worlds[family]
    for img, clean, d, cd, m in zip(w.images, w.clean_images, w.depths, w.clean_depths,
                                    w.transient_masks):
        np.testing.assert_array_equal(img[~m], clean[~m])
        np.testing.assert_array_equal(d[~m], cd[~m])
        assert (d[m] < cd[m]).all()  # a transient is the first hit, in front of the scene
        if m.any():
            assert np.abs(img[m] - clean[m]).max(axis=1).mean() > 0.05


@pytest.mark.parametrize("family", FAMILIES)
def test_transients_change_from_view_to_view(worlds, family):
    w = worlds[family]
    busy = [i for i, m in enumerate(w.transient_masks) if m.any()]
    assert len(busy) >= 2
    for i in busy:
        assert w.transients[i]
        for j in busy:
            if i < j:
                assert not np.array_equal(w.transient_masks[i], w.transient_masks[j])
    # view i's transients are absent from every other view j: where they would be the
    # first hit from camera j (and j has none of its own), view j shows the static scene
    checked = 0
    for i in busy:
        for j in range(w.num_views):
            if j == i:
                continue
            _, _, foreign = w.render(w.cameras[j], view=i)
            there = foreign & ~w.transient_masks[j]
            np.testing.assert_array_equal(w.images[j][there], w.clean_images[j][there])
            checked += int(there.sum())
    assert checked > 0


def test_object_family_has_toys_in_every_view(worlds):
    w = worlds["object"]
    for i, m in enumerate(w.transient_masks):
        assert 1 <= len({p.name for p in w.transients[i]}) <= 3
        assert 0 < m.mean() < 0.2


def test_street_share_of_views_with_passers_by():
    for occlusion, share in (("low", 0.5), ("medium", 0.625), ("high", 0.75)):
        w = make_world("street", num_views=8, seed=1, height=32, width=48, occlusion=occlusion)
        assert sum(bool(t) for t in w.transients) == round(share * 8)
        assert w.params["busy_views"] == [i for i, t in enumerate(w.transients) if t]


def test_occlusion_levels_cover_more():
    cover = {}
    for occlusion in ("low", "medium", "high"):
        masks = []
        for seed in range(3):
            w = make_world("street", num_views=8, seed=seed, height=32, width=56,
                           occlusion=occlusion)
            masks += w.transient_masks
        cover[occlusion] = np.mean(masks)
    assert cover["low"] < cover["medium"] < cover["high"]
    assert cover["high"] > 2 * cover["low"]


@pytest.mark.parametrize("family", FAMILIES)
def test_stored_views_match_a_fresh_cast(worlds, family):
    w = worlds[family]
    rgb, depth, mask = w.render(w.cameras[1], view=1)
    np.testing.assert_array_equal(rgb, w.images[1])
    np.testing.assert_array_equal(depth, w.depths[1])
    np.testing.assert_array_equal(mask, w.transient_masks[1])
    rgb, depth, mask = w.render(w.test_cameras[0])
    np.testing.assert_array_equal(rgb, w.test_images[0])
    np.testing.assert_array_equal(depth, w.test_depths[0])
    assert not mask.any()


@pytest.mark.parametrize("family", FAMILIES)
def test_test_views_lie_between_inputs_and_see_what_they_see(worlds, family):
    w = worlds[family]
    positions = np.stack([c.position for c in w.cameras])
    spacing = np.linalg.norm(np.diff(positions, axis=0), axis=1).max()
    for cam, depth in zip(w.test_cameras, w.test_depths):
        gaps = np.linalg.norm(positions - cam.position, axis=1)
        assert np.sort(gaps)[1] <= spacing  # between two neighbouring inputs
        points = cam.unproject(depth).reshape(-1, 3)
        seen = np.zeros(len(points), dtype=bool)
        for icam, idepth in zip(w.cameras, w.clean_depths):
            uv, z = icam.project(points)
            inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
            col = np.clip(np.nan_to_num(uv[:, 0]), 0, W - 1).astype(int)
            row = np.clip(np.nan_to_num(uv[:, 1]), 0, H - 1).astype(int)
            # unoccluded when the input's own first hit is at (nearly) the same depth
            seen |= inside & (np.abs(idepth[row, col] - z) < 0.03 * z)
        assert seen.mean() > 0.9


# -- analytic ray casting ----------------------------------------------------------------------

def rc_rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


TEX = Texture(base=(0.5, 0.5, 0.5), alt=(0.5, 0.5, 0.5))


@pytest.mark.parametrize("prim, origin, expected", [
    (rc.Sphere(TEX, radius=1.0), (0, -5, 0), 4.0),
    (rc.Sphere(TEX, center=(0, 0, 0.6), radius=1.0), (0, -5, 0), 5 - 0.8),
    (rc.Sphere(TEX, radius=10.0, inside=True), (0, -5, 0), 15.0),
    (rc.Plane(TEX, point=(0, 2, 0), normal=(0, -1, 0)), (0, -5, 0), 7.0),
    (rc.Plane(TEX, point=(0, 2, 0), normal=(0, 1, 0), half_size=(0.1, 0.1)), (0, -5, 0), 7.0),
    (rc.Plane(TEX, point=(0.2, 2, 0), normal=(0, 1, 0), half_size=(0.1, 0.1)), (0, -5, 0),
     np.inf),
    (rc.Box(TEX, half=(1, 0.5, 1)), (0, -5, 0), 4.5),
    (rc.Box(TEX, half=(0.5, 0.5, 1), rotation=rc_rot_z(np.pi / 4)), (0, -5, 0),
     5 - 0.5 * np.sqrt(2)),
    (rc.Box(TEX, half=(8, 8, 8), inside=True), (0, -5, 0), 13.0),
    (rc.Box(TEX, center=(0, 0, 3), half=(1, 1, 1)), (0, -5, 0), np.inf),
    (rc.Cylinder(TEX, base=(0, 0, -1), radius=0.5, height=2.0), (0, -5, 0), 4.5),
    (rc.Cylinder(TEX, base=(0, 0, -1), radius=0.5, height=0.9), (0, -5, 0), np.inf),
    (rc.Cylinder(TEX, base=(0, 6, 0), radius=0.5, height=2.0,
                 rotation=np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])), (0, -5, 0), 9.0),
])
def test_primitives_against_closed_forms(prim, origin, expected):
    # the ray (0, 1, 0) from origin, and the same ray with a direction twice as long: the
    # hit parameter is in units of the direction's length (camera depth for pixel rays)
    d = np.array([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]])
    t, _ = prim.intersect(np.asarray(origin, dtype=np.float64), d)
    np.testing.assert_allclose(t, [expected, expected / 2], rtol=1e-12)


def test_cylinder_cap_and_normals():
    cyl = rc.Cylinder(TEX, base=(0, 0, -1), radius=0.5, height=2.0)
    t, face = cyl.intersect(np.array([0.1, 0.0, 6.0]), np.array([[0.0, 0.0, -1.0]]))
    assert t[0] == pytest.approx(5.0) and face[0] == 2
    n, _ = cyl.surface(np.array([[0.1, 0.0, 1.0]]), face)
    np.testing.assert_allclose(n, [[0, 0, 1]])
    t, face = cyl.intersect(np.array([0.0, -5.0, 0.0]), np.array([[0.0, 1.0, 0.0]]))
    n, _ = cyl.surface(np.array([[0.0, -0.5, 0.0]]), face)
    np.testing.assert_allclose(n, [[0, -1, 0]], atol=1e-12)
    box = rc.Box(TEX, half=(8, 8, 8), inside=True)
    t, face = box.intersect(np.zeros(3), np.array([[0.0, 0.0, -1.0]]))
    n, _ = box.surface(np.array([[0.0, 0.0, -8.0]]), face)
    np.testing.assert_allclose(n, [[0, 0, 1]])  # a room's floor faces up, into the room


def test_ray_sphere_hits_lie_on_the_surface():
    rng = np.random.default_rng(0)
    tex = Texture(base=(0.5, 0.5, 0.5), alt=(0.5, 0.5, 0.5))
    prims = [rc.Sphere(tex, center=(0.3, 0.1, -0.2), radius=0.8),
             rc.Cylinder(tex, base=(0.1, 0.0, -0.5), radius=0.6, height=1.0,
                         rotation=rc_rot_z(0.3)),
             rc.Box(tex, center=(0.0, 0.2, 0.1), half=(0.4, 0.6, 0.5), rotation=rc_rot_z(0.7))]
    o = np.array([0.2, -4.0, 0.3])
    d = rng.normal(size=(2000, 3)) * 0.15 + [0, 1, 0]
    for prim in prims:
        t, face = prim.intersect(o, d)
        hit = np.isfinite(t)
        assert 0.2 < hit.mean() < 1.0
        x = o + d[hit] * t[hit, None]
        if isinstance(prim, rc.Sphere):
            np.testing.assert_allclose(np.linalg.norm(x - prim._c, axis=1), 0.8, atol=1e-9)
        elif isinstance(prim, rc.Cylinder):
            local = (x - prim._b) @ prim._R
            side = face[hit] == 0
            np.testing.assert_allclose(np.hypot(local[side, 0], local[side, 1]), 0.6, atol=1e-9)
            np.testing.assert_allclose(local[~side, 2] * (local[~side, 2] - 1.0), 0, atol=1e-9)
        else:
            local = (x - prim._c) @ prim._R
            assert np.allclose(np.max(np.abs(local) / prim._h, axis=1), 1.0, atol=1e-9)
        # no hit in front: a point halfway to the hit is outside the solid
        mid = o + d[hit] * (0.5 * t[hit, None])
        if isinstance(prim, rc.Sphere):
            assert (np.linalg.norm(mid - prim._c, axis=1) > 0.8).all()


@pytest.mark.parametrize("family", FAMILIES)
def test_screen_culling_changes_nothing(worlds, family):
    w = worlds[family]
    for cam in (w.cameras[0], w.test_cameras[-1]):
        o, d = cam.pixel_rays()
        d = d.reshape(-1, 3)
        full = rc.cast(w.static, o, d)
        culled = rc.cast(w.static, o, d, camera=cam)
        np.testing.assert_array_equal(full.t, culled.t)
        np.testing.assert_array_equal(full.index, culled.index)
        np.testing.assert_array_equal(full.face, culled.face)


def test_value_noise_is_smooth_and_seeded():
    x = np.linspace(0, 4, 401)
    a = value_noise(x, np.full_like(x, 0.3), 1)
    assert a.min() >= 0 and a.max() <= 1
    assert np.abs(np.diff(a)).max() < 0.05  # continuous
    np.testing.assert_array_equal(a, value_noise(x, np.full_like(x, 0.3), 1))
    assert not np.array_equal(a, value_noise(x, np.full_like(x, 0.3), 2))
    # integer shifts of the lattice give other values (no short period)
    zero = np.zeros_like(x)
    assert not np.allclose(value_noise(x, zero, 1), value_noise(x + 1, zero, 1))


def test_look_at_uses_opencv_axes():
    c2w = look_at((0, -5, 0), (0, 0, 0))
    np.testing.assert_allclose(c2w[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    cam = Camera(K=[[50, 0, 32], [0, 50, 24], [0, 0, 1]], camera_to_world=c2w, width=64,
                 height=48)
    uv, z = cam.project(np.array([[0, 0, 1.0], [1.0, 0, 0]]))
    assert z[0] == pytest.approx(5.0)
    assert uv[0, 1] < 24 and uv[0, 0] == pytest.approx(32)  # up in the world is up in the image
    assert uv[1, 0] > 32  # +x is on the right when looking along +y with z up


# -- stand-in backbone -------------------------------------------------------------------------

def _quat_to_matrix(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_rotation_to_quat_round_trips():
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = rng.normal(size=4)
        R = _quat_to_matrix(q)
        got = rotation_to_quat(R)
        np.testing.assert_allclose(_quat_to_matrix(got), R, atol=1e-12)
        assert got[0] >= 0
    for R in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]), np.eye(3)):
        np.testing.assert_allclose(_quat_to_matrix(rotation_to_quat(R)), R, atol=1e-12)


@pytest.mark.parametrize("family", FAMILIES)
def test_backbone_layout(worlds, family):
    w = worlds[family]
    s = reconstruct(w.cameras, w.images, w.depths, seed=0)
    s.validate()
    n = 4 * H * W
    assert len(s) == n and s.is_pixel_aligned
    np.testing.assert_array_equal(s.view_id, np.repeat(np.arange(4), H * W))
    np.testing.assert_array_equal(s.pixel_id, np.tile(np.arange(H * W), 4))
    assert all(a is b or np.array_equal(a, b) for a, b in zip(s.images, w.images))
    np.testing.assert_allclose(s.gaussians.opacities, 0.9)
    # colour: the DC term renders the pixel colour
    rgb = 0.28209479177387814 * s.gaussians.sh[:, 0] + 0.5
    np.testing.assert_allclose(rgb, np.concatenate([im.reshape(-1, 3) for im in w.images]),
                               atol=1e-6)
    for i, cam in enumerate(w.cameras):
        v = s.view_id == i
        # flat discs facing the camera: local axes are the camera axes
        R = _quat_to_matrix(s.gaussians.quats[v][0].astype(np.float64))
        np.testing.assert_allclose(R, cam.camera_to_world[:3, :3], atol=1e-6)
        z = cam.to_camera(s.gaussians.means[v])[:, 2]
        sc = s.gaussians.scales[v]
        np.testing.assert_allclose(sc[:, 0], z / cam.fx * 0.6, rtol=1e-4)
        np.testing.assert_allclose(sc[:, 2], 0.1 * sc[:, 0], rtol=1e-4)
        # on the pixel ray, at a depth within a few percent of the truth away from edges
        uv, _ = cam.project(s.gaussians.means[v])
        rows, cols = np.divmod(s.pixel_id[v], W)
        np.testing.assert_allclose(uv, np.stack([cols + 0.5, rows + 0.5], axis=1), atol=1e-3)
        rel = z / w.depths[i].reshape(-1) - 1
        assert np.median(np.abs(rel)) < 0.03 and np.median(np.abs(rel)) > 1e-4


def test_backbone_exact_without_imperfections(worlds):
    w = worlds["object"]
    s = reconstruct(w.cameras, w.images, w.depths, depth_blur=0, depth_noise=0)
    for i, cam in enumerate(w.cameras):
        expected = cam.unproject(w.depths[i]).reshape(-1, 3)
        np.testing.assert_allclose(s.gaussians.means[s.view_id == i], expected, rtol=1e-6,
                                   atol=1e-6)


def test_backbone_depth_smoothing_makes_flying_pixels(worlds):
    w = worlds["object"]
    s = reconstruct(w.cameras, w.images, w.depths, depth_noise=0, depth_blur=1.0)
    cam = w.cameras[0]
    z = cam.to_camera(s.gaussians.means[s.view_id == 0])[:, 2].reshape(H, W)
    d = w.depths[0].astype(np.float64)
    edge = np.zeros_like(d, dtype=bool)
    edge[:, 1:] |= np.abs(np.diff(d, axis=1)) > 0.2 * d[:, 1:]
    flat = ~edge & (np.abs(np.gradient(d)[0]) < 0.01 * d)
    assert np.median(np.abs(z[edge] / d[edge] - 1)) > 0.05  # between the two surfaces
    assert np.median(np.abs(z[flat] / d[flat] - 1)) < 0.002


def test_backbone_seeded():
    w = make_world("object", num_views=2, seed=0, height=16, width=32)
    a = reconstruct(w.cameras, w.images, w.depths, seed=5)
    b = reconstruct(w.cameras, w.images, w.depths, seed=5)
    c = reconstruct(w.cameras, w.images, w.depths, seed=6)
    np.testing.assert_array_equal(a.gaussians.means, b.gaussians.means)
    assert not np.array_equal(a.gaussians.means, c.gaussians.means)


def test_clean_reference_and_truth(worlds):
    w = worlds["street"]
    s = reconstruct(w.cameras, w.images, w.depths, seed=2)
    c = clean_reference(w, seed=2)
    truth = distractor_truth(s, w)
    assert truth.dtype == bool and truth.shape == (len(s),)
    np.testing.assert_array_equal(truth, np.concatenate([m.ravel() for m in w.transient_masks]))
    # same seed: the two predictions agree away from the transients (and the blur around them)
    near = np.concatenate([_dilate(m, 4).ravel() for m in w.transient_masks])
    np.testing.assert_array_equal(s.gaussians.means[~near], c.gaussians.means[~near])
    assert not np.array_equal(s.gaussians.means[truth], c.gaussians.means[truth])
    # a subset keeps its own view/pixel ids
    sub = s.subset(np.flatnonzero(truth)[::3])
    assert distractor_truth(sub, w).all()


def _dilate(m, r):
    out = m.copy()
    for dr in range(-r, r + 1):
        for dc in range(-r, r + 1):
            out |= np.roll(np.roll(m, dr, 0), dc, 1)
    return out


def test_backbone_bad_input(worlds):
    w = worlds["object"]
    with pytest.raises(ClearsplatError, match="depths"):
        reconstruct(w.cameras, w.images, w.depths[:2])
    with pytest.raises(ClearsplatError) as err:
        reconstruct(w.cameras, w.images, [d[:, :5] for d in w.depths])
    assert err.value.field == "depths[0]"
    with pytest.raises(ClearsplatError) as err:
        reconstruct(w.cameras, w.images, [d * 0 for d in w.depths])
    assert err.value.field == "depths[0]"
    with pytest.raises(ClearsplatError) as err:
        reconstruct(w.cameras, w.images, w.depths, opacity=1.5)
    assert err.value.field == "opacity"
    s = reconstruct(w.cameras, w.images, w.depths)
    s.pixel_id[0] = -1
    with pytest.raises(ClearsplatError) as err:
        distractor_truth(s, w)
    assert err.value.field == "pixel_id"


def test_backbone_reproduces_its_inputs():
    """One view's Gaussians rendered from its camera give back that input image."""
    render = pytest.importorskip("clearsplat.render").render
    from clearsplat.metrics import psnr

    for family in FAMILIES:
        w = make_world(family, num_views=4, seed=0)  # the default 256x448 of the demo
        s = reconstruct(w.cameras, w.images, w.depths, seed=0)
        c = clean_reference(w, seed=0)
        truth = distractor_truth(s, w)
        for i, cam in enumerate(w.cameras):
            own = render(s, cam, keep=s.view_id == i).rgb
            assert psnr(own, w.images[i]) > 28.0
            # all views together, without the transients, against the clean image
            assert psnr(render(c, cam).rgb, w.clean_images[i]) > 26.0
            if i in (0, 3):
                assert psnr(render(s, cam, keep=~truth).rgb, w.clean_images[i]) > 26.0
        for cam, img in zip(w.test_cameras, w.test_images):
            clean = psnr(render(c, cam).rgb, img)
            cluttered = psnr(render(s, cam).rgb, img)
            assert clean > 25.5
            assert cluttered < clean - 2.5  # the distractors cost a clear margin
