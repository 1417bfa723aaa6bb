"""Looking at results: filter bundles that load again, camera paths, render, video, export, view."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import clearsplat
from clearsplat.camera_path import interpolate_cameras, parse_size, resize_camera
from clearsplat.cameras import Camera, look_at
from clearsplat.cli import main
from clearsplat.errors import ClearsplatError


def png(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def read_mp4(path):
    """(codec, (width, height), frames) of a video, decoded by imageio-ffmpeg's own ffmpeg."""
    import re

    import imageio_ffmpeg
    exe = imageio_ffmpeg.get_ffmpeg_exe()
    info = subprocess.run([exe, "-hide_banner", "-i", str(path)], capture_output=True,
                          text=True).stderr
    m = re.search(r"Video: (\w+).*?, (\d+)x(\d+)", info)
    assert m, info
    w, h = int(m[2]), int(m[3])
    raw = subprocess.run([exe, "-v", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt",
                          "rgb24", "-"], capture_output=True, check=True).stdout
    frames = np.frombuffer(raw, np.uint8).reshape(-1, h, w, 3)
    return m[1], (w, h), list(frames)


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def filtered(tmp_path_factory):
    """A small scene (3 views of 32x56) and its filter output: (scene folder, output folder)."""
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=3, height=32, width=56)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    root = tmp_path_factory.mktemp("viewing")
    scene.save(root / "scene")
    assert main(["filter", str(root / "scene"), "--out", str(root / "filtered")]) == 0
    removed = np.load(root / "filtered" / "removed.npy")
    assert removed.any()
    return root / "scene", root / "filtered"


# ------------------------------------------------------------------------------------------------
# the filter's output is a bundle
# ------------------------------------------------------------------------------------------------
def test_filter_output_loads_as_a_bundle(filtered):
    scene_dir, out = filtered
    doc = json.loads((out / "cameras.json").read_text())
    assert doc["image_root"] == "../scene/images"
    assert not (out / "images").exists()                 # referred to, not copied
    scene = clearsplat.load_scene(scene_dir)
    again = clearsplat.load_scene(out)
    removed = np.load(out / "removed.npy")
    assert len(again) == int((~removed).sum())
    assert np.array_equal(again.gaussians.means, scene.gaussians.means[~removed])
    assert again.cameras == scene.cameras
    for a, b in zip(again.images, scene.images):
        assert np.array_equal(a, b)


def test_second_filter_and_copy_images(filtered, tmp_path, capsys):
    scene_dir, out = filtered
    code, _, err = run(["filter", out, "--out", tmp_path / "deep" / "twice"], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "deep" / "twice" / "cameras.json").read_text())
    assert Path(os.path.normpath(tmp_path / "deep" / "twice" / doc["image_root"])) \
        == Path(os.path.realpath(scene_dir / "images"))
    clearsplat.load_scene(tmp_path / "deep" / "twice")
    code, _, err = run(["filter", out, "--out", tmp_path / "copied", "--copy-images"], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "copied" / "cameras.json").read_text())
    assert "image_root" not in doc
    assert sorted(p.name for p in (tmp_path / "copied" / "images").iterdir()) \
        == ["000.png", "001.png", "002.png"]
    moved = tmp_path / "elsewhere"
    shutil.move(tmp_path / "copied", moved)              # self-contained: loads anywhere
    assert clearsplat.load_scene(moved).images is not None


def test_image_root_keeps_paths_inside_it(filtered, tmp_path):
    scene_dir, out = filtered
    bundle = tmp_path / "b"
    shutil.copytree(out, bundle)
    doc = json.loads((bundle / "cameras.json").read_text())
    doc["image_root"] = str(os.path.realpath(scene_dir / "images"))    # absolute is fine
    (bundle / "cameras.json").write_text(json.dumps(doc))
    clearsplat.load_scene(bundle)
    doc["frames"][1]["image"] = "../cameras.json"
    (bundle / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(ClearsplatError, match=r"'\.\.' refused") as e:
        clearsplat.load_scene(bundle)
    assert e.value.field == "frames[1].image"
    doc["image_root"] = 3
    (bundle / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(ClearsplatError) as e:
        clearsplat.load_scene(bundle)
    assert e.value.field == "image_root"


# ------------------------------------------------------------------------------------------------
# camera paths
# ------------------------------------------------------------------------------------------------
def _cams():
    K = [[50.0, 0, 32], [0, 50.0, 20], [0, 0, 1]]
    eyes = [(3, 0, 0.5), (0, 3, 1.0), (-3, 0, 0.5), (0, -3, 0.2)]
    return [Camera(K=K, camera_to_world=look_at(e, (0, 0, 0)), width=64, height=40)
            for e in eyes]


def test_path_passes_through_the_key_cameras():
    cams = _cams()
    path = interpolate_cameras(cams, 3 * 8 + 1)
    for k, cam in enumerate(cams):
        p = path[8 * k]
        assert np.allclose(p.camera_to_world, cam.camera_to_world, atol=1e-9)
        assert np.allclose(p.K, cam.K)


def test_path_frame_count_is_checked():
    from clearsplat.camera_path import MAX_FRAMES
    assert len(interpolate_cameras(_cams(), 7)) == 7
    for bad in (0, 2.5, True, MAX_FRAMES + 1, 10 ** 8):
        with pytest.raises(ClearsplatError) as e:
            interpolate_cameras(_cams(), bad)
        assert e.value.field == "frames"


def test_path_between_cameras_is_smooth_and_novel():
    cams = _cams()
    path = interpolate_cameras(cams, 61)
    pos = np.stack([c.position for c in path])
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert step.max() < 3 * np.median(step)              # no jumps
    turn = np.diff(np.diff(pos, axis=0), axis=0)
    assert np.linalg.norm(turn, axis=1).max() < 0.1       # no kinks at the key cameras
    # rotations: consecutive frames rotate by small, similar angles (slerp)
    angles = [np.degrees(np.arccos(np.clip((np.trace(a.camera_to_world[:3, :3].T
                                                     @ b.camera_to_world[:3, :3]) - 1) / 2,
                                           -1, 1))) for a, b in zip(path, path[1:])]
    assert max(angles) < 8
    # a frame halfway between two inputs is none of them
    mid = path[10]
    assert min(np.linalg.norm(mid.position - c.position) for c in cams) > 0.5
    for c in path:                                        # still rigid
        R = c.camera_to_world[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-9)


def test_slerp_midpoint_closed_form():
    """Two cameras at the same place turned 90 degrees apart: the midpoint is turned 45."""
    K = [[50.0, 0, 32], [0, 50.0, 20], [0, 0, 1]]
    a = Camera(K=K, camera_to_world=np.eye(4), width=64, height=40)
    rot = np.eye(4)
    rot[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]      # 90 degrees about y
    b = Camera(K=K, camera_to_world=rot, width=64, height=40)
    mid = interpolate_cameras([a, b], 3)[1]
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    assert np.allclose(mid.camera_to_world[:3, :3], [[c, 0, s], [0, 1, 0], [-s, 0, c]])
    assert np.allclose(mid.position, 0)


def test_resize_camera_keeps_the_view():
    cam = _cams()[0]
    big = resize_camera(cam, 128)
    assert (big.width, big.height) == (128, 80)
    # the same world point lands on the same relative image position
    pts = np.array([[0.1, 0.2, 0.3], [-0.4, 0.1, 0.0]])
    uv, _ = cam.project(pts)
    uv2, _ = big.project(pts)
    assert np.allclose(uv2, uv * 2)
    tall = resize_camera(cam, 64, 60)                     # more above and below, no stretch
    uv3, _ = tall.project(pts)
    assert np.allclose(uv3[:, 0], uv[:, 0]) and np.allclose(uv3[:, 1], uv[:, 1] + 10)
    assert parse_size("640x360") == (640, 360) and parse_size("320") == (320, None)
    for bad in ("0", "x", "12x", "-3", "1x2x3"):
        with pytest.raises(ClearsplatError):
            parse_size(bad)


# ------------------------------------------------------------------------------------------------
# render
# ------------------------------------------------------------------------------------------------
def test_render_camera_and_path(filtered, tmp_path, capsys):
    scene_dir, out = filtered
    scene = clearsplat.load_scene(scene_dir)
    frame = json.loads((scene_dir / "cameras.json").read_text())["frames"][1]
    (tmp_path / "cam.json").write_text(json.dumps(frame))
    code, stdout, err = run(["render", out, "--camera", tmp_path / "cam.json",
                             "--out", tmp_path / "one"], capsys)
    assert code == 0, err
    img = png(tmp_path / "one" / "frame_0000.png")
    expect = clearsplat.render(clearsplat.load_scene(out), scene.cameras[1]).rgb
    assert np.abs(img / 255.0 - expect).max() <= 0.5 / 255 + 1e-6
    # the filtered bundle renders like the original with the keep mask
    keep = ~np.load(out / "removed.npy")
    code, _, err = run(["render", scene_dir, "--filtered", out, "--camera", tmp_path / "cam.json",
                        "--out", tmp_path / "two"], capsys)
    assert code == 0, err
    assert np.array_equal(png(tmp_path / "two" / "frame_0000.png"), img)
    assert np.array_equal(img, np.round(np.clip(
        clearsplat.render(scene, scene.cameras[1], keep=keep).rgb, 0, 1) * 255).astype(np.uint8))
    # a path through the input cameras, resampled and resized
    code, _, err = run(["render", scene_dir, "--path", scene_dir / "cameras.json", "--frames", 5,
                        "--size", "28", "--out", tmp_path / "path"], capsys)
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "path").glob("frame_*.png"))
    assert len(names) == 5
    assert png(tmp_path / "path" / names[0]).shape == (16, 28, 3)
    cams, images = clearsplat.io.load_cameras(tmp_path / "path")    # what was rendered
    assert len(cams) == 5 and [p.name for p in images] == names
    assert np.allclose(cams[0].camera_to_world, scene.cameras[0].camera_to_world)
    assert np.allclose(cams[4].K, scene.cameras[2].scaled(0.5).K)


def test_render_bad_input(filtered, tmp_path, capsys):
    scene_dir, out = filtered
    (tmp_path / "cam.json").write_text(json.dumps({"width": 10, "height": 10,
                                                   "K": [[1, 0, 5], [0, 1, 5], [0, 0, 1]],
                                                   "camera_to_world": [[1, 0, 0, 0]]}))
    code, _, err = run(["render", scene_dir, "--camera", tmp_path / "cam.json",
                        "--out", tmp_path / "x"], capsys)
    assert code == 2 and "frames[0].camera_to_world" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x").exists()
    code, _, err = run(["render", scene_dir, "--path", scene_dir / "cameras.json", "--frames",
                        10 ** 8, "--out", tmp_path / "x"], capsys)
    assert code == 2 and "frames" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x").exists()


# ------------------------------------------------------------------------------------------------
# video
# ------------------------------------------------------------------------------------------------
def test_video_before_after(filtered, tmp_path, capsys):
    scene_dir, out = filtered
    mp4 = tmp_path / "v.mp4"
    code, stdout, err = run(["video", scene_dir, "--filtered", out, "--out", mp4,
                             "--frames", 9, "--size", "112"], capsys)
    assert code == 0, err
    codec, size, frames = read_mp4(mp4)
    assert codec == "h264" and size == (2 * 112 + 4, 64)
    assert len(frames) == 9
    # frame 0 is input camera 0: left all Gaussians, right the kept ones (H.264 is lossy)
    scene = clearsplat.load_scene(scene_dir)
    keep = ~np.load(out / "removed.npy")
    cam = resize_camera(scene.cameras[0], 112)
    before = clearsplat.render(scene, cam).rgb * 255
    after = clearsplat.render(scene, cam, keep=keep).rgb * 255
    left, right = frames[0][16:, :112].astype(float), frames[0][16:, 116:].astype(float)
    assert np.abs(left - before[16:]).mean() < 6
    assert np.abs(right - after[16:]).mean() < 6
    changed = np.abs(before - after).max(axis=2)[16:] > 40
    if changed.any():                    # where removal shows, each half matches its own render
        assert np.abs(right - after[16:])[changed].mean() < np.abs(right - before[16:])[changed].mean()
    # existing file: refused without --force, replaced with it
    code, _, err = run(["video", scene_dir, "--filtered", out, "--out", mp4, "--frames", 2],
                       capsys)
    assert code == 2 and "--force" in err
    code, _, err = run(["video", scene_dir, "--filtered", out, "--out", mp4, "--frames", 2,
                        "--force"], capsys)
    assert code == 0, err


def test_video_gif_fallback(filtered, tmp_path, monkeypatch):
    import imageio_ffmpeg
    from clearsplat.video import make_video

    def broken(*args, **kwargs):
        raise RuntimeError("no ffmpeg here")
    monkeypatch.setattr(imageio_ffmpeg, "write_frames", broken)
    scene_dir, out = filtered
    scene = clearsplat.load_scene(scene_dir)
    keep = ~np.load(out / "removed.npy")
    with pytest.warns(UserWarning, match="animated GIF"):
        written = make_video(tmp_path / "v.mp4", scene, keep, num_frames=4)
    assert written == tmp_path / "v.gif" and not (tmp_path / "v.mp4").exists()
    with Image.open(written) as gif:
        assert gif.n_frames == 4


def test_video_refuses_inputs_and_mismatch(filtered, tmp_path, capsys):
    scene_dir, out = filtered
    code, _, err = run(["video", scene_dir, "--filtered", out, "--out",
                        scene_dir / "gaussians.mp4", "--frames", 2], capsys)
    assert code == 0                   # a new file beside the inputs is fine
    code, _, err = run(["video", scene_dir, "--filtered", out, "--out",
                        scene_dir / "gaussians.mp4", "--frames", 2, "--force"], capsys)
    assert code == 2 and "input" in err
    os.remove(scene_dir / "gaussians.mp4")
    code, _, err = run(["video", out, "--filtered", out, "--out", tmp_path / "v.mp4"], capsys)
    assert code == 2 and "removed.npy" in err and "another scene" in err
    code, _, err = run(["video", scene_dir, "--filtered", out, "--out", tmp_path / "v.avi"],
                       capsys)
    assert code == 2 and ".mp4" in err


# ------------------------------------------------------------------------------------------------
# export
# ------------------------------------------------------------------------------------------------
def test_export_formats(filtered, tmp_path, capsys):
    from clearsplat.io.splat_formats import read_splat, read_spz
    scene_dir, out = filtered
    kept = clearsplat.load_scene(out).gaussians
    for name, reader in (("a.splat", read_splat), ("a.spz", read_spz),
                         ("a.ply", lambda p: clearsplat.read_ply(p)[0])):
        code, stdout, err = run(["export", out, "--to", tmp_path / name], capsys)
        assert code == 0, err
        g = reader(tmp_path / name)
        assert len(g) == len(kept)
    assert np.array_equal(clearsplat.read_ply(tmp_path / "a.ply")[0].means, kept.means)
    code, _, err = run(["export", out, "--to", tmp_path / "a.ply"], capsys)
    assert code == 2 and "--force" in err
    code, _, err = run(["export", out, "--to", tmp_path / "a.obj"], capsys)
    assert code == 2 and ".splat" in err
    code, _, err = run(["export", out, "--to", out / "gaussians.ply", "--force"], capsys)
    assert code == 2 and "input" in err


def test_export_drops_removed_unless_keep_all(filtered, tmp_path, capsys):
    scene_dir, _ = filtered
    code, _, err = run(["filter", scene_dir, "--out", tmp_path / "all", "--keep-all"], capsys)
    assert code == 0, err
    removed = np.load(tmp_path / "all" / "removed.npy")
    code, stdout, err = run(["export", tmp_path / "all", "--to", tmp_path / "a.ply"], capsys)
    assert code == 0 and "removed ones dropped" in stdout
    assert len(clearsplat.read_ply(tmp_path / "a.ply")[0]) == int((~removed).sum())
    code, _, err = run(["export", tmp_path / "all", "--to", tmp_path / "b.ply", "--keep-all"],
                       capsys)
    assert code == 0
    assert len(clearsplat.read_ply(tmp_path / "b.ply")[0]) == len(removed)


def test_export_bad_removed_npy(filtered, tmp_path, capsys):
    _, out = filtered
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    n = len(np.load(out / "removed.npy"))
    for content in (b"junk", np.zeros(7, bool), np.zeros(n, np.float32)):
        if isinstance(content, bytes):
            (bad / "removed.npy").write_bytes(content)
        else:
            np.save(bad / "removed.npy", content)
        code, _, err = run(["export", bad, "--to", tmp_path / "a.splat"], capsys)
        assert code == 2 and "removed.npy: removed:" in err, err
        assert len(err.strip().splitlines()) == 1 and not (tmp_path / "a.splat").exists()


# ------------------------------------------------------------------------------------------------
# viewer
# ------------------------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_viewer_serves_scene(filtered):
    pytest.importorskip("viser")
    import urllib.request
    from clearsplat.viewer import covariances, serve
    scene_dir, out = filtered
    scene = clearsplat.load_scene(scene_dir)
    keep = ~np.load(out / "removed.npy")
    viewer = serve(scene, keep=keep, port=_free_port())
    try:
        assert viewer.url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(viewer.url, timeout=120).read()
        assert b"<html" in page
        assert viewer.modes == ("original", "filtered", "removed")
        assert viewer.current == "filtered" and viewer.show.value == "filtered"
        assert len(viewer.frustums) == scene.num_views
        viewer.set_show("removed")
        assert viewer.current == "removed" and viewer.show.value == "removed"
        with pytest.raises(ClearsplatError):
            viewer.set_show("everything")
    finally:
        viewer.stop()
    # covariances against R S S R^T built from an explicit rotation
    g = scene.gaussians.subset(slice(0, 50))
    from scipy.spatial.transform import Rotation
    q = g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True)
    R = Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()
    expect = R @ (np.eye(3) * (g.scales ** 2)[:, None, :]) @ R.transpose(0, 2, 1)
    assert np.allclose(covariances(g), expect, rtol=1e-4, atol=1e-9)


def _browser():
    """A headless Chromium driven over DevTools, or skip where there is none."""
    from clearsplat.browser import HeadlessBrowser, find_browser
    if find_browser() is None:
        pytest.skip("no Chromium on this machine (Debian: apt-get install chromium)")
    return HeadlessBrowser(size=(800, 600))


def _wait_for_client(viewer, timeout: float = 300.0) -> None:
    """Until the page has connected to the viewer's server (it then sends the scene)."""
    import time
    deadline = time.monotonic() + timeout
    while not viewer.server.get_clients():
        assert time.monotonic() < deadline, \
            f"the page never connected to the viewer's server within {timeout:.0f} s"
        time.sleep(0.1)


@pytest.mark.slow
def test_viewer_in_headless_chromium(filtered):
    """The page loads in a real browser and draws the splats (WebGL through SwiftShader)."""
    pytest.importorskip("viser")
    from clearsplat.viewer import REMOVED_COLOUR, serve
    scene_dir, _ = filtered
    scene = clearsplat.load_scene(scene_dir)
    keep = np.ones(len(scene), bool)
    keep[::2] = False                    # half the Gaussians, everywhere: shown in highlight
    target = np.array(REMOVED_COLOUR) * 255

    def splat_fraction(img) -> float:
        # the highlight colour blended over the dark background (its hue kept)
        r, g, b = (img[..., c].astype(int) for c in range(3))
        return float(((r > 60) & (b > 0.5 * r * target[2] / target[0]) & (g < 0.45 * r)).mean())

    viewer = serve(scene, keep=keep, port=_free_port(), show="removed")
    try:
        with _browser() as browser:
            browser.open(viewer.url)
            _wait_for_client(viewer)
            img = browser.wait_until(lambda img: splat_fraction(img) > 0.02,
                                     what="the removed Gaussians in the highlight colour")
    finally:
        viewer.stop()
    assert splat_fraction(img) > 0.02


def test_clicking_a_camera_looks_through_it(filtered):
    """The frustum's click handler moves the browser camera onto the input camera."""
    import contextlib
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    from clearsplat.viewer import _look_through
    scene = clearsplat.load_scene(filtered[0])
    cam = scene.cameras[1]
    frustums = [SimpleNamespace(visible=True) for _ in scene.cameras]
    browser_camera = SimpleNamespace(fov=None, wxyz=None, position=None)
    client = SimpleNamespace(camera=browser_camera, atomic=contextlib.nullcontext)
    fov = 2 * np.arctan(0.5 * cam.height / cam.fy)
    _look_through(cam, fov, 1, frustums)(SimpleNamespace(client=client))
    w, x, y, z = browser_camera.wxyz
    assert np.allclose(Rotation.from_quat([x, y, z, w]).as_matrix(),
                       cam.camera_to_world[:3, :3])
    assert np.allclose(browser_camera.position, cam.position)
    assert browser_camera.fov == fov
    assert [f.visible for f in frustums] == [True, False, True]


def test_view_command_prints_the_url_and_serves(filtered):
    """``clearsplat view`` serves on 127.0.0.1, prints where, and stops on Ctrl-C."""
    pytest.importorskip("viser")
    import re
    import signal
    import sys
    import urllib.request
    scene_dir, out = filtered
    # A command started in the background by a non-interactive shell ignores SIGINT, and its
    # children inherit that: give the viewer the default disposition, as a terminal would.
    proc = subprocess.Popen([sys.executable, "-m", "clearsplat", "view", str(scene_dir),
                             "--filtered", str(out), "--port", str(_free_port())],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stdout.readline()       # printed once the server listens
        # the port asked for, or the next free one where another process took it meanwhile
        m = re.match(r"clearsplat viewer: (http://127\.0\.0\.1:\d+)", line)
        assert m, (line, proc.stderr.read() if proc.poll() is not None else "")
        page = urllib.request.urlopen(m[1], timeout=120).read()
        assert b"<html" in page
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130


def test_view_refuses_an_address_of_another_machine(filtered, capsys):
    code, _, err = run(["view", filtered[0], "--host", "192.0.2.1"], capsys)   # TEST-NET-1
    assert code == 2 and "--host" in err and len(err.splitlines()) == 1


# ------------------------------------------------------------------------------------------------
# the review panel
# ------------------------------------------------------------------------------------------------
def _scores(out) -> list:
    s = json.loads((out / "summary.json").read_text())
    return [c["scores"].get("individual", -np.inf) for c in s["candidates"]]


def test_review_panel_edits_as_the_cli_does(filtered, tmp_path, capsys):
    """List, filters, selection, toggle and save change the scene's state as `edit` would."""
    pytest.importorskip("viser")
    from clearsplat.review import load_filter_output
    from clearsplat.viewer import SELECTED_COLOUR, serve
    scene_dir, out = filtered
    scene = clearsplat.load_scene(scene_dir)
    output = load_filter_output(out)
    viewer = serve(scene, filtered=out, port=_free_port())
    try:
        review = viewer.review
        scores = _scores(out)
        k_all = len(scores)
        assert k_all >= 2
        # the list: every candidate, best individual score first
        assert review.selected is None and viewer.highlight.size == 0
        listed = [int(o.split(" ", 1)[0][1:]) for o in review.choice.options[1:]]
        assert listed == sorted(range(k_all), key=lambda k: (-scores[k], k))
        for k, option in zip(listed, review.choice.options[1:]):
            verdict = "accepted" if output.accepted[k] else "rejected"
            assert f"view {output.candidates[k]['view']}" in option and verdict in option
        review.list_filter.value = "accepted"
        assert review.listed() == [k for k in listed if output.accepted[k]]
        review.list_filter.value = "rejected"
        assert review.listed() == [k for k in listed if not output.accepted[k]]
        review.list_filter.value = "all"
        review.view_filter.value = "view 1"
        assert review.listed() == [k for k in listed if output.candidates[k]["view"] == 1]
        review.view_filter.value = "all views"
        # selecting: highlight, camera at the candidate's view, crops
        k = next(k for k in listed if output.accepted[k])
        review.choice.value = review.label(k)
        assert review.selected == k
        assert np.array_equal(viewer.highlight, output.sets.removal(k))
        assert viewer.shown()[viewer.highlight].all()      # shown although removed
        view = output.candidates[k]["view"]
        assert np.allclose(viewer.server.initial_camera.position,
                           scene.cameras[view].position)
        assert [f.visible for f in viewer.frustums].count(False) == 1
        assert not viewer.frustums[view].visible
        crops = review.crops.image
        assert crops.ndim == 3 and crops.shape[1] > 2 * crops.shape[0]
        assert (np.abs(crops.astype(int) - np.array(SELECTED_COLOUR) * 255) < 2).all(-1).any()
        assert review.accepted.value is True
        # the toggle: reject it, the scene follows
        review.accepted.value = False
        assert review.edits() == ([k], [])
        code, _, err = _run_edit(["edit", out, "--reject", k, "--out", tmp_path / "cli"],
                                 capsys)
        assert code == 0, err
        cli_removed = np.load(tmp_path / "cli" / "removed.npy")
        assert np.array_equal(review.removed, cli_removed)
        assert np.array_equal(viewer.keep, ~cli_removed)
        viewer.set_show("filtered")
        shown = viewer.shown()
        assert np.array_equal(shown, ~cli_removed | np.isin(np.arange(len(shown)),
                                                           viewer.highlight))
        # accept a rejected one as well, then flip the first back and forth
        j = next(j for j in listed if not output.accepted[j] and output.sets.removal(j).size)
        review.select(j)
        review.flip()
        review.flip(k)
        review.flip(k)
        assert review.edits() == ([k], [j])
        # save: the same folder as the command it prints
        review.out_text.value = str(tmp_path / "viewer")
        review.save_button.value = True                  # a click
        command = review.saved[1]
        printed = capsys.readouterr().out
        assert command in printed and command in review.status.content
        assert command == (f"clearsplat edit {out} --reject {k} --accept {j} "
                           f"--out {tmp_path / 'viewer'}")
        code, _, err = _run_edit(command.split()[1:-1] + [str(tmp_path / "cli2")], capsys)
        assert code == 0, err
        for name in ("removed.npy", "gaussians.ply", "removed.ply", "candidates.npz"):
            assert (tmp_path / "viewer" / name).read_bytes() == \
                (tmp_path / "cli2" / name).read_bytes(), name
        assert np.array_equal(np.load(tmp_path / "viewer" / "removed.npy"), review.removed)
        # a second save onto it needs the checkbox, and says why it did not save
        review.save_button.value = True
        assert "Not saved" in review.status.content and "--force" in review.status.content
        # clicking a splat selects its candidate; a click into nothing changes nothing
        g = viewer.scene.gaussians.means[output.sets.removal(k)]
        eye = scene.cameras[view].position
        assert review.pick(eye, g[0] - eye) == k
        assert review.pick(eye, -(g[0] - eye)) is None
    finally:
        viewer.stop()


def _run_edit(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_review_panel_needs_candidate_data(filtered, tmp_path):
    pytest.importorskip("viser")
    from clearsplat.viewer import serve
    scene_dir, out = filtered
    old = tmp_path / "old"
    shutil.copytree(out, old)
    (old / "candidates.npz").unlink()
    scene = clearsplat.load_scene(scene_dir)
    viewer = serve(scene, filtered=old, port=_free_port())
    try:
        assert viewer.review is None and viewer.current == "filtered"
        assert np.array_equal(viewer.keep, ~np.load(out / "removed.npy"))
    finally:
        viewer.stop()
    with pytest.raises(ClearsplatError) as e:
        serve(scene, filtered=out, port=_free_port(), select=99)
    assert e.value.field == "select"


def _scene_drawn(img, lit: float) -> bool:
    """More than ``lit`` of the pixels lit, and not viser's white page of a client still loading."""
    return (img.max(-1) > 40).mean() > lit and (img.min(-1) > 230).mean() < 0.5


def _highlight_fraction(img) -> float:
    from clearsplat.viewer import SELECTED_COLOUR
    target = np.array(SELECTED_COLOUR) * 255
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    # the highlight colour blended over whatever is behind it: green well above red and blue
    return float(((g > 80) & (r < 0.5 * g * max(target[0] / target[1], 0.3))
                  & (b < 0.6 * g)).mean())


@pytest.mark.slow
def test_review_selection_in_headless_chromium(filtered):
    """A selected candidate's Gaussians show in the highlight colour in a real browser, and
    nothing does from the same camera without a selection."""
    pytest.importorskip("viser")
    from clearsplat.review import load_filter_output
    from clearsplat.viewer import serve
    scene_dir, out = filtered
    scene = clearsplat.load_scene(scene_dir)
    output = load_filter_output(out)
    k = max(range(len(output.sets)), key=lambda k: output.sets.removal(k).size)
    view = int(output.sets.view[k])

    def drawn(img) -> bool:          # the scene (not the panel) is on screen
        return _scene_drawn(img[:, :440], 0.2)

    def shot(select):
        viewer = serve(scene, filtered=out, port=_free_port(), select=select)
        if select is None:
            viewer.look_through(view)             # the same camera, nothing selected
        try:
            with _browser() as browser:
                browser.open(viewer.url)
                _wait_for_client(viewer)
                if select is None:
                    img = browser.wait_until(drawn, what="the scene from the candidate's view")
                else:
                    img = browser.wait_until(
                        lambda img: drawn(img) and _highlight_fraction(img[:, :440]) > 0.002,
                        what=f"candidate {select}'s Gaussians in the highlight colour")
        finally:
            viewer.stop()
        return _highlight_fraction(img[:, :440].astype(int))

    selected = shot(k)
    plain = shot(None)
    assert selected > 0.002 and selected > 3 * plain, (selected, plain)
