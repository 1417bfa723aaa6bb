"""The examples run: the DepthSplat example's dry run removes the planted object, keeps the rest."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clearsplat.io import load_scene

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "depthsplat_inference.py"


def load_example():
    spec = importlib.util.spec_from_file_location("depthsplat_inference", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def object_mask(scene, example) -> np.ndarray:
    view, rows, cols = example.DRY_RUN_OBJECT
    w = scene.cameras[view].width
    r, c = scene.pixel_id // w, scene.pixel_id % w
    return ((scene.view_id == view) & (r >= rows.start) & (r < rows.stop)
            & (c >= cols.start) & (c < cols.stop))


def test_dry_run_removes_the_planted_object_and_keeps_the_wall(tmp_path):
    out = tmp_path / "filtered"
    proc = subprocess.run([sys.executable, str(EXAMPLE), "--dry-run", "--out", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "removed" in proc.stdout
    scene = load_scene(out)
    removed = scene.gaussians.opacities < 1e-6      # zero, as a PLY logit stores it
    obj = object_mask(scene, load_example())
    assert obj.sum() == 32 * 32 and len(scene) == 4 * 96 * 128
    assert removed[obj].mean() > 0.95, removed[obj].mean()
    assert removed[~obj].mean() < 0.01, removed[~obj].mean()
    # The saved images are the prediction's input views (view 1 shows the object).
    assert np.allclose(scene.images[1][40, 60], [0.85, 0.12, 0.10], atol=1 / 255)
    # A second run does not replace the bundle without --force.
    again = subprocess.run([sys.executable, str(EXAMPLE), "--dry-run", "--out", str(out)],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert again.returncode != 0 and "overwrite" in again.stderr


def test_dry_run_images_agree_with_the_cameras():
    """The wall seen by two views: the colour at a pixel of one is the colour at the pixel the
    cameras map it to in the other (what the old dry run broke)."""
    example = load_example()
    _, context = example.synthetic_prediction()
    images = np.moveaxis(context["image"][0], 1, -1)
    shift = 100.0 * 0.25 / 4.0                        # f * baseline / depth = 6.25 px
    w = images.shape[2]
    cols = np.arange(20, w - 20)
    for a, b in ((0, 2), (2, 3)):                      # views without the object
        d = shift * (b - a)
        # view b at column c sees the wall point that view a sees at column c + d.
        src = np.stack([np.interp(cols + d, np.arange(w) + 0.0, images[a][70, :, k])
                        for k in range(3)], -1)
        assert np.abs(src - images[b][70, cols]).mean() < 0.03


def test_encoder_state_dict_strips_the_model_wrapper_prefix():
    example = load_example()
    torch = pytest.importorskip("torch")
    weights = {"encoder.backbone.weight": torch.ones(2), "encoder.head.bias": torch.zeros(1),
               "decoder.background_color": torch.zeros(3)}
    for checkpoint in (weights, {"state_dict": weights, "epoch": 3}):
        got = example.encoder_state_dict(checkpoint)
        assert sorted(got) == ["backbone.weight", "head.bias"]
        assert got["backbone.weight"] is weights["encoder.backbone.weight"]
    with pytest.raises(SystemExit, match="no 'encoder.' weights"):
        example.encoder_state_dict({"model": weights})


def test_real_path_moves_the_batch_then_applies_the_shim_then_encodes(tmp_path, monkeypatch):
    """main() without DepthSplat: a stand-in encoder, shim and loader record what they get."""
    example = load_example()
    torch = pytest.importorskip("torch")
    gaussians_np, context_np = example.synthetic_prediction()
    calls = []

    class Gaussians:
        def __init__(self):
            for k, v in gaussians_np.items():
                setattr(self, k, torch.as_tensor(v))

    def shim(batch):
        calls.append(("shim", batch["context"]["image"].device.type))
        return {**batch, "context": {**batch["context"], "shimmed": True}}

    class Encoder:
        def __call__(self, context, global_step, deterministic=False):
            calls.append(("encoder", context.get("shimmed", False), global_step))
            return {"gaussians": Gaussians(), "depths": None}

    batch = {"context": {k: torch.as_tensor(v) for k, v in context_np.items()},
             "scene": ["wall"]}
    monkeypatch.setattr(example, "load_depthsplat",
                        lambda checkpoint, overrides, device: (Encoder(), shim, [batch]))
    monkeypatch.chdir(tmp_path)
    example.main(["--checkpoint", "model.pth", "--device", "cpu", "--out", "out"])
    assert calls == [("shim", "cpu"), ("encoder", True, 0)]
    scene = load_scene(tmp_path / "out" / "00000_0")
    assert (scene.gaussians.opacities < 1e-6)[object_mask(scene, example)].mean() > 0.95


def test_to_device_moves_nested_tensors():
    example = load_example()
    torch = pytest.importorskip("torch")
    batch = {"context": {"image": torch.zeros(1), "index": [torch.ones(1)]}, "scene": ["a"]}
    moved = example.to_device(batch, "cpu")
    assert moved["scene"] == ["a"] and moved["context"]["index"][0].device.type == "cpu"
