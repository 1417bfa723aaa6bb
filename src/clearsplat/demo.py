"""``clearsplat demo``: one cluttered synthetic scene, reconstructed, filtered, measured."""

from __future__ import annotations

import os
import time
from typing import Callable

import numpy as np

from .filter import FilterConfig, filter_distractors
from .metrics import psnr, removal_stats, ssim
from .render import render_batch
from .report import write_png, write_report
from .synth import clean_reference, distractor_truth, make_world, reconstruct

__all__ = ["run_demo"]


def run_demo(out_dir: str, *, family: str = "object", num_views: int = 8, seed: int = 0,
             height: int = 256, width: int = 448, config: FilterConfig | None = None,
             log: Callable[[str], None] = print, progress=None) -> dict:
    """Build, reconstruct and filter one cluttered scene; write pictures into ``out_dir``.

    Returns a dict with the table's numbers. ``out_dir`` receives ``test_XX_{baseline,
    filtered,reference,truth}.png``, the filter report (``report/report.html``) with a before |
    after video (``report/video.mp4``), the scene bundle (``scene/``), the filter's output
    bundle (``filtered/``, as ``clearsplat filter`` writes it) and ``summary.txt``.
    """
    config = config or FilterConfig()
    os.makedirs(out_dir, exist_ok=True)
    t0 = time.perf_counter()
    log(f"[1/4] building a {family} world with {num_views} cluttered views at {width}x{height}")
    world = make_world(family, num_views=num_views, seed=seed, height=height, width=width)
    log("[2/4] reconstructing with the stand-in backbone (one Gaussian per input pixel)")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=seed)
    clean = clean_reference(world)
    log(f"[3/4] filtering {len(scene):,} Gaussians")
    result = filter_distractors(scene, config=config, progress=progress)
    log("[4/4] rendering test views and writing pictures")
    n_test = len(world.test_cameras)
    before = render_batch(scene, world.test_cameras)
    after = render_batch(scene, world.test_cameras, [result.keep] * n_test)
    ref = render_batch(clean, world.test_cameras)
    for t in range(n_test):
        for name, r in (("baseline", before[t].rgb), ("filtered", after[t].rgb),
                        ("reference", ref[t].rgb), ("truth", world.test_images[t])):
            write_png(os.path.join(out_dir, f"test_{t:02d}_{name}.png"), r)
    video = _save_bundles_and_video(out_dir, scene, result, progress=progress)
    write_report(os.path.join(out_dir, "report"), scene, result,
                 video=os.path.relpath(video, os.path.join(out_dir, "report")))
    stats = removal_stats(result.removed, distractor_truth(scene, world))

    def mean(metric, renders):
        return float(np.mean([metric(r.rgb, im) for r, im in zip(renders, world.test_images)]))

    numbers = {
        "baseline_psnr": mean(psnr, before), "filtered_psnr": mean(psnr, after),
        "reference_psnr": mean(psnr, ref), "baseline_ssim": mean(ssim, before),
        "filtered_ssim": mean(ssim, after), "reference_ssim": mean(ssim, ref),
        "recall": stats["recall"], "other_removed": stats["static_removed"],
        "removed": int(result.removed.sum()), "gaussians": len(scene),
        "proposal_s": result.timings["proposal"],
        "verification_s": result.timings["verification"],
        "total_s": time.perf_counter() - t0,
    }
    table = "\n".join([
        f"{'':<28}{'PSNR':>8}{'SSIM':>9}",
        f"{'baseline (cluttered input)':<28}{numbers['baseline_psnr']:>8.2f}"
        f"{numbers['baseline_ssim']:>9.4f}",
        f"{'+ clearsplat filter':<28}{numbers['filtered_psnr']:>8.2f}"
        f"{numbers['filtered_ssim']:>9.4f}",
        f"{'clean-input reference':<28}{numbers['reference_psnr']:>8.2f}"
        f"{numbers['reference_ssim']:>9.4f}",
        "",
        f"removed {numbers['removed']:,} of {numbers['gaussians']:,} Gaussians; recall of "
        f"distractor Gaussians {numbers['recall']:.3f}; other Gaussians removed "
        f"{100 * numbers['other_removed']:.2f} %",
        f"filter time: proposal {numbers['proposal_s']:.2f} s, verification "
        f"{numbers['verification_s']:.2f} s; whole demo {numbers['total_s']:.1f} s",
        f"pictures: {out_dir} (test_*_baseline/filtered/reference/truth.png, "
        f"report/report.html)",
        f"before | after video: {video}",
        f"scene bundles: {os.path.join(out_dir, 'scene')} (input), "
        f"{os.path.join(out_dir, 'filtered')} (filter output); look at them in 3D with",
        f"  clearsplat view {os.path.join(out_dir, 'scene')} --filtered "
        f"{os.path.join(out_dir, 'filtered')}",
    ])
    with open(os.path.join(out_dir, "summary.txt"), "w") as f:
        f.write(table + "\n")
    log("")
    log(table)
    return numbers


def _save_bundles_and_video(out_dir, scene, result, *, progress=None):
    """``scene/`` and ``filtered/`` bundles, and ``report/video.mp4``; returns the video's path."""
    import json

    from .io import load_cameras, save_bundle_cameras, save_scene, write_ply
    from .video import make_video

    source = os.path.join(out_dir, "scene")
    save_scene(scene, source, overwrite=True)
    filtered = os.path.join(out_dir, "filtered")
    os.makedirs(filtered, exist_ok=True)
    kept = scene.subset(result.keep)
    write_ply(os.path.join(filtered, "gaussians.ply"), kept.gaussians, view_id=kept.view_id,
              pixel_id=kept.pixel_id)
    np.save(os.path.join(filtered, "removed.npy"), np.ascontiguousarray(result.removed, bool))
    with open(os.path.join(filtered, "summary.json"), "w") as f:
        json.dump(result.summary(), f, indent=1)
    cameras, images = load_cameras(source)
    save_bundle_cameras(filtered, cameras, images, render=scene.render_settings)
    os.makedirs(os.path.join(out_dir, "report"), exist_ok=True)
    return make_video(os.path.join(out_dir, "report", "video.mp4"), scene, result.keep,
                      num_frames=48, progress=progress)
