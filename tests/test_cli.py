"""The command line on bad input and on failure: one clear line, exit code 2, nothing half-written.

Every bad-input case checks: exit code 2, exactly one line on stderr, starting with
``clearsplat: error:``, naming the file and the field, no traceback, no output folder, no
temporary folder, and the input bundle unchanged (bytes and modification times).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import clearsplat.filter
from clearsplat.cli import main

# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
_PLY_TYPES = {"float": "f4", "double": "f8", "int": "i4", "uint": "u4", "uchar": "u1",
              "short": "i2", "ushort": "u2", "char": "i1", "int64": "i8", "uint64": "u8"}


def read_columns(path: Path) -> dict:
    """Columns of a binary little-endian PLY written by clearsplat (name -> array, in order)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    props = [line.split()[1:] for line in data[:end].decode().splitlines()
             if line.startswith("property")]
    dtype = np.dtype([(name, "<" + _PLY_TYPES[t]) for t, name in props])
    table = np.frombuffer(data, dtype=dtype, offset=end)
    return {name: (t, table[name].copy()) for t, name in props}


def write_columns(path: Path, cols: dict, *, fmt: str = "binary_little_endian") -> None:
    n = len(next(iter(cols.values()))[1]) if cols else 0
    head = ["ply", f"format {fmt} 1.0", f"element vertex {n}"]
    head += [f"property {t} {name}" for name, (t, _) in cols.items()] + ["end_header"]
    order = ">" if fmt == "binary_big_endian" else "<"
    table = np.empty(n, dtype=[(name, order + _PLY_TYPES[t]) for name, (t, _) in cols.items()])
    for name, (_, v) in cols.items():
        table[name] = v
    path.write_bytes(("\n".join(head) + "\n").encode() + table.tobytes())


def edit_ply(root: Path, fn) -> None:
    cols = read_columns(root / "gaussians.ply")
    fn(cols)
    write_columns(root / "gaussians.ply", cols)


def set_value(name, index, value):
    def fn(cols):
        t, v = cols[name]
        v = v.copy()
        v[index] = value
        cols[name] = (t, v)
    return fn


def drop(name):
    return lambda cols: cols.pop(name)


def edit_json(root: Path, fn) -> None:
    doc = json.loads((root / "cameras.json").read_text())
    fn(doc)
    (root / "cameras.json").write_text(json.dumps(doc))


def png16(path: Path, samples: np.ndarray, color_type: int) -> None:
    """A 16-bit PNG written by hand (Pillow cannot write 16-bit colour)."""
    arr = np.asarray(samples, dtype=">u2")
    raw = b"".join(b"\x00" + row.tobytes() for row in arr)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", arr.shape[1], arr.shape[0], 16, color_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def state(root: Path) -> dict:
    """Bytes and modification times of every file under ``root``."""
    return {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_error(err: str, *fragments: str) -> str:
    lines = err.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    line = lines[0]
    assert line.startswith("clearsplat: error: "), line
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in line, f"{fragment!r} not in {line!r}"
    return line


def leftovers(parent: Path) -> list:
    return sorted(p.name for p in parent.iterdir() if ".clearsplat-" in p.name
                  or ".old-" in p.name)


# ------------------------------------------------------------------------------------------------
# fixtures
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """A small valid bundle: 3 views of 32x56, 5376 pixel-aligned Gaussians."""
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=3, height=32, width=56)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    root = tmp_path_factory.mktemp("cli") / "scene"
    scene.save(root)
    return root


@pytest.fixture
def bundle(source, tmp_path):
    """A fresh copy of the bundle; the test may edit it, then ``snap()`` records it."""
    root = tmp_path / "scene"
    shutil.copytree(source, root)
    return root


def _filter(bundle, out, capsys, *extra):
    before = state(bundle)
    code, stdout, err = run(["filter", bundle, "--out", out, *extra], capsys)
    assert state(bundle) == before, "the input bundle was modified"
    return code, stdout, err


# ------------------------------------------------------------------------------------------------
# success and output safety
# ------------------------------------------------------------------------------------------------
def test_filter_writes_only_out(bundle, tmp_path, capsys):
    listing = sorted(p.name for p in tmp_path.iterdir())
    code, stdout, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    assert "clearsplat: error" not in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(listing + ["out"])
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        ".clearsplat.json", "cameras.json", "candidates.npz", "gaussians.ply", "removed.npy",
        "removed.ply", "summary.json"]
    removed = np.load(tmp_path / "out" / "removed.npy")
    assert removed.dtype == bool and removed.shape == (5376,)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["removed"] == int(removed.sum())
    assert len(read_columns(tmp_path / "out" / "gaussians.ply")["x"][1]) == 5376 - removed.sum()


def test_missing_parent_folders_are_created(bundle, tmp_path, capsys):
    code, _, err = _filter(bundle, tmp_path / "a" / "b" / "out", capsys)
    assert code == 0, err
    assert (tmp_path / "a" / "b" / "out" / "removed.npy").is_file()


def test_existing_output_needs_force(bundle, tmp_path, capsys):
    out = tmp_path / "out"
    assert _filter(bundle, out, capsys)[0] == 0
    (out / "note.txt").write_text("mine")
    before = state(out)
    code, _, err = _filter(bundle, out, capsys)
    assert code == 2
    assert_one_error(err, str(out), "--out", "not empty", "--force")
    assert state(out) == before
    code, _, err = _filter(bundle, out, capsys, "--force")
    assert code == 0, err
    assert not (out / "note.txt").exists() and (out / "removed.npy").is_file()
    assert leftovers(tmp_path) == []


def test_empty_existing_folder_is_used(bundle, tmp_path, capsys):
    (tmp_path / "out").mkdir()
    assert _filter(bundle, tmp_path / "out", capsys)[0] == 0
    assert (tmp_path / "out" / "removed.npy").is_file()


def test_force_refuses_unrelated_folders_and_the_input(bundle, tmp_path, capsys):
    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.jpg").write_bytes(b"precious")
    code, _, err = _filter(bundle, other, capsys, "--force")
    assert code == 2
    assert_one_error(err, str(other), "--out", "clearsplat did not write")
    assert (other / "holiday.jpg").read_bytes() == b"precious"
    for out in (bundle, tmp_path):                 # the bundle itself, and a folder holding it
        code, _, err = _filter(bundle, out, capsys, "--force")
        assert code == 2
        assert_one_error(err, str(out), "--out", "would replace an input")
    assert leftovers(tmp_path) == []


def test_existing_file_as_out(bundle, tmp_path, capsys):
    out = tmp_path / "out"
    out.write_text("a file")
    code, _, err = _filter(bundle, out, capsys)
    assert code == 2
    assert_one_error(err, str(out), "--out", "not a folder")
    assert out.read_text() == "a file"
    code, _, err = _filter(bundle, out, capsys, "--force")    # a file is never replaced
    assert code == 2
    assert_one_error(err, str(out), "--out", "not a folder")
    assert out.read_text() == "a file"


def _fake_filter(exc, monkeypatch):
    """Make the filter report progress, then fail with ``exc``."""
    def fake(scene, *, config=None, extractor=None, progress=None):
        progress("render", 1, scene.num_views)
        raise exc
    monkeypatch.setattr(clearsplat.filter, "filter_distractors", fake)


def test_interrupted_run_leaves_nothing(bundle, tmp_path, capsys, monkeypatch):
    _fake_filter(KeyboardInterrupt(), monkeypatch)
    code, _, err = _filter(bundle, tmp_path / "new" / "out", capsys)
    assert code == 130
    assert err.splitlines()[-1] == "clearsplat: interrupted; nothing was written"
    assert not (tmp_path / "new").exists()
    assert leftovers(tmp_path) == []


def test_sigterm_leaves_nothing(bundle, tmp_path, capsys, monkeypatch):
    def fake(scene, *, config=None, extractor=None, progress=None):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):        # the handler runs between bytecodes
            pass
        raise AssertionError("SIGTERM was not turned into an interrupt")
    monkeypatch.setattr(clearsplat.filter, "filter_distractors", fake)
    handler = signal.getsignal(signal.SIGTERM)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 130, err
    assert signal.getsignal(signal.SIGTERM) == handler
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []


def test_failure_while_writing_leaves_nothing(bundle, tmp_path, capsys, monkeypatch):
    import clearsplat.report

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device", str(tmp_path / "x.png"))
    monkeypatch.setattr(clearsplat.report, "write_report", broken)
    code, _, err = _filter(bundle, tmp_path / "a" / "out", capsys, "--report")
    assert code == 1
    assert_one_error(err, "No space left on device")
    assert not (tmp_path / "a").exists() and leftovers(tmp_path) == []


def test_failure_with_force_keeps_the_old_output(bundle, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert _filter(bundle, out, capsys)[0] == 0
    before = state(out)
    _fake_filter(RuntimeError("a bug"), monkeypatch)
    with pytest.raises(RuntimeError, match="a bug"):      # a bug is not bad input: traceback
        _filter(bundle, out, capsys, "--force")
    assert state(out) == before and leftovers(tmp_path) == []


def test_usage_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["filter", "somewhere"])
    assert e.value.code == 2
    assert_one_error(capsys.readouterr().err, "--out", "required")


@pytest.mark.parametrize("argv, fragments", [
    (["--set", "eta"], ("--set", "expected KEY=VALUE")),
    (["--set", "eta=nan"], ("--set", "non-finite")),
    (["--set", "no_such_option=1"], ("no_such_option", "unknown option")),
    (["--preset", "nope"], ("preset", "unknown preset")),
    (["--set", "eta=abc"], ("eta: got 'abc'", "a number in [0, 1]")),
    (["--set", "dilation=abc"], ("dilation: got 'abc'", "an integer >= 0")),
    (["--set", "num_verify_views=x"], ("num_verify_views: got 'x'", "an integer >= 1")),
    (["--set", "verify=maybe"], ("verify: got 'maybe'", "true or false")),
    (["--set", "eta=2"], ("eta: got 2", "a number in [0, 1]")),
    (["--set", "epsilon=-1"], ("epsilon: got -1", "a number in [0, 3]")),
    (["--set", "refine=sideways"], ("refine: got 'sideways'", "'static-depth', 'depth', 'none'")),
    (["--features", "dinov9"], ("features: got 'dinov9'", "'dinov2', 'dinov3'")),
])
def test_bad_options(bundle, tmp_path, capsys, argv, fragments):
    code, _, err = _filter(bundle, tmp_path / "out", capsys, *argv)
    assert code == 2
    assert_one_error(err, *fragments)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------
# the catalogue of bad input
# ------------------------------------------------------------------------------------------------
def _garbage(root):
    (root / "gaussians.ply").write_bytes(np.random.default_rng(0).bytes(3000))


def _truncate(root):
    data = (root / "gaussians.ply").read_bytes()
    (root / "gaussians.ply").write_bytes(data[:-7])


def _count_lies(root):
    data = (root / "gaussians.ply").read_bytes()
    (root / "gaussians.ply").write_bytes(data.replace(b"element vertex 5376",
                                                      b"element vertex 5377", 1))


def _type_lies(root):
    data = (root / "gaussians.ply").read_bytes()
    (root / "gaussians.ply").write_bytes(data.replace(b"property float x\n",
                                                      b"property double x\n", 1))


def _symlink_out(root):
    outside = root.parent / "elsewhere.png"
    shutil.copy(root / "images" / "000.png", outside)
    (root / "images" / "000.png").unlink()
    os.symlink(outside, root / "images" / "000.png")


def _frames(n):
    return lambda d: d.update(frames=d["frames"][:n])


PLY, CAMS = "gaussians.ply", "cameras.json"
CASES = {
    # PLY structure
    "garbage PLY": (_garbage, PLY, "header", "not a PLY file"),
    "truncated PLY": (_truncate, PLY, "vertex", "file too short"),
    "count lies": (_count_lies, PLY, "vertex", "file too short"),
    "type lies": (_type_lies, PLY, "vertex", "file too short"),
    "missing PLY": (lambda r: (r / PLY).unlink(), PLY, "gaussians", "not found"),
    # PLY values
    "missing f_dc_0": (lambda r: edit_ply(r, drop("f_dc_0")), PLY, "f_dc_0", "missing"),
    "missing opacity": (lambda r: edit_ply(r, drop("opacity")), PLY, "opacity", "missing"),
    "nan x": (lambda r: edit_ply(r, set_value("x", 7, np.nan)), PLY, "x", "non-finite"),
    "inf f_dc_1": (lambda r: edit_ply(r, set_value("f_dc_1", 9, np.inf)), PLY, "f_dc_1",
                   "non-finite"),
    "-inf opacity": (lambda r: edit_ply(r, set_value("opacity", 3, -np.inf)), PLY, "opacity",
                     "non-finite"),
    "zero scale": (lambda r: edit_ply(r, set_value("scale_1", 4, -np.inf)), PLY, "scale_1",
                   "non-finite"),
    "scale underflows to zero": (lambda r: edit_ply(r, set_value("scale_2", 4, -200.0)), PLY,
                                 "scale_2", "outside the float32 range"),
    "zero quaternion": (lambda r: [edit_ply(r, set_value(f"rot_{c}", 11, 0.0))
                                   for c in range(4)], PLY, "rot_0..3", "zero quaternion"),
    "view_id out of range": (lambda r: edit_ply(r, set_value("view_id", 5, 3)), PLY, "view_id",
                             "out of range"),
    "view_id negative": (lambda r: edit_ply(r, set_value("view_id", 5, -2)), PLY, "view_id",
                         "below -1"),
    "shared with a pixel": (lambda r: edit_ply(r, set_value("view_id", 5, -1)), PLY,
                            "pixel_id", "out of range for view -1"),
    "pixel_id out of range": (lambda r: edit_ply(r, set_value("pixel_id", 5, 32 * 56)), PLY,
                              "pixel_id", "out of range"),
    # cameras.json
    "malformed JSON": (lambda r: (r / CAMS).write_text('{"frames": [}'), CAMS,
                       "line 1 column 13", "malformed JSON"),
    "no cameras file": (lambda r: (r / CAMS).unlink(), "scene", "cameras", "no cameras.json"),
    "no frames": (lambda r: edit_json(r, _frames(0)), CAMS, "frames", "no frames"),
    "missing K": (lambda r: edit_json(r, lambda d: d["frames"][1].pop("K")), CAMS,
                  "frames[1].K", "missing key"),
    "missing width": (lambda r: edit_json(r, lambda d: d["frames"][0].pop("width")), CAMS,
                      "frames[0].width", "missing key"),
    "nan in K": (lambda r: edit_json(r, lambda d: d["frames"][0]["K"][0].__setitem__(
        2, float("nan"))), CAMS, "frames[0].K[0][2]", "non-finite"),
    "inf in pose": (lambda r: edit_json(r, lambda d: d["frames"][2]["camera_to_world"][1]
                                        .__setitem__(3, float("inf"))), CAMS,
                    "frames[2].camera_to_world[1][3]", "non-finite"),
    "singular camera": (lambda r: edit_json(r, lambda d: d["frames"][1].update(
        camera_to_world=[[0.0] * 4] * 3 + [[0, 0, 0, 1.0]])), CAMS,
        "frames[1].camera_to_world", "singular"),
    "zero focal length": (lambda r: edit_json(r, lambda d: d["frames"][1]["K"][1].__setitem__(
        1, 0.0)), CAMS, "frames[1].K", "focal lengths must be positive"),
    "fewer frames than views": (lambda r: edit_json(r, _frames(2)), PLY, "view_id",
                                "out of range"),
    # images
    "image missing": (lambda r: (r / "images" / "001.png").unlink(), "images/001.png",
                      "frames[1].image", "not found"),
    "image unreadable": (lambda r: (r / "images" / "001.png").write_bytes(b"\x89PNG" + bytes(9)),
                         "images/001.png", "image", "not an image"),
    "image truncated": (lambda r: (r / "images" / "002.png").write_bytes(
        (r / "images" / "002.png").read_bytes()[:200]), "images/002.png", "image",
        "cannot decode"),
    "image of the wrong size": (lambda r: Image.new("RGB", (56, 31)).save(
        r / "images" / "002.png"), "images/002.png", "frames[2].height", "camera says 56x32"),
    "image as BMP": (lambda r: Image.new("RGB", (56, 32)).save(r / "images" / "000.png",
                                                               format="BMP"),
                     "images/000.png", "image", "unsupported image format BMP"),
    "image path ../": (lambda r: edit_json(r, lambda d: d["frames"][0].update(
        image="../scene/images/000.png")), CAMS, "frames[0].image", "leaves the bundle"),
    "absolute image path": (lambda r: edit_json(r, lambda d: d["frames"][0].update(
        image=str(r / "images" / "000.png"))), CAMS, "frames[0].image", "absolute path"),
    "image symlink out of the bundle": (_symlink_out, CAMS, "frames[0].image",
                                        "symbolic link"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input(bundle, tmp_path, capsys, case):
    edit, where, field, reason = CASES[case]
    edit(bundle)
    code, stdout, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 2, err
    line = assert_one_error(err, f": {field}: ", reason)
    named = line[len("clearsplat: error: "):].split(f": {field}: ")[0]
    assert named.endswith(where), f"{line!r} does not name {where}"
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []


def test_a_ply_without_view_id_is_associated_from_the_images(bundle, tmp_path, capsys,
                                                             monkeypatch):
    # A scene from any trainer: no view_id (nor pixel_id). The filter recovers each
    # Gaussian's view from the input images, says so in one line, and indexes the user's file.
    import clearsplat.cli.filter as command
    edit_ply(bundle, drop("view_id"))
    n = read_columns(bundle / "gaussians.ply")["x"][1].size
    told = []
    monkeypatch.setattr(command, "Bar", lambda: lambda *a: told.append(a))    # the progress bar
    code, stdout, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    # The association's progress, one camera at a time, before the filter's own stages.
    views = len(json.loads((bundle / "cameras.json").read_text())["frames"])
    assert told[:views] == [("associate", k, views) for k in range(1, views + 1)], told[:5]
    assert told[views:] and all(stage != "associate" for stage, _, _ in told[views:])
    # Its Gaussians lie on their pixels' rays, as a per-pixel model puts them: each gets its
    # view and pixel.
    assert _association_line(stdout, n) == (n, n, 0, 0)
    assert np.load(tmp_path / "out" / "removed.npy").shape == (n,)
    # ... and the commands that show a filter output take the same bundle with it.
    cam = tmp_path / "cam.json"
    frame = json.loads((bundle / "cameras.json").read_text())["frames"][0]
    cam.write_text(json.dumps(frame))
    with pytest.warns(UserWarning, match=r"ambiguous \(the PLY has no view_id\)"):
        assert main(["render", str(bundle), "--camera", str(cam), "--filtered",
                     str(tmp_path / "out"), "--out", str(tmp_path / "renders")]) == 0
    assert list((tmp_path / "renders").glob("*.png"))


def _association_line(stdout: str, n: int) -> tuple[int, int, int, int]:
    """The counts of ``clearsplat filter``'s association line: got a view, of them with their
    pixel, shared, ambiguous."""
    line = next(x for x in stdout.splitlines() if x.startswith("associated "))
    found = re.fullmatch(rf"associated {n:,} Gaussians from images: ([\d,]+) got a view"
                         r"(?: \(([\d,]+) with their pixel\))?, (?:([\d,]+) shared by several "
                         r"views, )?([\d,]+) ambiguous \(the PLY has no view_id\)", line)
    assert found, line
    got, pixels, shared, ambiguous = (int((x or "0").replace(",", "")) for x in found.groups())
    assert got + shared + ambiguous == n
    return got, pixels, shared, ambiguous


def test_a_trained_scene_is_associated_from_the_images(bundle, tmp_path, capsys):
    # Centres off their pixels' rays (as a trainer leaves them): no Gaussian gets a pixel; the
    # static ones the views see alike are shared.
    edit_ply(bundle, drop("view_id"))
    def move(cols):
        for axis, step in zip("xyz", (0.003, -0.002, 0.004)):
            t, v = cols[axis]
            cols[axis] = (t, v + np.float32(step) * np.sin(np.arange(len(v), dtype=np.float32)))
    edit_ply(bundle, move)
    n = read_columns(bundle / "gaussians.ply")["x"][1].size
    code, stdout, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    got, pixels, shared, ambiguous = _association_line(stdout, n)
    assert got > 0 and shared > 0 and pixels == 0
    assert np.load(tmp_path / "out" / "removed.npy").shape == (n,)


def test_a_ply_without_view_id_and_images_is_refused(bundle, tmp_path, capsys):
    edit_ply(bundle, drop("view_id"))
    (bundle / "images" / "000.png").unlink()
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 2
    assert_one_error(err, "000.png", "image file not found")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------
# what is converted, and scenes the filter cannot work on
# ------------------------------------------------------------------------------------------------
def _reference(source, tmp_path_factory, cache={}):
    """removed.npy of the unedited bundle (computed once)."""
    if "removed" not in cache:
        out = tmp_path_factory.mktemp("ref") / "out"
        assert main(["filter", str(source), "--out", str(out)]) == 0
        cache["removed"] = (out / "removed.npy").read_bytes()
    return cache["removed"]


def test_big_endian_and_ascii_ply_give_the_same_result(bundle, source, tmp_path,
                                                       tmp_path_factory, capsys):
    expected = _reference(source, tmp_path_factory)
    cols = read_columns(bundle / "gaussians.ply")
    for fmt in ("binary_big_endian", "ascii"):
        if fmt == "ascii":
            n = len(cols["x"][1])
            head = ["ply", "format ascii 1.0", f"element vertex {n}"]
            head += [f"property {t} {name}" for name, (t, _) in cols.items()] + ["end_header"]
            rows = zip(*[v.tolist() if v.dtype.kind != "f" else
                         [repr(float(x)) for x in v] for _, (_, v) in cols.items()])
            body = "".join(" ".join(map(str, r)) + "\n" for r in rows)
            (bundle / "gaussians.ply").write_text("\n".join(head) + "\n" + body)
        else:
            write_columns(bundle / "gaussians.ply", cols, fmt=fmt)
        code, _, err = _filter(bundle, tmp_path / fmt, capsys)
        assert code == 0, err
        assert (tmp_path / fmt / "removed.npy").read_bytes() == expected, fmt


@pytest.mark.parametrize("kind", ["gray", "rgba", "palette", "gray16", "rgb16", "rgba16"])
def test_convertible_images_are_accepted(bundle, tmp_path, capsys, kind):
    path = bundle / "images" / "001.png"
    rgb = np.asarray(Image.open(path).convert("RGB"))
    if kind == "gray":
        Image.fromarray(rgb).convert("L").save(path)
    elif kind == "rgba":
        Image.fromarray(np.dstack([rgb, np.full(rgb.shape[:2], 128, np.uint8)])).save(path)
    elif kind == "palette":
        Image.fromarray(rgb).convert("P").save(path)
    elif kind == "gray16":
        Image.fromarray(rgb[..., 0].astype(np.uint16) * 257).save(path)
    else:
        samples = rgb.astype(np.uint16) * 257
        if kind == "rgba16":
            samples = np.dstack([samples, np.full(rgb.shape[:2], 65535, np.uint16)])
        png16(path, samples, 2 if kind == "rgb16" else 6)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    assert "clearsplat: error" not in err


def test_zero_gaussians(bundle, tmp_path, capsys):
    edit_ply(bundle, lambda cols: cols.update({k: (t, v[:0]) for k, (t, v) in cols.items()}))
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    assert "clearsplat: warning: the scene has no Gaussians" in err.splitlines()
    assert np.load(tmp_path / "out" / "removed.npy").shape == (0,)
    assert len(read_columns(tmp_path / "out" / "gaussians.ply")["x"][1]) == 0


def test_single_view_is_returned_unchanged_with_a_warning(bundle, tmp_path, capsys):
    edit_json(bundle, _frames(1))
    keep = read_columns(bundle / "gaussians.ply")["view_id"][1] == 0

    def only_view0(cols):
        for k, (t, v) in list(cols.items()):
            cols[k] = (t, v[keep])
    edit_ply(bundle, only_view0)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    warning = [ln for ln in err.splitlines() if ln.startswith("clearsplat: warning:")]
    assert len(warning) == 1 and "single input view" in warning[0]
    removed = np.load(tmp_path / "out" / "removed.npy")
    assert removed.shape == (int(keep.sum()),) and not removed.any()


def test_all_gaussians_behind_every_camera(bundle, tmp_path, capsys):
    cams = json.loads((bundle / "cameras.json").read_text())["frames"]
    c2w = np.array([f["camera_to_world"] for f in cams])
    # a point behind all three cameras: their mean centre minus twice their mean viewing axis
    behind = c2w[:, :3, 3].mean(0) - 20.0 * c2w[:, :3, 2].mean(0)
    assert all((np.linalg.inv(m) @ np.append(behind, 1.0))[2] < -1 for m in c2w)

    def move(cols):
        n = len(cols["x"][1])
        offsets = np.random.default_rng(0).normal(0, 0.05, (n, 3)).astype(np.float32)
        for j, c in enumerate("xyz"):
            cols[c] = ("float", (behind[j] + offsets[:, j]).astype(np.float32))
    edit_ply(bundle, move)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 0, err
    assert any(ln.startswith("clearsplat: warning:") and "camera" in ln
               for ln in err.splitlines()), err
    assert not np.load(tmp_path / "out" / "removed.npy").any()


def test_scene_too_large_for_memory(bundle, tmp_path, capsys, monkeypatch):
    import clearsplat._memory as memory
    monkeypatch.setattr(memory, "available_memory", lambda: 2 * 10**6)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 2
    line = assert_one_error(err, str(bundle), ": memory: ", "needs about", "2 MB available")
    assert "GB" in line or "MB" in line
    assert not (tmp_path / "out").exists() and leftovers(tmp_path) == []
    monkeypatch.setenv("CLEARSPLAT_MEMORY_CHECK", "0")
    assert _filter(bundle, tmp_path / "out", capsys)[0] == 0


def test_ply_too_large_to_read(bundle, tmp_path, capsys, monkeypatch):
    import clearsplat._memory as memory
    import clearsplat.io.ply as ply
    monkeypatch.setattr(ply, "_CHECK_ABOVE", 0)
    monkeypatch.setattr(memory, "available_memory", lambda: 10**5)
    code, _, err = _filter(bundle, tmp_path / "out", capsys)
    assert code == 2
    assert_one_error(err, str(bundle / "gaussians.ply"), ": gaussians: ",
                     "reading this file needs about")
