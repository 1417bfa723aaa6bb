"""The paper's evaluation on RobustNeRF and NeRF On-the-go: view configurations and scores.

1. :func:`view_configurations` picks, per scene and input count, four configurations of
   training (``clutter``) input views and clean (``extra``) test views, as the paper's
   Experiments section describes: each starts from the input and test view that share the most
   COLMAP sparse points, then adds views to grow the scene coverage both sets observe.
2. :func:`write_configurations` writes each as a bundle-to-be (``cameras.json`` + ``images/``
   of the inputs, ``test/cameras.json`` + ``test/images/`` of the test views,
   ``view_config.json``) for a backbone to fill in with its ``gaussians.ply``.
3. ``clearsplat batch`` filters the filled bundles; :func:`evaluate_predictions` renders the
   prediction and its filtered version at the test views and scores them (PSNR, SSIM, and
   LPIPS only when its weights are on this machine), and :func:`format_table` prints the
   paper's table (rows: prediction and + filter per dataset; columns: PSNR / SSIM / LPIPS per
   input count, averaged over the configurations of a scene, then over the scenes).

The growth rule is written out in ``docs/benchmarks.md`` ("Real datasets"): the paper gives the
idea, not the procedure, and not the number of test views (``num_test``, default 3).
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .errors import ClearsplatError

__all__ = ["ViewConfiguration", "view_configurations", "write_configurations",
           "evaluate_prediction", "evaluate_predictions", "format_table", "CONFIG_FILE"]

#: The file that describes a bundle-to-be (dataset, scene, views, configuration, image names).
CONFIG_FILE = "view_config.json"


@dataclass
class ViewConfiguration:
    """Input and test views of one configuration (indices into the dataset's images).

    Attributes
    ----------
    index : int
        0..3, the configuration of this scene and input count.
    inputs : list of int
        Training images given to the backbone, in the order they were added.
    test : list of int
        Clean test images scored, in the order they were added.
    covisibility : int
        Sparse points seen by at least one input and at least one test view.
    """

    index: int
    inputs: list
    test: list
    covisibility: int


def _visibility_matrix(dataset) -> np.ndarray:
    if dataset.visibility is None:
        raise ClearsplatError("view configurations need the COLMAP sparse points (sparse/0 "
                              "with points3D) for co-visibility", path=dataset.root,
                              field="sparse/0")
    ids = np.unique(np.concatenate([v for v in dataset.visibility] + [np.zeros(0, np.int64)]))
    vis = np.zeros((len(dataset.visibility), ids.size), dtype=bool)
    for i, v in enumerate(dataset.visibility):
        vis[i, np.searchsorted(ids, v)] = True
    return vis


def view_configurations(dataset, num_inputs: int, *, count: int = 4,
                        num_test: int = 3) -> list[ViewConfiguration]:
    """The paper's view configurations of one scene for ``num_inputs`` input views.

    Parameters
    ----------
    dataset : Dataset
        From :func:`clearsplat.io.datasets.read_dataset`, with sparse-point visibility.
    num_inputs : int
        Input views per configuration (4, 8, 16 in the paper).
    count : int, default 4
        Configurations per scene and input count.
    num_test : int, default 3
        Test views per configuration.

    Returns
    -------
    list of ViewConfiguration
        ``count`` of them (fewer only when the scene has fewer distinct seed pairs).

    Notes
    -----
    Seeds: the (input, test) pairs sorted by shared sparse points (ties: lower indices
    first); each configuration takes the best pair whose input and test view no earlier
    configuration started from. Growth: while a set is short, the next input view is the one
    that adds the most points seen by both sets, ties broken by the points it shares with the
    test set, then by index; after each input one test view is added the same way, until
    ``num_test``. Deterministic.
    """
    if isinstance(num_inputs, bool) or not isinstance(num_inputs, (int, np.integer)) \
            or num_inputs < 1:
        raise ClearsplatError(f"expected a positive int, got {num_inputs!r}", field="views")
    train, test = list(dataset.train), list(dataset.test)
    if num_inputs > len(train):
        raise ClearsplatError(f"{num_inputs} input views asked for, the scene has "
                              f"{len(train)} training images", path=dataset.root,
                              field="views")
    num_test = min(num_test, len(test))
    vis = _visibility_matrix(dataset)
    shared = vis[train].astype(np.int32) @ vis[test].T.astype(np.int32)
    order = sorted(((-int(shared[a, b]), train[a], test[b]) for a in range(len(train))
                    for b in range(len(test))))
    used_in, used_test, seeds = set(), set(), []
    for _, i, t in order:
        if i not in used_in and t not in used_test:
            seeds.append((i, t))
            used_in.add(i)
            used_test.add(t)
            if len(seeds) == count:
                break
    configs = []
    for k, (i0, t0) in enumerate(seeds):
        inputs, tests = [i0], [t0]
        seen_in, seen_test = vis[i0].copy(), vis[t0].copy()
        while len(inputs) < num_inputs or len(tests) < num_test:
            if len(inputs) < num_inputs:
                j = _best(vis, [i for i in train if i not in inputs], seen_in, seen_test)
                inputs.append(j)
                seen_in |= vis[j]
            if len(tests) < num_test:
                j = _best(vis, [t for t in test if t not in tests], seen_test, seen_in)
                tests.append(j)
                seen_test |= vis[j]
        configs.append(ViewConfiguration(k, inputs, tests, int((seen_in & seen_test).sum())))
    return configs


def _best(vis, candidates, own, other) -> int:
    """The candidate adding the most points to ``own & other``; ties: most shared, lowest."""
    base = int((own & other).sum())
    return min(candidates, key=lambda c: (-(int(((own | vis[c]) & other).sum()) - base),
                                          -int((vis[c] & other).sum()), c))


def _bundle_frames(dataset, indices, folder: Path) -> None:
    from .io import save_cameras
    (folder / "images").mkdir(parents=True)
    rel = []
    for i in indices:
        src = dataset.image_paths[i]
        shutil.copyfile(src, folder / "images" / src.name)
        rel.append(f"images/{src.name}")
    save_cameras(folder / "cameras.json", [dataset.cameras[i] for i in indices], rel)


def write_configurations(datasets: Sequence, out, *, views: Sequence[int] = (4, 8, 16),
                         count: int = 4, num_test: int = 3, force: bool = False,
                         log: Callable[[str], None] = lambda s: None) -> list[Path]:
    """Write every scene's view configurations as bundles-to-be under ``out``.

    Parameters
    ----------
    datasets : sequence of Dataset
    out : str or os.PathLike
        Written in full or not at all (:func:`clearsplat.io.output.output_folder`):
        ``out/<kind>/<scene>-<n>v-c<k>/`` with ``cameras.json``, ``images/``,
        ``test/cameras.json``, ``test/images/`` and :data:`CONFIG_FILE`.
    views : sequence of int
        Input counts.
    count, num_test : int
        As in :func:`view_configurations`.
    force : bool
        Replace an ``out`` that clearsplat wrote.

    Returns
    -------
    list of Path
        The bundle folders (final paths), for the backbone to add ``gaussians.ply`` to.
    """
    from .io.output import output_folder

    names = [f"{d.kind}/{d.name}" for d in datasets]
    if len(set(names)) != len(names):
        raise ClearsplatError("two scenes of the same dataset share a folder name",
                              field="DATASET")
    plans = [(d, n, view_configurations(d, n, count=count, num_test=num_test))
             for d in datasets for n in views]
    folders = []
    with output_folder(out, inputs=[d.root for d in datasets], force=force,
                       command="prepare") as tmp:
        for d, n, configs in plans:
            for c in configs:
                rel = Path(d.kind) / f"{d.name}-{n}v-c{c.index}"
                folder = tmp / rel
                _bundle_frames(d, c.inputs, folder)
                _bundle_frames(d, c.test, folder / "test")
                doc = {"dataset": d.kind, "scene": d.name, "views": n, **asdict(c),
                       "input_images": [d.names[i] for i in c.inputs],
                       "test_images": [d.names[i] for i in c.test],
                       "source": os.fspath(d.root)}
                (folder / CONFIG_FILE).write_text(json.dumps(doc, indent=1) + "\n")
                folders.append(Path(out) / rel)
                log(f"{rel}: inputs {', '.join(doc['input_images'])}; test "
                    f"{', '.join(doc['test_images'])}; {c.covisibility} shared points")
    return folders


def _scores(gaussians, cameras, images, lpips_on: bool) -> dict:
    from .metrics import lpips, psnr, ssim
    from .render import render_batch
    renders = [r.rgb for r in render_batch(gaussians, cameras)]
    out = {"psnr": float(np.mean([psnr(r, im) for r, im in zip(renders, images)])),
           "ssim": float(np.mean([ssim(r, im) for r, im in zip(renders, images)])),
           "lpips": None}
    if lpips_on:
        out["lpips"] = float(np.mean([lpips(r, im) for r, im in zip(renders, images)]))
    return out


def evaluate_prediction(bundle, filtered=None) -> dict:
    """Score one filled bundle-to-be and, when given, its filtered output on its test views.

    Parameters
    ----------
    bundle : str or os.PathLike
        A folder written by :func:`write_configurations` holding the backbone's
        ``gaussians.ply``.
    filtered : str or os.PathLike, optional
        Its ``clearsplat filter`` / ``clearsplat batch`` output folder.

    Returns
    -------
    dict
        ``dataset``, ``scene``, ``views``, ``config`` (from :data:`CONFIG_FILE`),
        ``prediction`` and ``filtered`` (None without ``filtered``): each ``{"psnr", "ssim",
        "lpips"}``, ``lpips`` None when no local LPIPS weights exist.
    """
    from .io import load_cameras, read_image, read_ply
    from .metrics import lpips_available

    bundle = Path(bundle)
    try:
        meta = json.loads((bundle / CONFIG_FILE).read_text())
    except FileNotFoundError:
        raise ClearsplatError(f"no {CONFIG_FILE}: not a folder written by clearsplat "
                              "prepare", path=bundle, field=CONFIG_FILE) from None
    except (OSError, ValueError) as e:
        raise ClearsplatError(f"cannot read JSON ({e})", path=bundle / CONFIG_FILE,
                              field=CONFIG_FILE) from None
    for key in ("dataset", "scene", "views", "index"):
        if key not in meta:
            raise ClearsplatError("missing key", path=bundle / CONFIG_FILE, field=key)
    cameras, paths = load_cameras(bundle / "test")
    images = [read_image(p, expected_size=(c.width, c.height)) for c, p in zip(cameras, paths)]
    lpips_on = lpips_available()
    pred, _, _ = read_ply(bundle / "gaussians.ply")
    row = {"dataset": meta["dataset"], "scene": meta["scene"], "views": int(meta["views"]),
           "config": int(meta["index"]), "bundle": os.fspath(bundle),
           "prediction": _scores(pred, cameras, images, lpips_on), "filtered": None}
    if filtered is not None:
        g, _, _ = read_ply(Path(filtered) / "gaussians.ply")
        row["filtered"] = _scores(g, cameras, images, lpips_on)
    return row


def evaluate_predictions(bundles: Sequence, filtered_root=None, *,
                         log: Callable[[str], None] = lambda s: None) -> list[dict]:
    """:func:`evaluate_prediction` for each bundle; its filtered output is
    ``filtered_root/<bundle folder name>`` (what ``clearsplat batch`` writes), when given."""
    rows = []
    for b in bundles:
        b = Path(b)
        filtered = None
        if filtered_root is not None:
            filtered = Path(filtered_root) / b.name
            if not (filtered / "gaussians.ply").is_file():
                raise ClearsplatError("no filtered output for this prediction (run clearsplat "
                                      "batch on the bundles first)", path=filtered,
                                      field="--filtered")
        rows.append(evaluate_prediction(b, filtered))
        log(f"{b.name}: PSNR {rows[-1]['prediction']['psnr']:.2f}"
            + ("" if filtered is None else f" -> {rows[-1]['filtered']['psnr']:.2f}"))
    return rows


_DATASET_TITLES = {"robustnerf": "RobustNeRF dataset", "onthego": "NeRF On-the-go dataset"}


def aggregate(rows: Sequence[dict]) -> dict:
    """``{(dataset, part, views): {"psnr", "ssim", "lpips"}}``: mean over each scene's
    configurations, then over the scenes (``lpips`` None when any score lacks it)."""
    per_scene: dict = {}
    for r in rows:
        for part in ("prediction", "filtered"):
            if r[part] is not None:
                per_scene.setdefault((r["dataset"], part, r["views"], r["scene"]),
                                     []).append(r[part])
    means: dict = {}
    for (ds, part, v, _), scores in per_scene.items():
        means.setdefault((ds, part, v), []).append(
            {m: (None if any(s[m] is None for s in scores)
                 else float(np.mean([s[m] for s in scores]))) for m in ("psnr", "ssim", "lpips")})
    return {k: {m: (None if any(s[m] is None for s in v) else float(np.mean([s[m] for s in v])))
                for m in ("psnr", "ssim", "lpips")} for k, v in means.items()}


def format_table(rows: Sequence[dict], *, label: str = "Prediction") -> str:
    """The paper's main table: per dataset, the prediction and ``+ filter`` rows, PSNR / SSIM
    / LPIPS per input count. LPIPS reads ``n/a`` when no local weights exist."""
    agg = aggregate(rows)
    views = sorted({r["views"] for r in rows})
    head = f"{'':<14}" + "".join(f"{f'{v} views':^24}" for v in views)
    sub = f"{'Method':<14}" + "".join(f"{'PSNR':>8}{'SSIM':>8}{'LPIPS':>8}" for _ in views)
    lines = [head, sub]
    for ds in [d for d in _DATASET_TITLES if any(r["dataset"] == d for r in rows)]:
        n = len({r["scene"] for r in rows if r["dataset"] == ds})
        lines.append(f"{_DATASET_TITLES[ds]} ({n} scene{'s' * (n != 1)})")
        for part, name in (("prediction", label), ("filtered", "+ filter")):
            cells = [agg.get((ds, part, v)) for v in views]
            if all(c is None for c in cells):
                continue
            line = f"{name:<14}"
            for c in cells:
                if c is None:
                    line += f"{'-':>8}{'-':>8}{'-':>8}"
                else:
                    lp = "n/a" if c["lpips"] is None else f"{c['lpips']:.3f}"
                    line += f"{c['psnr']:>8.2f}{c['ssim']:>8.3f}{lp:>8}"
            lines.append(line)
    if any(r["prediction"]["lpips"] is None for r in rows):
        lines.append("LPIPS n/a: no local LPIPS weights (pip install lpips, with its AlexNet "
                     "weights on this machine)")
    return "\n".join(lines)
