"""Output folders written safely: nothing a user owns is ever replaced or lost.

Every command that writes a folder (``filter``, ``import``, ``demo``, ``batch``, ``render``, ...)
goes through :func:`output_folder`:

- ``out`` names a folder; a name that looks like a file (``filtered.ply``) is refused;
- ``out`` may not be an input, contain an input, or be a file or link;
- an existing non-empty ``out`` is replaced only with ``force=True`` and only when clearsplat
  wrote it (it holds :data:`MARKER`, or the ``removed.npy`` + ``summary.json`` pair of an earlier
  ``clearsplat filter``); inside an input folder nothing is ever replaced (a new or empty folder
  there may be written);
- everything is written into a hidden temporary folder beside ``out`` (created with the user's
  umask) and renamed into place at the end, so a failed or interrupted run leaves nothing behind
  and an earlier output stays whole until the new one is complete.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from ..errors import ClearsplatError

__all__ = ["MARKER", "FILE_SUFFIXES", "check_output_folder", "output_folder", "is_clearsplat_output"]

#: The file that marks a folder as written by clearsplat (JSON: command and version).
MARKER = ".clearsplat.json"
#: Names ending like this are files, not the folder that ``--out`` names.
FILE_SUFFIXES = (".ply", ".json", ".npy", ".npz", ".splat", ".spz", ".mp4", ".gif", ".png",
                 ".jpg", ".jpeg", ".txt", ".csv", ".html")
_LEGACY_MARKERS = ("removed.npy", "summary.json")


def is_clearsplat_output(folder) -> bool:
    """True for a folder that clearsplat wrote (its marker, or an earlier filter's outputs)."""
    folder = Path(folder)
    if not folder.is_dir() or folder.is_symlink():
        return False
    if (folder / MARKER).is_file():
        return True
    return all((folder / m).is_file() for m in _LEGACY_MARKERS)


def _inside(child: str, parent: str) -> bool:
    return child == parent or child.startswith(parent.rstrip(os.sep) + os.sep)


def check_output_folder(out, *, inputs: Iterable = (), force: bool = False,
                        field: str = "--out", given: str | None = None) -> None:
    """Raise :class:`ClearsplatError` unless ``out`` may be written (see the module docstring).

    Parameters
    ----------
    out : str or os.PathLike
        The output folder.
    inputs : iterable of paths
        Files and folders the command reads; ``out`` may not be one of them or hold one.
    force : bool
        Allow replacing a non-empty folder that clearsplat wrote.
    field, given : str
        The option and the path as the user typed it, for the message.
    """
    given = os.fspath(out) if given is None else given
    if os.path.basename(os.path.normpath(os.fspath(out))).lower().endswith(FILE_SUFFIXES):
        raise ClearsplatError("names a file, but this option takes a folder (the command writes "
                              "several files into it); choose a folder name",
                              path=given, field=field)
    real_out = os.path.realpath(out)
    inside_input = False
    for inp in inputs:
        real_in = os.path.realpath(inp)
        if _inside(real_in, real_out):
            raise ClearsplatError("would replace an input (it is or contains "
                                  f"{os.fspath(inp)}); choose another folder",
                                  path=given, field=field)
        if _inside(real_out, real_in):
            inside_input = True
    if not os.path.lexists(out):
        return
    if os.path.islink(out) or not os.path.isdir(out):
        raise ClearsplatError("exists and is not a folder; clearsplat only ever replaces a "
                              "folder it wrote, choose another name", path=given, field=field)
    if not os.listdir(out):
        return
    wrote = is_clearsplat_output(out)
    if inside_input:
        raise ClearsplatError("is inside an input folder and not empty; clearsplat never "
                              "replaces anything inside an input, choose a new folder",
                              path=given, field=field)
    if not wrote:
        raise ClearsplatError(f"exists, is not empty and clearsplat did not write it (no "
                              f"{MARKER}); clearsplat never replaces such a folder, choose "
                              f"another", path=given, field=field)
    if not force:
        raise ClearsplatError("exists and is not empty (an earlier clearsplat output); pass "
                              "--force to replace it", path=given, field=field)


def _umask() -> int:
    """The process's umask, read without changing it where the system allows (Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)              # elsewhere: set and restore at once
    os.umask(mask)
    return mask


def _makedirs(parent: str, field: str) -> list:
    """Create ``parent`` and its missing ancestors; return those created, deepest first."""
    made = []
    p = parent
    while p and not os.path.exists(p):
        made.append(p)
        p = os.path.dirname(p.rstrip(os.sep))
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError as e:
        raise ClearsplatError(f"cannot create the folder ({e.strerror})", path=parent,
                              field=field) from None
    return made


def _swap_into_place(src: str, dest: str) -> None:
    from .bundle import swap_into_place
    swap_into_place(src, dest)


@contextlib.contextmanager
def output_folder(out, *, inputs: Iterable = (), force: bool = False, command: str = "",
                  field: str = "--out", given: str | None = None) -> Iterator[Path]:
    """Check ``out``, yield a fresh temporary folder beside it, then swap it into place.

    The caller writes its files into the yielded folder. On a normal exit the folder gets
    :data:`MARKER` (``{"command": command, "version": ...}``) and replaces ``out``; on any
    exception (Ctrl-C included) it is deleted together with the parent folders this call
    created, and ``out`` is left as it was.

    Examples
    --------
    >>> with output_folder("filtered", inputs=["scene"]) as tmp:   # doctest: +SKIP
    ...     np.save(tmp / "removed.npy", removed)
    """
    from .. import __version__

    inputs = list(inputs)
    check_output_folder(out, inputs=inputs, force=force, field=field, given=given)
    out = os.path.abspath(out)
    parent = os.path.dirname(out)
    made = _makedirs(parent, field)
    tmp = None
    try:
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}.clearsplat-", dir=parent)
        os.chmod(tmp, 0o777 & ~_umask())
        yield Path(tmp)
        with open(os.path.join(tmp, MARKER), "w") as f:
            json.dump({"command": command, "version": __version__}, f)
            f.write("\n")
        # checked again: another process may have created ``out`` in the meantime
        check_output_folder(out, inputs=inputs, force=force, field=field, given=given)
        _swap_into_place(tmp, out)
        tmp = None
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        for d in made:                  # deepest first; only if still empty
            with contextlib.suppress(OSError):
                os.rmdir(d)
        raise
