"""Nothing a user owns is ever lost: the real CLI in a temporary folder, byte-for-byte checks.

Every case runs ``clearsplat`` as a user would and then compares the input bundle and every
file of the user's beside it with what was there before (bytes and modification times).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from clearsplat.cli import main
from clearsplat.io.output import MARKER, check_output_folder, output_folder
from clearsplat import ClearsplatError


def state(root: Path) -> dict:
    """Bytes, modification time and mode of every file, folder and link under ``root``."""
    out = {}
    for p in sorted([root, *root.rglob("*")]):
        st = p.lstat()
        body = (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() and not p.is_symlink()
                else os.readlink(p) if p.is_symlink() else "dir")
        out[str(p.relative_to(root))] = (body, st.st_mtime_ns if p.is_file() else 0,
                                         stat.S_IMODE(st.st_mode))
    return out


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=3, height=24, width=32)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    root = tmp_path_factory.mktemp("safety") / "B"
    scene.save(root)
    return root


@pytest.fixture
def home(source, tmp_path, monkeypatch):
    """A user's folder: the bundle B, notes.txt, photos/, and a link to B; cwd is here."""
    shutil.copytree(source, tmp_path / "B")
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "holiday.jpg").write_bytes(b"\xff\xd8precious")
    (tmp_path / "link-to-B").symlink_to(tmp_path / "B")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def cli(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error(err: str, *fragments) -> None:
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("clearsplat: error: "), err
    for f in fragments:
        assert f in lines[0], f"{f!r} not in {lines[0]!r}"


REFUSED = [
    # --out, extra options, fragments of the one-line error
    ("B/gaussians.ply", ["--force"], ["B/gaussians.ply", "--out", "names a file",
                                      "takes a folder"]),
    ("B/cameras.json", ["--force"], ["names a file"]),
    ("notes.txt", ["--force"], ["notes.txt", "names a file"]),
    ("notes.txt", [], ["notes.txt", "names a file"]),
    ("filtered.ply", [], ["filtered.ply", "names a file", "takes a folder"]),
    ("summary.JSON", [], ["names a file"]),
    ("B", ["--force"], ["would replace an input"]),
    (".", ["--force"], ["would replace an input"]),
    ("link-to-B", ["--force"], ["would replace an input"]),
    ("B/images", ["--force"], ["B/images", "inside an input"]),
    ("photos", ["--force"], ["photos", "clearsplat did not write it"]),
    ("photos", [], ["photos", "clearsplat did not write it"]),
]


@pytest.mark.parametrize("out, extra, fragments", REFUSED,
                         ids=[f"{o} {' '.join(e)}" for o, e, _ in REFUSED])
def test_refused_outputs_touch_nothing(home, capsys, out, extra, fragments):
    before = state(home)
    code, stdout, err = cli(["filter", "B", "--out", out, *extra], capsys)
    assert code == 2
    one_error(err, *fragments)
    assert state(home) == before


def test_a_file_without_suffix_is_never_replaced(home, capsys):
    (home / "README").write_text("mine")
    before = state(home)
    for extra in ([], ["--force"]):
        code, _, err = cli(["filter", "B", "--out", "README", *extra], capsys)
        assert code == 2
        one_error(err, "README", "not a folder")
    assert state(home) == before


def test_a_link_to_a_clearsplat_folder_is_not_replaced(home, capsys):
    assert cli(["filter", "B", "--out", "out"], capsys)[0] == 0
    (home / "out-link").symlink_to(home / "out")
    before = state(home)
    code, _, err = cli(["filter", "B", "--out", "out-link", "--force"], capsys)
    assert code == 2
    one_error(err, "out-link", "not a folder")
    assert state(home) == before


def test_inside_an_input_a_new_folder_is_written_but_nothing_replaced(home, capsys):
    before = state(home / "B")
    code, _, err = cli(["filter", "B", "--out", "B/filtered"], capsys)
    assert code == 0, err
    assert (home / "B" / "filtered" / MARKER).is_file()
    after = state(home / "B")
    assert {k: v for k, v in after.items() if not k.startswith("filtered")} == before
    snapshot = state(home)
    code, _, err = cli(["filter", "B", "--out", "B/filtered", "--force"], capsys)
    assert code == 2
    one_error(err, "inside an input")
    assert state(home) == snapshot


def test_force_replaces_only_what_clearsplat_wrote(home, capsys):
    assert cli(["filter", "B", "--out", "out"], capsys)[0] == 0
    assert (home / "out" / MARKER).is_file()
    before = state(home)
    code, _, err = cli(["filter", "B", "--out", "out"], capsys)
    assert code == 2
    one_error(err, "out", "earlier clearsplat output", "--force")
    assert state(home) == before
    code, _, err = cli(["filter", "B", "--out", "out", "--force"], capsys)
    assert code == 0, err
    others = {k: v for k, v in state(home).items() if not k.startswith("out")}
    assert others == {k: v for k, v in before.items() if not k.startswith("out")}
    assert sorted(p.name for p in home.iterdir()) == sorted(
        ["B", "notes.txt", "photos", "link-to-B", "out"])


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_output_folder_follows_the_umask(tmp_path, mask):
    old = os.umask(mask)
    try:
        with output_folder(tmp_path / "a" / "out", command="test") as tmp:
            (tmp / "x.txt").write_text("x")
    finally:
        os.umask(old)
    for p in (tmp_path / "a", tmp_path / "a" / "out"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o777 & ~mask, oct(p.stat().st_mode)
    assert stat.S_IMODE((tmp_path / "a" / "out" / "x.txt").stat().st_mode) == 0o666 & ~mask


def test_cli_output_follows_the_umask(home):
    """The real command in a process with umask 002: a group-writable output folder."""
    proc = subprocess.run(["sh", "-c", f"umask 002 && exec {sys.executable} -m clearsplat filter "
                           f"B --out shared"], cwd=home, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert stat.S_IMODE((home / "shared").stat().st_mode) == 0o775


def test_check_output_folder_api(tmp_path):
    (tmp_path / "in").mkdir()
    with pytest.raises(ClearsplatError) as e:
        check_output_folder(tmp_path / "x.ply")
    assert e.value.field == "--out" and e.value.path == str(tmp_path / "x.ply")
    with pytest.raises(ClearsplatError, match="would replace an input"):
        check_output_folder(tmp_path, inputs=[tmp_path / "in"], force=True)
    check_output_folder(tmp_path / "new", inputs=[tmp_path / "in"])


# ------------------------------------------------------------------------------------------------
# clearsplat demo: the same temporary-folder-then-swap writing
# ------------------------------------------------------------------------------------------------
DEMO = ["demo", "--views", "3", "--resolution", "32x48"]


@pytest.mark.parametrize("views", ["0", "1", "-2"])
def test_demo_with_too_few_views_leaves_nothing(home, capsys, views):
    before = state(home)
    code, _, err = cli(["demo", "--out", "new/demo", "--views", views], capsys)
    assert code == 2
    one_error(err, "--views", "at least 2")
    assert state(home) == before


def test_demo_refuses_what_filter_refuses(home, capsys):
    before = state(home)
    for out, extra, fragment in (("photos", ["--force"], "clearsplat did not write it"),
                                 ("notes.txt", ["--force"], "names a file"),
                                 ("B", ["--force"], "not empty")):
        code, _, err = cli([*DEMO, "--out", out, *extra], capsys)
        assert code == 2
        one_error(err, out, fragment)
    assert state(home) == before


def test_demo_replaces_its_own_output_whole(home, capsys):
    code, stdout, err = cli([*DEMO, "--out", "demo"], capsys)
    assert code == 0, err
    first = sorted(p.name for p in (home / "demo").iterdir())
    assert MARKER in first and "summary.txt" in first and "test_00_filtered.png" in first
    assert "pictures: demo " in stdout
    assert "building a synthetic 'object' world" in stdout and " a object" not in stdout
    (home / "demo" / "test_07_filtered.png").write_bytes(b"stale picture of an earlier run")
    before = state(home)
    code, _, err = cli([*DEMO, "--out", "demo"], capsys)
    assert code == 2
    one_error(err, "demo", "--force")
    assert state(home) == before
    code, _, err = cli([*DEMO, "--out", "demo", "--force", "--seed", "1"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (home / "demo").iterdir()) == first     # no stale picture
    assert sorted(p.name for p in home.iterdir()) == sorted(
        ["B", "notes.txt", "photos", "link-to-B", "demo"])
    assert (home / "demo" / "report" / "report.html").is_file()


def test_demo_failure_leaves_nothing(home, capsys, monkeypatch):
    import clearsplat.demo

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(clearsplat.demo, "write_report", broken)
    before = state(home)
    code, _, err = cli([*DEMO, "--out", "new/demo"], capsys)
    assert code == 1
    assert "No space left on device" in err
    assert state(home) == before
