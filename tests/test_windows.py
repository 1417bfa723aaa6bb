"""A long capture in windows of consecutive views (:mod:`clearsplat.batch.windows`).

Checked against obviously-correct references: the windows' removals against each window's
scene filtered on its own in memory; one window holding every view against the whole-capture
filter, file for file; the pieces read from and written to a PLY against ``read_ply`` and
``write_ply``; a run killed with SIGKILL and started again against an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import clearsplat
from clearsplat import ClearsplatError, FilterConfig, filter_distractors
from clearsplat.batch import filter_scene, filter_windows, plan_windows
from clearsplat.filter.pipeline import resolve_auto
from clearsplat.cli import main
from clearsplat.io import load_scene, read_ply, write_ply
from clearsplat.io import ply as ply_module
from clearsplat.io.ply import PlyRows
from clearsplat.review import write_removal

HAVE_RAY = importlib.util.find_spec("ray") is not None
OPTIONS = {"window": 4, "margin": 2}


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A 14-frame video-like street (passers-by over several frames) as a bundle."""
    from clearsplat.synth import make_world, reconstruct
    root = tmp_path_factory.mktemp("windows")
    world = make_world("street", num_views=14, height=32, width=48, seed=3,
                       transients="video")
    reconstruct(world.cameras, world.images, world.depths, seed=3).save(root / "video")
    return root / "video"


@pytest.fixture(scope="module")
def windowed(video, tmp_path_factory):
    out = tmp_path_factory.mktemp("windowed") / "out"
    filter_windows(video, out, **OPTIONS)
    return out


@pytest.mark.parametrize("views, window, margin", [(1, 32, 8), (5, 32, 8), (14, 4, 2),
                                                   (100, 32, 8), (300, 32, 8), (97, 7, 0),
                                                   (1000, 32, 8)])
def test_plan_judges_every_view_once_with_its_margin(views, window, margin):
    plan = plan_windows(views, window=window, margin=margin)
    judged = [v for w in plan for v in w.judged]
    assert judged == list(range(views))
    sizes = [len(w.judged) for w in plan]
    assert max(sizes) - min(sizes) <= 1
    assert len(plan) == max(1, round(views / window))
    for w in plan:
        assert w.held == range(max(0, w.judged.start - margin),
                               min(views, w.judged.stop + margin))


def _big_endian_copy(src: Path, dest: Path) -> None:
    data = src.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].replace(b"binary_little_endian", b"binary_big_endian")
    rows = PlyRows(src)
    table = np.frombuffer(data, dtype=rows.dtype, count=rows.count, offset=end)
    dest.write_bytes(header + table.astype(rows.dtype.newbyteorder(">")).tobytes())


@pytest.mark.parametrize("order", ["little", "big"])
def test_rows_read_in_pieces_as_read_ply_reads_them(video, tmp_path, monkeypatch, order):
    path = video / "gaussians.ply"
    if order == "big":
        _big_endian_copy(path, tmp_path / "big.ply")
        path = tmp_path / "big.ply"
    monkeypatch.setattr(ply_module, "PIECE_ROWS", 1000)    # many pieces
    whole, view_id, pixel_id = read_ply(path)
    rows = PlyRows(path)
    assert rows.count == len(whole)
    assert np.array_equal(rows.column("view_id"), view_id)
    rng = np.random.default_rng(0)
    for pick in (np.arange(len(whole)), np.sort(rng.choice(len(whole), 777, replace=False)),
                 np.array([5]), np.zeros(0, np.int64)):
        g, v, p = rows.read(pick)
        ref = whole.subset(pick)
        for name in ("means", "scales", "quats", "opacities", "sh"):
            assert np.array_equal(getattr(g, name), getattr(ref, name)), name
        assert np.array_equal(v, view_id[pick]) and np.array_equal(p, pixel_id[pick])


def test_rows_written_in_pieces_as_write_ply_writes_them(video, tmp_path, monkeypatch):
    monkeypatch.setattr(ply_module, "PIECE_ROWS", 1000)
    scene = load_scene(video)
    removed = np.random.default_rng(1).random(len(scene)) < 0.3
    rows = PlyRows(video / "gaussians.ply")
    for keep_all in (False, True):
        ref = tmp_path / f"ref-{keep_all}"
        ref.mkdir()
        write_removal(ref, scene, removed, keep_all=keep_all)
        kept = np.arange(len(scene)) if keep_all else np.flatnonzero(~removed)
        rows.write_rows(tmp_path / "kept.ply", kept,
                        zero_opacity=removed[kept] if keep_all else None)
        assert (tmp_path / "kept.ply").read_bytes() == (ref / "gaussians.ply").read_bytes()
        rows.write_rows(tmp_path / "gone.ply", np.flatnonzero(removed))
        assert (tmp_path / "gone.ply").read_bytes() == (ref / "removed.ply").read_bytes()
    with pytest.raises(ValueError):
        rows.select([3, 2])


def test_windows_remove_what_each_window_decides_on_its_own(video, windowed):
    """Reference: each window's views cut from the whole scene in memory, filtered, and the
    accepted candidates of the views it judges taken."""
    scene = load_scene(video)
    config = resolve_auto(FilterConfig(), scene.num_views)
    expected = np.zeros(len(scene), bool)
    for w in plan_windows(scene.num_views, **OPTIONS):
        rows = np.flatnonzero(np.isin(scene.view_id, list(w.held)))
        part = dataclasses.replace(
            scene.subset(rows), view_id=(scene.view_id[rows] - w.held.start).astype(np.int32),
            cameras=scene.cameras[w.held.start:w.held.stop],
            images=scene.images[w.held.start:w.held.stop])
        result = filter_distractors(part, config=config)
        for c in result.candidates:
            if c.view + w.held.start in w.judged and c.accepted:
                expected[rows[c.expanded]] = True
    removed = np.load(windowed / "removed.npy")
    assert expected.any()
    assert np.array_equal(removed, expected)
    summary = json.loads((windowed / "summary.json").read_text())
    assert summary["removed"] == int(removed.sum())
    assert [w["judged"] for w in summary["windows"]] == [[0, 4], [4, 7], [7, 10], [10, 14]]
    assert sum(w["removed"] for w in summary["windows"]) >= int(removed.sum())
    assert all(c["view"] in range(14) for c in summary["candidates"])
    assert [c["index"] for c in summary["candidates"]] == list(range(len(summary["candidates"])))


def test_one_window_holding_every_view_is_the_whole_filter(video, tmp_path):
    filter_windows(video, tmp_path / "one", window=100)
    filter_scene(video, tmp_path / "whole", windows=False)
    for name in ("gaussians.ply", "removed.npy", "removed.ply", "candidates.npz",
                 "cameras.json", ".clearsplat.json"):
        assert (tmp_path / "one" / name).read_bytes() == \
            (tmp_path / "whole" / name).read_bytes(), name
    a, b = (json.loads((tmp_path / n / "summary.json").read_text()) for n in ("one", "whole"))
    assert [(w["judged"], w["held"], w["removed"]) for w in a.pop("windows")] == \
        [([0, 14], [0, 14], b["removed"])]
    a.pop("timings"), b.pop("timings")
    assert a == b


def test_keep_all_writes_every_row_with_the_removed_transparent(video, windowed, tmp_path):
    filter_windows(video, tmp_path / "all", keep_all=True, **OPTIONS)
    removed = np.load(windowed / "removed.npy")
    g, _, _ = read_ply(tmp_path / "all" / "gaussians.ply")
    whole, _, _ = read_ply(video / "gaussians.ply")
    assert len(g) == len(whole)
    assert (g.opacities[removed] < 1e-6).all()
    assert np.array_equal(g.opacities[~removed], whole.opacities[~removed])


_KILLED = """
import os, signal, sys
import clearsplat.batch.windows as w
real = w.filter_window
def dying(job):
    if job["index"] == 2:           # windows 0 and 1 are written: SIGKILL, as a user's kill -9
        os.kill(os.getpid(), signal.SIGKILL)
    return real(job)
w.filter_window = dying
w.filter_windows(sys.argv[1], sys.argv[2], window=4, margin=2)
"""


def test_a_killed_run_resumes_and_loses_nothing(video, windowed, tmp_path, capsys):
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-c", _KILLED, str(video), str(out)])
    assert run.returncode == -signal.SIGKILL
    assert not out.exists()
    state = tmp_path / ".out.clearsplat-windows"
    assert sorted(p.name for p in state.glob("window-*.npz")) == ["window-0.npz",
                                                                 "window-1.npz"]
    lines = []
    filter_windows(video, out, log=lines.append, **OPTIONS)
    assert "resuming: 2 of 4 windows done in an interrupted run" in lines
    assert not state.exists()
    for name in ("gaussians.ply", "removed.npy", "removed.ply", "candidates.npz"):
        assert (out / name).read_bytes() == (windowed / name).read_bytes(), name


@pytest.mark.parametrize("change", ["config", "version"])
def test_a_changed_config_starts_afresh(video, tmp_path, monkeypatch, change):
    import clearsplat
    import clearsplat.batch.windows as wmod

    out = tmp_path / "out"
    state = tmp_path / ".out.clearsplat-windows"
    subprocess.run([sys.executable, "-c", _KILLED, str(video), str(out)])
    assert len(list(state.glob("window-*.npz"))) == 2
    before = json.loads((state / "plan.json").read_text())
    seen = []
    real_run = wmod._run

    def run(jobs, *args):
        # Every window runs again, under a plan that names the new config.
        seen.append(len(jobs))
        assert json.loads((state / "plan.json").read_text())[change] != before[change]
        return real_run(jobs, *args)

    monkeypatch.setattr(wmod, "_run", run)
    lines = []
    if change == "version":
        monkeypatch.setattr(clearsplat, "__version__", "0.0.1")
    config = FilterConfig.preset("video") if change == "config" else None
    filter_windows(video, out, config=config, log=lines.append, **OPTIONS)
    assert not any(line.startswith("resuming") for line in lines)
    assert seen == [len(plan_windows(14, **OPTIONS))]


def test_a_second_run_into_the_same_out_is_refused(video, windowed, capsys):
    before = (windowed / "removed.npy").read_bytes()
    with pytest.raises(ClearsplatError, match="--force"):
        filter_windows(video, windowed, **OPTIONS)
    assert (windowed / "removed.npy").read_bytes() == before


def test_a_failing_window_is_reported_alone_and_the_others_kept(video, tmp_path, monkeypatch):
    import clearsplat.batch.windows as w
    real = w.filter_window

    def failing(job):
        if job["index"] == 1:
            raise RuntimeError("disk on fire")
        return real(job)

    monkeypatch.setattr(w, "filter_window", failing)
    with pytest.raises(ClearsplatError, match=r"window 1 \(views 4..6\) failed: RuntimeError: "
                                              r"disk on fire; 1 of 4 windows failed"):
        filter_windows(video, tmp_path / "out", **OPTIONS)
    state = tmp_path / ".out.clearsplat-windows"
    assert sorted(p.name for p in state.glob("window-*.npz")) == [
        "window-0.npz", "window-2.npz", "window-3.npz"]
    assert not (tmp_path / "out").exists()


def test_bad_view_ids_get_one_line(video, tmp_path):
    bad = tmp_path / "bad"
    import shutil
    shutil.copytree(video, bad)
    g, view_id, pixel_id = read_ply(bad / "gaussians.ply")
    view_id[10] = 99
    write_ply(bad / "gaussians.ply", g, view_id=view_id, pixel_id=pixel_id)
    with pytest.raises(ClearsplatError, match="view id 99 at vertex 10 is out of range") as e:
        filter_windows(bad, tmp_path / "out", **OPTIONS)
    assert e.value.field == "view_id"
    assert not (tmp_path / "out").exists()
    assert not (tmp_path / ".out.clearsplat-windows").exists()


def _random_rotations(rng, n):
    q = rng.standard_normal((n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize("eps2d, antialiased", [(0.3, False), (0.3, True), (3.0, False)])
def test_seen_by_holds_every_gaussian_the_rasterizer_draws(eps2d, antialiased):
    """Reference: the Gaussians the rasterizer keeps after culling (``PreparedView.visible``),
    and each Gaussian rendered alone: whatever covers a pixel of a camera is seen."""
    from clearsplat import Camera, RenderSettings
    from clearsplat.batch.windows import seen_by
    from clearsplat.cameras import look_at
    from clearsplat.render import prepare, render
    from clearsplat.scene import Gaussians
    rng = np.random.default_rng(7)
    settings = RenderSettings(eps2d=eps2d, antialiased=antialiased)
    cams = [Camera(K=[[40.0, 0, 30.0], [0, 40.0, 20.0], [0, 0, 1]],
                   camera_to_world=look_at(eye, (0.0, 0.0, 0.0)), width=60, height=40)
            for eye in ((0.0, -4.0, 0.5), (3.0, -3.0, 1.0))]
    n = 600
    means = rng.uniform(-6, 6, (n, 3))
    scales = np.exp(rng.uniform(np.log(0.005), np.log(0.8), (n, 3)))
    scales[: n // 2] = scales[: n // 2, :1]       # the first half round, the rest elongated
    g = Gaussians(means=means, scales=scales, quats=_random_rotations(rng, n),
                  opacities=rng.uniform(0.05, 0.99, n), sh=rng.uniform(0, 1, (n, 1, 3)))
    for k in range(len(cams)):
        seen = seen_by(means, scales, cams[k:k + 1], eps2d=eps2d)
        kept = np.zeros(n, bool)
        kept[prepare(g, cams[k], settings=settings).visible] = True
        drawn = np.array([render(g, cams[k], keep=np.arange(n) == i,
                                 settings=settings).alpha.max() > 0 for i in range(n)])
        assert drawn.sum() > 100 and not (drawn & ~kept).any()
        assert not (kept & ~seen).any()
        # Not everything: of the round ones, at most half again as many seen as drawn (the
        # bound takes an elongated one's largest scale in every direction). Checked where the
        # opacity does not cull: the bound ignores it, and the antialiased mode lowers small
        # Gaussians' opacity until more are culled.
        round_ = np.arange(n) < n // 2
        if not antialiased:
            assert seen[round_].sum() <= 1.5 * drawn[round_].sum()
    assert np.array_equal(seen_by(means, scales, cams, eps2d=eps2d),
                          seen_by(means, scales, cams[:1], eps2d=eps2d)
                          | seen_by(means, scales, cams[1:], eps2d=eps2d))
    # Closed form: a point one pixel inside the image's left border is seen; 5 px outside
    # it is not (its reach is 3.5 sqrt(0.3) + 1 = 2.9 px); behind the camera is not.
    cam = Camera(K=[[50.0, 0, 30.0], [0, 50.0, 20.0], [0, 0, 1]], camera_to_world=np.eye(4),
                 width=60, height=40)
    tiny = np.full((4, 3), 1e-6)
    pts = np.array([[(1 - 30) / 50 * 2, 0, 2], [(-5 - 30) / 50 * 2, 0, 2], [0, 0, -2],
                    [(-2.5 - 30) / 50 * 2, 0, 2]])
    assert seen_by(pts, tiny, [cam]).tolist() == [True, False, False, True]
    assert seen_by(pts, tiny, [cam], eps2d=3.0).tolist() == [True, True, False, True]
    assert seen_by(np.zeros((0, 3)), np.zeros((0, 3)), [cam]).shape == (0,)


@pytest.fixture(scope="module")
def fused(video, tmp_path_factory):
    """The video with a third of its Gaussians shared by every view (view id -1), as a fused
    export's static content is."""
    import shutil
    root = tmp_path_factory.mktemp("fused") / "fused"
    shutil.copytree(video, root)
    from clearsplat.scene import Gaussians
    g, view_id, pixel_id = read_ply(root / "gaussians.ply")
    shared = np.random.default_rng(5).random(len(g)) < 1 / 3
    view_id[shared], pixel_id[shared] = -1, -1
    # And a small shared Gaussian 0.1 in front of each camera: the cameras move forward, so
    # only those up to its own see it, and the last windows do not hold the first ones'.
    cams = load_scene(video).cameras
    ahead = np.stack([c.camera_to_world[:3, 3] + 0.1 * c.camera_to_world[:3, 2] for c in cams])
    # And three far behind every camera, which no window holds.
    first = cams[0].camera_to_world
    ahead = np.concatenate([ahead, first[:3, 3] - 30.0 * first[:3, 2]
                            + np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]])])
    k = len(ahead)
    g = Gaussians(means=np.concatenate([g.means, ahead]),
                  scales=np.concatenate([g.scales, np.full((k, 3), 1e-3, g.scales.dtype)]),
                  quats=np.concatenate([g.quats, np.tile(g.quats[:1], (k, 1))]),
                  opacities=np.concatenate([g.opacities, np.full(k, 0.5, g.opacities.dtype)]),
                  sh=np.concatenate([g.sh, g.sh[:k]]))
    write_ply(root / "gaussians.ply", g, view_id=np.concatenate([view_id, np.full(k, -1)]),
              pixel_id=np.concatenate([pixel_id, np.full(k, -1)]))
    assert all((c.to_camera(ahead[-3:])[:, 2] < 0).all() for c in cams)
    return root


def test_shared_gaussians_go_to_the_windows_that_see_them(fused, tmp_path, monkeypatch):
    """Reference: each window's scene cut from the whole in memory, its views' Gaussians and
    the shared ones its cameras see (seen_by), filtered on its own; and what each window loads
    holds every shared Gaussian that the rasterizer keeps in one of its cameras and none that
    lies behind them all."""
    import clearsplat.batch.windows as w_module
    from clearsplat.batch.windows import seen_by
    from clearsplat.render import prepare
    loaded = {}
    load = w_module._load_window

    def spy(bundle, state, window):
        scene, rows = load(bundle, state, window)
        loaded[window.index] = rows
        return scene, rows

    monkeypatch.setattr(w_module, "_load_window", spy)
    scene = load_scene(fused)
    config = resolve_auto(FilterConfig(), scene.num_views)
    shared = scene.view_id == -1
    expected = np.zeros(len(scene), bool)
    held_shared = []
    for w in plan_windows(scene.num_views, **OPTIONS):
        cams = scene.cameras[w.held.start:w.held.stop]
        mine = shared & seen_by(scene.gaussians.means, scene.gaussians.scales, cams)
        held_shared.append(int(mine.sum()))
        rows = np.flatnonzero(np.isin(scene.view_id, list(w.held)) | mine)
        part = dataclasses.replace(
            scene.subset(rows), view_id=np.where(shared[rows], -1, scene.view_id[rows]
                                                 - w.held.start).astype(np.int32),
            cameras=cams, images=scene.images[w.held.start:w.held.stop])
        result = filter_distractors(part, config=config)
        for c in result.candidates:
            if c.view + w.held.start in w.judged and c.accepted:
                expected[rows[c.expanded]] = True
    # Every window holds shared Gaussians; the last does not hold those in front of the first
    # cameras.
    assert min(held_shared) > 0 and held_shared[-1] <= shared.sum() - 8
    ticks = []
    filter_windows(fused, tmp_path / "out",
                   progress=lambda stage, done, total: ticks.append((stage, done, total)),
                   **OPTIONS)
    # The shared Gaussians are found one camera at a time (one piece of the file), then the
    # windows run.
    assert ticks == ([("windows", 0, 4)] + [("shared", k, 14) for k in range(1, 15)]
                     + [("windows", k, 4) for k in range(1, 5)])
    removed = np.load(tmp_path / "out" / "removed.npy")
    assert expected.any()
    assert np.array_equal(removed, expected)
    assert not (tmp_path / ".out.clearsplat-windows").exists()
    behind = np.flatnonzero(shared)[-3:]
    for w in plan_windows(scene.num_views, **OPTIONS):
        rows = loaded[w.index]
        drawn = np.zeros(len(scene), bool)
        for c in scene.cameras[w.held.start:w.held.stop]:
            drawn[prepare(scene.gaussians, c, settings=scene.render_settings).visible] = True
        assert np.isin(np.flatnonzero(shared & drawn), rows).all()
        assert not np.isin(behind, rows).any()
        assert np.array_equal(rows, np.flatnonzero(np.isin(scene.view_id, list(w.held))
                                                   | (shared & seen_by(
                                                       scene.gaussians.means,
                                                       scene.gaussians.scales,
                                                       scene.cameras[w.held.start:w.held.stop]))))
    # No region maps to a shared Gaussian: all are kept, in the output PLY too.
    kept = read_ply(tmp_path / "out" / "gaussians.ply")[1]
    assert not removed[shared].any() and (kept == -1).sum() == shared.sum()


def test_a_shared_gaussian_with_a_pixel_gets_one_line(fused, tmp_path):
    import shutil
    bad = tmp_path / "bad"
    shutil.copytree(fused, bad)
    g, view_id, pixel_id = read_ply(bad / "gaussians.ply")
    i = int(np.flatnonzero(view_id == -1)[3])
    pixel_id[i] = 5
    write_ply(bad / "gaussians.ply", g, view_id=view_id, pixel_id=pixel_id)
    with pytest.raises(ClearsplatError, match=rf"pixel id 5 at vertex {i} is out of range for "
                                              r"view -1 \(-1: shared, no pixel\)") as e:
        filter_windows(bad, tmp_path / "out", **OPTIONS)
    assert e.value.field == "pixel_id"
    assert not (tmp_path / "out").exists()
    assert not (tmp_path / ".out.clearsplat-windows").exists()


def test_a_fused_capture_in_one_window_is_the_whole_filter(fused, tmp_path, monkeypatch,
                                                            capsys):
    import clearsplat.batch.windows as w
    filter_windows(fused, tmp_path / "one", window=100)
    filter_scene(fused, tmp_path / "whole", windows=False)
    for name in ("gaussians.ply", "removed.npy", "removed.ply", "candidates.npz"):
        assert (tmp_path / "one" / name).read_bytes() == \
            (tmp_path / "whole" / name).read_bytes(), name
    # The command filters a long fused capture in windows.
    monkeypatch.setattr(w, "WINDOWS_FROM", 10)
    monkeypatch.setattr(w, "WINDOW_VIEWS", 7)
    assert main(["filter", str(fused), "--out", str(tmp_path / "windowed")]) == 0
    out = capsys.readouterr().out
    assert "in 2 windows of about 7 views" in out
    summary = json.loads((tmp_path / "windowed" / "summary.json").read_text())
    assert len(summary["windows"]) > 1


def test_the_command_uses_windows_from_the_threshold(video, tmp_path, monkeypatch, capsys):
    import clearsplat.batch.windows as w
    monkeypatch.setattr(w, "WINDOWS_FROM", 10)
    monkeypatch.setattr(w, "WINDOW_VIEWS", 7)
    assert main(["filter", str(video), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "in 2 windows of about 7 views" in out
    assert len(json.loads((tmp_path / "out" / "summary.json").read_text())["windows"]) == 2


@pytest.mark.skipif(not HAVE_RAY, reason="ray is not installed (pip install 'clearsplat[batch]')")
def test_windows_on_ray_remove_the_same(video, windowed, tmp_path):
    lines, ticks = [], []
    filter_windows(video, tmp_path / "ray", workers=2, log=lines.append,
                   progress=lambda stage, done, total: ticks.append((stage, done, total)),
                   **OPTIONS)
    for name in ("gaussians.ply", "removed.npy", "removed.ply", "candidates.npz"):
        assert (tmp_path / "ray" / name).read_bytes() == (windowed / name).read_bytes(), name
    assert ticks == [("windows", k, 4) for k in range(5)]


def test_a_windowed_output_is_reviewed_as_any_other(windowed, tmp_path):
    """Its candidates (numbered across the windows, in the capture's rows) feed `edit`."""
    from clearsplat.review import read_candidates
    summary = json.loads((windowed / "summary.json").read_text())
    sets = read_candidates(windowed / "candidates.npz", num_gaussians=summary["gaussians"],
                           count=len(summary["candidates"]))
    k = next(c["index"] for c in summary["candidates"] if c["accepted"])
    assert main(["edit", str(windowed), "--reject", str(k), "--out",
                 str(tmp_path / "edited")]) == 0
    before = np.load(windowed / "removed.npy")
    after = np.load(tmp_path / "edited" / "removed.npy")
    restored = np.flatnonzero(before & ~after)
    expanded = sets.expanded[sets.expanded_offsets[k]:sets.expanded_offsets[k + 1]]
    assert restored.size and np.isin(restored, expanded).all()
    assert not (after & ~before).any()


def test_an_order_that_does_not_follow_the_path_is_told(video, tmp_path):
    """A video's frames break no order; the same frames shuffled break most of it, and the
    windowed run says so (a warning in the log and in summary.json)."""
    from clearsplat.batch.windows import order_breaks
    scene = load_scene(video)
    assert not order_breaks(scene.cameras, margin=2).any()
    perm = np.random.default_rng(0).permutation(scene.num_views)
    assert order_breaks([scene.cameras[i] for i in perm], margin=2).mean() > 0.5
    # Reference: the nearest camera by brute force, one view at a time, shuffled order.
    cams = [scene.cameras[i] for i in perm]
    centres = [c.camera_to_world[:3, 3] for c in cams]
    found = order_breaks(cams, margin=1)
    for i in range(scene.num_views):
        d = [np.inf if j == i else np.linalg.norm(centres[i] - centres[j])
             for j in range(scene.num_views)]
        assert found[i] == (abs(int(np.argmin(d)) - i) > 1)
    shuffled = tmp_path / "shuffled"
    inverse = np.argsort(perm)
    g, view_id, pixel_id = read_ply(video / "gaussians.ply")
    dataclasses.replace(scene, view_id=inverse[view_id].astype(np.int32),
                        cameras=[scene.cameras[i] for i in perm],
                        images=[scene.images[i] for i in perm]).save(shuffled)
    lines = []
    filter_windows(shuffled, tmp_path / "out", log=lines.append, **OPTIONS)
    told = [line for line in lines if "does not follow the camera path" in line]
    assert len(told) == 1
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert told[0] in summary["warnings"]


@pytest.mark.skipif(not HAVE_RAY, reason="ray is not installed (pip install 'clearsplat[batch]')")
def test_a_window_larger_than_every_ray_node_gets_one_line(video, tmp_path, monkeypatch):
    import clearsplat.batch.windows as w
    monkeypatch.setattr(w, "_window_memory",
                        lambda windows, *a, **k: [10 ** 15] * len(windows))
    with pytest.raises(ClearsplatError, match=r"a window needs about 1000000.0 GB, the largest "
                                              r"Ray node has") as e:
        filter_windows(video, tmp_path / "out", workers=1, **OPTIONS)
    assert e.value.field == "memory"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("bundle", ["video", "fused"])
def test_each_window_asks_for_at_least_what_it_holds(bundle, request):
    """The memory a window asks Ray for grows with its rows and covers what it holds: its
    rows as read from the file, and its scene decoded (Gaussians, association, images); of a
    fused capture, the shared Gaussians its cameras see too."""
    from clearsplat.batch.windows import _window_memory, seen_by
    path = request.getfixturevalue(bundle)
    rows = PlyRows(path / "gaussians.ply")
    whole = load_scene(path)
    views = rows.column("view_id")
    plan = plan_windows(whole.num_views, **OPTIONS)
    g = whole.gaussians
    held = [np.isin(views, list(w.held)) | ((views == -1) & seen_by(
        g.means, g.scales, whole.cameras[w.held.start:w.held.stop])) for w in plan]
    shared = [int((h & (views == -1)).sum()) for h in held]
    need = _window_memory(plan, views, whole.cameras, rows.dtype.itemsize, FilterConfig(),
                          shared=shared)
    for m, w, mine in zip(need, plan, held):
        part = whole.subset(mine)
        p = part.gaussians
        decoded = sum(a.nbytes for a in (p.means, p.scales, p.quats, p.opacities, p.sh,
                                          part.view_id, part.pixel_id))
        decoded += sum(whole.images[i].nbytes for i in w.held)
        assert m >= int(mine.sum()) * rows.dtype.itemsize + decoded
    counts = [int(h.sum()) for h in held]
    assert (np.argsort(need, kind="stable") == np.argsort(counts, kind="stable")).all()


@pytest.mark.parametrize("views", [2, 7, 8, 23, 24, 40])
@pytest.mark.parametrize("preset", ["default", "video", "fast", "exact"])
def test_windows_resolve_auto_options_as_the_filter_does(views, preset, monkeypatch):
    """What each window runs: the choices filter_distractors makes for the whole capture."""
    from clearsplat import Camera
    from clearsplat.filter import pipeline
    from clearsplat.scene import Gaussians, Scene

    class Seen(Exception):
        pass

    seen = {}
    monkeypatch.setattr(pipeline, "view_plan",
                        lambda scene, **kw: seen.update(kw) or None)

    def stop(scene, config, extractor, backend, report, *, hold, plan, **kw):
        seen["hold"] = hold
        raise Seen

    monkeypatch.setattr(pipeline, "run_round", stop)
    cams = [Camera(K=[[8, 0, 8], [0, 8, 8], [0, 0, 1]],
                   camera_to_world=np.eye(4), width=16, height=16)
            for _ in range(views)]
    g = Gaussians(np.zeros((views, 3), np.float32) + [0, 0, 2], np.full((views, 3), 0.1,
                  np.float32), np.tile(np.float32([1, 0, 0, 0]), (views, 1)),
                  np.full(views, 0.5, np.float32), np.zeros((views, 1, 3), np.float32))
    scene = Scene(g, np.arange(views, dtype=np.int32), np.zeros(views, np.int64), cams,
                  [np.zeros((16, 16, 3), np.float32)] * views)
    config = FilterConfig.preset(preset)
    with pytest.raises(Seen):
        filter_distractors(scene, config=config)
    auto = resolve_auto(config, views)
    assert (seen["neighbours"], seen["verify_views"]) == (auto.neighbours, auto.verify_views)
    assert seen["hold"] == (auto.rounds > 1)
    assert "auto" not in (auto.rounds, auto.neighbours, auto.verify_views)


def test_the_long_video_benchmark_runs_end_to_end(tmp_path, capsys):
    """``benchmarks/video_windows.py`` on a tiny capture: both modes in fresh processes, the
    same removals (one window holds every view), the quality columns and the reach."""
    from scripts import load_script
    bench = load_script("benchmarks/video_windows.py")
    assert bench.main(["--frames", "6", "--resolution", "32x48", "--modes", "windows,whole",
                       "--cache", str(tmp_path), "--reach",
                       "--json", str(tmp_path / "rows.json")]) == 0
    out = capsys.readouterr().out
    assert "6 frames: every camera's renders hold all 6 views" in out
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert [r["mode"] for r in rows] == ["windows", "whole"] and rows[1]["same"] == "yes"
    assert all(0 <= r["recall"] <= 1 and r["peak_gb"] > 0 for r in rows)
    # A voxel-fused export of the same capture, its views recovered from the images.
    assert bench.main(["--frames", "6", "--resolution", "32x48", "--modes", "whole",
                       "--cache", str(tmp_path), "--fused",
                       "--json", str(tmp_path / "fused.json")]) == 0
    fused = load_scene(tmp_path / "street-video-6-32x48-fused")
    assert (fused.view_id == -1).any() and len(fused) < len(load_scene(
        tmp_path / "street-video-6-32x48"))
    row, = json.loads((tmp_path / "fused.json").read_text())
    assert row["gaussians"] == len(fused) and 0 <= row["recall"] <= 1
    assert "(fused: frame " in capsys.readouterr().out
    # Kept for the next run, but made again where another clearsplat recovered its views.
    record = tmp_path / "street-video-6-32x48-fused" / "association.json"
    made = json.loads(record.read_text())
    assert made["clearsplat"] == clearsplat.__version__
    record.write_text(json.dumps({**made, "clearsplat": "0.0.1", "largest_frame": 99}))
    assert bench.main(["--frames", "6", "--resolution", "32x48", "--modes", "whole",
                       "--cache", str(tmp_path), "--fused", "--no-quality"]) == 0
    out = capsys.readouterr().out
    assert "(made " in out and "-fused in " in out
    assert json.loads(record.read_text()) == made
    assert bench.main(["--frames", "6", "--resolution", "32x48", "--modes", "whole",
                       "--cache", str(tmp_path), "--fused", "--no-quality"]) == 0
    assert "-fused in " not in capsys.readouterr().out


def test_the_fused_association_summary_counts_by_hand():
    from scripts import load_script
    bench = load_script("benchmarks/video_windows.py")
    view_id = np.array([2, 2, 2, -1, 0, 5, 1, 9])
    distractor = np.array([False, False, False, True, True, True, True, True])
    frame = np.array([0, 0, 0, 3, 0, 3, 1, 3])
    d = bench.fused_association(view_id, distractor, frame, 10)
    # distractor voxels: -1 (shared), 0 (own), 5 (2 away), 1 (own), 9 (6 away)
    assert d == {"largest_frame": 2, "largest_share": 3 / 8, "distractor_own": 2 / 5,
                 "distractor_near": 1 / 5, "distractor_shared": 1 / 5}


def test_candidate_sets_concatenate_as_one_packing_of_all():
    """Reference: every candidate packed at once; and the arrays round trip."""
    from clearsplat.filter import Candidate
    from clearsplat.review import CandidateSets
    rng = np.random.default_rng(4)

    def candidate(k):
        pixels = rng.random((12, 9)) < (0.3 if k % 4 else 0.0)      # some empty regions
        g = np.sort(rng.choice(500, rng.integers(0, 30), replace=False))
        e = None if k % 3 == 0 else np.sort(rng.choice(500, rng.integers(0, 60),
                                                        replace=False))
        return Candidate(k, int(rng.integers(0, 7)), 1, pixels, g, e)

    cands = [candidate(k) for k in range(11)]
    whole = CandidateSets.from_candidates(cands, num_gaussians=500)
    parts = [CandidateSets.from_candidates(c, num_gaussians=500)
             for c in (cands[:4], [], cands[4:5], cands[5:])]
    joined = CandidateSets.concatenate(parts, num_gaussians=500)
    for name, a in whole.arrays().items():
        b = joined.arrays()[name]
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    back = CandidateSets.from_arrays(whole.arrays())
    assert all(np.array_equal(a, back.arrays()[k]) for k, a in whole.arrays().items())
