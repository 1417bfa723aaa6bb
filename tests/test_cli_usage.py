"""The command line's own surface: help, version, bare invocation, bench's early checks."""

from __future__ import annotations

import subprocess
import sys

import pytest

import clearsplat
import clearsplat.bench
from clearsplat.cli import main
from clearsplat.filter import PRESETS
from clearsplat.filter.config import FIELD_SPECS


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"clearsplat {clearsplat.__version__}"


def test_bare_command_prints_help_and_exits_0():
    proc = subprocess.run([sys.executable, "-m", "clearsplat"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: clearsplat")
    for command in ("demo", "filter", "bench"):
        assert command in proc.stdout
    assert proc.stderr == ""


def test_filter_help_lists_presets_and_fields(capsys):
    with pytest.raises(SystemExit) as e:
        main(["filter", "--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for name in PRESETS:
        assert f"{name}:" in text
    assert 'paper: the paper\'s procedure exactly; needs DINOv3: pip install "clearsplat[dino]"' \
        in text and "checkpoint" in text
    for name, spec in FIELD_SPECS.items():
        assert f"{name} {spec.allowed()}" in text


def test_unknown_command_is_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["filtre"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "invalid choice: 'filtre'" in err


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if the benchmark starts its work."""
    def fail(*args, **kwargs):
        raise AssertionError("the benchmark ran before its dependencies were checked")
    monkeypatch.setattr(clearsplat.bench, "run_suite", fail)
    monkeypatch.setattr(clearsplat.bench, "run_real_checks", fail)


@pytest.mark.parametrize("argv, missing, fragments", [
    ([], "skimage", ("scikit-image", 'pip install "clearsplat[bench]"', "--no-real-check")),
    (["--no-real-check", "--preset", "paper"], "transformers",
     ("'paper'", "'dinov3'", 'pip install "clearsplat[dino]"')),
    (["--no-real-check", "--set", "device=cuda"], "gsplat",
     ("'cuda'", 'pip install "clearsplat[gpu]"')),
])
def test_bench_checks_dependencies_first(argv, missing, fragments, no_work, monkeypatch,
                                         tmp_path, capsys):
    monkeypatch.setitem(sys.modules, missing, None)
    code = main(["bench", "--out", str(tmp_path / "b"), *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("clearsplat: error: ")
    for fragment in fragments:
        assert fragment in err, err
    assert not (tmp_path / "b").exists()


def test_bench_checks_its_output_folder_first(no_work, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    code = main(["bench", "--no-real-check", "--out", str(mine), "--force"])
    assert code == 2
    assert "clearsplat did not write" in capsys.readouterr().err
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_bench_writes_through_an_output_folder(tmp_path, capsys):
    out = tmp_path / "b"
    code = main(["bench", "--no-real-check", "--families", "object", "--views", "2",
                 "--resolution", "24x32", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    names = sorted(p.name for p in out.iterdir())
    assert ".clearsplat.json" in names and "results.json" in names
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]
    code = main(["bench", "--no-real-check", "--families", "object", "--views", "2",
                 "--resolution", "24x32", "--out", str(out)])
    assert code == 2 and "--force" in capsys.readouterr().err


def test_filter_command_imports_no_scipy(tmp_path):
    """The filter's morphology is NumPy: a whole default run (its refinement's windows and
    connected components) of two rounds starts no SciPy import (about 0.3 s)."""
    from clearsplat.io import save_scene
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=4, seed=0, height=48, width=64)
    save_scene(reconstruct(world.cameras, world.images, world.depths, seed=0),
               tmp_path / "scene")
    code = ("import sys; from clearsplat.cli import main; "
            f"code = main(['filter', {str(tmp_path / 'scene')!r}, '--out', "
            f"{str(tmp_path / 'out')!r}, '--set', 'rounds=2']); "
            "assert code == 0; bad = [m for m in sys.modules if m.startswith('scipy')]; "
            "assert not bad, bad")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "removed" in proc.stdout


def test_every_preset_has_help():
    from clearsplat.cli._common import PRESET_HELP
    from clearsplat.filter import PRESETS
    assert set(PRESET_HELP) == set(PRESETS)
    assert all(PRESET_HELP[name].strip() for name in PRESETS)
