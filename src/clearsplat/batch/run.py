"""Many scenes at once: ``clearsplat batch`` as a library call.

Each scene is one Ray task running :func:`~clearsplat.batch.filter_scene` into
``OUT/<scene folder name>/``. Tasks ask Ray for ``cpus_per_scene`` CPUs and for the scene's
estimated memory (Ray's ``memory`` resource), so a node never runs more scenes than its memory
holds. A failing scene fails alone; a second run skips the scenes whose output is complete.
"""

from __future__ import annotations

import csv
import glob
import io
import json
import os
import shutil
import time
from pathlib import Path
from typing import Callable, Iterable, Sequence

from ..errors import ClearsplatError
from .engine import TaskFailed, node_memory, ray_cluster, run_tasks
from .scene import estimate_scene_memory, filter_scene, is_complete

__all__ = ["find_scenes", "run_batch", "write_summary", "SUMMARY_FIELDS"]

#: Columns of ``summary.csv`` (and keys of each row of ``summary.json``).
SUMMARY_FIELDS = ("scene", "status", "gaussians", "removed", "seconds", "error", "path")
_RESERVED = {"summary.csv", "summary.json"}


def find_scenes(specs: Iterable[str]) -> list[Path]:
    """Scene folders from folders, glob patterns and text files listing paths.

    Parameters
    ----------
    specs : iterable of str
        Each is a folder (a scene), a file (one path per line, relative to the file's folder;
        blank lines and ``#`` comments skipped) or a glob pattern (``data/*/pred``, ``**``
        allowed) whose matching folders are scenes.

    Returns
    -------
    list of Path
        In the order given (glob matches sorted), each folder once.

    Raises
    ------
    ClearsplatError
        A pattern that matches no folder, a listed path that is not a folder, or two scenes
        with the same folder name (their outputs would collide).
    """
    found: list[Path] = []
    for spec in specs:
        p = Path(spec)
        if p.is_dir():
            found.append(p)
        elif p.is_file():
            try:
                lines = p.read_text(encoding="utf-8").splitlines()
            except (OSError, UnicodeDecodeError) as e:
                raise ClearsplatError(f"cannot read the list of scenes ({e})", path=p,
                                      field="SCENE") from None
            for lineno, line in enumerate(lines, start=1):
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                q = Path(s) if os.path.isabs(s) else p.parent / s
                if not q.is_dir():
                    raise ClearsplatError(f"{s!r} is not a folder", path=p,
                                          field=f"line {lineno}")
                found.append(q)
        else:
            matches = sorted(Path(m) for m in glob.glob(spec, recursive=True))
            matches = [m for m in matches if m.is_dir()]
            if not matches:
                raise ClearsplatError("no such folder, and as a pattern it matches no folder",
                                      path=spec, field="SCENE")
            found.extend(matches)
    scenes, seen, names = [], set(), {}
    for s in found:
        real = os.path.realpath(s)
        if real in seen:
            continue
        seen.add(real)
        name = Path(real).name
        if name in names:
            raise ClearsplatError(f"two scenes are named {name!r} ({names[name]} and {s}); "
                                  "their outputs would collide: rename one", field="SCENE")
        if name in _RESERVED or name.startswith("."):
            raise ClearsplatError(f"a scene folder may not be named {name!r} (the batch "
                                  "folder uses that name)", path=s, field="SCENE")
        names[name] = s
        scenes.append(s)
    return scenes


def _prepare_out(out: Path, scenes: Sequence[Path]) -> None:
    """Create ``out`` (or accept an earlier batch's folder) and mark it as a batch folder."""
    from .. import __version__
    from ..io.output import MARKER, check_output_folder

    # a batch folder is never replaced as a whole: ``force`` only lets an earlier one through
    check_output_folder(out, inputs=scenes, force=True)
    if out.is_dir() and any(out.iterdir()):
        try:
            marker = json.loads((out / MARKER).read_text())
        except (OSError, ValueError):
            marker = None
        if not isinstance(marker, dict) or marker.get("command") != "batch":
            raise ClearsplatError("holds another command's output, not an earlier batch's; "
                                  "choose another folder", path=out, field="--out")
        return
    out.mkdir(parents=True, exist_ok=True)
    with open(out / MARKER, "w") as f:
        json.dump({"command": "batch", "version": __version__}, f)
        f.write("\n")


def _existing_state(dest: Path, *, config, keep_all, report) -> str:
    """``missing``, ``complete``, ``other-settings``, ``partial`` (ours) or ``foreign``."""
    from ..filter import FilterConfig
    from ..io.output import is_clearsplat_output

    if not dest.exists() or (dest.is_dir() and not dest.is_symlink() and not any(dest.iterdir())):
        return "missing"
    if is_complete(dest, config=config, keep_all=keep_all, report=report):
        return "complete"
    if not is_clearsplat_output(dest):
        return "foreign"
    try:
        recorded = json.loads((dest / "summary.json").read_text()).get("config")
    except (OSError, ValueError, AttributeError):
        recorded = None
    wanted = json.loads(json.dumps((config or FilterConfig()).to_dict()))
    if recorded is not None and recorded != wanted:
        return "other-settings"
    return "partial"


def _remove_stale_temporaries(out: Path, name: str) -> None:
    """Delete the temporary folders an interrupted run left for this scene."""
    for p in out.glob(f".{glob.escape(name)}.clearsplat-*"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)


def _scene_task(job: dict) -> dict:
    """One scene in a worker: :func:`filter_scene`, its failure caught as a one-line error."""
    t0 = time.perf_counter()
    try:
        r = filter_scene(job["scene"], job["out"], config=job["config"],
                         keep_all=job["keep_all"], report=job["report"],
                         copy_images=job["copy_images"], force=job["force"])
    except MemoryError:
        return {"status": "failed", "seconds": time.perf_counter() - t0,
                "error": "out of memory (see 'memory' in docs/errors.md)"}
    except Exception as e:              # noqa: BLE001 - one scene's failure must not stop others
        text = " ".join(str(e).split())
        if not isinstance(e, (ClearsplatError, OSError)):
            text = f"{type(e).__name__}: {text}"
        return {"status": "failed", "seconds": time.perf_counter() - t0, "error": text}
    return {"status": "ok", "gaussians": r["gaussians"], "removed": r["removed"],
            "seconds": r["seconds"], "error": "", "warnings": r["warnings"]}


def write_summary(rows: Sequence[dict], out) -> list[Path]:
    """Write ``out/summary.csv`` and ``out/summary.json`` (atomically); return their paths."""
    from ..io.ply import atomic_write_bytes

    out = Path(out)
    clean = [{k: r.get(k, "") for k in SUMMARY_FIELDS} for r in rows]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(SUMMARY_FIELDS), lineterminator="\n")
    w.writeheader()
    for r in clean:
        w.writerow({k: (f"{v:.2f}" if k == "seconds" and isinstance(v, float) else v)
                    for k, v in r.items()})
    paths = [out / "summary.csv", out / "summary.json"]
    atomic_write_bytes(paths[0], buf.getvalue().encode())
    counts = {s: sum(r["status"] == s for r in clean) for s in ("ok", "skipped", "failed")}
    doc = {"scenes": len(clean), **counts, "rows": clean}
    atomic_write_bytes(paths[1], (json.dumps(doc, indent=1) + "\n").encode())
    return paths


def run_batch(scenes: Sequence, out, *, config=None, keep_all: bool = False,
              report: bool = False, copy_images: bool = False, force: bool = False,
              address: str | None = None,
              num_cpus: int | None = None, cpus_per_scene: float = 1,
              progress: Callable[[str, int, int], None] | None = None,
              on_scene: Callable[[dict], None] | None = None) -> list[dict]:
    """Filter many scene bundles on Ray, each into ``out/<scene folder name>/``.

    Parameters
    ----------
    scenes : sequence of str or os.PathLike
        Bundle folders (see :func:`find_scenes`); their folder names must differ.
    out : str or os.PathLike
        The batch folder: created, or an earlier batch's folder (resumed).
    config : FilterConfig, optional
        The filter's settings, the same for every scene.
    keep_all, report, copy_images : bool
        As for ``clearsplat filter``.
    force : bool, default False
        Filter every scene again, replacing earlier outputs. Without it complete outputs
        are skipped, half-written ones redone, and an output made with other settings is
        a failure of that scene.
    address : str, optional
        Join this Ray cluster (``"auto"``, ``"HOST:PORT"``, ``"ray://HOST:PORT"``); default: a
        local Ray instance started and stopped by this call.
    num_cpus : int, optional
        CPUs of the local instance (default: all).
    cpus_per_scene : float, default 1
        CPUs each scene asks Ray for.
    progress : callable, optional
        ``progress("scenes", done, total)`` after each scene.
    on_scene : callable, optional
        Called with each scene's row when it finishes.

    Returns
    -------
    list of dict
        One row per scene, in the order given: ``scene``, ``status`` (``ok``, ``skipped``,
        ``failed``), ``gaussians``, ``removed``, ``seconds``, ``error`` (one line), ``path``,
        and ``memory`` (the estimate in bytes) for the scenes that ran.
    """
    from ..filter import FilterConfig

    config = config or FilterConfig()
    if not cpus_per_scene or cpus_per_scene <= 0:
        raise ClearsplatError(f"must be positive, got {cpus_per_scene!r}",
                              field="--cpus-per-scene")
    scenes = [Path(s) for s in scenes]
    out = Path(out)
    _prepare_out(out, scenes)
    rows = [{"scene": Path(os.path.realpath(s)).name, "path": os.fspath(s), "status": "",
             "gaussians": "", "removed": "", "seconds": "", "error": ""} for s in scenes]
    jobs, todo = [], []
    for i, s in enumerate(scenes):
        dest = out / rows[i]["scene"]
        state = "missing" if force else _existing_state(dest, config=config,
                                                        keep_all=keep_all, report=report)
        if state == "complete":
            summary = json.loads((dest / "summary.json").read_text())
            rows[i].update(status="skipped", gaussians=summary["gaussians"],
                           removed=summary["removed"], seconds=0.0)
            continue
        if state == "other-settings":
            rows[i].update(status="failed", seconds=0.0, error=(
                f"{dest}: --out: holds an output made with other filter settings; pass "
                "--force to replace it"))
            continue
        _remove_stale_temporaries(out, rows[i]["scene"])
        todo.append(i)
        jobs.append({"scene": os.fspath(s), "out": os.fspath(dest), "config": config,
                     "keep_all": keep_all, "report": report, "copy_images": copy_images,
                     "force": force or state == "partial"})
    total, done = len(scenes), len(scenes) - len(todo)

    def finish(i, result):
        nonlocal done
        rows[i].update(result)
        done += 1
        write_summary(rows, out)
        if on_scene:
            on_scene(rows[i])
        if progress:
            progress("scenes", done, total)

    if progress and done:
        progress("scenes", done, total)
    if todo:
        with ray_cluster(address=address, num_cpus=num_cpus) as ray:
            largest = max(node_memory(ray), default=0.0)
            runnable, options = [], []
            for i, job in zip(todo, jobs):
                need = max(int(estimate_scene_memory(job["scene"])), 1)
                rows[i]["memory"] = need
                if largest and need > largest:
                    finish(i, {"status": "failed", "seconds": 0.0, "error": (
                        f"{job['scene']}: memory: needs about {need / 1e9:.1f} GB, the "
                        f"largest Ray node offers {largest / 1e9:.1f} GB")})
                    continue
                runnable.append((i, job))
                options.append({"num_cpus": cpus_per_scene, "memory": need})
            for k, result in run_tasks(ray, _scene_task, [j for _, j in runnable],
                                       options=options):
                if isinstance(result, TaskFailed):
                    result = {"status": "failed", "seconds": "", "error": str(result)}
                finish(runnable[k][0], result)
    write_summary(rows, out)
    return rows
