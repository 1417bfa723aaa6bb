"""One version: ``clearsplat.__version__`` is the only place it is written; the build metadata,
``clearsplat --version`` and the newest section of CHANGELOG.md agree with it."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
from pathlib import Path

import pytest

import clearsplat
from clearsplat.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")               # Python 3.11 and later
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _changelog_versions() -> list[str]:
    text = (ROOT / "CHANGELOG.md").read_text()
    return re.findall(r"^## \[([^\]]+)\]", text, re.M)


def test_version_flag_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"clearsplat {clearsplat.__version__}"
    out = subprocess.run([sys.executable, "-m", "clearsplat", "--version"], check=True,
                         capture_output=True, text=True).stdout
    assert out.strip() == f"clearsplat {clearsplat.__version__}"


def test_newest_changelog_section_is_the_version():
    versions = _changelog_versions()
    assert versions, "CHANGELOG.md has no '## [X.Y.Z] - date' section"
    assert "Unreleased" not in versions, "a release leaves no 'Unreleased' section"
    assert versions[0] == clearsplat.__version__
    assert re.fullmatch(r"\d+\.\d+\.\d+", versions[0])
    # newest first, each version once
    keys = [tuple(int(x) for x in v.split(".")) for v in versions]
    assert keys == sorted(set(keys), reverse=True)
    dated = re.findall(r"^## \[[^\]]+\] - (\d{4}-\d{2}-\d{2})$", (ROOT / "CHANGELOG.md")
                       .read_text(), re.M)
    assert len(dated) == len(versions)


def test_installed_metadata_is_the_version():
    installed = importlib.metadata.version("clearsplat")
    assert installed == clearsplat.__version__, (
        f"the installed metadata says {installed}, the package {clearsplat.__version__}: "
        "reinstall the checkout (pip install -e '.[dev]')")


def test_pyproject_reads_the_version_from_the_package():
    meta = _pyproject()
    assert "version" not in meta["project"] and "version" in meta["project"]["dynamic"]
    provider = meta["tool"]["scikit-build"]["metadata"]["version"]
    assert provider["provider"] == "scikit_build_core.metadata.regex"
    source = ROOT / provider["input"]
    assert source == ROOT / "src" / "clearsplat" / "__init__.py"
    written = re.findall(r'^__version__ = "([^"]+)"$', source.read_text(), re.M)
    assert written == [clearsplat.__version__]


def test_wheel_builds_test_the_demo_and_run_on_tags():
    meta = _pyproject()
    cibw = meta["tool"]["cibuildwheel"]
    assert "clearsplat demo --views 4" in cibw["test-command"]
    assert {"linux", "macos", "windows"} <= set(cibw)
    workflow = (ROOT / ".github" / "workflows" / "wheels.yml").read_text()
    assert 'tags: ["v*"]' in workflow and "pypa/cibuildwheel@" in workflow
    assert "python -m build --sdist" in workflow
