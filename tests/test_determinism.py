"""The same input gives byte-identical output across runs and thread counts."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clearsplat.cli import main


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    """The object world, 4 views of 64x112 (28,672 Gaussians), with distractors to remove."""
    from clearsplat.synth import make_world, reconstruct
    world = make_world("object", num_views=4, height=64, width=112)
    scene = reconstruct(world.cameras, world.images, world.depths, seed=1)
    root = tmp_path_factory.mktemp("determinism") / "scene"
    scene.save(root)
    return root


def _outputs(out: Path) -> tuple[bytes, bytes]:
    return (out / "removed.npy").read_bytes(), (out / "gaussians.ply").read_bytes()


def test_thread_counts_and_repeats_give_identical_bytes(bundle, tmp_path, capsys):
    runs = {}
    for name, threads in (("t1", 1), ("t2", 2), ("t2-again", 2), ("t3", 3)):
        out = tmp_path / name
        assert main(["filter", str(bundle), "--out", str(out), "--set",
                     f"num_threads={threads}"]) == 0
        runs[name] = _outputs(out)
    capsys.readouterr()
    removed = np.load(tmp_path / "t1" / "removed.npy")
    assert removed.dtype == bool and removed.shape == (4 * 64 * 112,)
    assert 0 < removed.sum() < removed.size // 10      # something is removed, not everything
    for name in ("t2", "t2-again", "t3"):
        assert runs[name][0] == runs["t1"][0], f"removed.npy differs for {name}"
        assert runs[name][1] == runs["t1"][1], f"gaussians.ply differs for {name}"


def test_omp_num_threads_gives_identical_bytes(bundle, tmp_path):
    """The default thread count (None: all cores) follows OMP_NUM_THREADS; a fresh process each."""
    results = []
    for threads in ("1", "2"):
        out = tmp_path / f"omp{threads}"
        env = {**os.environ, "OMP_NUM_THREADS": threads}
        proc = subprocess.run([sys.executable, "-m", "clearsplat", "filter", str(bundle),
                               "--out", str(out)], env=env, capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert "Traceback" not in proc.stderr
        results.append(_outputs(out))
    assert results[0] == results[1]
    assert np.load(tmp_path / "omp1" / "removed.npy").any()
