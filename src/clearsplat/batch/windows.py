"""A long capture filtered in windows of consecutive views, in bounded memory, locally or on Ray.

The filter of one capture holds every view's Gaussians, renders and masks; its memory grows
with the capture. A video's frames need only their neighbours: from :data:`WINDOWS_FROM`
views on, :func:`filter_windows` splits the input views, in input order, into blocks of about
:data:`WINDOW_VIEWS` views. Each window holds its block and :data:`MARGIN_VIEWS` views on
each side, filters them as one scene (:func:`clearsplat.filter_distractors`, the config's
``"auto"`` options resolved for the whole capture), and keeps the verdicts of the candidates
proposed in its own block: every view is judged once, with its neighbours on both sides
around it. The margin holds each judged view's neighbourhood (its seven most co-visible views
and the views that verify it, the nearest frames of a video) and their own neighbours, whose
first-round removals the second round builds on.

What a window holds is read from the PLY in pieces (:class:`clearsplat.io.ply.PlyRows`): its
rows and images only, never the whole file. Gaussians shared by several views (view id -1, a
fused export) belong to no block: a window holds those that its cameras can see
(:func:`seen_by`), as static content around its own; they are found once, when the run starts,
and their rows kept in the state folder. Each window's verdicts are written to the state folder
beside ``out`` (``.OUT.clearsplat-windows``) as it finishes, so a killed run started again with
the same input, config and clearsplat version resumes with the windows not yet done; the
outputs are written at the end, the kept rows copied from the input a piece at a time. The
windows run one after another in this process, or as tasks of a Ray cluster
(``workers``/``address``, through :func:`clearsplat.batch.run_tasks`; the state folder and the
bundle must be reachable at the same paths on every node). The removals are the same either
way.

Windows follow the input order: they suit a video or any capture taken along a path. Where
the order does not follow the cameras (:func:`order_breaks`: more than a tenth of the views
have their nearest camera outside their margin), the run says so in a warning: the frames
should be ordered along the path first.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._memory import return_free_memory
from ..errors import ClearsplatError
from ..io.bundle import bundle_camera_file, check_association
from ..scene import SHARED

__all__ = ["Window", "plan_windows", "filter_windows", "uses_windows", "order_breaks",
           "seen_by", "WINDOW_VIEWS", "MARGIN_VIEWS", "WINDOWS_FROM"]

#: Views each window judges (about; the capture is split into blocks of equal size).
WINDOW_VIEWS = 32
#: Views on each side of a block that its window also holds, for their neighbourhoods.
MARGIN_VIEWS = 8
#: Captures of this many views or more are filtered in windows (docs/method.md, "A long video").
WINDOWS_FROM = 96

_STATE_SUFFIX = ".clearsplat-windows"
_PLAN_FILE = "plan.json"


@dataclass(frozen=True)
class Window:
    """One window: the views it judges and the views it holds (``range`` of input views)."""

    index: int
    judged: range
    held: range

    def record(self) -> dict:
        return {"index": self.index, "judged": [self.judged.start, self.judged.stop],
                "held": [self.held.start, self.held.stop]}


def plan_windows(num_views: int, *, window: int = WINDOW_VIEWS,
                 margin: int = MARGIN_VIEWS) -> list[Window]:
    """The windows of a capture of ``num_views`` views: blocks of about ``window`` views in
    input order (as many as ``round(num_views / window)``, at least one, of equal size to
    within one view), each held with ``margin`` views on each side."""
    if window < 1 or margin < 0:
        raise ValueError("window must be at least 1 and margin at least 0")
    count = max(1, round(num_views / window))
    bounds = np.linspace(0, num_views, count + 1).round().astype(int)
    return [Window(k, range(int(a), int(b)), range(max(0, int(a) - margin),
                                                 min(num_views, int(b) + margin)))
            for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]


def uses_windows(num_views: int) -> bool:
    """Whether :func:`clearsplat.batch.filter_scene` filters a capture of ``num_views``
    views in windows (from :data:`WINDOWS_FROM` views on)."""
    return num_views >= WINDOWS_FROM


def order_breaks(cameras, *, margin: int = MARGIN_VIEWS) -> np.ndarray:
    """(V,) bool: the views whose nearest camera (by centre) is more than ``margin`` places
    away in input order. In a capture whose order follows the camera path (a video) there
    are almost none; windows of consecutive views cut these views off their neighbours."""
    centres = np.stack([np.asarray(c.camera_to_world)[:3, 3] for c in cameras])
    v = len(centres)
    out = np.zeros(v, bool)
    if v < 2:
        return out
    for a in range(0, v, 1024):
        d = np.linalg.norm(centres[a:a + 1024, None] - centres[None], axis=2)
        d[np.arange(d.shape[0]), np.arange(a, a + d.shape[0])] = np.inf
        out[a:a + d.shape[0]] = np.abs(np.argmin(d, axis=1) - np.arange(a, a + d.shape[0])) \
            > margin
    return out


#: A Gaussian's reach in the image, in standard deviations of its projection: the rasterizer
#: draws it to where its alpha falls below 1/255, at most sqrt(2 ln 255) = 3.33 of them.
_REACH_SIGMAS = 3.5


def seen_by(means, scales, cameras, *, eps2d: float = 0.3) -> np.ndarray:
    """The Gaussians that may cover a pixel of at least one of ``cameras``.

    A Gaussian is seen where its centre lies in front of the camera and the disc of
    :data:`_REACH_SIGMAS` times its projected standard deviation around the centre's projection
    meets the image. The projected standard deviation is bounded by the largest scale times
    the Frobenius norm of the projection's Jacobian at the centre (it is never smaller than
    the largest singular value), widened by the rasterizer's blur ``eps2d`` and one pixel: a
    Gaussian the rasterizer draws in a camera is always seen; a few that it does not draw may
    be.

    Parameters
    ----------
    means : (M, 3) array_like
        World centres.
    scales : (M, 3) array_like
        Standard deviations along the Gaussians' axes (world units).
    cameras : sequence of Camera
    eps2d : float, default 0.3
        The blur added to every projected covariance, px^2 (``RenderSettings.eps2d``).

    Returns
    -------
    (M,) bool
    """
    means = np.asarray(means, np.float64)
    largest = _largest_scales(scales, len(means))
    out = np.zeros(len(means), bool)
    for cam in cameras:
        out |= _seen_by_camera(means, largest, cam, eps2d)
    return out


def _largest_scales(scales, count: int) -> np.ndarray:
    return np.asarray(scales, np.float64).max(axis=1) if count else np.zeros(0)


def _seen_by_camera(means: np.ndarray, largest: np.ndarray, cam, eps2d: float) -> np.ndarray:
    """:func:`seen_by` for one camera, given each Gaussian's largest scale."""
    pc = cam.to_camera(means)
    z = pc[:, 2]
    front = z > 0
    zf = np.where(front, z, 1.0)
    x, y = pc[:, 0] / zf, pc[:, 1] / zf
    jac2 = (cam.fx / zf) ** 2 * (1 + x * x) + (cam.fy / zf) ** 2 * (1 + y * y)
    reach = _REACH_SIGMAS * np.sqrt(largest ** 2 * jac2 + eps2d) + 1.0
    u, v = cam.fx * x + cam.cx, cam.fy * y + cam.cy
    return front & (u > -reach) & (u < cam.width + reach) & (v > -reach) \
        & (v < cam.height + reach)


#: :func:`filter_windows` warns when more than this share of the views break the order.
_BREAKS_WARN = 0.1


def _view_rows(views: np.ndarray, held: range) -> np.ndarray:
    """(M,) int64: the rows whose view is in ``held``, in file order (a piece at a time)."""
    from ..io.ply import PIECE_ROWS
    parts = []
    for a in range(0, views.shape[0], PIECE_ROWS):
        v = np.asarray(views[a:a + PIECE_ROWS])
        parts.append(np.flatnonzero((v >= held.start) & (v < held.stop)) + a)
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


def _shared_file(state: Path, window: Window) -> Path:
    return state / f"shared-{window.index}.npy"


def _find_shared(ply, views: np.ndarray, cameras, windows: list[Window], state: Path, *,
                 eps2d: float, report) -> None:
    """Write each window's shared rows (view id -1, seen by one of its cameras: :func:`seen_by`)
    into the state folder, for the windows whose file is not there yet; the shared Gaussians
    read a piece at a time, each camera's view of a piece found once, each told to
    ``report("shared", done, total)``."""
    from ..io.ply import PIECE_ROWS
    todo = [w for w in windows if not _shared_file(state, w).is_file()]
    if not todo:
        return
    shared = np.flatnonzero(views == SHARED)
    found: dict = {w.index: [] for w in todo}
    needed = sorted({i for w in todo for i in w.held})
    total = len(range(0, shared.size, PIECE_ROWS)) * len(needed)
    done = 0
    for a in range(0, shared.size, PIECE_ROWS):
        rows = shared[a:a + PIECE_ROWS]
        g = ply.read(rows)[0]
        means = g.means.astype(np.float64)
        largest = _largest_scales(g.scales, rows.size)
        seen = {w.index: np.zeros(rows.size, bool) for w in todo}
        for i in needed:
            hit = _seen_by_camera(means, largest, cameras[i], eps2d)
            for w in todo:
                if i in w.held:
                    seen[w.index] |= hit
            done += 1
            report("shared", done, total)
        for w in todo:
            found[w.index].append(rows[seen[w.index]])
        del g, means, largest, seen
    for w in todo:
        rows = np.concatenate(found.pop(w.index)) if shared.size else np.zeros(0, np.int64)
        tmp = state / f".shared-{w.index}.tmp.npy"
        np.save(tmp, rows.astype(np.int64))
        os.replace(tmp, _shared_file(state, w))


def _load_window(bundle: Path, state: Path, window: Window):
    """The window's scene (views renumbered from 0; shared Gaussians stay -1) and its rows in
    the input PLY: its views' rows and the shared ones its cameras see, in file order."""
    from ..io import load_cameras, load_render_settings, read_image
    from ..io.ply import PlyRows
    from ..scene import Scene

    views = np.load(state / "views.npy", mmap_mode="r")
    rows = _view_rows(views, window.held)
    del views
    shared = np.load(_shared_file(state, window))
    if shared.size:
        rows = np.union1d(rows, shared)
    gaussians, view_id, pixel_id = PlyRows(bundle / "gaussians.ply").read(rows)
    cameras, image_paths = load_cameras(bundle)
    held = list(window.held)
    images = [read_image(image_paths[i], expected_size=(cameras[i].width, cameras[i].height))
              for i in held]
    settings = load_render_settings(bundle_camera_file(bundle))
    view_id = np.where(view_id == SHARED, SHARED, view_id - window.held.start)
    scene = Scene(gaussians, view_id.astype(np.int32), pixel_id,
                  [cameras[i] for i in held], images, settings)
    return scene, rows


def filter_window(job: dict) -> dict:
    """Filter one window and write its verdicts into the state folder (a Ray task, or a plain
    call): ``window-K.npz`` with the rows its judged candidates remove and those candidates
    (rows and views of the whole capture). Returns the window's counts and seconds."""
    from ..filter import filter_distractors
    from ..filter.pipeline import keep_mask
    from ..review import CandidateSets

    t0 = time.perf_counter()
    window = Window(job["index"], range(*job["judged"]), range(*job["held"]))
    state = Path(job["state"])
    scene, rows = _load_window(Path(job["bundle"]), state, window)
    result = filter_distractors(scene, config=job["config"])
    lo = window.held.start
    own = [c for c in result.candidates if c.view + lo in window.judged]
    removed = ~keep_mask(own, len(scene))
    shifted = [dataclasses.replace(c, view=c.view + lo, gaussians=rows[c.gaussians],
                                   expanded=None if c.expanded is None else rows[c.expanded],
                                   verify_views=[v + lo for v in c.verify_views])
               for c in own]
    sets = CandidateSets.from_candidates(shifted, num_gaussians=job["count"])
    records = [c.record() for c in shifted]
    done = {"removed": int(removed.sum()),
            "seconds": time.perf_counter() - t0, "warnings": list(result.warnings),
            "timings": {k: float(v) for k, v in result.timings.items()}}
    arrays = {f"c_{k}": np.asarray(v) for k, v in sets.arrays().items()}
    tmp = state / f".window-{window.index}.tmp.npz"
    np.savez(tmp, removed=rows[removed], records=np.array(json.dumps(records)),
             done=np.array(json.dumps(done)), **arrays)
    os.replace(tmp, state / f"window-{window.index}.npz")
    del scene, result, own, shifted, sets, arrays
    return_free_memory()    # the next window in this process starts from a clean heap
    return done


def _state_folder(out: Path) -> Path:
    return out.parent / f".{out.name}{_STATE_SUFFIX}"


def _fingerprint(bundle: Path, config, windows: list[Window]) -> dict:
    """What a resumed run must share with the run that wrote the state folder (the version
    too: the state folder holds the shared Gaussians each window's cameras see)."""
    from .. import __version__
    ply = bundle / "gaussians.ply"
    st = ply.stat()
    cams = hashlib.sha256(Path(bundle_camera_file(bundle)).read_bytes()).hexdigest()
    return {"version": __version__, "bundle": os.fspath(bundle.resolve()),
            "ply_size": st.st_size,
            "ply_mtime_ns": st.st_mtime_ns, "cameras": cams,
            "config": json.loads(json.dumps(config.to_dict())),
            "windows": [w.record() for w in windows]}


def _begin_state(state: Path, fingerprint: dict, views: np.ndarray, log) -> set:
    """Open the state folder: the windows already done when it belongs to this same run,
    a fresh folder otherwise."""
    plan = state / _PLAN_FILE
    if state.is_dir():
        try:
            same = json.loads(plan.read_text()) == fingerprint
        except (OSError, ValueError):
            same = False
        if same:
            done = {int(p.stem.split("-")[1]) for p in state.glob("window-*.npz")}
            if done and log is not None:
                log(f"resuming: {len(done)} of {len(fingerprint['windows'])} windows done "
                    "in an interrupted run")
            return done
        if not plan.is_file() and any(state.iterdir()):
            raise ClearsplatError("exists and was not written by clearsplat; move it away",
                                  path=state, field="--out")
        shutil.rmtree(state)
    state.mkdir(parents=True)
    np.save(state / "views.npy", views)
    plan.write_text(json.dumps(fingerprint, indent=1))
    return set()


def filter_windows(scene, out, *, config=None, keep_all: bool = False,
                   copy_images: bool = False, force: bool = False,
                   workers: int | None = None, address: str | None = None,
                   window: int | None = None, margin: int | None = None,
                   progress=None, log=None) -> dict:
    """Filter the bundle ``scene`` in windows of consecutive views and write the outputs.

    Parameters
    ----------
    scene : str or os.PathLike
        The bundle folder; its ``gaussians.ply`` binary with ``view_id`` (-1: shared by
        several views, held by every window whose cameras see it).
    out : str or os.PathLike
        The output folder, written in full at the end (:func:`clearsplat.batch.filter_scene`
        writes the same files, but ``report/``).
    config : FilterConfig, optional
        Default ``FilterConfig()``.
    keep_all, copy_images, force : bool
        As in :func:`clearsplat.batch.filter_scene`.
    workers : int, optional
        Run the windows as tasks of a local Ray instance with this many CPUs.
    address : str, optional
        Run them on the Ray cluster at this address (``"auto"``, ``"HOST:PORT"``).
    window, margin : int, optional
        Views per block and views held on each side (:func:`plan_windows`); default
        :data:`WINDOW_VIEWS` and :data:`MARGIN_VIEWS`.
    progress : callable, optional
        ``progress("windows", done, total)`` as windows finish; before them, for a capture
        with shared Gaussians, ``progress("shared", done, total)`` as each camera's are found.
    log : callable, optional
        ``log(line)``: the capture's size and the windows, once.

    Returns
    -------
    dict
        As :func:`clearsplat.batch.filter_scene`, with ``windows`` (their count).

    Raises
    ------
    ClearsplatError
        Bad input (naming the file and field), an ``out`` that may not be written, or a window
        that failed (its views and the cause; the windows done are kept for a rerun).
    """
    from ..filter import FilterConfig
    from ..filter.pipeline import resolve_auto
    from ..io.output import check_output_folder

    t0 = time.perf_counter()
    window = WINDOW_VIEWS if window is None else window
    margin = MARGIN_VIEWS if margin is None else margin
    bundle, out = Path(scene), Path(out)
    check_output_folder(out, inputs=[bundle], force=force)
    config = config or FilterConfig()
    ply, cameras, image_paths, views = _checked_input(bundle)
    windows = plan_windows(len(cameras), window=window, margin=margin)
    warned = _order_warning(cameras, windows, margin)
    for line in warned if log is not None else ():
        log(line)
    state = _state_folder(out)
    done = _begin_state(state, _fingerprint(bundle, config, windows), views, log)
    if log is not None:
        log(f"{ply.count:,} Gaussians, {len(cameras)} views, in {len(windows)} "
            f"window{'s' * (len(windows) != 1)} of about {window} views (+{margin} on each "
            "side)")
    report = progress or (lambda stage, d, total: None)
    report("windows", len(done), len(windows))
    resolved = resolve_auto(config, len(cameras))
    from ..io import load_render_settings
    _find_shared(ply, views, cameras, windows, state,
                 eps2d=load_render_settings(bundle_camera_file(bundle)).eps2d, report=report)
    shared = [int(np.load(_shared_file(state, w), mmap_mode="r").shape[0]) for w in windows]
    memory = _window_memory(windows, views, cameras, ply.dtype.itemsize, resolved,
                            shared=shared)
    del views
    jobs = [{**w.record(), "bundle": os.fspath(bundle.resolve()),
             "state": os.fspath(state.resolve()), "count": ply.count,
             "config": resolved, "memory": memory[w.index]}
            for w in windows if w.index not in done]
    finished = [len(done)]

    def tick():
        finished[0] += 1
        report("windows", finished[0], len(windows))

    failed = _run(jobs, workers, address, tick)
    if failed:
        w, cause = failed[0]
        raise ClearsplatError(f"window {w['index']} (views {w['judged'][0]}.."
                              f"{w['judged'][1] - 1}) failed: {cause}; {len(failed)} of "
                              f"{len(windows)} windows failed, the others are kept for a "
                              "rerun", path=bundle, field="window")
    removed, summary, sets = _merged(state, windows, ply.count, config, warned)
    _write_outputs(out, bundle, ply, removed, summary, sets, cameras, image_paths,
                   keep_all=keep_all, copy_images=copy_images, force=force)
    shutil.rmtree(state, ignore_errors=True)
    return {"gaussians": int(ply.count), "removed": summary["removed"],
            "accepted": summary["accepted"], "candidates": len(summary["candidates"]),
            "seconds": time.perf_counter() - t0, "warnings": summary["warnings"],
            "windows": len(windows)}


def _window_memory(windows: list[Window], views: np.ndarray, cameras, record_bytes: int,
                   config, *, shared=None) -> list[int]:
    """Bytes each window may need at its peak: its rows read and decoded, and the filter's
    estimate for its Gaussians and cameras (Ray's ``memory`` resource for its task).
    ``shared``: per window, the shared Gaussians it holds besides its views' own."""
    from .._memory import estimate_filter_memory
    per_view = np.bincount(views[views >= 0], minlength=len(cameras))
    budget = None if config.view_memory is None else int(config.view_memory * 1e9)
    out = []
    for k, w in enumerate(windows):
        n = int(per_view[w.held.start:w.held.stop].sum()) + (0 if shared is None
                                                               else int(shared[k]))
        out.append(2 * n * record_bytes + estimate_filter_memory(
            n, cameras[w.held.start:w.held.stop], view_budget=budget))
    return out


def _checked_input(bundle: Path):
    """The bundle's PLY (in pieces), cameras, image paths and every row's view (int32),
    checked: a view (or -1, shared) for every row, an image for every view."""
    from ..io import load_cameras
    from ..io.ply import PlyRows

    ply = PlyRows(bundle / "gaussians.ply")
    cameras, image_paths = load_cameras(bundle)
    if "view_id" not in ply.dtype.names:
        raise ClearsplatError("property 'view_id' is missing: a capture filtered in windows "
                              "needs each Gaussian's view", path=ply.path, field="view_id")
    views = ply.column("view_id")
    bad = ((views < 0) & (views != SHARED)) | (views >= len(cameras)) \
        | (views != np.round(views))
    if bad.any():
        i = int(np.argmax(bad))
        raise ClearsplatError(f"view id {views[i]} at vertex {i} is out of range: the bundle "
                              f"has {len(cameras)} cameras (0..{len(cameras) - 1}, or -1: "
                              "shared)", path=ply.path, field="view_id")
    if "pixel_id" in ply.dtype.names and (views == SHARED).any():   # a second pass: fused only
        check_association(views.astype(np.int64), ply.column("pixel_id"), cameras, ply.path)
    missing = [i for i, p in enumerate(image_paths) if p is None or not Path(p).is_file()]
    if missing:
        raise ClearsplatError(f"frame {missing[0]} image file not found ({len(missing)} of "
                              f"{len(image_paths)} missing); the filter needs the input images",
                              path=bundle_camera_file(bundle), field=f"frames[{missing[0]}]")
    return ply, cameras, image_paths, views.astype(np.int32)


def _order_warning(cameras, windows: list[Window], margin: int) -> list[str]:
    """The warning (a list of one, or empty) for an input order that does not follow the
    camera path, where there are several windows to cut it."""
    if len(windows) < 2:
        return []
    breaks = order_breaks(cameras, margin=margin)
    if breaks.mean() <= _BREAKS_WARN:
        return []
    return [f"the input order does not follow the camera path: for {int(breaks.sum())} of "
            f"{len(cameras)} views the nearest camera is more than {margin} views away, and "
            "windows of consecutive views cut them off their neighbours; order the frames "
            "along the path"]


def _merged(state: Path, windows: list[Window], count: int, config, warned: list):
    """The windows' files merged: the (N,) removal, ``summary.json`` and the candidates
    (numbered across the windows, in window order)."""
    from ..review import CandidateSets
    removed = np.zeros(count, bool)
    parts, records, summaries = [], [], []
    for w in windows:
        with np.load(state / f"window-{w.index}.npz") as z:
            removed[z["removed"]] = True
            parts.append(CandidateSets.from_arrays(
                {k[2:]: z[k] for k in z.files if k.startswith("c_")}))
            records.extend(json.loads(str(z["records"])))
            summaries.append(json.loads(str(z["done"])))
    for k, r in enumerate(records):
        r["index"] = k
    warned = list(warned)
    for s in summaries:
        warned.extend(m for m in s["warnings"] if m not in warned)
    summary = {"config": config.to_dict(), "gaussians": int(count),
               "removed": int(removed.sum()), "candidates": records,
               "accepted": int(sum(r["accepted"] for r in records)),
               "timings": _summed([s["timings"] for s in summaries]),
               "windows": [dict(w.record(), removed=s["removed"], seconds=round(s["seconds"], 3))
                           for w, s in zip(windows, summaries)],
               "warnings": warned}
    return removed, summary, CandidateSets.concatenate(parts, num_gaussians=count)


def _write_outputs(out: Path, bundle: Path, ply, removed, summary: dict, sets, cameras,
                   image_paths, *, keep_all: bool, copy_images: bool, force: bool) -> None:
    """What ``clearsplat filter`` writes, the rows copied from the input a piece at a time."""
    from ..io import load_render_settings, save_bundle_cameras
    from ..io.output import output_folder
    from ..review import CANDIDATES_FILE, REMOVED_FILE, write_candidates

    with output_folder(out, inputs=[bundle], force=force, command="filter") as tmp:
        kept = np.arange(ply.count) if keep_all else np.flatnonzero(~removed)
        ply.write_rows(tmp / "gaussians.ply", kept,
                       zero_opacity=removed[kept] if keep_all else None)
        np.save(tmp / "removed.npy", removed)
        ply.write_rows(tmp / REMOVED_FILE, np.flatnonzero(removed))
        write_candidates(tmp / CANDIDATES_FILE, sets, num_gaussians=ply.count)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
        save_bundle_cameras(tmp, cameras, image_paths, located_at=out, copy_images=copy_images,
                            render=load_render_settings(bundle_camera_file(bundle)))


def _summed(timings: list) -> dict:
    out: dict = {}
    for t in timings:
        for k, v in t.items():
            out[k] = out.get(k, 0.0) + v
    return {k: round(v, 4) for k, v in out.items()}


def _run(jobs: list, workers, address, tick) -> list:
    """Run :func:`filter_window` on each job, here or on Ray, calling ``tick()`` as each
    ends; the failed ones as ``(job, cause)``."""
    if workers is None and address is None:
        failed = []
        for job in jobs:
            try:
                filter_window(job)
            except Exception as e:      # reported with the others', the rest go on
                failed.append((job, f"{type(e).__name__}: {' '.join(str(e).split())}"))
            tick()
        return failed
    from .engine import TaskFailed, node_memory, ray_cluster, run_tasks
    failed = []
    with ray_cluster(address=address, num_cpus=workers) as ray:
        largest = max(node_memory(ray), default=0.0)
        need = max((job["memory"] for job in jobs), default=0)
        if largest and need > largest:
            raise ClearsplatError(f"a window needs about {need / 1e9:.1f} GB, the largest "
                                  f"Ray node has {largest / 1e9:.1f} GB", field="memory")
        # Each task asks for its window's memory, so that a node runs no more windows at
        # once than it holds; a worker that died is started again once, a window that
        # raised is reported.
        options = [{"num_cpus": 1, "max_retries": 1, "memory": max(job["memory"], 1)}
                   for job in jobs]
        for i, result in run_tasks(ray, filter_window, jobs, options=options):
            if isinstance(result, TaskFailed):
                failed.append((jobs[i], str(result)))
            tick()
    return failed
