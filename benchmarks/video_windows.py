"""A whole video filtered in windows: time, peak memory and quality as the frames grow.

Usage::

    python benchmarks/video_windows.py --frames 100,300 --resolution 128x192
    python benchmarks/video_windows.py --frames 100 --modes whole,windows
    python benchmarks/video_windows.py --frames 1000 --modes windows,ray --no-quality
    python benchmarks/video_windows.py --frames 100 --modes windows --reach
    python benchmarks/video_windows.py --frames 100,300 --modes whole,windows --fused

Per frame count, the video-like street (``make_world("street", transients="video")``: each
passer-by stays for 2-5 consecutive frames, seed 0) is reconstructed by the stand-in backbone
and written as a bundle into ``--cache`` (kept for the next run, with the ground truth and the
test views' reference PSNRs). The street holds about 300 frames; a longer capture is made of
streets of 250 frames side by side (seeds 0, 1, ...), one after another in the input order,
and gets no quality columns (time, memory and the same removals only). With ``--fused`` the
prediction is written as a voxel-fused export instead (AnySplat's fusion, about 5 pixels per
voxel: ``association_quality.voxel_fused_export``) and each voxel's view recovered from the
images (:func:`clearsplat.adapters.associate.associate_fused`; the static voxels shared by
several views, view id -1); a voxel is a distractor where most of its pixels are. Each mode
then filters the bundle in a fresh process, exactly as ``clearsplat filter`` does, with the
default config:

- ``whole``: the whole capture in one filter run (:func:`clearsplat.batch.filter_scene` with
  ``windows=False``);
- ``windows``: in windows of consecutive frames (:func:`clearsplat.batch.filter_windows`), one
  after another in that process;
- ``ray``: the same windows as tasks of a local Ray instance with ``--workers`` CPUs.

Reported per run: wall seconds, the process's peak resident memory (``VmHWM``; in the ray mode
the driver's, its workers being Ray's processes), and against the ground truth recall of the
distractor Gaussians, the PSNR gain on the held-out test views as a share of the clean input's
gain (the clean twin's PSNR minus the unfiltered one), and the share of the other Gaussians
removed. Runs of
the same frame count also report whether their removals equal the first run's.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

_RUN = """
import re, sys
from clearsplat.batch import filter_scene, filter_windows
mode, bundle, out = sys.argv[1:4]
if mode == "whole":
    filter_scene(bundle, out, windows=False)
elif mode == "windows":
    filter_windows(bundle, out)
else:
    filter_windows(bundle, out, workers=int(sys.argv[4]))
status = open("/proc/self/status").read()
print("peak kB", re.search(r"VmHWM:\\s+(\\d+)", status).group(1))
"""


#: The street is about 90 m long, a frame 0.35 m further: longer captures are made of
#: streets of this many frames each, side by side (1 km apart, out of each other's view).
SEGMENT_FRAMES = 250


def make_long_bundle(folder: Path, frames: int, height: int, width: int, seed: int = 0):
    """A capture of more frames than one street holds: consecutive segments of
    :data:`SEGMENT_FRAMES` frames, each the video-like street of its own seed moved 1 km
    along x, written as one bundle with ``truth.npy`` (no test views: time and memory only)."""
    from clearsplat import Camera
    from clearsplat.io import save_scene
    from clearsplat.scene import Gaussians, Scene
    from clearsplat.synth import distractor_truth, make_world, reconstruct

    parts, cams, images, truths = [], [], [], []
    for k, at in enumerate(range(0, frames, SEGMENT_FRAMES)):
        n = min(SEGMENT_FRAMES, frames - at)
        world = make_world("street", num_views=n, seed=seed + k, height=height, width=width,
                           transients="video")
        scene = reconstruct(world.cameras, world.images, world.depths, seed=seed + k)
        truths.append(distractor_truth(scene, world))
        shift = np.array([1000.0 * k, 0.0, 0.0])
        g = scene.gaussians
        parts.append((Gaussians(g.means + shift.astype(np.float32), g.scales, g.quats,
                                g.opacities, g.sh), scene.view_id + at, scene.pixel_id))
        for c in scene.cameras:
            c2w = c.camera_to_world.copy()
            c2w[:3, 3] += shift
            cams.append(Camera(K=c.K, camera_to_world=c2w, width=c.width, height=c.height))
        images.extend(scene.images)
        del world, scene
    g = Gaussians(*(np.concatenate([getattr(p[0], a) for p in parts])
                    for a in ("means", "scales", "quats", "opacities", "sh")))
    whole = Scene(g, np.concatenate([p[1] for p in parts]).astype(np.int32),
                  np.concatenate([p[2] for p in parts]), cams, images)
    del parts
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    save_scene(whole, tmp)
    np.save(tmp / "truth.npy", np.concatenate(truths))
    tmp.rename(folder)


def make_bundle(folder: Path, frames: int, height: int, width: int, seed: int = 0) -> None:
    """The video-like street of ``frames`` frames as a bundle in ``folder``, with
    ``truth.npy`` (distractor Gaussians) and ``quality.npz`` (test views and their PSNRs);
    above 300 frames :func:`make_long_bundle`."""
    from clearsplat.bench import _quality
    from clearsplat.io import save_scene
    from clearsplat.synth import clean_reference, distractor_truth, make_world, reconstruct

    if frames > 300:
        return make_long_bundle(folder, frames, height, width, seed)
    world = make_world("street", num_views=frames, seed=seed, height=height, width=width,
                       transients="video")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=seed)
    truth = distractor_truth(scene, world)
    base = _quality(scene, None, world.test_cameras, world.test_images)["psnr"]
    exact = _quality(scene, ~truth, world.test_cameras, world.test_images)["psnr"]
    clean = clean_reference(world)
    ref = _quality(clean, None, world.test_cameras, world.test_images)["psnr"]
    del clean
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    save_scene(scene, tmp)
    np.save(tmp / "truth.npy", truth)
    np.savez(tmp / "quality.npz", K=np.stack([c.K for c in world.test_cameras]),
             c2w=np.stack([c.camera_to_world for c in world.test_cameras]),
             images=np.stack(world.test_images), base=base, exact=exact, clean=ref)
    tmp.rename(folder)


def make_fused_bundle(folder: Path, source: Path, seed: int = 0) -> None:
    """The per-pixel bundle ``source`` as a voxel-fused export with its views recovered from
    the images, in ``folder``, with the voxels' ``truth.npy``, ``quality.npz`` (the test
    views, the fused scene's unfiltered PSNR and the clean twin's) and ``association.json``
    (:func:`fused_association`, and the clearsplat version that recovered the views)."""
    import importlib.util

    import clearsplat
    from clearsplat import Camera, Scene
    from clearsplat.adapters.associate import associate_fused
    from clearsplat.bench import _quality
    from clearsplat.io import load_scene, save_scene

    spec = importlib.util.spec_from_file_location(
        "association_quality", Path(__file__).with_name("association_quality.py"))
    aq = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(aq)
    scene = load_scene(source)
    fused, voxel, _ = aq.voxel_fused_export(scene, seed=seed)
    truth = np.load(source / "truth.npy").astype(np.float64)
    k = len(fused)
    share = np.bincount(voxel, truth, minlength=k) / np.bincount(voxel, minlength=k)
    frame = aq.majority_view(voxel, scene.view_id, scene.num_views, weights=truth)
    cameras, images = scene.cameras, scene.images
    del scene, voxel
    a = associate_fused(fused, cameras, images)
    out = Scene(fused, view_id=a.view_id, pixel_id=a.pixel_id, cameras=cameras, images=images)
    q = dict(np.load(source / "quality.npz"))
    h, w = q["images"].shape[1:3]
    tests = [Camera(K=kk, camera_to_world=c, width=w, height=h) for kk, c in zip(q["K"], q["c2w"])]
    q["base"] = _quality(out, None, tests, list(q["images"]))["psnr"]
    tmp = folder.with_name(folder.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    save_scene(out, tmp)
    np.save(tmp / "truth.npy", share > 0.5)
    np.savez(tmp / "quality.npz", **q)
    (tmp / "association.json").write_text(json.dumps(
        {**fused_association(a.view_id, share > 0.5, frame, len(cameras)),
         "clearsplat": clearsplat.__version__}))
    tmp.rename(folder)


def _fused_is_current(folder: Path) -> bool:
    """Whether the fused bundle ``folder`` exists with its views recovered by this clearsplat
    (another version's association would give other figures)."""
    import clearsplat
    record = folder / "association.json"
    return record.is_file() and \
        json.loads(record.read_text()).get("clearsplat") == clearsplat.__version__


def fused_association(view_id: np.ndarray, distractor: np.ndarray, frame: np.ndarray,
                      frames: int) -> dict:
    """What the recovered association did on a fused video: the frame given the most voxels
    and their share; of the distractor voxels, the shares given their own frame (the one most
    of their distractor pixels came from, ``frame``), a frame 1-4 away, and shared (-1)."""
    counts = np.bincount(view_id[view_id >= 0], minlength=frames)
    v, f = view_id[distractor], frame[distractor]
    near = (v >= 0) & (v != f) & (np.abs(v - f) <= 4)
    return {"largest_frame": int(np.argmax(counts)),
            "largest_share": float(counts.max() / len(view_id)),
            "distractor_own": float(np.mean(v == f)), "distractor_near": float(np.mean(near)),
            "distractor_shared": float(np.mean(v == -1))}


def measure(mode: str, bundle: Path, out: Path, workers: int) -> dict:
    """Run one mode in a fresh process; its wall time and peak memory (with its children)."""
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", _RUN, mode, str(bundle), str(out),
                          str(workers)], stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t
    if run.returncode != 0:
        raise SystemExit(f"{mode} on {bundle} failed (status {run.returncode})")
    # The process's own high-water mark (VmHWM): a child's ru_maxrss would also count the
    # memory of this process, which made the bundle, as it was when the child started. The
    # ray mode's figure is the driver's; its workers are Ray's processes.
    peak = int(run.stdout.split("peak kB")[-1])
    return {"mode": mode, "wall": wall, "peak_gb": peak * 1024 / 1e9}


def score(bundle: Path, removed: np.ndarray) -> dict:
    """Recall, share of the clean gain and other Gaussians removed, from a run's removal."""
    from clearsplat import Camera
    from clearsplat.bench import _quality
    from clearsplat.io import load_scene
    from clearsplat.metrics import removal_stats

    truth = np.load(bundle / "truth.npy")
    stats = removal_stats(removed, truth)
    q = np.load(bundle / "quality.npz")
    scene = load_scene(bundle, require_images=False)
    h, w = q["images"].shape[1:3]
    cams = [Camera(K=k, camera_to_world=c, width=w, height=h) for k, c in zip(q["K"], q["c2w"])]
    filtered = _quality(scene, ~removed, cams, list(q["images"]))["psnr"]
    base, clean = float(q["base"]), float(q["clean"])
    return {"recall": stats["recall"], "other": stats["static_removed"],
            "gain": filtered - base, "of_clean": (filtered - base) / (clean - base)}


def reach(bundle: Path) -> str:
    """How far, in input order, each view's neighbourhood reaches in the whole capture's plan
    (``neighbours="auto"``, mutual verification views): what the windows' margin must hold."""
    from clearsplat.filter import FilterConfig
    from clearsplat.filter.neighbours import view_plan
    from clearsplat.filter.pipeline import resolve_auto
    from clearsplat.io import load_scene

    scene = load_scene(bundle, require_images=False)
    auto = resolve_auto(FilterConfig(), scene.num_views)
    plan = view_plan(scene, neighbours=auto.neighbours, verify_views=auto.verify_views,
                     num_verify_views=auto.num_verify_views)
    if plan is None or plan.hoods is None:
        return f"every camera's renders hold all {scene.num_views} views (below 24 views)"
    hood = np.array([np.abs(np.flatnonzero(h) - j).max() for j, h in enumerate(plan.hoods)])
    verify = np.array([np.abs(np.array(v) - i).max() for i, v in enumerate(plan.verifiers)])
    return (f"reach in frames: verification views at most {verify.max()}; the views a "
            f"camera's renders hold: median {np.median(hood):g}, at most {hood.max()}, "
            f"within 8 for {int((hood <= 8).sum())} of {hood.size} views")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", default="100,300")
    p.add_argument("--resolution", default="128x192", help="HxW (default: %(default)s)")
    p.add_argument("--modes", default="windows", help="whole, windows, ray (comma-separated)")
    p.add_argument("--workers", type=int, default=2, help="Ray CPUs for the ray mode")
    p.add_argument("--cache", default="video-cache", help="bundles are kept here")
    p.add_argument("--no-quality", action="store_true", help="time and memory only")
    p.add_argument("--json", help="also write the rows here")
    p.add_argument("--fused", action="store_true",
                   help="a voxel-fused export of each video, its views recovered from the images")
    p.add_argument("--reach", action="store_true",
                   help="also print how far each view's neighbourhood reaches (in frames)")
    args = p.parse_args(argv)
    height, width = (int(x) for x in args.resolution.lower().split("x"))
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"{'frames':>6} {'Gaussians':>11} {'mode':>8} {'wall s':>8} {'s/frame':>8} "
          f"{'peak GB':>8} {'recall':>7} {'of clean':>9} {'other':>7} {'same':>5}")
    for frames in (int(f) for f in args.frames.split(",")):
        bundle = cache / f"street-video-{frames}-{height}x{width}"
        if not bundle.is_dir():
            t = time.perf_counter()
            make_bundle(bundle, frames, height, width)
            print(f"(made {bundle} in {time.perf_counter() - t:.0f} s)", flush=True)
        if args.fused:
            source, bundle = bundle, Path(f"{bundle}-fused")
            if not _fused_is_current(bundle):      # the association of this clearsplat
                shutil.rmtree(bundle, ignore_errors=True)
                t = time.perf_counter()
                make_fused_bundle(bundle, source)
                print(f"(made {bundle} in {time.perf_counter() - t:.0f} s)", flush=True)
            d = json.loads((bundle / "association.json").read_text())
            print(f"(fused: frame {d['largest_frame']} holds {100 * d['largest_share']:.0f} % "
                  f"of the voxels; the distractor voxels: {100 * d['distractor_own']:.0f} % "
                  f"given their frame, {100 * d['distractor_near']:.0f} % a frame 1-4 away, "
                  f"{100 * d['distractor_shared']:.0f} % shared)", flush=True)
        n = int(np.load(bundle / "truth.npy", mmap_mode="r").shape[0])
        if args.reach:
            print(f"{frames} frames: {reach(bundle)}", flush=True)
        first = None
        for mode in args.modes.split(","):
            out = cache / f"out-{frames}-{height}x{width}{'-fused' * args.fused}-{mode}"
            row = measure(mode, bundle, out, args.workers)
            row.update(frames=frames, gaussians=n)
            removed = np.load(out / "removed.npy")
            if not args.no_quality and (bundle / "quality.npz").is_file():
                row.update(score(bundle, removed))
            same = "" if first is None else ("yes" if np.array_equal(first, removed) else
                                             f"{int((first != removed).sum())} differ")
            first = removed if first is None else first
            row["same"] = same
            rows.append(row)
            qual = ("" if "recall" not in row else
                    f"{row['recall']:>7.3f} {row['of_clean'] * 100:>8.0f}% "
                    f"{row['other'] * 100:>6.2f}%")
            print(f"{frames:>6} {n:>11,} {mode:>8} {row['wall']:>8.1f} "
                  f"{row['wall'] / frames:>8.3f} {row['peak_gb']:>8.2f} {qual} {same:>5}",
                  flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
