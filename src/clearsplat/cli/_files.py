"""Helpers of the commands that look at results: one output file, a scene with its filter result."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError

__all__ = ["check_output_file", "load_scene_and_keep", "removed_mask"]


def check_output_file(path, *, inputs=(), force: bool = False, field: str = "--out",
                      suffixes: tuple = ()) -> Path:
    """Refuse an output file that is an input, a folder, or (without ``force``) any existing file.

    The writers write a temporary file beside ``path`` and rename it into place, so a failed
    run leaves an existing file as it was. Missing parent folders are created.
    """
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise ClearsplatError(f"expected a file name ending in {' or '.join(suffixes)}",
                              path=path, field=field)
    real = os.path.realpath(p)
    for inp in inputs:
        r = os.path.realpath(inp)
        inside = os.path.isdir(r) and real.startswith(r.rstrip(os.sep) + os.sep)
        if real == r or (inside and os.path.lexists(p)):     # an input, or a file in one
            raise ClearsplatError(f"would overwrite an input ({os.fspath(inp)}); choose "
                                  "another file", path=path, field=field)
    if p.is_dir():
        raise ClearsplatError("is a folder; this option takes a file name", path=path,
                              field=field)
    if os.path.lexists(p) and not force:
        raise ClearsplatError("exists; pass --force to replace it", path=path, field=field)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ClearsplatError(f"cannot create the folder ({e.strerror})", path=p.parent,
                              field=field) from None
    return p


def removed_mask(folder, n: int | None, *, required: bool = True):
    """``removed.npy`` of a ``clearsplat filter`` output, checked against ``n`` Gaussians.

    Returns None when the file is absent and not ``required``; ``n=None`` skips the length
    check.
    """
    path = Path(folder) / "removed.npy"
    if not path.is_file():
        if not required:
            return None
        raise ClearsplatError("not found: expected the output folder of 'clearsplat filter'",
                              path=path, field="removed")
    try:
        removed = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise ClearsplatError(f"cannot read ({' '.join(str(e).split())})", path=path,
                              field="removed") from None
    if removed.dtype != bool or removed.ndim != 1:
        raise ClearsplatError(f"expected a 1-D bool array, got {removed.dtype} {removed.shape}",
                              path=path, field="removed")
    if n is not None and len(removed) != n:
        raise ClearsplatError(f"{len(removed)} entries for the scene's {n} Gaussians: "
                              "this filter output belongs to another scene", path=path,
                              field="removed")
    return removed


def load_scene_and_keep(scene_path, filtered=None):
    """The scene (images if present) and the Gaussians kept by the filter output ``filtered``.

    A PLY without ``view_id`` is associated from the images as ``clearsplat filter`` does it
    (the same views, one warning line), so that a filter output of it applies here.

    Returns
    -------
    scene : Scene
    keep : (N,) bool or None
        None without ``filtered``.
    """
    from ..io import load_scene

    scene = load_scene(scene_path, require_images=False, associate=True)
    if filtered is None:
        return scene, None
    if not Path(filtered).is_dir():
        raise ClearsplatError("expected the output folder of 'clearsplat filter'",
                              path=filtered, field="--filtered")
    return scene, ~removed_mask(filtered, len(scene))
