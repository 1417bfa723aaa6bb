"""One scene: filter a bundle into an output folder, exactly as ``clearsplat filter`` does.

:func:`filter_scene` is the unit of work of a batch. It is a plain function (no Ray), so a
batch run and a single ``clearsplat filter`` run write the same files: ``gaussians.ply``,
``removed.npy``, ``removed.ply`` and ``candidates.npz`` (for ``clearsplat edit``),
``summary.json`` (whose ``timings`` are the only values that change from run
to run), ``report/`` with ``report=True``, and the marker of :mod:`clearsplat.io.output`.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path


from ..errors import ClearsplatError

__all__ = ["write_filter_outputs", "filter_scene", "is_complete", "ply_vertex_count",
           "estimate_scene_memory", "FILTER_FILES"]

#: The files every ``clearsplat filter`` output folder holds.
FILTER_FILES = ("cameras.json", "gaussians.ply", "removed.npy", "summary.json",
                "candidates.npz", "removed.ply")


def write_filter_outputs(folder, scene, result, *, keep_all: bool = False,
                         report: bool = False, source: str | None = None, located_at=None,
                         copy_images: bool = False) -> None:
    """Write what ``clearsplat filter`` writes into ``folder`` (an existing, empty folder).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder to write into.
    scene : Scene
        The filtered scene.
    result : FilterResult
        What :func:`clearsplat.filter_distractors` returned for ``scene``.
    keep_all : bool, default False
        Keep every Gaussian in ``gaussians.ply``, the removed ones with zero opacity.
    report : bool, default False
        Also write the diagnostic pictures, a before | after video and the HTML page into
        ``folder/report``.
    source : str, optional
        The input bundle. With it the folder is itself a bundle: its ``cameras.json`` refers to
        the input's images (or copies them, ``copy_images``), so that it loads again from
        ``located_at`` (where ``folder`` is moved to; default ``folder``); the report names it.
    located_at : str or os.PathLike, optional
        The folder's final place, when it is written elsewhere first.
    copy_images : bool, default False
        Copy the input images into the folder instead of referring to them.
    """
    from ..io import load_cameras, save_bundle_cameras
    from ..review import CANDIDATES_FILE, write_candidates, write_removal

    write_removal(folder, scene, result.removed, keep_all=keep_all)
    # what 'clearsplat edit' needs to flip a verdict: every candidate's Gaussians
    write_candidates(os.path.join(folder, CANDIDATES_FILE), result.candidates,
                     num_gaussians=len(scene))
    with open(os.path.join(folder, "summary.json"), "w") as f:
        json.dump(result.summary(), f, indent=1)
    if source is not None:
        cameras, image_paths = load_cameras(source)
        save_bundle_cameras(folder, cameras, image_paths, located_at=located_at,
                            copy_images=copy_images, render=scene.render_settings)
    if report:                          # report and video modules only when asked for
        from ..report import write_report
        from ..video import make_video
        os.makedirs(os.path.join(folder, "report"), exist_ok=True)
        video = make_video(os.path.join(folder, "report", "video.mp4"), scene, result.keep,
                           num_frames=48)
        write_report(os.path.join(folder, "report"), scene, result, source=source,
                     video=video.name)


def filter_scene(scene, out, *, config=None, keep_all: bool = False, report: bool = False,
                 copy_images: bool = False, force: bool = False, progress=None,
                 log=None, windows: bool | None = None, workers: int | None = None,
                 address: str | None = None) -> dict:
    """Load the bundle ``scene``, filter it and write the outputs into the folder ``out``.

    Parameters
    ----------
    scene : str or os.PathLike
        The bundle folder (see :func:`clearsplat.io.load_scene`).
    out : str or os.PathLike
        The output folder, written in full or not at all
        (:func:`clearsplat.io.output.output_folder`).
    config : FilterConfig, optional
        Default: ``FilterConfig()``.
    keep_all, report, copy_images : bool
        As in :func:`write_filter_outputs`.
    force : bool, default False
        Replace an ``out`` folder that clearsplat wrote earlier.
    progress : callable, optional
        ``progress(stage, done, total)``, passed to the filter (and to the association of a
        PLY without ``view_id``).
    log : callable, optional
        ``log(line)``, told the scene's size once it is loaded (``clearsplat filter`` prints it).
    windows : bool, optional
        Filter the capture in windows of consecutive views (:func:`clearsplat.batch.
        filter_windows`: memory bounded by a window). Default: from
        :data:`~clearsplat.batch.windows.WINDOWS_FROM` views on, where the bundle's PLY is
        binary with ``view_id`` and no report is asked for, and whenever ``workers`` or
        ``address`` is given.
    workers, address : optional
        Run the windows as Ray tasks: on a local instance with ``workers`` CPUs, or on the
        cluster at ``address``.

    Returns
    -------
    dict
        ``gaussians``, ``removed``, ``accepted``, ``candidates`` (counts), ``seconds`` (wall
        time of the whole call) and ``warnings`` (list of str, each once).

    Raises
    ------
    ClearsplatError
        Bad input (naming the file and field) or an ``out`` that may not be written.
    """
    from ..filter import filter_distractors
    from ..io import load_scene
    from ..io.output import check_output_folder, output_folder

    t0 = time.perf_counter()
    check_output_folder(out, inputs=[scene], force=force)
    # Ray asked for: the windows are what it spreads
    asked = bool(windows) or workers is not None or address is not None
    if windows is None:
        windows = asked or (not report and _windowed(scene))
    if windows:
        from .windows import filter_windows
        if report:
            raise ClearsplatError("a capture filtered in windows has no report (it would "
                                  "render the whole capture at once); leave out --report",
                                  field="--report")
        return filter_windows(scene, out, config=config, keep_all=keep_all,
                              copy_images=copy_images, force=force, workers=workers,
                              address=address, progress=progress, log=log)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # A PLY without view_id: each Gaussian's view recovered from the images (one line).
        loaded = load_scene(scene, associate=True, progress=progress)
        if log is not None:
            log(f"{len(loaded):,} Gaussians, {loaded.num_views} views")
            for w in caught:        # told once, here, before the filter runs
                log(str(w.message))
            del caught[:]
        try:
            result = filter_distractors(loaded, config=config, progress=progress)
        except ClearsplatError as e:
            if e.path is None:          # an in-memory check: the scene is the file at fault
                raise ClearsplatError(e.reason, path=os.fspath(scene), field=e.field) from None
            raise
    shown = []
    for message in [str(w.message) for w in caught] + list(result.warnings):
        if message not in shown:
            shown.append(message)
    with output_folder(out, inputs=[scene], force=force, command="filter") as tmp:
        with warnings.catch_warnings(record=True) as caught_writing:     # the GIF fallback's
            warnings.simplefilter("always")
            write_filter_outputs(tmp, loaded, result, keep_all=keep_all, report=report,
                                 source=os.fspath(scene), located_at=out,
                                 copy_images=copy_images)
    for message in (str(w.message) for w in caught_writing):
        if message not in shown:
            shown.append(message)
    s = result.summary()
    return {"gaussians": s["gaussians"], "removed": s["removed"], "accepted": s["accepted"],
            "candidates": len(s["candidates"]), "seconds": time.perf_counter() - t0,
            "warnings": shown}


def _windowed(scene) -> bool:
    """Whether the bundle ``scene`` is filtered in windows by default: enough views, and a
    binary PLY with ``view_id`` that can be read in pieces."""
    from ..io import load_cameras
    from ..io.ply import PlyRows
    from .windows import uses_windows
    try:
        cameras, _ = load_cameras(scene)
        if not uses_windows(len(cameras)):
            return False
        return "view_id" in PlyRows(Path(scene) / "gaussians.ply").dtype.names
    except ClearsplatError:
        return False        # the whole-capture path reports the bad input


def ply_vertex_count(path) -> int | None:
    """The vertex count a PLY file's header declares, or None when the header is unreadable."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    for line in head[:end].splitlines():
        words = line.split()
        if len(words) == 3 and words[0] == b"element" and words[1] == b"vertex" \
                and words[2].isdigit():
            return int(words[2])
    return None


def is_complete(out, *, config=None, keep_all: bool = False, report: bool = False) -> bool:
    """True when ``out`` holds a whole ``clearsplat filter`` output made with these settings.

    Checks the marker (command ``filter``), the files, that ``summary.json`` records
    ``config`` (default ``FilterConfig()``), that ``gaussians.ply`` holds the kept Gaussians
    (every Gaussian with ``keep_all``), and ``report/`` when ``report`` is set.
    """
    from ..filter import FilterConfig
    from ..io.output import MARKER

    out = Path(out)
    try:
        marker = json.loads((out / MARKER).read_text())
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(marker, dict) or marker.get("command") != "filter" \
            or not isinstance(summary, dict):
        return False
    if not all((out / name).is_file() for name in FILTER_FILES):
        return False
    if report and not (out / "report").is_dir():
        return False
    wanted = json.loads(json.dumps((config or FilterConfig()).to_dict()))
    if summary.get("config") != wanted:
        return False
    try:
        expected = summary["gaussians"] - (0 if keep_all else summary["removed"])
    except (KeyError, TypeError):
        return False
    return ply_vertex_count(out / "gaussians.ply") == expected


def estimate_scene_memory(scene) -> int:
    """Bytes that filtering the bundle ``scene`` may need at its peak (an upper estimate).

    The reading peak of its ``gaussians.ply`` plus the filter's own estimate
    (:func:`clearsplat._memory.estimate_filter_memory`, with the Gaussian count from the PLY
    header and the cameras from the bundle). Unreadable parts count as zero: the scene then
    fails on its own when it runs.
    """
    from .._memory import estimate_filter_memory, estimate_read_memory
    from ..io import load_cameras

    ply = Path(scene) / "gaussians.ply"
    try:
        size = ply.stat().st_size
    except OSError:
        size = 0
    try:
        cameras, _ = load_cameras(scene)
    except ClearsplatError:
        cameras = []
    n = ply_vertex_count(ply) or 0
    try:
        with open(ply, "rb") as f:
            ascii_ply = b"format ascii" in f.read(1 << 10)
    except OSError:
        ascii_ply = False
    return estimate_read_memory(size, ascii=ascii_ply) + estimate_filter_memory(n, cameras)
