"""The synthetic distractor benchmark: worlds x view counts x seeds, any filter config.

``clearsplat bench`` prints tables shaped like the paper's (quality, clean-scene preservation,
runtime) and writes JSON, CSV and a plot. Ground truth comes from analytic ray casting
(:mod:`clearsplat.synth`), never from the rasterizer under test.
"""

from __future__ import annotations

import csv
import json
import os
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .filter import FilterConfig, filter_distractors
from .filter.config import parse_value
from .metrics import lpips, lpips_available, psnr, removal_stats, ssim
from .render import render_batch
from .synth import clean_reference, distractor_truth, make_world, reconstruct
from .synth.realism import parse_realism, realistic_reconstruction

__all__ = ["BenchCase", "ABLATIONS", "parse_config", "parse_value", "run_real_checks",
           "format_real_checks", "run_case", "run_cell", "run_suite", "format_tables",
           "write_outputs"]

#: The ablation of docs/method.md: each departure of the default from the paper switched off
#: alone (one row for every option in which ``FilterConfig()`` differs from the
#: ``paper-local`` preset), the paper's procedure, the paper's own ablations, and options that
#: are off by default switched on.
ABLATIONS = {
    "default": "default",
    "paper-local": "paper-local",
    "paper+excl-own": "paper-local+verify_base=exclude-own",
    # Each option in which the default differs from the paper, set to the paper's value alone.
    "full-base": "default+verify_base=full",
    # ... and the individual test's base without the default's second step (the other views'
    # candidates left in, as the additional test leaves them).
    "exclude-own-base": "default+verify_base=exclude-own",
    "no-refine": "default+refine=none",
    "plain-depth": "default+refine=depth",
    "holes-count": "default+verify_holes=count",
    "no-rel-score": "default+min_relative_score=0",
    "one-round": "default+rounds=1",
    "every-view": "default+neighbours=null+verify_views=centres",
    "remove-hidden": "default+verify_hidden=null",
    "composite": "default+reveal_reference=composite",
    # The paper's own ablations, on the default.
    "rgb": "default+features=rgb",
    "single<tau2": "default+single_threshold=true",
    "single<tau1": "default+second_range=false",
    "no-verify": "default+verify=false",
    # Options that are off by default, switched on.
    "+rel-score=0.5": "default+min_relative_score=0.5",
    "video": "video",
}


def parse_config(spec: str) -> FilterConfig:
    """A config from ``PRESET[+key=value...]``, e.g. ``default+refine=none+tau1=0.4``; a part
    without ``=`` continues the previous value (``verify_mask=proposals+revealing``)."""
    from .errors import ClearsplatError
    preset, *items = spec.split("+")
    raw: dict = {}
    key = None
    for item in items:
        if "=" not in item:
            if key is None:
                raise ClearsplatError(f"expected key=value, got {item!r}", field="--config")
            raw[key] += "+" + item.strip()
            continue
        key, v = item.split("=", 1)
        key = key.strip()
        raw[key] = v.strip()
    changes = {k: parse_value(v) for k, v in raw.items()}
    return FilterConfig.preset(preset.strip()).replace(**changes)


@dataclass
class BenchCase:
    """One benchmark cell: a world and the configs to run on it."""

    family: str
    num_views: int
    seed: int
    height: int = 256
    width: int = 448
    configs: dict = field(default_factory=lambda: {"default": FilterConfig()})
    realism: str = "plain"
    occlusion: str = "medium"
    transients: str = "shots"


def _quality(scene, keep, cameras, images) -> dict:
    """Mean PSNR / SSIM / LPIPS of ``scene`` (restricted to ``keep``) on test views."""
    renders = render_batch(scene, cameras, [keep] * len(cameras))
    out = {"psnr": float(np.mean([psnr(r.rgb, im) for r, im in zip(renders, images)])),
           "ssim": float(np.mean([ssim(r.rgb, im) for r, im in zip(renders, images)]))}
    if lpips_available():
        out["lpips"] = float(np.mean([lpips(r.rgb, im) for r, im in zip(renders, images)]))
    else:
        out["lpips"] = None
    return out


def run_case(case: BenchCase, *, log: Callable[[str], None] = lambda s: None,
             extractor=None) -> list[dict]:
    """Run every config of ``case`` on its cluttered world and on the clean twin.

    Returns one row (dict) per config with quality, accuracy, preservation and timings.
    """
    t0 = time.perf_counter()
    world = make_world(case.family, num_views=case.num_views, seed=case.seed,
                       height=case.height, width=case.width, occlusion=case.occlusion,
                       transients=case.transients)
    t_world = time.perf_counter() - t0
    t0 = time.perf_counter()
    if parse_realism(case.realism):
        scene, truth = realistic_reconstruction(world, case.realism, seed=case.seed)
        t_recon = time.perf_counter() - t0
        clean, _ = realistic_reconstruction(world, case.realism, seed=case.seed, clean=True)
    else:  # the plain stand-in, exactly as before the realism scenarios
        scene = reconstruct(world.cameras, world.images, world.depths, seed=case.seed)
        t_recon = time.perf_counter() - t0
        clean = clean_reference(world)
        truth = distractor_truth(scene, world)
    base_q = _quality(scene, None, world.test_cameras, world.test_images)
    ref_q = _quality(clean, None, world.test_cameras, world.test_images)
    # Removing exactly the distractor Gaussians: the gain a perfect filter would give.
    exact_q = _quality(scene, ~truth, world.test_cameras, world.test_images)
    rows = []
    for name, cfg in case.configs.items():
        log(f"{_where(case)}: {name}")
        res = filter_distractors(scene, config=cfg, extractor=extractor)
        q = _quality(scene, res.keep, world.test_cameras, world.test_images)
        stats = removal_stats(res.removed, truth)
        clean_res = filter_distractors(clean, config=cfg, extractor=extractor)
        clean_q = _quality(clean, clean_res.keep, world.test_cameras, world.test_images)
        rows.append({
            "realism": case.realism,
            "family": _family(case), "views": case.num_views, "seed": case.seed,
            "config": name,
            "gaussians": len(scene),
            "baseline": base_q, "filtered": q, "reference": ref_q, "exact": exact_q,
            "recall": stats["recall"], "other_removed": stats["static_removed"],
            "distractor_gaussians": int(truth.sum()),
            "candidates": len(res.candidates),
            "accepted": int(sum(c.accepted for c in res.candidates)),
            "clean_baseline": ref_q, "clean_filtered": clean_q,
            "clean_removed": float(clean_res.removed.mean()),
            "time_world": t_world, "time_reconstruct": t_recon,
            "time_proposal": res.timings["proposal"],
            "time_verification": res.timings["verification"],
        })
    return rows


def run_suite(*, families: Sequence[str] = ("object", "street"),
              views: Sequence[int] = (4, 8, 16), seeds: Sequence[int] = (0,),
              configs: dict | None = None, height: int = 256, width: int = 448,
              log: Callable[[str], None] = lambda s: None, extractor=None,
              realism: Sequence[str] = ("plain",), occlusion: str = "medium",
              transients: str = "shots",
              workers: int | None = None, address: str | None = None) -> list[dict]:
    """Run the benchmark grid; rows as returned by :func:`run_case`, in grid order.

    ``realism`` lists the backbone scenarios (:data:`clearsplat.synth.realism.SCENARIOS`);
    ``occlusion`` is the worlds' level of transients (``make_world``: low, medium, high) and
    ``transients`` how they come and go (``"shots"``, or ``"video"`` for the street family).
    With ``workers`` or ``address`` each cell (scenario, world, view count, seed) is a Ray task
    (:mod:`clearsplat.batch`): ``workers`` CPUs of a local Ray instance started and stopped
    here, or the cluster at ``address``. Otherwise the cells run one after another in this
    process. The rows are the same either way; only the timings differ.
    """
    configs = configs or {"default": FilterConfig()}
    for r in realism:
        parse_realism(r)                 # fail on a bad name before any work
    cases = [BenchCase(family, v, seed, height, width, configs, r, occlusion, transients)
             for r in realism for family in families for v in views for seed in seeds]
    if workers is None and address is None:
        rows = []
        for case in cases:
            rows.extend(run_case(case, log=log, extractor=extractor))
        return rows
    from .batch import TaskFailed, ray_cluster, run_tasks
    results: list = [None] * len(cases)
    with ray_cluster(address=address, num_cpus=workers) as ray:
        for i, result in run_tasks(ray, run_cell, [(c, extractor) for c in cases]):
            c = cases[i]
            where = _where(c)
            if isinstance(result, TaskFailed):
                raise RuntimeError(f"{where}: {result}")
            results[i] = result
            log(f"{where}: done")
    return [row for rows in results for row in rows]


def _family(case: BenchCase) -> str:
    """The family's name in rows and tables, with its occlusion level where not medium and
    ``video`` for video-like transients."""
    name = case.family if case.occlusion == "medium" else f"{case.family}/{case.occlusion}"
    return name if case.transients == "shots" else f"{name}/video"


def _where(case: BenchCase) -> str:
    """A cell's name in progress lines (the scenario only where it is not the plain one)."""
    name = f"{_family(case)} {case.num_views} views seed {case.seed}"
    return name if case.realism == "plain" else f"{case.realism} {name}"


def run_cell(job: tuple) -> list[dict]:
    """``run_case(case, extractor=extractor)`` for ``job = (case, extractor)``: one Ray task."""
    case, extractor = job
    return run_case(case, extractor=extractor)


def run_real_checks(configs: dict, *, extractor=None,
                    log: Callable[[str], None] = lambda s: None) -> list[dict]:
    """The real-image check (Middlebury stereo pair, a real object pasted into one view) for
    each config; see :func:`clearsplat.synth.stereo.real_image_check`."""
    from .synth.stereo import real_image_check
    rows = []
    for name, cfg in configs.items():
        log(f"real-image check: {name}")
        r = real_image_check(cfg, extractor=extractor)
        rows.append({"config": name, **{k: float(r[k]) for k in (
            "iou", "recall", "precision", "psnr_before", "psnr_after", "psnr_clean",
            "other_removed")}})
    return rows


def format_real_checks(rows: list[dict]) -> str:
    """The real-image check as a table."""
    lines = ["Real-image check: Middlebury Motorcycle pair (scikit-image), a real object pasted "
             "into one view",
             f"{'config':<15}{'IoU':>6} {'recall':>7} {'precision':>9}  {'other-view PSNR':>15} "
             f"{'+filter':>8} {'no paste':>8}  {'other removed':>13}"]
    for r in rows:
        lines.append(f"{r['config']:<15}{r['iou']:>6.3f} {r['recall']:>7.3f} "
                     f"{r['precision']:>9.3f}  {r['psnr_before']:>15.2f} {r['psnr_after']:>8.2f} "
                     f"{r['psnr_clean']:>8.2f}  {100 * r['other_removed']:>12.2f}%")
    return "\n".join(lines)


def _mean(rows, key):
    vals = [key(r) for r in rows]
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def _fmt(v, spec):
    return "n/a" if v is None else format(v, spec)


def aggregate(rows: list[dict]) -> list[dict]:
    """Mean over seeds per (realism, config, family, views)."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r.get("realism", "plain"), r["config"], r["family"], r["views"]),
                          []).append(r)
    out = []
    for (real, cfg, fam, v), rs in groups.items():
        a = {"realism": real, "config": cfg, "family": fam, "views": v, "runs": len(rs)}
        for part in ("baseline", "filtered", "reference", "exact", "clean_baseline",
                     "clean_filtered"):
            for m in ("psnr", "ssim", "lpips"):
                a[f"{part}_{m}"] = _mean(rs, lambda r: r[part][m] if part in r else None)
        for k in ("recall", "other_removed", "clean_removed", "time_reconstruct",
                  "time_proposal", "time_verification", "candidates", "accepted", "gaussians"):
            a[k] = _mean(rs, lambda r: r[k])
        out.append(a)
    return out


def format_tables(rows: list[dict]) -> str:
    """The three tables (quality, clean-scene preservation, runtime) as text.

    A *scenario* column appears when some rows come from a realism scenario other than
    ``"plain"``; *exact* is the PSNR gain of removing exactly the distractor Gaussians and
    *of exact* the share of it the filter reaches."""
    agg = aggregate(rows)
    with_real = any(a["realism"] != "plain" for a in agg)

    cw = max([12] + [len(a["config"]) + 1 for a in agg])

    def head(a=None):
        if a is None:
            return (f"{'scenario':<10}" if with_real else "") + \
                f"{'config':<{cw}}{'family':<8}{'views':>5}"
        return (f"{a['realism']:<10}" if with_real else "") + \
            f"{a['config']:<{cw}}{a['family']:<8}{a['views']:>5}"

    lines = ["Quality on test views (mean over seeds); LPIPS n/a: no local weights",
             f"{head()}  {'PSNR base':>9} {'+filter':>8} {'gain':>6} {'exact':>6} "
             f"{'of exact':>8} {'ref':>6}  {'SSIM base':>9} {'+filter':>8} {'ref':>6}  "
             f"{'LPIPS':>6}  {'recall':>6} {'other':>6}"]
    for a in agg:
        gain = a["filtered_psnr"] - a["baseline_psnr"]
        exact = None if a["exact_psnr"] is None else a["exact_psnr"] - a["baseline_psnr"]
        share = None if not exact or exact <= 0 else 100 * gain / exact
        lines.append(
            f"{head(a)}  {a['baseline_psnr']:>9.2f} "
            f"{a['filtered_psnr']:>8.2f} {gain:>+6.2f} {_fmt(exact, '+6.2f'):>6} "
            f"{_fmt(share, '7.0f') + '%' if share is not None else 'n/a':>8} "
            f"{a['reference_psnr']:>6.2f}  "
            f"{a['baseline_ssim']:>9.4f} {a['filtered_ssim']:>8.4f} {a['reference_ssim']:>6.4f}  "
            f"{_fmt(a['filtered_lpips'], '6.3f'):>6}  {a['recall']:>6.3f} "
            f"{100 * a['other_removed']:>5.2f}%")
    lines += ["", "Clean scenes (filter applied to the clean-input reconstruction)",
              f"{head()}  {'PSNR':>7} {'+filter':>8} "
              f"{'change':>7}  {'SSIM':>7} {'+filter':>8}  {'removed':>8}"]
    for a in agg:
        d = a["clean_filtered_psnr"] - a["clean_baseline_psnr"]
        lines.append(
            f"{head(a)}  {a['clean_baseline_psnr']:>7.2f} "
            f"{a['clean_filtered_psnr']:>8.2f} {d:>+7.3f}  {a['clean_baseline_ssim']:>7.4f} "
            f"{a['clean_filtered_ssim']:>8.4f}  {100 * a['clean_removed']:>7.3f}%")
    lines += ["", "Runtime (seconds, mean over seeds)",
              f"{head()}  {'Gaussians':>10} {'reconstruct':>11} "
              f"{'proposal':>9} {'verification':>12} {'candidates':>10} {'accepted':>8}"]
    for a in agg:
        lines.append(
            f"{head(a)}  {a['gaussians']:>10.0f} "
            f"{a['time_reconstruct']:>11.2f} {a['time_proposal']:>9.2f} "
            f"{a['time_verification']:>12.2f} {a['candidates']:>10.1f} {a['accepted']:>8.1f}")
    return "\n".join(lines)


def write_outputs(rows: list[dict], out_dir: str | os.PathLike,
                  real_checks: list[dict] | None = None) -> list[str]:
    """Write ``results.json``, ``results.csv`` (aggregated) and ``gain.png``; return the paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    p = os.path.join(out_dir, "results.json")
    with open(p, "w") as f:
        json.dump({"rows": rows, "aggregate": aggregate(rows), "real_image_check": real_checks},
                  f, indent=1)
    paths.append(p)
    agg = aggregate(rows)
    p = os.path.join(out_dir, "results.csv")
    with open(p, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(agg[0].keys()))
        w.writeheader()
        w.writerows(agg)
    paths.append(p)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return paths
    keys = sorted({(a["realism"], a["config"], a["family"]) for a in agg})
    # Many series (realism scenarios): a wider figure with the legend beside the axes.
    wide = len(keys) > 8
    fig, ax = plt.subplots(figsize=(9, 4.5) if wide else (5, 3.2), dpi=120)
    for (real, cfg, fam) in keys:
        pts = sorted((a["views"], a["filtered_psnr"] - a["baseline_psnr"]) for a in agg
                     if (a["realism"], a["config"], a["family"]) == (real, cfg, fam))
        label = f"{cfg} / {fam}" if real == "plain" else f"{real} / {cfg} / {fam}"
        ax.plot([v for v, _ in pts], [g for _, g in pts], marker="o", label=label)
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("input views")
    ax.set_ylabel("PSNR gain over baseline (dB)")
    if wide:
        ax.legend(fontsize=5, ncol=2, loc="center left", bbox_to_anchor=(1.01, 0.5))
    else:
        ax.legend(fontsize=7)
    fig.tight_layout()
    p = os.path.join(out_dir, "gain.png")
    fig.savefig(p)
    plt.close(fig)
    paths.append(p)
    return paths
