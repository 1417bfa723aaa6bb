"""Speed of the CPU rasterizer on a pixel-aligned scene (a script, not a test).

Eight cameras on an arc look at a textured floor with a few spheres. Each view's depth is ray
cast analytically and unprojected into one flat Gaussian per pixel, facing its camera, about a
pixel wide, opacity 0.9, DC colour from a procedural texture: 8 x 256 x 448 = 917,504
Gaussians, as a pixel-aligned feed-forward model would predict them. Every camera then renders
all of them at 256x448.

Usage::

    python benchmarks/render_speed.py [--repeats 5] [--threads 1 2]
    python benchmarks/render_speed.py --layers       # render_layers against two per pass
    python benchmarks/render_speed.py --rows 1       # one row a step on an AVX-512 machine

Prints, per thread count, the median over the 8 cameras of the median milliseconds of a full
render (wall clock, and the process CPU time it used), of prepare alone (projection, depth
sort, tile binning) and of compositing alone; also the mean absolute difference between each
render and the ray-cast image of that view (a sanity check that the scene renders as built).
Last, the full render in gsplat's antialiased mode (eps2d 0.1) and the PSNR between classic and
antialiased renders of the same views.

With ``--layers``, instead: every camera renders each of the other seven views' Gaussians on its
own (as the filter's reveal reference does), once with ``PreparedView.render_layers`` (one pass
over the tile lists) and once two per ``render_pair`` (the route of the other backends); the
medians over cameras of their median milliseconds, and whether the results are equal.

``--rows 1`` makes the compositing take one row of pixels a step where the machine would take
two (AVX-512; ``clearsplat._core.rows_per_step()``): the same bits, for a comparison.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from clearsplat import Camera, Gaussians, RenderSettings, Scene
from clearsplat.cameras import look_at
from clearsplat.render import prepare, render
from clearsplat.metrics import psnr
from clearsplat.render._kernels import max_threads
from clearsplat.render.base import _TiledView
from clearsplat.scene import rgb_to_sh_dc

WIDTH, HEIGHT, FOCAL = 448, 256, 400.0
SPHERES = [((0.0, 0.6, 0.0), 0.6, (0.85, 0.25, 0.2)), ((-1.3, 0.4, 0.8), 0.4, (0.2, 0.6, 0.9)),
           ((1.2, 0.5, -0.7), 0.5, (0.3, 0.8, 0.35))]


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) to a quaternion w, x, y, z (w > 0 branch; fine for cameras here)."""
    w = np.sqrt(max(1e-12, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                     (R[1, 0] - R[0, 1]) / (4 * w)])


def cameras() -> list[Camera]:
    K = [[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]]
    cams = []
    for a in np.linspace(-0.6, 0.6, 8):
        eye = (4.0 * np.sin(a), 2.2, -4.0 * np.cos(a))
        cams.append(Camera(K=K, camera_to_world=look_at(eye, (0.0, 0.0, 0.5), up=(0.0, 1.0, 0.0)),
                           width=WIDTH, height=HEIGHT))
    return cams


def ray_cast(cam: Camera):
    """Camera depth (H, W) and colour (H, W, 3) of the floor (y = 0) and spheres."""
    o, d = cam.pixel_rays()
    depth = np.where(d[..., 1] < 0, -o[1] / np.minimum(d[..., 1], -1e-12), np.inf)
    p = o + d * depth[..., None]
    checker = (np.floor(p[..., 0] * 2) + np.floor(p[..., 2] * 2)) % 2
    stripes = 0.5 + 0.5 * np.sin(p[..., 0] * 9.0 + p[..., 2] * 3.0)
    colour = np.stack([0.25 + 0.5 * checker, 0.3 + 0.4 * stripes, 0.6 - 0.3 * checker], -1)
    for centre, radius, rgb in SPHERES:
        oc = o - np.asarray(centre)
        a = np.sum(d * d, -1)
        b = 2 * np.sum(d * oc, -1)
        c = oc @ oc - radius**2
        disc = b * b - 4 * a * c
        t = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
        hit = (t > 0) & (t < depth)
        normal = (o + d * t[..., None] - np.asarray(centre)) / radius
        shade = 0.5 + 0.5 * np.clip(normal[..., 1], 0, 1)
        colour = np.where(hit[..., None], np.asarray(rgb) * shade[..., None], colour)
        depth = np.where(hit, t, depth)
    assert np.isfinite(depth).all(), "every pixel must hit the floor or a sphere"
    return depth, colour


def build_scene() -> tuple[Scene, list[np.ndarray]]:
    cams = cameras()
    parts, images = [], []
    for cam in cams:
        depth, colour = ray_cast(cam)
        n = depth.size
        sigma = 0.5 * depth.reshape(-1) / FOCAL  # half a pixel at that depth
        scales = np.stack([sigma, sigma, sigma * 1e-2], 1)  # flat, facing the camera
        quat = rotmat_to_quat(cam.camera_to_world[:3, :3])
        parts.append(Gaussians(means=cam.unproject(depth).reshape(-1, 3), scales=scales,
                               quats=np.tile(quat, (n, 1)), opacities=np.full(n, 0.9),
                               sh=rgb_to_sh_dc(colour.reshape(-1, 1, 3))))
        images.append(colour.astype(np.float32))
    g = Gaussians(*(np.concatenate([getattr(p, a) for p in parts])
                    for a in ("means", "scales", "quats", "opacities", "sh")))
    view_id = np.repeat(np.arange(len(cams)), WIDTH * HEIGHT)
    pixel_id = np.tile(np.arange(WIDTH * HEIGHT), len(cams))
    return Scene(g, view_id, pixel_id, cams, images), images


def median_ms(fn, repeats: int) -> tuple[float, float]:
    """Median wall-clock and process CPU milliseconds of ``fn()``."""
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


def layer_speed(repeats: int) -> None:
    """Each camera renders the other views' Gaussians, one view at a time: one pass against two
    per render_pair."""
    scene, _ = build_scene()
    one, pairs, same = [], [], True
    for i, cam in enumerate(scene.cameras):
        view = prepare(scene, cam)
        layers = [scene.view_id == j for j in range(len(scene.cameras)) if j != i]
        one.append(median_ms(lambda: view.render_layers(layers), repeats)[0])
        pairs.append(median_ms(lambda: _TiledView.render_layers(view, layers), repeats)[0])
        a, b = view.render_layers(layers), _TiledView.render_layers(view, layers)
        same &= all(np.array_equal(x, y) for ra, rb in zip(a, b) for x, y in zip(ra, rb))
    print(f"{len(scene):,} Gaussians, {len(scene.cameras)} cameras, 7 layers each, "
          f"{max_threads()} threads: render_layers {np.median(one):.1f} ms, two per "
          f"render_pair {np.median(pairs):.1f} ms (ratio {np.median(one) / np.median(pairs):.2f});"
          f" equal: {same}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="renders per camera and setting")
    parser.add_argument("--threads", type=int, nargs="*", default=None,
                        help="thread counts to time (default: 1 and all cores)")
    parser.add_argument("--layers", action="store_true",
                        help="time render_layers against two layers per render_pair instead")
    parser.add_argument("--rows", type=int, choices=(1, 2), default=None,
                        help="the compositing's rows of pixels per step (default: the "
                             "machine's, 2 with AVX-512)")
    args = parser.parse_args()
    from clearsplat import _core
    _core.set_rows_per_step(args.rows or 0)
    print(f"compositing: {_core.rows_per_step()} row(s) of pixels a step")
    threads = args.threads or sorted({1, max_threads()})
    if args.layers:
        layer_speed(args.repeats)
        return

    t = time.perf_counter()
    scene, images = build_scene()
    print(f"scene: {len(scene):,} Gaussians, {len(scene.cameras)} views of {WIDTH}x{HEIGHT} "
          f"(built in {time.perf_counter() - t:.1f} s)")
    views = [prepare(scene, cam) for cam in scene.cameras]
    mem = sum(v.memory_bytes for v in views)
    print(f"visible per view: {np.mean([v.num_visible for v in views]):,.0f}; "
          f"8 prepared views hold {mem / 2**20:.0f} MiB")
    errs = [np.abs(v.render().rgb - im).mean() for v, im in zip(views, images)]
    print(f"mean |render - ray-cast image| per view: {np.mean(errs):.4f} (max {max(errs):.4f})")
    del views

    # CPU time (all threads together) shows the work; on a shared machine wall time with
    # several threads also depends on what else runs.
    print(f"\n{'threads':>7} | {'full render ms':>14} | {'(cpu ms)':>8} | {'prepare ms':>10} | "
          f"{'composite ms':>12}")
    print("-" * 67)
    for nt in threads:
        full, cpu, prep, comp = [], [], [], []
        for cam in scene.cameras:
            w, c = median_ms(lambda: render(scene, cam, num_threads=nt), args.repeats)
            full.append(w)
            cpu.append(c)
            prep.append(median_ms(lambda: prepare(scene, cam, num_threads=nt), args.repeats)[0])
            view = prepare(scene, cam, num_threads=nt)
            comp.append(median_ms(view.render, args.repeats)[0])
        print(f"{nt:>7} | {np.median(full):>14.1f} | {np.median(cpu):>8.1f} | "
              f"{np.median(prep):>10.1f} | {np.median(comp):>12.1f}")

    # The same views in gsplat's antialiased mode (ReSplat's settings): its cost, and how far
    # its images are from the classic ones on pixel-sized Gaussians.
    aa = RenderSettings(antialiased=True, eps2d=0.1)
    nt = max(threads)
    full, cpu, gap = [], [], []
    for cam in scene.cameras:
        w, c = median_ms(lambda: render(scene, cam, num_threads=nt, settings=aa), args.repeats)
        full.append(w)
        cpu.append(c)
        gap.append(psnr(render(scene, cam).rgb, render(scene, cam, settings=aa).rgb))
    print(f"\nantialiased, eps2d 0.1, {nt} threads: full render {np.median(full):.1f} ms "
          f"({np.median(cpu):.1f} cpu ms); PSNR classic vs antialiased {np.mean(gap):.1f} dB")

if __name__ == "__main__":
    main()
