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
             log: Callable[[str], None] = print, progress=None, force: bool = False) -> dict:
    """Build, reconstruct and filter one cluttered scene; write pictures into ``out_dir``.

    ``out_dir`` is written the way every clearsplat output folder is
    (:func:`clearsplat.io.output.output_folder`): checked before any work, filled in a
    temporary folder and swapped into place at the end, so a failed run leaves nothing and an
    earlier demo's pictures never mix with new ones. ``force=True`` replaces an earlier
    clearsplat output folder, nothing else.

    Returns a dict with the table's numbers. ``out_dir`` receives ``test_XX_{baseline,
    filtered,reference,truth}.png``, the filter report (``report/report.html``) with a before |
    after video (``report/video.mp4``), the scene bundle (``scene/``), the filter's output
    bundle (``filtered/``, as ``clearsplat filter`` writes it) and ``summary.txt``.
    """
    from .io.output import check_output_folder, output_folder

    config = config or FilterConfig()
    check_output_folder(out_dir, force=force)
    t0 = time.perf_counter()
    log(f"[1/4] building a synthetic {family!r} world with {num_views} cluttered views at "
        f"{width}x{height}")
    world = make_world(family, num_views=num_views, seed=seed, height=height, width=width)
    log("[2/4] reconstructing with the stand-in backbone (one Gaussian per input pixel)")
    scene = reconstruct(world.cameras, world.images, world.depths, seed=seed)
    clean = clean_reference(world)
    log(f"[3/4] filtering {len(scene):,} Gaussians")
    result = filter_distractors(scene, config=config, progress=progress)
    log("[4/4] rendering test views and writing pictures")
    before = render_batch(scene, world.test_cameras)
    after = render_batch(scene, world.test_cameras, [result.keep] * len(world.test_cameras))
    ref = render_batch(clean, world.test_cameras)
    numbers = _numbers(world, scene, result, before, after, ref)
    with output_folder(out_dir, force=force, command="demo") as tmp:
        _write_pictures(tmp, world, before, after, ref)
        video = _save_bundles_and_video(tmp, scene, result, progress=progress)
        write_report(os.path.join(tmp, "report"), scene, result,
                     source=f"synthetic {family!r} world, {num_views} views, seed {seed}, "
                            f"{width}x{height} (clearsplat demo)", video=video.name)
        numbers["total_s"] = time.perf_counter() - t0
        table = _table(numbers, out_dir) + "\n" + _where(out_dir, video.name)
        with open(os.path.join(tmp, "summary.txt"), "w") as f:
            f.write(table + "\n")
    log("")
    log(table)
    return numbers


def _write_pictures(folder, world, before, after, ref) -> None:
    """``test_XX_{baseline,filtered,reference,truth}.png`` per test view."""
    for t in range(len(world.test_cameras)):
        for name, r in (("baseline", before[t].rgb), ("filtered", after[t].rgb),
                        ("reference", ref[t].rgb), ("truth", world.test_images[t])):
            write_png(os.path.join(folder, f"test_{t:02d}_{name}.png"), r)


def _numbers(world, scene, result, before, after, ref) -> dict:
    stats = removal_stats(result.removed, distractor_truth(scene, world))

    def mean(metric, renders):
        return float(np.mean([metric(r.rgb, im) for r, im in zip(renders, world.test_images)]))

    return {
        "baseline_psnr": mean(psnr, before), "filtered_psnr": mean(psnr, after),
        "reference_psnr": mean(psnr, ref), "baseline_ssim": mean(ssim, before),
        "filtered_ssim": mean(ssim, after), "reference_ssim": mean(ssim, ref),
        "recall": stats["recall"], "other_removed": stats["static_removed"],
        "removed": int(result.removed.sum()), "gaussians": len(scene),
        "proposal_s": result.timings["proposal"],
        "verification_s": result.timings["verification"],
    }


def _table(numbers: dict, out_dir) -> str:
    return "\n".join([
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
    ])


def _where(out_dir, video_name: str) -> str:
    scene, filtered = os.path.join(out_dir, "scene"), os.path.join(out_dir, "filtered")
    return "\n".join([
        f"before | after video: {os.path.join(out_dir, 'report', video_name)}",
        f"scene bundles: {scene} (input), {filtered} (filter output); in 3D:",
        f"  clearsplat view {scene} --filtered {filtered}",
    ])


def _save_bundles_and_video(folder, scene, result, *, progress=None):
    """``scene/`` and ``filtered/`` bundles, and ``report/video.mp4``; returns the video's path.

    ``filtered/`` holds what ``clearsplat filter scene --out filtered`` writes (without its
    report); its ``cameras.json`` refers to the images of ``scene/`` (``image_root``).
    """
    from .batch import write_filter_outputs
    from .io import save_scene
    from .video import make_video

    source = os.path.join(folder, "scene")
    save_scene(scene, source)
    filtered = os.path.join(folder, "filtered")
    os.makedirs(filtered)
    write_filter_outputs(filtered, scene, result, source=source)
    os.makedirs(os.path.join(folder, "report"), exist_ok=True)
    return make_video(os.path.join(folder, "report", "video.mp4"), scene, result.keep,
                      num_frames=48, progress=progress)
