"""``clearsplat batch``: many scenes on Ray, outputs identical to single ``clearsplat filter`` runs.

The Ray tests share one local Ray instance (module fixture); one slow test starts a second Ray
node with ``ray start --head --block`` on 127.0.0.1 (own ports and temp folder), runs the
command against it with ``--address`` and stops it by its process id.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from clearsplat import ClearsplatError, FilterConfig
from clearsplat.batch import (estimate_scene_memory, filter_scene, find_scenes, is_complete,
                              ply_vertex_count, run_batch)
from clearsplat.cli import main
from clearsplat.io import load_cameras

HAVE_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="ray is not installed "
                                                    "(pip install 'clearsplat[batch]')")
GOOD = ("a", "b", "c")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Three small bundles, one with a truncated PLY, and each filtered by the CLI alone."""
    from clearsplat.synth import make_world, reconstruct
    root = tmp_path_factory.mktemp("batch")
    for seed, name in enumerate(GOOD):
        world = make_world("object", num_views=3, height=32, width=56, seed=seed)
        reconstruct(world.cameras, world.images, world.depths, seed=1).save(
            root / "scenes" / name)
    shutil.copytree(root / "scenes" / "a", root / "scenes" / "broken")
    ply = root / "scenes" / "broken" / "gaussians.ply"
    ply.write_bytes(ply.read_bytes()[:-1000])
    for name in GOOD:
        assert main(["filter", str(root / "scenes" / name), "--out",
                     str(root / "single" / name)]) == 0
    return root


def same_output(a: Path, b: Path) -> None:
    """Byte-identical files; ``summary.json`` equal but for the timings; ``cameras.json`` equal
    but for the image paths, which lead from each folder to the same input images."""
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert names == [".clearsplat.json", "cameras.json", "candidates.npz", "gaussians.ply",
                     "removed.npy", "removed.ply", "summary.json"]
    for n in (".clearsplat.json", "gaussians.ply", "removed.npy"):
        assert (a / n).read_bytes() == (b / n).read_bytes(), n
    # cameras.json refers to the input images relative to where each output lies: the same
    # cameras and the same image files, whatever the folder.
    (ca, ia), (cb, ib) = load_cameras(a), load_cameras(b)
    assert ca == cb
    assert [Path(p).resolve() for p in ia] == [Path(p).resolve() for p in ib]
    sa, sb = (json.loads((p / "summary.json").read_text()) for p in (a, b))
    assert sa.pop("timings").keys() == sb.pop("timings").keys()
    assert sa == sb
    ja, jb = (json.loads((p / "cameras.json").read_text()) for p in (a, b))
    for doc in (ja, jb):                # and every other key of the file the same
        doc.pop("image_root", None)
        for frame in doc["frames"]:
            frame.pop("image")
    assert ja == jb


def mtimes(folder: Path) -> dict:
    return {p: p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


# ------------------------------------------------------------------------------------------------
# without Ray
# ------------------------------------------------------------------------------------------------
def test_find_scenes(data, tmp_path):
    scenes = data / "scenes"
    assert find_scenes([str(scenes / "b"), str(scenes / "a")]) == [scenes / "b", scenes / "a"]
    assert [p.name for p in find_scenes([str(scenes / "*")])] == ["a", "b", "broken", "c"]
    listing = tmp_path / "list.txt"
    listing.write_text(f"# scenes\n\n{os.path.relpath(scenes / 'c', tmp_path)}\n"
                       f"{scenes / 'a'}\n{scenes / 'c'}\n")
    assert [p.name for p in find_scenes([str(listing), str(scenes / "a")])] == ["c", "a"]
    with pytest.raises(ClearsplatError, match="matches no folder"):
        find_scenes([str(tmp_path / "nothing*")])
    listing.write_text("missing\n")
    with pytest.raises(ClearsplatError, match="line 1.*not a folder"):
        find_scenes([str(listing)])
    shutil.copytree(scenes / "a", tmp_path / "other" / "a")
    with pytest.raises(ClearsplatError, match="two scenes are named 'a'"):
        find_scenes([str(scenes / "a"), str(tmp_path / "other" / "a")])


def test_filter_scene_writes_what_filter_writes(data, tmp_path):
    r = filter_scene(data / "scenes" / "b", tmp_path / "b")
    same_output(tmp_path / "b", data / "single" / "b")
    removed = np.load(tmp_path / "b" / "removed.npy")
    assert (r["gaussians"], r["removed"]) == (removed.size, int(removed.sum()))
    assert r["seconds"] > 0
    with pytest.raises(ClearsplatError, match="--force"):
        filter_scene(data / "scenes" / "b", tmp_path / "b")
    with pytest.raises(ClearsplatError, match="broken.*gaussians"):
        filter_scene(data / "scenes" / "broken", tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_complete_outputs_and_memory_estimate(data, tmp_path):
    out = data / "single" / "a"
    assert is_complete(out)
    assert not is_complete(out, config=FilterConfig(tau1=0.3))
    assert not is_complete(out, keep_all=True)       # the PLY holds only the kept Gaussians
    assert not is_complete(out, report=True)
    copy = tmp_path / "a"
    shutil.copytree(out, copy)
    (copy / "removed.npy").unlink()
    assert not is_complete(copy)
    summary = json.loads((out / "summary.json").read_text())
    assert ply_vertex_count(out / "gaussians.ply") == summary["gaussians"] - summary["removed"]
    assert ply_vertex_count(data / "scenes" / "a" / "cameras.json") is None

    from clearsplat._memory import estimate_filter_memory, estimate_read_memory
    from clearsplat.io import load_scene
    scene = load_scene(data / "scenes" / "a")
    ply = data / "scenes" / "a" / "gaussians.ply"
    assert estimate_scene_memory(data / "scenes" / "a") == (
        estimate_read_memory(ply.stat().st_size)
        + estimate_filter_memory(len(scene), scene.cameras))


def test_bad_batch_folder(data, tmp_path, capsys):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    code = main(["batch", str(data / "scenes" / "a"), "--out", str(foreign)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("clearsplat: error: ") and "mine" in err
    assert (foreign / "notes.txt").read_text() == "keep me"
    code = main(["batch", str(data / "scenes" / "a"), "--out", str(data / "scenes")])
    assert code == 2 and "would replace an input" in capsys.readouterr().err


def test_bad_options_are_one_line(data, tmp_path, capsys):
    for argv, fragment in (
            (["bench", "--workers", "0", "--out", str(tmp_path / "b")], "--workers"),
            (["batch", str(data / "scenes" / "a"), "--out", str(tmp_path / "o"),
              "--cpus-per-scene", "0"], "--cpus-per-scene"),
            (["batch", str(data / "scenes" / "a"), "--out", str(tmp_path / "o"),
              "--cpus-per-scene", "nan"], "--cpus-per-scene"),
            (["batch", str(data / "scenes" / "a"), "--out", str(tmp_path / "o"),
              "--num-cpus", "0"], "--num-cpus"),
            (["batch", str(tmp_path / "none*"), "--out", str(tmp_path / "o")], "SCENE")):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and fragment in err, err
    assert not (tmp_path / "o").exists() and not (tmp_path / "b").exists()


@needs_ray
def test_unreachable_address_is_one_line(data, tmp_path, capsys):
    # before the module's Ray instance starts: a connected process would use that one
    code = main(["batch", str(data / "scenes" / "a"), "--out", str(tmp_path / "o"),
                 "--address", f"127.0.0.1:{_free_port()}"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "cannot reach a Ray cluster" in err


# ------------------------------------------------------------------------------------------------
# on a local Ray instance
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def local_ray():
    if not HAVE_RAY:
        pytest.skip("ray is not installed (pip install 'clearsplat[batch]')")
    import ray
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
             logging_level="ERROR")
    yield ray
    ray.shutdown()


@needs_ray
def test_batch_matches_single_runs_and_isolates_failure(data, tmp_path, local_ray):
    out = tmp_path / "out"
    scenes = [data / "scenes" / n for n in ("a", "broken", "b", "c")]
    rows = run_batch(scenes, out)
    assert [r["scene"] for r in rows] == ["a", "broken", "b", "c"]
    assert [r["status"] for r in rows] == ["ok", "failed", "ok", "ok"]
    bad = rows[1]["error"]
    assert "broken" in bad and "gaussians.ply" in bad and "\n" not in bad
    assert not (out / "broken").exists()
    for name in GOOD:
        same_output(out / name, data / "single" / name)
    assert sorted(p.name for p in out.iterdir()) == [
        ".clearsplat.json", "a", "b", "c", "summary.csv", "summary.json"]
    doc = json.loads((out / "summary.json").read_text())
    assert (doc["scenes"], doc["ok"], doc["failed"], doc["skipped"]) == (4, 3, 1, 0)
    for row in doc["rows"]:
        if row["status"] == "ok":
            s = json.loads((out / row["scene"] / "summary.json").read_text())
            assert (row["gaussians"], row["removed"]) == (s["gaussians"], s["removed"])
            assert row["seconds"] > 0 and row["error"] == ""
    csv_lines = (out / "summary.csv").read_text().splitlines()
    assert csv_lines[0] == "scene,status,gaussians,removed,seconds,error,path"
    assert csv_lines[2].startswith("broken,failed,,,")


@needs_ray
def test_resume_skips_finished_and_redoes_half_written(data, tmp_path, local_ray):
    out = tmp_path / "out"
    scenes = [data / "scenes" / n for n in GOOD]
    assert [r["status"] for r in run_batch(scenes, out)] == ["ok"] * 3
    before = mtimes(out / "a") | mtimes(out / "c")
    (out / "b" / "removed.npy").unlink()                      # half-written by hand
    stale = out / ".b.clearsplat-dead"                        # a killed run's temporary
    stale.mkdir()
    rows = run_batch(scenes, out)
    assert [r["status"] for r in rows] == ["skipped", "ok", "skipped"]
    assert mtimes(out / "a") | mtimes(out / "c") == before
    assert not stale.exists()
    for name in GOOD:
        same_output(out / name, data / "single" / name)
    assert rows[0]["gaussians"] == 5376 and rows[0]["removed"] == json.loads(
        (out / "a" / "summary.json").read_text())["removed"]

    other = FilterConfig(tau1=0.3)
    rows = run_batch(scenes[:1], out, config=other)
    assert rows[0]["status"] == "failed" and "other filter settings" in rows[0]["error"]
    rows = run_batch(scenes[:1], out, config=other, force=True)
    assert rows[0]["status"] == "ok" and is_complete(out / "a", config=other)


@needs_ray
def test_memory_is_a_ray_resource(data, tmp_path, local_ray, monkeypatch):
    import clearsplat.batch.run as batch_run
    from clearsplat.batch import run_tasks
    from clearsplat.batch.engine import node_memory

    seen = []

    def spy(ray, fn, items, *, options=None):
        seen.extend(options)
        return run_tasks(ray, fn, items, options=options)

    monkeypatch.setattr(batch_run, "run_tasks", spy)
    scenes = [data / "scenes" / n for n in ("a", "b")]
    run_batch(scenes, tmp_path / "out", cpus_per_scene=1)
    assert seen == [{"num_cpus": 1, "memory": estimate_scene_memory(s)} for s in scenes]

    # a scene larger than every node fails alone, with the numbers, and is never submitted
    largest = max(node_memory(local_ray))
    monkeypatch.setattr(batch_run, "estimate_scene_memory",
                        lambda s: int(2 * largest) if Path(s).name == "a" else 1000)
    seen.clear()
    rows = run_batch([data / "scenes" / "a", data / "scenes" / "c"], tmp_path / "out2")
    assert [r["status"] for r in rows] == ["failed", "ok"]
    assert "memory" in rows[0]["error"] and "largest Ray node" in rows[0]["error"]
    assert len(seen) == 1

    # Ray holds a task back while the memory it asked for is taken: never oversubscribed
    def hold(seconds):
        start = time.time()
        time.sleep(seconds)
        return start, time.time()

    big = {"num_cpus": 1, "memory": int(0.6 * largest)}
    spans = [r for _, r in run_tasks(local_ray, hold, [1.0, 1.0], options=[big, big])]
    (s0, e0), (s1, e1) = sorted(spans)
    assert s1 >= e0 - 0.05, "two tasks of 60 % of the node's memory ran at once"


@needs_ray
def test_bench_grid_on_ray_gives_the_same_rows(local_ray):
    from clearsplat.bench import format_tables, run_suite
    grid = dict(families=("object",), views=(3,), seeds=(0, 1), height=32, width=48)
    serial = run_suite(**grid)
    logged = []
    on_ray = run_suite(**grid, workers=2, log=logged.append)
    assert sorted(logged) == ["object 3 views seed 0: done", "object 3 views seed 1: done"]

    def strip(rows):
        return [{k: v for k, v in r.items() if not k.startswith("time_")} for r in rows]
    assert strip(on_ray) == strip(serial)
    assert [r["seed"] for r in on_ray] == [0, 1]
    assert format_tables(on_ray).split("Runtime")[0] == format_tables(serial).split("Runtime")[0]


# ------------------------------------------------------------------------------------------------
# the command, in its own process: a local instance, and a second Ray node joined by --address
# ------------------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray_processes(marker: str) -> list[str]:
    ps = subprocess.run(["ps", "-ww", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if marker in line]


def _cli(args, env):
    return subprocess.run([sys.executable, "-m", "clearsplat", *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=300)


@needs_ray
@pytest.mark.slow
def test_command_locally_and_on_a_second_ray_node(data, tmp_path):
    # short paths: Ray's sockets live under the temp folder (107-character limit)
    temp = tempfile.mkdtemp(prefix="csray", dir="/tmp")
    env = dict(os.environ, RAY_TMPDIR=temp, RAY_AUTH_MODE="disabled")
    env.pop("RAY_ADDRESS", None)
    head = None
    try:
        # local: started and stopped by the command, nothing left running
        r = _cli(["batch", *(data / "scenes" / n for n in GOOD), "--out", tmp_path / "local"],
                 env)
        assert r.returncode == 0, r.stderr
        assert "3 filtered, 0 already done, 0 failed" in r.stdout
        assert _ray_processes(temp) == []
        for name in GOOD:
            same_output(tmp_path / "local" / name, data / "single" / name)

        # a second node: ray start --head on 127.0.0.1, its own ports and temp folder
        port = _free_port()
        head = subprocess.Popen(       # `ray start`, wherever pip put the script
            [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--block",
             "--node-ip-address=127.0.0.1", f"--port={port}", f"--temp-dir={temp}", "--num-cpus=2",
             "--include-dashboard=false", "--disable-usage-stats",
             "--object-store-memory=100000000",
             *(f"--{opt}={_free_port()}" for opt in (
                 "dashboard-agent-listen-port", "dashboard-agent-grpc-port",
                 "runtime-env-agent-port", "metrics-export-port", "node-manager-port",
                 "object-manager-port"))],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            start_new_session=True)
        deadline = time.time() + 120
        while time.time() < deadline:     # until the head's GCS listens
            try:
                socket.create_connection(("127.0.0.1", port), 1).close()
                break
            except OSError:
                assert head.poll() is None, "ray start --head failed"
                time.sleep(0.5)
        scenes = [data / "scenes" / n for n in ("a", "broken", "c")]
        r = _cli(["batch", *scenes, "--out", tmp_path / "cluster",
                  "--address", f"127.0.0.1:{port}"], env)
        assert r.returncode == 1, r.stderr
        assert "2 filtered, 0 already done, 1 failed" in r.stdout
        failed = [line for line in r.stderr.splitlines() if "scene failed" in line]
        assert len(failed) == 1 and "broken" in failed[0] and "gaussians.ply" in failed[0]
        for name in ("a", "c"):
            same_output(tmp_path / "cluster" / name, data / "single" / name)
        assert _ray_processes(temp), "the second node is gone before it was stopped"

        # resume on the cluster: finished scenes are skipped
        r = _cli(["batch", *scenes, "--out", tmp_path / "cluster",
                  "--address", f"127.0.0.1:{port}"], env)
        assert r.returncode == 1 and "0 filtered, 2 already done, 1 failed" in r.stdout
    finally:
        if head is not None:            # stop the node we started (by its id: `ray stop`
            head.send_signal(signal.SIGTERM)      # would stop every Ray of this user)
            try:
                head.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(head.pid, signal.SIGKILL)
                head.wait()
        deadline = time.time() + 30
        while _ray_processes(temp) and time.time() < deadline:
            time.sleep(0.5)
        left = _ray_processes(temp)
        shutil.rmtree(temp, ignore_errors=True)
    assert left == [], f"Ray processes left running: {left}"
