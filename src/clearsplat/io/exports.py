"""Gaussians from the PLY exports of feed-forward models.

Their ``export_ply`` functions write the vertex layout of 3DGS (``x y z nx ny nz f_dc_0..2
[f_rest_*] opacity scale_0..2 rot_0..3``), but not always its meaning (upstream code read for
each: ``docs/backbones.md``):

- **opacity**: pixelSplat, MVSplat, NoPoSplat, YoNoSplat and AnySplat write the opacity itself
  (``opacities[..., None]``); DepthSplat and ReSplat write ``torch.logit`` of it, as 3DGS does.
  Reading a raw opacity as a logit turns 0.9 into 0.71 and every Gaussian semi-transparent.
- **colour**: most write only the DC band (``harmonics[..., 0]``); ReSplat writes all bands,
  NoPoSplat/YoNoSplat/AnySplat with ``save_sh_dc_only=False``; some forks write plain RGB.
- **frame**: pixelSplat/MVSplat move the scene into a viewer frame (median recentred, divided
  by the largest 95 % quantile, rotated by a fixed "+Z up" rotation times the first view's
  world-to-camera rotation); DepthSplat rotates by the first view's world-to-camera rotation
  and ReSplat by the middle view's (no translation); NoPoSplat/YoNoSplat/AnySplat keep the
  first view's camera frame. ``to_world`` undoes a known similarity.
- **rotations**: pixelSplat's visualizer, YoNoSplat and ReSplat write each Gaussian's
  camera-frame rotation (the encoders' un-rotated ``rotations``), not its world rotation.
- **order and borders**: several exports trim an image border and reorder the vertices
  (``"h w spp v"``, view fastest); none write ``view_id``.

:func:`read_export` reads such a file's columns with the right options (or a ``preset``).
:func:`clearsplat.io.importers.import_export` recovers the association and the world frame.
"""

from __future__ import annotations

import numpy as np

from ..errors import ClearsplatError
from ..scene import Gaussians, rgb_to_sh_dc
from .ply import RAW_PREFIX, read_ply

__all__ = ["read_export", "EXPORT_PRESETS"]

#: Options matching each model's ``export_ply`` (see the module docstring).
EXPORT_PRESETS = {
    "3dgs": {"opacity": "logit", "color": "sh"},
    "pixelsplat": {"opacity": "raw", "color": "sh"},
    "mvsplat": {"opacity": "raw", "color": "sh"},
    "depthsplat": {"opacity": "logit", "color": "sh"},
    "noposplat": {"opacity": "raw", "color": "sh"},
    "anysplat": {"opacity": "raw", "color": "sh"},
    "resplat": {"opacity": "logit", "color": "sh"},
    "yonosplat": {"opacity": "raw", "color": "sh"},
}


def read_export(path, *, preset: str | None = None, opacity: str | None = None,
                color: str | None = None, to_world=None, saturated_logits: bool = False):
    """Read a model's PLY export as clearsplat Gaussians.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.ply`` file.
    preset : str, optional
        One of :data:`EXPORT_PRESETS` (``"depthsplat"``, ``"mvsplat"``, ``"pixelsplat"``,
        ``"noposplat"``, ``"anysplat"``, ``"resplat"``, ``"yonosplat"``, ``"3dgs"``); explicit
        options override it. Without a preset the file is read as 3DGS.
    opacity : {"logit", "raw"}
        How the ``opacity`` column is stored: ``"raw"`` values are the opacities (must lie in
        [0, 1]).
    color : {"sh", "dc", "rgb"}
        ``"sh"``: ``f_dc``/``f_rest`` are SH coefficients (all bands kept); ``"dc"``: keep the
        DC band only; ``"rgb"``: ``f_dc_0..2`` are RGB in [0, 1] (converted to DC; ``f_rest``
        dropped).
    to_world : (4, 4) array_like, optional
        A similarity ``[[s R, t], [0, 1]]`` from the file's frame to the world: centres become
        ``s R x + t``, scales ``s * scales``, rotations ``R q``, SH rotated by ``R``.
    saturated_logits : bool
        Infinite opacity logits read as opacity 0 or 1 (:func:`clearsplat.io.read_ply`).

    Returns
    -------
    gaussians : Gaussians
    view_id, pixel_id : (N,) arrays or None
        As stored in the file (model exports have none).

    Raises
    ------
    ClearsplatError
        Naming the file and field: unknown preset or option; raw opacities outside [0, 1]
        (the file stores logits); RGB outside [0, 1]; a ``to_world`` that is not a similarity;
        and everything :func:`clearsplat.io.read_ply` raises.
    """
    if preset is not None and preset not in EXPORT_PRESETS:
        raise ClearsplatError(f"unknown preset {preset!r} (known: "
                              f"{', '.join(sorted(EXPORT_PRESETS))})", field="preset")
    opts = dict(EXPORT_PRESETS[preset or "3dgs"])
    if opacity is not None:
        opts["opacity"] = opacity
    if color is not None:
        opts["color"] = color
    if opts["opacity"] not in ("logit", "raw"):
        raise ClearsplatError(f"must be 'logit' or 'raw', got {opts['opacity']!r}",
                              field="opacity")
    if opts["color"] not in ("sh", "dc", "rgb"):
        raise ClearsplatError(f"must be 'sh', 'dc' or 'rgb', got {opts['color']!r}",
                              field="color")
    g, view_id, pixel_id = read_ply(path, saturated_logits=saturated_logits)
    extra = dict(g.extra)
    opac, sh, means, scales, quats = g.opacities, g.sh, g.means, g.scales, g.quats
    if opts["opacity"] == "raw":
        raw = extra.pop(RAW_PREFIX + "opacity")
        opac = np.asarray(raw, dtype=np.float32)
        if len(opac) and (opac.min() < 0 or opac.max() > 1):
            raise ClearsplatError(f"raw opacities must lie in [0, 1], found {opac.min():.4g}.."
                                  f"{opac.max():.4g}: this file stores logits "
                                  "(use opacity='logit')", path=path, field="opacity")
    if opts["color"] == "rgb":
        rgb = sh[:, 0] * np.float32(1.0)
        if len(rgb) and (rgb.min() < -1e-3 or rgb.max() > 1 + 1e-3):
            raise ClearsplatError(f"RGB values outside [0, 1] ({rgb.min():.3g}..{rgb.max():.3g})"
                                  ": the file stores SH coefficients (use color='dc')",
                                  path=path, field="f_dc_0")
        sh = rgb_to_sh_dc(np.clip(rgb, 0, 1))[:, None, :]
    elif opts["color"] == "dc":
        sh = sh[:, :1]
    if sh.shape[1] != g.sh.shape[1] or opts["color"] == "rgb":
        for key in [k for k in extra if k.startswith(RAW_PREFIX + "f_")]:
            del extra[key]
    if to_world is not None:
        means, scales, quats, sh = _similarity(to_world, means, scales, quats, sh, path)
        for key in [k for k in extra if k.startswith(RAW_PREFIX)
                    and k[len(RAW_PREFIX):] in ("x", "y", "z", "scale_0", "scale_1", "scale_2",
                                                "rot_0", "rot_1", "rot_2", "rot_3")]:
            del extra[key]
    out = Gaussians(means=means, scales=scales, quats=quats, opacities=opac, sh=sh,
                    extra=extra)
    out.validate(path=path)
    return out, view_id, pixel_id


def _similarity(matrix, means, scales, quats, sh, path):
    from ..adapters._common import matrices_to_quats, quats_to_matrices
    from ..adapters.sh_rotation import rotate_sh
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.isfinite(m).all() or not np.allclose(m[3], [0, 0, 0, 1]):
        raise ClearsplatError(f"expected a finite 4x4 similarity, got shape {m.shape}",
                              path=path, field="to_world")
    sr = m[:3, :3]
    s = np.cbrt(np.linalg.det(sr))
    rot = sr / s if s > 0 else sr
    if not (s > 0 and np.allclose(rot.T @ rot, np.eye(3), atol=1e-5)):
        raise ClearsplatError("not a similarity (uniform scale times a proper rotation)",
                              path=path, field="to_world")
    new_means = (means.astype(np.float64) @ sr.T + m[:3, 3]).astype(np.float32)
    new_scales = (scales.astype(np.float64) * s).astype(np.float32)
    new_quats = matrices_to_quats(rot[None] @ quats_to_matrices(quats)).astype(np.float32) \
        if len(quats) else quats
    new_sh = rotate_sh(sh, rot) if sh.shape[1] > 1 and len(sh) else sh
    return new_means, new_scales, new_quats, new_sh

