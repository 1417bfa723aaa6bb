"""Opt-in: the real encoders (random weights, CPU, 2 views of 128 px) through the adapters and
through ``clearsplat import`` of their own export function's file.

Runs only when an environment variable points at an upstream checkout (never vendored):
``CLEARSPLAT_UPSTREAM_DEPTHSPLAT=/path/to/depthsplat``. What is stubbed and the results per
backbone are in ``docs/backbones.md`` ("Checked against the upstream encoders").
Each check: every Gaussian of the adapted scene projects into the pixel its ``pixel_id`` names
(within 0.5 px of the centre per axis), and the imported export holds the same Gaussians at the
same views and pixels.
"""

from __future__ import annotations

import os
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from clearsplat import Camera
from clearsplat.io.importers import _residuals, import_export

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore")     # the upstream code's own warnings
H = W = 128
TRAINING_ONLY = ["torchvision", "huggingface_hub", "diff_gaussian_rasterization", "gsplat",
                 "xformers", "wandb", "lightning", "pytorch_lightning", "lightning_fabric",
                 "lpips", "moviepy", "skvideo", "cv2", "colorspacious", "hydra", "omegaconf",
                 "dacite", "matplotlib", "beartype"]


def _checkout(name):
    path = os.environ.get(f"CLEARSPLAT_UPSTREAM_{name.upper()}")
    if not path:
        pytest.skip(f"set CLEARSPLAT_UPSTREAM_{name.upper()} to an upstream checkout")
    return Path(path)


@pytest.fixture
def upstream_path(request):
    """Put one checkout's ``src`` package on the path, with the stubs, and take it off after."""
    added, undo = [], []

    def use(name):
        root = _checkout(name)
        import upstream_stubs
        undo.append(upstream_stubs.install(TRAINING_ONLY))
        sys.path.insert(0, str(root))
        added.append(str(root))
        return root

    yield use
    for p in added:
        sys.path.remove(p)
    for u in undo:
        u()
    for m in [m for m in sys.modules if m == "src" or m.startswith("src.")]:
        del sys.modules[m]


def _context(v=2, seed=0, size=H):
    """Two views of a textured scene: images, OpenCV camera-to-world, normalised intrinsics."""
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(1, v, 3, size, size, generator=g)
    ext = torch.eye(4).repeat(1, v, 1, 1)
    for i in range(v):
        a = 0.08 * i
        ext[0, i, :3, :3] = torch.tensor([[np.cos(a), 0, np.sin(a)], [0, 1, 0],
                                          [-np.sin(a), 0, np.cos(a)]], dtype=torch.float32)
        ext[0, i, :3, 3] = torch.tensor([0.3 * i, 0.05 * i, 0.0])
    intr = torch.tensor([[0.9, 0, 0.5], [0, 0.9, 0.5], [0, 0, 1]]).repeat(1, v, 1, 1)
    return {"image": img, "extrinsics": ext, "intrinsics": intr,
            "near": torch.full((1, v), 0.5), "far": torch.full((1, v), 20.0)}


def _cameras(ctx):
    h, w = ctx["image"].shape[-2:]
    return [Camera(K=np.diag([w, h, 1.0]) @ ctx["intrinsics"][0, i].numpy(),
                   camera_to_world=ctx["extrinsics"][0, i].double().numpy(), width=w, height=h)
            for i in range(ctx["image"].shape[1])]


def _inside(scene):
    d = _residuals(scene.gaussians.means.astype(np.float64), scene.cameras, scene.view_id,
                   scene.pixel_id)
    return float((np.abs(d) <= 0.5 + 1e-4).all(axis=1).mean()), float(np.abs(d).max())


def _build(cls_cfg, values):
    """A config dataclass from a dict, nested dataclasses built by their field types."""
    import dataclasses
    import typing
    hints = typing.get_type_hints(cls_cfg)
    kw = {}
    for f in fields(cls_cfg):
        if f.name not in values:
            continue
        t, v = hints[f.name], values[f.name]
        if t is float and isinstance(v, str):              # YAML 1.1 reads 1e-10 as text
            v = float(v)
        kw[f.name] = _build(t, v) if dataclasses.is_dataclass(t) and isinstance(v, dict) else v
    return cls_cfg(**kw)


class _TinyViT(torch.nn.Module):
    """Stands in for DINOv2 (fetched by ``torch.hub`` from GitHub): patch features of the
    shapes ``get_intermediate_layers`` returns, from random projections."""

    def __init__(self, dim):
        super().__init__()
        self.mask_token = torch.nn.Parameter(torch.zeros(1, dim))
        self.proj = torch.nn.ModuleList(torch.nn.Conv2d(3, dim, 14, 14) for _ in range(4))

    def get_intermediate_layers(self, x, n, return_class_token=False):
        return [p(x).flatten(2).transpose(1, 2) for p in self.proj]


def test_depthsplat_encoder(upstream_path, tmp_path, monkeypatch):
    import yaml
    root = upstream_path("depthsplat")
    monkeypatch.setattr(torch.hub, "load", lambda *a, **k: _TinyViT(384))
    from src.model.encoder.encoder_depthsplat import EncoderDepthSplat, EncoderDepthSplatCfg
    from src.model.ply_export import save_gaussian_ply
    from clearsplat.adapters import from_depthsplat

    values = yaml.safe_load((root / "config/model/encoder/depthsplat.yaml").read_text())
    torch.manual_seed(0)
    enc = EncoderDepthSplat(_build(EncoderDepthSplatCfg, values)).eval()
    ctx = _context()
    dump = {}
    with torch.no_grad():
        out = enc(ctx, global_step=0, deterministic=True, visualization_dump=dump)
    gaussians = out["gaussians"] if isinstance(out, dict) else out
    scene = from_depthsplat(gaussians, ctx["extrinsics"], ctx["intrinsics"], ctx["image"],
                            height=H, width=W)
    inside, worst = _inside(scene)
    assert inside == 1.0, worst
    path = tmp_path / "gaussians.ply"
    save_gaussian_ply(gaussians, dump, {"context": ctx}, path)
    imported, report = import_export(path, "depthsplat", _cameras(ctx))
    print(f"\ndepthsplat: adapter {len(scene)} Gaussians, {100 * inside:.2f} % in their pixel "
          f"(max offset {worst:.3f} px); import: {report.summary()}")
    assert report.inside_pixel == 1.0
    # the same Gaussians: match each imported vertex to the adapted one at its view and pixel
    key = scene.view_id.astype(np.int64) * H * W + scene.pixel_id
    pos = {int(k): i for i, k in enumerate(key)}
    idx = np.array([pos[int(k)] for k in imported.view_id.astype(np.int64) * H * W +
                    imported.pixel_id])
    assert np.allclose(imported.gaussians.means, scene.gaussians.means[idx], atol=1e-4)
    assert np.allclose(imported.gaussians.opacities, scene.gaussians.opacities[idx],
                       atol=1e-5)


def _hwsv_trim(x, v, trim=8):
    """The figure scripts' ``"() (v h w spp) ... -> h w spp v ..."`` and border mask."""
    from einops import rearrange
    x = rearrange(x, "() (v h w spp) ... -> h w spp v ...", v=v, h=H, w=W)
    mask = torch.zeros(x.shape[:4], dtype=torch.bool)
    mask[trim:-trim, trim:-trim] = True
    return x[mask][None]


def test_mvsplat_encoder(upstream_path, tmp_path):
    import types

    import yaml
    from scipy.spatial.transform import Rotation
    root = upstream_path("mvsplat")
    import src.global_cfg as global_cfg
    global_cfg.set_cfg(types.SimpleNamespace(mode="test", dataset=types.SimpleNamespace(
        view_sampler=types.SimpleNamespace(num_context_views=2))))
    from src.model.encoder.encoder_costvolume import EncoderCostVolume, EncoderCostVolumeCfg
    from src.model.ply_export import export_ply
    from clearsplat.adapters import from_mvsplat

    values = yaml.safe_load((root / "config/model/encoder/costvolume.yaml").read_text())
    torch.manual_seed(0)
    enc = EncoderCostVolume(_build(EncoderCostVolumeCfg, values)).eval()
    ctx = _context()
    dump = {}
    with torch.no_grad():
        gaussians = enc(ctx, global_step=0, deterministic=True, visualization_dump=dump)
    scene = from_mvsplat(gaussians, ctx["extrinsics"], ctx["intrinsics"], ctx["image"],
                         height=H, width=W)
    inside, worst = _inside(scene)
    assert inside == 1.0, worst
    # the paper figure script: trim, camera rotations turned by their view, export_ply
    v = ctx["image"].shape[1]
    view = _hwsv_trim(torch.arange(v).repeat_interleave(H * W)[None], v)[0]
    c2w = ctx["extrinsics"][0, view, :3, :3].numpy()
    cam_rot = _hwsv_trim(dump["rotations"], v)[0].numpy()
    world_rot = Rotation.from_matrix(c2w @ Rotation.from_quat(cam_rot).as_matrix()).as_quat()
    path = tmp_path / "gaussians.ply"
    export_ply(ctx["extrinsics"][0, 0], _hwsv_trim(gaussians.means, v)[0],
               _hwsv_trim(dump["scales"], v)[0], torch.from_numpy(world_rot).float(),
               _hwsv_trim(gaussians.harmonics, v)[0], _hwsv_trim(gaussians.opacities, v)[0],
               path)
    imported, report = import_export(path, "mvsplat", _cameras(ctx))
    print(f"\nmvsplat: adapter {len(scene)} Gaussians, {100 * inside:.2f} % in their pixel "
          f"(max offset {worst:.3f} px); import: {report.summary()}")
    assert report.inside_pixel >= 0.999
    key = scene.view_id.astype(np.int64) * H * W + scene.pixel_id
    pos = {int(k): i for i, k in enumerate(key)}
    idx = np.array([pos[int(k)] for k in imported.view_id.astype(np.int64) * H * W +
                    imported.pixel_id])
    err = np.linalg.norm(imported.gaussians.means - scene.gaussians.means[idx], axis=1)
    depth = np.linalg.norm(scene.gaussians.means[idx], axis=1)
    assert np.median(err / depth) < 1e-2


def _same_gaussians(imported, scene):
    """Each imported vertex matched to the adapted Gaussian of its view and pixel."""
    hw = scene.cameras[0].height * scene.cameras[0].width
    key = scene.view_id.astype(np.int64) * hw + scene.pixel_id
    pos = {int(k): i for i, k in enumerate(key)}
    return np.array([pos[int(k)] for k in imported.view_id.astype(np.int64) * hw +
                     imported.pixel_id])


def test_noposplat_encoder(upstream_path, tmp_path):
    import yaml
    root = upstream_path("noposplat")
    from src.model.encoder.backbone.backbone_croco import BackboneCrocoCfg
    from src.model.encoder.encoder_noposplat import EncoderNoPoSplat, EncoderNoPoSplatCfg
    from src.model.ply_export import export_ply
    from clearsplat.adapters import from_noposplat

    values = yaml.safe_load((root / "config/model/encoder/noposplat.yaml").read_text())
    values.pop("defaults")
    backbone = yaml.safe_load((root / "config/model/encoder/backbone/croco.yaml").read_text())
    values["backbone"] = _build(BackboneCrocoCfg, backbone)
    torch.manual_seed(0)
    enc = EncoderNoPoSplat(_build(EncoderNoPoSplatCfg, values)).eval()
    ctx = _context()
    ctx["extrinsics"] = torch.linalg.inv(ctx["extrinsics"][:, :1]) @ ctx["extrinsics"]
    dump = {}
    with torch.no_grad():
        gaussians = enc(ctx, global_step=0, visualization_dump=dump)
    scene = from_noposplat(gaussians, ctx["extrinsics"], ctx["intrinsics"], ctx["image"],
                           height=H, width=W)
    # a point-map model: with random weights the points are not on their pixels' rays, so
    # the layout is checked against the encoder's own per-pixel dump instead
    per_pixel = dump["means"][0].reshape(-1, 3).numpy()
    assert np.allclose(scene.gaussians.means, per_pixel, atol=1e-5)
    path = tmp_path / "gaussians.ply"
    export_ply(gaussians.means[0], dump["scales"][0], dump["rotations"][0],
               gaussians.harmonics[0], gaussians.opacities[0], path)
    # random weights: the points miss their pixels, which a real import refuses
    imported, report = import_export(path, "noposplat", _cameras(ctx), allow_misaligned=True)
    idx = _same_gaussians(imported, scene)
    print(f"\nnoposplat: {len(scene)} Gaussians; import: {report.summary()}")
    assert np.array_equal(idx, np.arange(len(scene)))
    assert np.allclose(imported.gaussians.means, scene.gaussians.means, atol=1e-5)
    cov_a = np.einsum("nij,nj,nkj->nik", *_rs(imported))
    cov_b = np.einsum("nij,nj,nkj->nik", *_rs(scene))
    assert np.allclose(cov_a, cov_b, atol=1e-6 * np.abs(cov_b).max())


def _rs(scene):
    from clearsplat.adapters._common import quats_to_matrices
    r = quats_to_matrices(scene.gaussians.quats)
    return r, scene.gaussians.scales.astype(np.float64) ** 2, r


def test_yonosplat_encoder(upstream_path, tmp_path):
    root = upstream_path("yonosplat")
    import yaml
    from einops import rearrange
    from src.model.encoder.backbone.backbone_local_global import BackboneLocalGlobalCfg
    from src.model.encoder.encoder_yonosplat import EncoderYoNoSplat, EncoderYoNoSplatCfg
    from src.model.ply_export import export_ply
    from clearsplat.adapters import from_yonosplat
    from clearsplat.errors import ClearsplatError

    values = yaml.safe_load((root / "config/model/encoder/yonosplat.yaml").read_text())
    values.pop("defaults")
    backbone = yaml.safe_load((root / "config/model/encoder/backbone/local_global.yaml")
                              .read_text())
    values["backbone"] = _build(BackboneLocalGlobalCfg, backbone)
    values["use_checkpoint"] = False
    torch.manual_seed(0)
    enc = EncoderYoNoSplat(_build(EncoderYoNoSplatCfg, values)).eval()
    size = 112                                       # a multiple of the 14-pixel patches
    ctx = _context(size=size)
    dump = {}
    with torch.no_grad():
        gaussians = enc(ctx, global_step=0, visualization_dump=dump)
    scene = from_yonosplat(gaussians, dump["c2w"], ctx["intrinsics"], ctx["image"],
                           height=size, width=size)
    # a point-map model: the layout is checked against the encoder's own per-pixel dump
    assert np.allclose(scene.gaussians.means, dump["means"][0].reshape(-1, 3).numpy(),
                       atol=1e-5)
    # test_step's export: trim 8, opacity > 0.01, "h w spp v", local rotations, raw opacity
    h, w = size, size
    op = rearrange(gaussians.opacities, "() (v h w spp) -> h w spp v", spp=1, h=h, w=w)
    mask = torch.zeros_like(op, dtype=torch.bool)
    mask[8:-8, 8:-8] = True

    def trim(x, m):
        return rearrange(x, "() (v h w spp) ... -> h w spp v ...", spp=1, h=h, w=w)[m][None]

    cams = [Camera(K=c.K, camera_to_world=dump["c2w"][0, i].double().numpy(), width=w,
                   height=h) for i, c in enumerate(_cameras(ctx))]
    for cut, name in ((False, "uncut.ply"), (True, "cut.ply")):
        m = mask & (op > 0.01) if cut else mask
        export_ply(trim(gaussians.means, m)[0], trim(dump["scales"], m)[0],
                   trim(dump["rotations"], m)[0], trim(gaussians.harmonics, m)[0],
                   trim(gaussians.opacities, m)[0], tmp_path / name, save_sh_dc_only=True)
    # random weights: the points miss their pixels, which a real import refuses
    imported, report = import_export(tmp_path / "uncut.ply", "yonosplat", cams,
                                     opacity_cut=0, allow_misaligned=True)
    idx = _same_gaussians(imported, scene)
    print(f"\nyonosplat: {len(scene)} Gaussians; import: {report.summary()}; "
          f"{int((op[mask] <= 0.01).sum())} trimmed opacities <= 0.01")
    assert np.allclose(imported.gaussians.means, scene.gaussians.means[idx], atol=1e-5)
    cov_a = np.einsum("nij,nj,nkj->nik", *_rs(imported))
    cov_b = np.einsum("nij,nj,nkj->nik", *_rs(scene.subset(idx)))
    assert np.allclose(cov_a, cov_b, atol=1e-5 * np.abs(cov_b).max())
    if (op[mask] <= 0.01).any():
        with pytest.raises(ClearsplatError, match="without recording which"):
            import_export(tmp_path / "cut.ply", "yonosplat", cams, allow_misaligned=True)
    else:
        again, _ = import_export(tmp_path / "cut.ply", "yonosplat", cams,
                                 allow_misaligned=True)
        assert np.array_equal(again.pixel_id, imported.pixel_id)


def _torch_scatter_stand_in():
    """``torch_scatter``'s ``scatter_add``/``scatter_max`` along dim 0 (a compiled extension;
    the same sums and maxima with PyTorch's own scatter)."""
    import types
    mod = types.ModuleType("torch_scatter")

    def scatter_add(src, index, dim=0):
        assert dim == 0
        out = torch.zeros((int(index.max()) + 1,) + tuple(src.shape[1:]), dtype=src.dtype)
        return out.index_add_(0, index, src)

    def scatter_max(src, index, dim=0):
        assert dim == 0
        out = torch.full((int(index.max()) + 1,) + tuple(src.shape[1:]), -torch.inf,
                         dtype=src.dtype)
        return out.scatter_reduce(0, index, src, "amax", include_self=False), None

    mod.scatter_add, mod.scatter_max = scatter_add, scatter_max
    return mod


def test_anysplat_encoder(upstream_path, tmp_path, monkeypatch):
    import yaml
    root = upstream_path("anysplat")
    monkeypatch.setitem(sys.modules, "torch_scatter", _torch_scatter_stand_in())
    from src.model.encoder.anysplat import EncoderAnySplat, EncoderAnySplatCfg
    from src.model.encoder.backbone.backbone_croco import BackboneCrocoCfg
    from src.model.encoder.vggt.models.vggt import VGGT
    from src.model.encoder.vggt.utils.geometry import \
        batchify_unproject_depth_map_to_point_map
    from src.model.encoder.vggt.utils.pose_enc import pose_encoding_to_extri_intri
    from src.model.ply_export import export_ply
    from clearsplat.adapters import anysplat_voxel_inverse, from_anysplat

    # random weights instead of the checkpoint download
    monkeypatch.setattr(VGGT, "from_pretrained", classmethod(lambda cls, *a, **k: cls()),
                        raising=False)
    values = yaml.safe_load((root / "config/model/encoder/anysplat.yaml").read_text())
    values.pop("defaults")
    values["backbone"] = _build(BackboneCrocoCfg, yaml.safe_load(
        (root / "config/model/encoder/backbone/croco.yaml").read_text()))
    exp = yaml.safe_load((root / "config/experiment/dl3dv.yaml").read_text())
    values.update(exp["model"]["encoder"])               # the released setting
    values["distill"] = False                            # as inference() sets it
    torch.manual_seed(0)
    enc = EncoderAnySplat(_build(EncoderAnySplatCfg, values)).eval()
    # the bfloat16 aggregator's tokens go to float32 heads: CUDA autocast casts them, the
    # CPU needs it said
    enc.aggregator.register_forward_hook(
        lambda m, i, o: ([t.float() for t in o[0]], o[1]))
    conf = {}
    enc.gaussian_param_head.register_forward_hook(
        lambda m, i, o: conf.__setitem__("conf", o[:, :, enc.raw_gs_dim].detach()))
    size = 112
    img = _context(size=size)["image"]
    with torch.no_grad():
        out = enc(img, global_step=0)
    n = out.gaussians.means.shape[1]
    enc_last = out.pred_pose_enc_list[-1]
    ours = anysplat_voxel_inverse(enc_last, out.depth_dict["depth"],
                                  voxel_size=enc.voxel_size, num_gaussians=n)
    ext, intr = pose_encoding_to_extri_intri(enc_last, (size, size))
    pts = batchify_unproject_depth_map_to_point_map(out.depth_dict["depth"], ext, intr)
    vox = (pts[0].reshape(-1, 3) / enc.voxel_size).round().int()
    exact = torch.unique(vox, dim=0, return_inverse=True)[1].numpy()
    same = float((ours == exact).mean())
    # the fused centres from the recovered index equal the encoder's Gaussians
    c = conf["conf"][0].reshape(-1).double().numpy()
    inv = torch.from_numpy(exact)
    top = np.full(n, -np.inf)
    np.maximum.at(top, exact, c)
    wgt = np.exp(c - top[exact])
    tot = np.bincount(exact, weights=wgt, minlength=n)
    fused = np.zeros((n, 3))
    np.add.at(fused, exact, pts[0].reshape(-1, 3).double().numpy() * (wgt / (tot[exact] + 1e-6))
              [:, None])
    assert np.allclose(fused, out.gaussians.means[0].double().numpy(), atol=1e-4)
    scene = from_anysplat(out.gaussians, out.pred_context_pose["extrinsic"],
                          out.pred_context_pose["intrinsic"], img, height=size, width=size,
                          voxel_inverse=inv, confidence=conf["conf"])
    assert len(scene) == n
    # without voxels: pixel-aligned; VGGT's half pixel handled
    enc.cfg.voxelize = False
    with torch.no_grad():
        out2 = enc(img, global_step=0)
    pix = from_anysplat(out2.gaussians, out2.pred_context_pose["extrinsic"],
                        out2.pred_context_pose["intrinsic"], img, height=size, width=size)
    inside, worst = _inside(pix)
    plain = from_anysplat(out2.gaussians, out2.pred_context_pose["extrinsic"],
                          out2.pred_context_pose["intrinsic"], img, height=size, width=size,
                          vggt_pixels=False)
    d = _residuals(plain.gaussians.means.astype(np.float64), plain.cameras, plain.view_id,
                   plain.pixel_id)
    plain_offset = float(np.median(np.abs(d)))
    path = tmp_path / "gaussians.ply"
    g2 = out2.gaussians
    export_ply(g2.means[0], g2.scales[0], g2.rotations[0], g2.harmonics[0], g2.opacities[0],
               path)
    cams = [Camera(K=np.diag([size, size, 1.0]) @ out2.pred_context_pose["intrinsic"][0, i]
                   .double().numpy(), camera_to_world=out2.pred_context_pose["extrinsic"][0, i]
                   .double().numpy(), width=size, height=size) for i in range(2)]
    imported, report = import_export(path, "anysplat", cams, voxelized=False)
    print(f"\nanysplat: voxelised {n} Gaussians from {2 * size * size} pixels, NumPy "
          f"voxel_inverse equal to the encoder's for {100 * same:.3f} % of pixels; no voxels: "
          f"{100 * inside:.2f} % in their pixel (max offset {worst:.3f} px; median offset "
          f"{plain_offset:.3f} px without the half-pixel shift); import: "
          f"{report.summary()}")
    assert same > 0.999
    assert inside == 1.0
    assert report.inside_pixel == 1.0
    assert np.allclose(imported.gaussians.means, pix.gaussians.means, atol=1e-5)
