"""Review the filter's decisions: flip a candidate's verdict without running the filter again.

A ``clearsplat filter`` output folder keeps, besides ``removed.npy``, each candidate's Gaussians
and pixel region (:data:`CANDIDATES_FILE`) and the removed Gaussians themselves
(:data:`REMOVED_FILE`, their original values), so that

- **rejecting** candidate k restores exactly the Gaussians of its removal set that no other
  accepted candidate removes, and
- **accepting** candidate k removes its removal set: its expanded Gaussians [hat C_k] where the
  filter computed them (every candidate that passed the individual test), otherwise (the filter
  never expands a candidate the individual test rejected) its own Gaussians [C_k].

:func:`edit_removed` is that rule on arrays; :func:`edit_filter_output` applies it to a folder
and writes a new one (``clearsplat edit`` and the viewer's review panel both call it).
Formats: ``docs/conventions.md``, "Outputs".
"""

from __future__ import annotations

import io
import json
import os
import shlex
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ClearsplatError

__all__ = [
    "CANDIDATES_FILE",
    "REMOVED_FILE",
    "CandidateSets",
    "FilterOutput",
    "edit_command",
    "edit_filter_output",
    "edit_removed",
    "load_filter_output",
    "load_full_scene",
    "parse_ids",
    "read_candidates",
    "write_candidates",
]

#: Per candidate its Gaussians, expanded Gaussians and pixel region (NumPy ``.npz``).
CANDIDATES_FILE = "candidates.npz"
#: The removed Gaussians with their original values, in input order (a 3DGS PLY).
REMOVED_FILE = "removed.ply"
_FORMAT = 1
_EDITABLE = ("filter", "edit")          # marker commands of folders that can be edited


# ------------------------------------------------------------------------------------------------
# the candidate file
# ------------------------------------------------------------------------------------------------
def _ragged(arrays, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Concatenated values and (K+1,) int64 offsets: item k is ``flat[off[k]:off[k+1]]``."""
    sizes = [len(a) for a in arrays]
    offsets = np.zeros(len(sizes) + 1, np.int64)
    np.cumsum(sizes, out=offsets[1:])
    flat = (np.concatenate([np.asarray(a, dtype) for a in arrays]) if arrays
            else np.zeros(0, dtype))
    return flat.astype(dtype, copy=False), offsets


@dataclass(frozen=True, eq=False)
class CandidateSets:
    """Each candidate's Gaussians, expanded Gaussians and pixel region, stored compactly.

    Item ``k`` of every array belongs to candidate ``k`` (its ``index`` in ``summary.json``).
    Gaussian indices refer to the input, in input order (``0 <= i < num_gaussians``).

    Attributes
    ----------
    num_gaussians : int
        N, the input's Gaussian count.
    view : (K,) int32
        The input view each candidate was proposed in.
    gaussians, gaussians_offsets : (G,) int32 or int64, (K+1,) int64
        [C_k], the Gaussians the region maps to after refinement, concatenated.
    expanded, expanded_offsets : (E,) int32 or int64, (K+1,) int64
        [hat C_k], concatenated; empty for candidates without an expansion.
    has_expanded : (K,) bool
        Whether the filter expanded the candidate (it does so only for those that passed the
        individual test).
    boxes : (K, 4) int32
        The region's bounding box ``row0, col0, row1, col1`` (ends exclusive) in the view's
        image; all 0 for an empty region.
    bits, bits_offsets : (B,) uint8, (K+1,) int64
        The region inside its box, row-major, packed 8 pixels a byte (``np.packbits``).
    """

    num_gaussians: int
    view: np.ndarray
    gaussians: np.ndarray
    gaussians_offsets: np.ndarray
    expanded: np.ndarray
    expanded_offsets: np.ndarray
    has_expanded: np.ndarray
    boxes: np.ndarray
    bits: np.ndarray
    bits_offsets: np.ndarray

    def __len__(self) -> int:
        return int(self.view.shape[0])

    @classmethod
    def from_candidates(cls, candidates, *, num_gaussians: int) -> CandidateSets:
        """Pack a list of :class:`clearsplat.filter.Candidate` (in index order)."""
        n = int(num_gaussians)
        dtype = np.int32 if n < 2 ** 31 else np.int64
        boxes, packed = [], []
        for c in candidates:
            m = np.asarray(c.pixels, bool)
            rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
            if rows.size == 0:
                boxes.append((0, 0, 0, 0))
                packed.append(np.zeros(0, np.uint8))
                continue
            box = (rows[0], cols[0], rows[-1] + 1, cols[-1] + 1)
            boxes.append(box)
            packed.append(np.packbits(m[box[0]:box[2], box[1]:box[3]].ravel()))
        g, g_off = _ragged([c.gaussians for c in candidates], dtype)
        e, e_off = _ragged([c.expanded if c.expanded is not None else ()
                            for c in candidates], dtype)
        bits, b_off = _ragged(packed, np.uint8)
        return cls(n, np.array([c.view for c in candidates], np.int32), g, g_off, e, e_off,
                   np.array([c.expanded is not None for c in candidates], bool),
                   np.array(boxes, np.int32).reshape(-1, 4), bits, b_off)

    @classmethod
    def from_arrays(cls, arrays: dict) -> CandidateSets:
        """The set whose :meth:`arrays` these are (not checked: :func:`read_candidates`
        checks a file)."""
        return cls(int(arrays["num_gaussians"]),
                   **{name: np.asarray(arrays[name]) for name in cls.__dataclass_fields__
                      if name != "num_gaussians"})

    @classmethod
    def concatenate(cls, sets, *, num_gaussians: int) -> CandidateSets:
        """The candidates of ``sets`` one after the other, their Gaussian indices already of
        the same input of ``num_gaussians`` (the windows of a long capture)."""
        n = int(num_gaussians)
        dtype = np.int32 if n < 2 ** 31 else np.int64

        def items(name, dt):
            return _ragged([flat[off[k]:off[k + 1]] for s in sets
                            for flat, off in [(getattr(s, name), getattr(s, name + "_offsets"))]
                            for k in range(len(s))], dt)

        def joined(name, dt):
            return np.concatenate([np.zeros(0, dt)] + [getattr(s, name) for s in sets]
                                  ).astype(dt)

        g, g_off = items("gaussians", dtype)
        e, e_off = items("expanded", dtype)
        bits, b_off = items("bits", np.uint8)
        boxes = np.concatenate([np.zeros((0, 4), np.int32)] + [s.boxes for s in sets])
        return cls(n, joined("view", np.int32), g, g_off, e, e_off,
                   joined("has_expanded", bool), boxes.astype(np.int32), bits, b_off)

    # -- per candidate -----------------------------------------------------------------------
    def own(self, k: int) -> np.ndarray:
        """(M,) int64: [C_k], candidate ``k``'s Gaussians."""
        return self.gaussians[self.gaussians_offsets[k]:self.gaussians_offsets[k + 1]] \
            .astype(np.int64)

    def expansion(self, k: int) -> np.ndarray | None:
        """(M',) int64: [hat C_k], or None where the filter did not expand candidate ``k``."""
        if not self.has_expanded[k]:
            return None
        return self.expanded[self.expanded_offsets[k]:self.expanded_offsets[k + 1]] \
            .astype(np.int64)

    def removal(self, k: int) -> np.ndarray:
        """(M',) int64: what accepting candidate ``k`` removes (see the module docstring)."""
        e = self.expansion(k)
        return self.own(k) if e is None else e

    def pixels(self, k: int, shape: tuple) -> np.ndarray:
        """(H, W) bool: candidate ``k``'s region in an image of ``shape`` (H, W)."""
        out = np.zeros(shape, bool)
        r0, c0, r1, c1 = (int(v) for v in self.boxes[k])
        if r1 > r0 and c1 > c0:
            bits = self.bits[self.bits_offsets[k]:self.bits_offsets[k + 1]]
            out[r0:r1, c0:c1] = np.unpackbits(bits, count=(r1 - r0) * (c1 - c0)) \
                .reshape(r1 - r0, c1 - c0).astype(bool)
        return out

    def covered(self, accepted: np.ndarray) -> np.ndarray:
        """(N,) int32: how many of the ``accepted`` ((K,) bool) candidates remove each Gaussian."""
        count = np.zeros(self.num_gaussians, np.int32)
        for k in np.flatnonzero(accepted):
            count[self.removal(int(k))] += 1
        return count

    def arrays(self) -> dict:
        return {"format": np.int64(_FORMAT), "num_gaussians": np.int64(self.num_gaussians),
                "view": self.view, "gaussians": self.gaussians,
                "gaussians_offsets": self.gaussians_offsets, "expanded": self.expanded,
                "expanded_offsets": self.expanded_offsets, "has_expanded": self.has_expanded,
                "boxes": self.boxes, "bits": self.bits, "bits_offsets": self.bits_offsets}


def write_candidates(path, candidates, *, num_gaussians: int) -> None:
    """Write :data:`CANDIDATES_FILE` for ``candidates`` of a scene of ``num_gaussians``.

    The file is an ``.npz`` (deflated, fixed member dates: the same candidates give the same
    bytes) that :func:`read_candidates` reads back; ``candidates`` may also be a
    :class:`CandidateSets`.
    """
    sets = candidates if isinstance(candidates, CandidateSets) else \
        CandidateSets.from_candidates(candidates, num_gaussians=num_gaussians)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, a in sets.arrays().items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(a), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, buf.getvalue())


def read_candidates(path, *, num_gaussians: int | None = None,
                    count: int | None = None) -> CandidateSets:
    """Read and check :data:`CANDIDATES_FILE`.

    Parameters
    ----------
    path : str or os.PathLike
    num_gaussians, count : int, optional
        N and K the file must hold (the ``summary.json`` beside it).

    Raises
    ------
    ClearsplatError
        A missing or unreadable file, a missing array or one of the wrong shape, an index
        out of range; the field names the array.
    """
    path = Path(path)
    if not path.is_file():
        raise ClearsplatError("not found: this filter output holds no candidate data (written "
                              "by an earlier clearsplat); run 'clearsplat filter' again to "
                              "review it", path=path, field="candidates")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise ClearsplatError(f"cannot read ({' '.join(str(e).split())})", path=path,
                              field="candidates") from None
    need = CandidateSets.__dataclass_fields__
    for name in list(need) + ["format"]:
        if name not in arrays:
            raise ClearsplatError("missing", path=path, field=name)
    if int(arrays["format"]) != _FORMAT:
        raise ClearsplatError(f"format {int(arrays['format'])}; this clearsplat reads "
                              f"{_FORMAT}", path=path, field="format")
    n = int(arrays.pop("num_gaussians"))
    if num_gaussians is not None and n != num_gaussians:
        raise ClearsplatError(f"{n} Gaussians, the folder's summary.json {num_gaussians}",
                              path=path, field="num_gaussians")
    k = arrays["view"].shape[0]
    if count is not None and k != count:
        raise ClearsplatError(f"{k} candidates, the folder's summary.json {count}",
                              path=path, field="view")

    def check(name, ok, what):
        if not ok:
            raise ClearsplatError(what, path=path, field=name)

    check("boxes", arrays["boxes"].shape == (k, 4), f"expected shape ({k}, 4)")
    check("has_expanded", arrays["has_expanded"].shape == (k,)
          and arrays["has_expanded"].dtype == bool, f"expected ({k},) bool")
    for name in ("gaussians", "expanded", "bits"):
        off = arrays[f"{name}_offsets"]
        flat = arrays[name]
        check(f"{name}_offsets", off.shape == (k + 1,) and off[0] == 0
              and off[-1] == flat.shape[0] and (np.diff(off) >= 0).all(),
              f"expected {k + 1} rising offsets from 0 to {flat.shape[0]}")
        check(name, flat.ndim == 1 and flat.dtype.kind in "iu", "expected 1-D integers")
        if name != "bits" and flat.size:
            check(name, flat.min() >= 0 and flat.max() < n,
                  f"Gaussian index outside 0..{n - 1}")
    return CandidateSets.from_arrays({**arrays, "num_gaussians": n})


# ------------------------------------------------------------------------------------------------
# the rule
# ------------------------------------------------------------------------------------------------
def edit_removed(removed, sets: CandidateSets, accepted, *, reject=(), accept=()
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The removal after rejecting and accepting candidates.

    Parameters
    ----------
    removed : (N,) bool
        The current removal (``removed.npy``).
    sets : CandidateSets
    accepted : (K,) bool
        The current verdicts.
    reject, accept : iterable of int
        Candidate indices; none in both.

    Returns
    -------
    removed : (N,) bool
        ``removed`` less, for each rejected candidate, its removal set minus the Gaussians an
        accepted candidate (after this edit) removes; plus every accepted candidate's removal
        set. When ``removed`` is the union of the accepted candidates' sets (as the filter
        writes it), so is the result.
    accepted : (K,) bool
        The new verdicts.
    """
    removed = np.array(removed, dtype=bool)
    accepted = np.array(accepted, dtype=bool)
    reject = sorted({int(k) for k in reject})
    accept = sorted({int(k) for k in accept})
    if removed.shape != (sets.num_gaussians,):
        raise ClearsplatError(f"expected ({sets.num_gaussians},), got {removed.shape}",
                              field="removed")
    if accepted.shape != (len(sets),):
        raise ClearsplatError(f"expected ({len(sets)},), got {accepted.shape}",
                              field="accepted")
    for name, ids in (("reject", reject), ("accept", accept)):
        bad = [k for k in ids if not 0 <= k < len(sets)]
        if bad:
            raise ClearsplatError(f"no candidate {bad[0]} (there are {len(sets)})", field=name)
    both = set(reject) & set(accept)
    if both:
        raise ClearsplatError(f"candidate {min(both)} both rejected and accepted",
                              field="accept")
    accepted[reject] = False
    accepted[accept] = True
    if reject:
        cover = sets.covered(accepted) > 0
        for k in reject:
            r = sets.removal(k)
            removed[r[~cover[r]]] = False
    for k in accept:
        removed[sets.removal(k)] = True
    return removed, accepted


def parse_ids(text: str | None, *, field: str) -> list[int]:
    """``"3,5, 7"`` -> ``[3, 5, 7]`` (empty or None: ``[]``)."""
    if text is None or not text.strip():
        return []
    out = []
    for word in text.split(","):
        word = word.strip()
        if not word.isdigit():
            raise ClearsplatError(f"expected candidate indices separated by commas "
                                  f"(like 3,5,7), got {word!r}", field=field)
        out.append(int(word))
    return out


# ------------------------------------------------------------------------------------------------
# folders
# ------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class FilterOutput:
    """A ``clearsplat filter`` (or ``clearsplat edit``) output folder, read and checked.

    Attributes
    ----------
    folder : Path
    summary : dict
        ``summary.json``.
    removed : (N,) bool
        ``removed.npy``.
    accepted : (K,) bool
        The verdicts of ``summary.json``'s candidates.
    sets : CandidateSets
        ``candidates.npz``.
    """

    folder: Path
    summary: dict
    removed: np.ndarray
    accepted: np.ndarray
    sets: CandidateSets

    @property
    def candidates(self) -> list:
        """The candidate records of ``summary.json`` (``index``, ``view``, ``scores``, ...)."""
        return self.summary["candidates"]


def _not_a_filter_output(folder: Path, path: Path, why: str):
    return ClearsplatError(f"{why}: expected the output folder of 'clearsplat filter' or "
                           "'clearsplat edit'", path=path, field="filtered")


def load_filter_output(folder) -> FilterOutput:
    """Read a filter output folder with its candidate data (:class:`FilterOutput`).

    Raises
    ------
    ClearsplatError
        A folder that ``clearsplat filter`` did not write (file and field named), a
        ``summary.json`` without candidates, a ``removed.npy`` of the wrong length, or no
        (or bad) candidate data.
    """
    from .io.output import MARKER

    folder = Path(folder)
    if not folder.is_dir():
        raise _not_a_filter_output(folder, folder, "not a folder")
    marker = folder / MARKER
    if marker.is_file():
        try:
            command = json.loads(marker.read_text()).get("command")
        except (ValueError, OSError, AttributeError):
            command = None
        if command not in _EDITABLE:
            raise ClearsplatError(f"written by 'clearsplat {command}', not by 'clearsplat "
                                  "filter' or 'clearsplat edit'", path=marker, field="command")
    path = folder / "summary.json"
    if not path.is_file():
        raise _not_a_filter_output(folder, path, "not found")
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, OSError) as e:
        raise ClearsplatError(f"cannot read ({' '.join(str(e).split())})", path=path,
                              field="summary") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("candidates"), list):
        raise ClearsplatError("missing (not a filter summary)", path=path, field="candidates")
    n = summary.get("gaussians")
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        raise ClearsplatError(f"expected a count, got {n!r}", path=path, field="gaussians")
    accepted = []
    for k, c in enumerate(summary["candidates"]):
        if not isinstance(c, dict) or c.get("index") != k:
            raise ClearsplatError(f"expected a candidate with index {k}", path=path,
                                  field=f"candidates[{k}].index")
        if not isinstance(c.get("accepted"), bool):
            raise ClearsplatError("expected true or false", path=path,
                                  field=f"candidates[{k}].accepted")
        accepted.append(c["accepted"])
    rpath = folder / "removed.npy"
    if not rpath.is_file():
        raise _not_a_filter_output(folder, rpath, "not found")
    try:
        removed = np.load(rpath, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise ClearsplatError(f"cannot read ({' '.join(str(e).split())})", path=rpath,
                              field="removed") from None
    if removed.dtype != bool or removed.shape != (n,):
        raise ClearsplatError(f"expected ({n},) bool as summary.json counts, got "
                              f"{removed.dtype} {removed.shape}", path=rpath, field="removed")
    sets = read_candidates(folder / CANDIDATES_FILE, num_gaussians=n,
                           count=len(summary["candidates"]))
    views = [c.get("view") for c in summary["candidates"]]
    if views != sets.view.tolist():
        k = next(i for i, (a, b) in enumerate(zip(views, sets.view.tolist())) if a != b)
        raise ClearsplatError(f"candidate {k} is of view {sets.view[k]} here and {views[k]} "
                              "in summary.json: the files come from different runs",
                              path=folder / CANDIDATES_FILE, field="view")
    return FilterOutput(folder, summary, removed, np.array(accepted, bool), sets)


def load_full_scene(output: FilterOutput, *, require_images: bool = False):
    """All N Gaussians of the input, rebuilt from ``gaussians.ply`` and :data:`REMOVED_FILE`.

    Returns the :class:`~clearsplat.Scene` in input order with the original values (each
    property as it was in the input PLY), the folder's cameras and, where present, images.
    """
    from .io import load_scene, read_ply
    from .scene import Gaussians, Scene

    folder = output.folder
    kept = load_scene(folder, require_images=require_images)
    n, removed = output.removed.size, output.removed
    rpath = folder / REMOVED_FILE
    if not rpath.is_file():
        raise ClearsplatError("not found: this filter output does not hold its removed "
                              "Gaussians (written by an earlier clearsplat); run 'clearsplat "
                              "filter' again to review it", path=rpath, field="candidates")
    gone, view_id, pixel_id = read_ply(rpath)
    if len(gone) != int(removed.sum()):
        raise ClearsplatError(f"{len(gone)} vertices for the {int(removed.sum())} removed in "
                              "removed.npy", path=rpath, field="vertex count")
    if len(kept) == n:                  # written with --keep-all
        kept_rows = kept.subset(~removed)
    elif len(kept) == n - len(gone):
        kept_rows = kept
    else:
        raise ClearsplatError(f"{len(kept)} vertices; removed.npy asks for {n - len(gone)} "
                              f"(or {n} with --keep-all)", path=folder / "gaussians.ply",
                              field="vertex count")
    a, b = kept_rows.gaussians, gone
    if a.sh.shape[1:] != b.sh.shape[1:] and len(a) and len(b):
        raise ClearsplatError(f"SH shape {b.sh.shape[1:]}, gaussians.ply {a.sh.shape[1:]}",
                              path=rpath, field="sh")

    def merge(x, y):
        shape = (y if len(x) == 0 else x).shape[1:]
        out = np.empty((n,) + shape, np.result_type(x, y))
        out[~removed], out[removed] = x, y
        return out

    extra = {}
    for key in set(a.extra) | set(b.extra):
        if key in a.extra and key in b.extra:
            extra[key] = merge(a.extra[key], b.extra[key])
        elif not key.startswith("__"):          # a raw column may be missing; a property not
            raise ClearsplatError(f"property {key!r} is in only one of gaussians.ply and "
                                  f"{REMOVED_FILE}", path=rpath, field=key)
    sh = merge(a.sh, b.sh)
    g = Gaussians(merge(a.means, b.means), merge(a.scales, b.scales),
                  merge(a.quats, b.quats), merge(a.opacities, b.opacities), sh, extra)
    view_id = merge(kept_rows.view_id, view_id if view_id is not None
                    else np.zeros(len(b), np.int32))
    pixel_id = merge(kept_rows.pixel_id, pixel_id if pixel_id is not None
                     else np.full(len(b), -1, np.int64))
    return Scene(g, view_id, pixel_id, kept.cameras, kept.images, kept.render_settings)


def _has_own_images(folder: Path) -> bool:
    try:
        doc = json.loads((folder / "cameras.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and "image_root" not in doc


def edit_filter_output(filtered, out, *, reject=(), accept=(), keep_all: bool = False,
                       copy_images: bool | None = None, force: bool = False) -> dict:
    """Write ``out``: the filter output ``filtered`` with candidates rejected and accepted.

    Parameters
    ----------
    filtered : str or os.PathLike
        A ``clearsplat filter`` (or ``clearsplat edit``) output folder; only read.
    out : str or os.PathLike
        The new folder, written through :func:`clearsplat.io.output.output_folder` (in full or
        not at all; never ``filtered``; ``force`` replaces only a folder clearsplat wrote).
    reject, accept : iterable of int
        Candidate indices (``summary.json``'s ``index``); see :func:`edit_removed`.
    keep_all : bool, default False
        As ``clearsplat filter --keep-all``: every vertex in ``gaussians.ply``, the removed
        ones with opacity 0. Otherwise they are dropped.
    copy_images : bool, optional
        Copy the images into ``out/images``; default: when ``filtered`` holds its own.
    force : bool, default False

    Returns
    -------
    dict
        The record appended to ``summary.json``'s ``edits``: ``reject``, ``accept`` (sorted
        indices), ``restored`` and ``removed`` (Gaussians the edit restored and removed),
        ``gaussians_removed`` (the count after it), ``source`` (``filtered``).

    Raises
    ------
    ClearsplatError
        Unknown indices (field ``--reject``/``--accept``, file ``summary.json``), a folder
        that is not a filter output or holds no candidate data, an ``out`` that may not be
        written. Nothing is written then.
    """
    from .io import save_bundle_cameras
    from .io.bundle import load_cameras
    from .io.output import check_output_folder, output_folder

    folder = Path(filtered)
    check_output_folder(out, inputs=[folder], force=force)
    output = load_filter_output(folder)
    reject = sorted({int(k) for k in reject})
    accept = sorted({int(k) for k in accept})
    k_all = len(output.sets)
    for flag, ids in (("--reject", reject), ("--accept", accept)):
        bad = [k for k in ids if not 0 <= k < k_all]
        if bad:
            span = f"0 to {k_all - 1}" if k_all else "none"
            raise ClearsplatError(f"no candidate {bad[0]}: this output has {k_all} "
                                  f"candidates ({span})", path=folder / "summary.json",
                                  field=flag)
    both = sorted(set(reject) & set(accept))
    if both:
        raise ClearsplatError(f"candidate {both[0]} is also given to --reject",
                              path=folder / "summary.json", field="--accept")
    scene = load_full_scene(output)
    removed, accepted = edit_removed(output.removed, output.sets, output.accepted,
                                     reject=reject, accept=accept)
    record = {"reject": reject, "accept": accept,
              "restored": int((output.removed & ~removed).sum()),
              "removed": int((removed & ~output.removed).sum()),
              "gaussians_removed": int(removed.sum()),
              "source": os.path.relpath(os.path.abspath(folder),
                                        os.path.dirname(os.path.abspath(out)))}
    summary = json.loads(json.dumps(output.summary))
    for k in reject + accept:
        c = summary["candidates"][k]
        c.setdefault("filter_reason", c.get("reason"))
        c["reason"] = "accepted in review" if accepted[k] else "rejected in review"
        c["accepted"] = bool(accepted[k])
    summary["removed"] = int(removed.sum())
    summary["accepted"] = int(accepted.sum())
    summary["edits"] = list(summary.get("edits", [])) + [record]
    cameras, image_paths = load_cameras(folder)
    own_images = _has_own_images(folder) if copy_images is None else copy_images
    with output_folder(out, inputs=[folder], force=force, command="edit") as tmp:
        write_removal(tmp, scene, removed, keep_all=keep_all)
        write_candidates(tmp / CANDIDATES_FILE, output.sets, num_gaussians=output.sets
                         .num_gaussians)
        with open(tmp / "summary.json", "w") as f:
            json.dump(summary, f, indent=1)
        save_bundle_cameras(tmp, cameras, image_paths, located_at=out, copy_images=own_images,
                            render=scene.render_settings)
    return record


def write_removal(folder, scene, removed: np.ndarray, *, keep_all: bool = False) -> None:
    """Write a filter output's removal into ``folder``: ``gaussians.ply`` (the kept
    Gaussians; with ``keep_all`` every one, the removed at opacity 0), ``removed.npy``
    ((N,) bool) and ``removed.ply`` (the removed Gaussians as they were, so that a rejection
    can restore them). Shared by ``clearsplat filter`` and ``clearsplat edit``."""
    from .io import write_ply
    removed = np.ascontiguousarray(removed, dtype=bool)
    if keep_all:
        kept = scene.with_opacities(np.where(removed, 0.0, scene.gaussians.opacities))
    else:
        kept = scene.subset(~removed)
    write_ply(os.path.join(folder, "gaussians.ply"), kept.gaussians, view_id=kept.view_id,
              pixel_id=kept.pixel_id)
    np.save(os.path.join(folder, "removed.npy"), removed)
    gone = scene.subset(removed)
    write_ply(os.path.join(folder, REMOVED_FILE), gone.gaussians, view_id=gone.view_id,
              pixel_id=gone.pixel_id)


def edit_command(filtered, out, *, reject=(), accept=(), keep_all: bool = False,
                 force: bool = False) -> str:
    """The ``clearsplat edit`` command line that :func:`edit_filter_output` runs."""
    words = ["clearsplat", "edit", os.fspath(filtered)]
    if reject:
        words += ["--reject", ",".join(str(k) for k in sorted(set(reject)))]
    if accept:
        words += ["--accept", ",".join(str(k) for k in sorted(set(accept)))]
    words += ["--out", os.fspath(out)]
    words += ["--keep-all"] * keep_all + ["--force"] * force
    return " ".join(shlex.quote(w) for w in words)
