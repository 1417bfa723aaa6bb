"""Gaussians as a vertex PLY in the layout of the original 3DGS code.

On disk (see ``docs/conventions.md``): ``x y z``, optional ``nx ny nz``, ``f_dc_0..2``,
``f_rest_*`` (channel-major), ``opacity`` (logit), ``scale_0..2`` (log), ``rot_0..3``
(w x y z), then any other properties, then the integer ``view_id`` and ``pixel_id``.

Reading accepts ``binary_little_endian``, ``binary_big_endian`` and ``ascii`` files, every
PLY scalar type and its alias (``float``/``float32``, ``int``/``int32``, ...; ``int64`` and
``uint64`` as an extension). Properties with unknown names go to :attr:`Gaussians.extra` with
their type. Elements other than ``vertex`` (faces, ...) are skipped and not written back;
an element with list properties placed *before* the vertex element of a binary file cannot be
skipped and is refused. Writing always produces ``binary_little_endian``.

Exact round trip
----------------
Memory holds opacities in [0, 1] and linear scales, the file their logit and log, so
converting back and forth would not reproduce the file. The reader therefore keeps the raw
on-disk columns that are not stored bit for bit in memory (``opacity``, ``scale_*``, any core
column whose type is not float32, and ``view_id``/``pixel_id``) in private entries of
``Gaussians.extra`` whose keys start with :data:`RAW_PREFIX`. They follow the Gaussians through
``subset`` and ``dataclasses.replace``. The writer uses the raw value of every element whose
in-memory value still equals the value derived from it, and computes the others afresh
(in float64, then rounded to float32). Loading and saving an unchanged file therefore reproduces
every property value bit for bit, and the bytes too when the file was binary little-endian with
only a vertex element and no comments.
"""

from __future__ import annotations

import os
import re
import secrets
from dataclasses import dataclass, field as dc_field
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError
from ..scene import Gaussians

__all__ = ["read_ply", "write_ply", "atomic_write_bytes", "RAW_PREFIX", "PlyRows"]

#: Prefix of the private ``Gaussians.extra`` keys holding raw on-disk columns.
RAW_PREFIX = "__ply_raw__:"

#: Opacities are clipped into [OPACITY_EPS, 1 - OPACITY_EPS] before the logit.
OPACITY_EPS = 1e-7

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
    "int64": "i8", "uint64": "u8",
}
_CANONICAL = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
              "u4": "uint", "f4": "float", "f8": "double", "i8": "int64", "u8": "uint64"}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_NAME_RE = re.compile(r"^[^\s]+$")
_REST_RE = re.compile(r"^f_rest_(\d+)$")
_XYZ = ("x", "y", "z")
_NORMALS = ("nx", "ny", "nz")
_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
_SCALE = ("scale_0", "scale_1", "scale_2")
_ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
_REQUIRED = _XYZ + _DC + ("opacity",) + _SCALE + _ROT
_INDEX = ("view_id", "pixel_id")


# ------------------------------------------------------------------------------------------------
# header
# ------------------------------------------------------------------------------------------------
@dataclass
class _Property:
    name: str
    token: str                  # type as spelled in the file
    dtype: str | None           # numpy code, e.g. "f4"; None for list properties
    is_list: bool = False
    list_types: tuple = ()      # (count code, item code) of a list property


@dataclass
class _Element:
    name: str
    count: int
    props: list = dc_field(default_factory=list)


@dataclass
class _Header:
    fmt: str
    elements: list
    comments: list
    body_offset: int


def _parse_header(data: bytes, path) -> _Header:
    if not data.startswith(b"ply"):
        raise ClearsplatError(f"not a PLY file (starts with {data[:8]!r})", path=path,
                              field="header")
    end = data.find(b"end_header")
    if end < 0:
        raise ClearsplatError("no 'end_header' line: truncated file or not a PLY file",
                              path=path, field="header")
    newline = data.find(b"\n", end)
    if newline < 0 or data[end:newline].strip() != b"end_header":
        raise ClearsplatError("malformed 'end_header' line", path=path, field="header")
    try:
        text = data[:end].decode("ascii")
    except UnicodeDecodeError as e:
        raise ClearsplatError(f"header is not ASCII text (byte {e.start})", path=path,
                              field="header") from None
    lines = [ln.strip() for ln in text.replace("\r\n", "\n").split("\n")]
    if lines[0] != "ply":
        raise ClearsplatError(f"first line must be 'ply', got {lines[0]!r}", path=path,
                              field="header")
    fmt, elements, comments = None, [], []
    for lineno, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words:
            continue
        key = words[0]
        where = f"header line {lineno}"
        if key == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise ClearsplatError(f"unsupported format line {line!r} (expected ascii, "
                                      "binary_little_endian or binary_big_endian)",
                                      path=path, field=where)
            fmt = words[1]
        elif key in ("comment", "obj_info"):
            comments.append(line)
        elif key == "element":
            if len(words) != 3 or not _is_count(words[2]):
                raise ClearsplatError(f"malformed element line {line!r} (expected "
                                      "'element NAME COUNT' with COUNT >= 0)",
                                      path=path, field=where)
            elements.append(_Element(words[1], int(words[2])))
        elif key == "property":
            if not elements:
                raise ClearsplatError("property before any element", path=path, field=where)
            el = elements[-1]
            if len(words) == 5 and words[1] == "list":
                for t in words[2:4]:
                    if t not in _TYPES:
                        raise ClearsplatError(f"unknown type {t!r}", path=path,
                                              field=f"{el.name}.{words[4]}")
                if _TYPES[words[2]][0] == "f":
                    raise ClearsplatError("list count type must be an integer type",
                                          path=path, field=f"{el.name}.{words[4]}")
                prop = _Property(words[4], "list", None, True,
                                 (_TYPES[words[2]], _TYPES[words[3]]))
            elif len(words) == 3:
                if words[1] not in _TYPES:
                    raise ClearsplatError(f"unknown property type {words[1]!r} (known: "
                                          f"{', '.join(sorted(_TYPES))})", path=path,
                                          field=words[2] if el.name == "vertex"
                                          else f"{el.name}.{words[2]}")
                prop = _Property(words[2], words[1], _TYPES[words[1]])
            else:
                raise ClearsplatError(f"malformed property line {line!r}", path=path,
                                      field=where)
            if any(p.name == prop.name for p in el.props):
                raise ClearsplatError(f"property {prop.name!r} appears twice in element "
                                      f"{el.name!r}", path=path, field=prop.name)
            el.props.append(prop)
        else:
            raise ClearsplatError(f"unknown header keyword {key!r}", path=path, field=where)
    if fmt is None:
        raise ClearsplatError("no 'format' line", path=path, field="header")
    names = [e.name for e in elements]
    if names.count("vertex") != 1:
        raise ClearsplatError(f"expected exactly one 'vertex' element, found elements "
                              f"{names}", path=path, field="vertex")
    vertex = elements[names.index("vertex")]
    for p in vertex.props:
        if p.is_list:
            raise ClearsplatError("list properties are not supported in the vertex element",
                                  path=path, field=p.name)
    return _Header(fmt, elements, comments, newline + 1)


def _is_count(word: str) -> bool:
    return word.isdigit()


# ------------------------------------------------------------------------------------------------
# body
# ------------------------------------------------------------------------------------------------
def _read_body(data: bytes, header: _Header, path) -> dict:
    """The vertex columns as native-endian arrays, keyed by property name (file order)."""
    if header.fmt == "ascii":
        return _read_ascii(data[header.body_offset:], header, path)
    order = _FORMATS[header.fmt]
    offset = header.body_offset
    for el in header.elements:
        if el.name == "vertex":
            dtype = np.dtype([(p.name, order + p.dtype) for p in el.props])
            need = el.count * dtype.itemsize
            have = len(data) - offset
            if have < need:
                raise ClearsplatError(
                    f"file too short: the header promises {el.count} vertices of "
                    f"{dtype.itemsize} bytes ({need} bytes) but only {have} bytes follow "
                    "(truncated file, or the count in the header is wrong)",
                    path=path, field="vertex")
            rows = np.frombuffer(data, dtype=dtype, count=el.count, offset=offset)
            last = el is header.elements[-1]
            if last and have > need:
                raise ClearsplatError(
                    f"{have - need} unexpected bytes after the {el.count} vertices "
                    "(the count in the header is wrong, or the file is corrupt)",
                    path=path, field="vertex")
            return _split_columns(rows, el.props)
        if any(p.is_list for p in el.props):
            raise ClearsplatError(
                f"cannot skip element {el.name!r} with list properties that comes before "
                "the vertex element in a binary file; move the vertex element first",
                path=path, field=el.name)
        offset += el.count * sum(np.dtype(p.dtype).itemsize for p in el.props)
        if offset > len(data):
            raise ClearsplatError(f"file too short for element {el.name!r}", path=path,
                                  field=el.name)
    raise AssertionError("unreachable: vertex element checked in header")


#: Rows per block when moving between a row table and columns: a block of every column stays
#: in cache, so each byte of the table is read (or written) once.
_BLOCK_ROWS = 8192


def _split_columns(rows: np.ndarray, props) -> dict:
    """Native-endian contiguous columns of a structured row table, block by block."""
    n = rows.shape[0]
    if rows.dtype.isnative and all(np.dtype(p.dtype).itemsize == 4 for p in props) \
            and rows.dtype.itemsize == 4 * len(props):
        # The usual 3DGS file: 4-byte properties only. Transpose the (n, k) table of 32-bit
        # words block by block (a block stays in cache) into one array per column.
        k = len(props)
        words = rows.view(np.uint32).reshape(n, k)
        out = [np.empty(n, dtype=np.uint32) for _ in props]
        block = np.empty((k, _BLOCK_ROWS), dtype=np.uint32)
        for a in range(0, n, _BLOCK_ROWS):
            b = min(a + _BLOCK_ROWS, n)
            np.copyto(block[:, :b - a], words[a:b].T)
            for j, col in enumerate(out):
                col[a:b] = block[j, :b - a]
        return {p.name: col.view(np.dtype(p.dtype)) for p, col in zip(props, out)}
    cols = {p.name: np.empty(n, dtype=np.dtype(p.dtype)) for p in props}
    for a in range(0, n, _BLOCK_ROWS):
        block = rows[a:a + _BLOCK_ROWS]
        for name, col in cols.items():
            col[a:a + _BLOCK_ROWS] = block[name]
    return cols


def _read_ascii(body: bytes, header: _Header, path) -> dict:
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError as e:
        raise ClearsplatError(f"ASCII body holds a non-ASCII byte at offset {e.start}",
                              path=path, field="vertex") from None
    lines = [ln for ln in text.split("\n") if ln.strip()]
    start = 0
    for el in header.elements:
        if el.name != "vertex":
            start += el.count           # one line per element row
            continue
        rows = lines[start:start + el.count]
        if len(rows) < el.count:
            raise ClearsplatError(
                f"file too short: the header promises {el.count} vertices but "
                f"{max(len(rows), 0)} lines follow (truncated file, or the count in the "
                "header is wrong)", path=path, field="vertex")
        if el is header.elements[-1] and len(lines) > start + el.count:
            raise ClearsplatError(
                f"{len(lines) - start - el.count} unexpected lines after the {el.count} "
                "vertices (the count in the header is wrong)", path=path, field="vertex")
        nprop = len(el.props)
        tokens = [r.split() for r in rows]
        for i, t in enumerate(tokens):
            if len(t) != nprop:
                raise ClearsplatError(f"vertex {i} has {len(t)} values, the header "
                                      f"declares {nprop} properties", path=path,
                                      field="vertex")
        table = np.array(tokens, dtype=str).reshape(el.count, nprop)
        return {p.name: _parse_column(table[:, j], p, path) for j, p in enumerate(el.props)}
    raise AssertionError("unreachable: vertex element checked in header")


def _parse_column(words: np.ndarray, prop: _Property, path) -> np.ndarray:
    dtype = np.dtype(prop.dtype)
    try:
        if dtype.kind == "f":
            values = words.astype(np.float64)
        else:
            values = words.astype(np.int64) if dtype != np.uint64 else words.astype(np.uint64)
    except (ValueError, OverflowError):
        bad = next((i for i, w in enumerate(words) if not _parses(w, dtype)), 0)
        raise ClearsplatError(f"vertex {bad}: {str(words[bad])!r} is not a valid {prop.token}",
                              path=path, field=prop.name) from None
    if dtype.kind == "f":
        big = np.abs(values) > np.finfo(dtype).max      # finite, but inf once cast
        if big.any():
            i = int(np.argmax(big))
            raise ClearsplatError(f"vertex {i}: {str(words[i])!r} does not fit in {prop.token}",
                                  path=path, field=prop.name)
        return np.ascontiguousarray(values.astype(dtype))
    info = np.iinfo(dtype)
    out_of_range = (values < info.min) | (values > info.max)
    if out_of_range.any():
        i = int(np.argmax(out_of_range))
        raise ClearsplatError(f"vertex {i}: {str(words[i])} does not fit in {prop.token}",
                              path=path, field=prop.name)
    return np.ascontiguousarray(values.astype(dtype))


def _parses(word: str, dtype: np.dtype) -> bool:
    try:
        float(word) if dtype.kind == "f" else int(word)
    except ValueError:
        return False
    return True


# ------------------------------------------------------------------------------------------------
# conversions between disk and memory (shared by reader and writer, so they agree bit for bit)
# ------------------------------------------------------------------------------------------------
def _opacity_from_logit(raw: np.ndarray) -> np.ndarray:
    """Sigmoid in float64 without overflow, rounded to float32."""
    x = np.asarray(raw, dtype=np.float64)
    # 1 / (1 + e^-x) for x >= 0 and e^x / (1 + e^x) below, with e = e^-|x| for both.
    e = np.exp(-np.abs(x))
    num = np.where(x >= 0, 1.0, e)
    e += 1.0
    num /= e
    return num.astype(np.float32)


def _logit_from_opacity(o: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(o, dtype=np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    return np.log(p / (1.0 - p)).astype(np.float32)


def _scale_from_log(raw: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return np.exp(np.asarray(raw, dtype=np.float64)).astype(np.float32)


def _log_from_scale(s: np.ndarray) -> np.ndarray:
    return np.log(np.asarray(s, dtype=np.float64)).astype(np.float32)


def _identity_f32(raw: np.ndarray) -> np.ndarray:
    return np.asarray(raw).astype(np.float32)


# ------------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------------
def read_ply(path, *, saturated_logits: bool = False
             ) -> tuple[Gaussians, np.ndarray | None, np.ndarray | None]:
    """Read Gaussians from a 3DGS-layout PLY file.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.ply`` file (binary little/big-endian or ASCII). It is only read.
    saturated_logits : bool, default False
        Read an infinite ``opacity`` logit as opacity 1 (``+inf``) or 0 (``-inf``): what an
        export writes that takes ``log(p / (1 - p))`` of an opacity that saturated in float32
        (Depth Anything 3's). Otherwise it is refused as any non-finite value.

    Returns
    -------
    gaussians : Gaussians
        Opacities in [0, 1] and linear scales (float32). Unknown properties (``nx ny nz``,
        custom fields) are in ``gaussians.extra`` with their on-disk type; private
        ``RAW_PREFIX`` entries keep the raw columns for an exact round trip.
    view_id : (N,) int32 or None
        The ``view_id`` property (-1: shared by several views), or None when the file has
        none.
    pixel_id : (N,) int64 or None
        The ``pixel_id`` property, or None when the file has none.

    Raises
    ------
    ClearsplatError
        Naming the file and the property: unreadable or truncated file, missing property,
        non-finite value, a log scale outside the float32 range, a zero quaternion,
        a non-integer ``view_id``/``pixel_id``; or (field ``gaussians``) a file too large to
        decode in the available memory, refused before it is read.
    """
    path = Path(path)
    _check_read_memory(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ClearsplatError("file not found", path=path, field="gaussians") from None
    except OSError as e:
        raise ClearsplatError(f"cannot read file ({e.strerror})", path=path,
                              field="gaussians") from None
    header = _parse_header(data, path)
    cols = _read_body(data, header, path)
    types = {p.name: p.token for p in next(e for e in header.elements
                                           if e.name == "vertex").props}
    return _columns_to_gaussians(cols, types, header.comments, path,
                                 saturated_logits=saturated_logits)


def _check_read_memory(path: Path) -> None:
    """Refuse, before reading it, a file whose decoding would not fit in memory."""
    from .._memory import check_memory, estimate_read_memory

    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(256)
    except OSError:
        return                  # reported by the read that follows
    estimate = estimate_read_memory(size, ascii=b"format ascii" in head)
    if estimate > _CHECK_ABOVE:
        check_memory(estimate, what="reading this file", path=path, field="gaussians",
                     advice="use a machine with more memory (an ASCII file needs about four "
                            "times more than a binary one)")


#: Files whose estimated decoding memory is below this are read without asking the system.
_CHECK_ABOVE = 256 * 2**20


def _columns_to_gaussians(cols: dict, types: dict, comments: list, path, *,
                          saturated_logits: bool = False):
    for name in _REQUIRED:
        if name not in cols:
            raise ClearsplatError(
                "required property is missing (a 3DGS PLY has x y z, f_dc_0..2, "
                "opacity, scale_0..2, rot_0..3)", path=path, field=name)
    for name, col in cols.items():
        finite = np.isfinite(col) if col.dtype.kind == "f" else None
        if finite is not None and saturated_logits and name == "opacity":
            finite = finite | np.isinf(col)     # a saturated logit: opacity 0 or 1
        if finite is not None and not finite.all():
            i = int(np.argmax(~finite))
            raise ClearsplatError(f"non-finite value {col[i]} (first at vertex {i})",
                                  path=path, field=name)
    for name in _XYZ + _DC + _ROT + tuple(c for c in cols if _REST_RE.match(c)):
        col = cols[name]
        if col.dtype.kind == "f" and col.dtype.itemsize > 4:
            big = np.abs(col) > np.finfo(np.float32).max
            if big.any():
                i = int(np.argmax(big))
                raise ClearsplatError(f"value {col[i]:.3g} (vertex {i}) is outside the float32 "
                                      "range", path=path, field=name)
    n = len(cols["x"])
    rest = sorted((int(m.group(1)), name) for name in cols
                  if (m := _REST_RE.match(name)))
    m = len(rest)
    if [i for i, _ in rest] != list(range(m)) or m % 3 or (m // 3 + 1) not in (1, 4, 9, 16, 25):
        raise ClearsplatError(
            f"expected f_rest_0..f_rest_{{M-1}} with M in 0, 9, 24, 45, 72 (SH degree 0..4), "
            f"got "
            f"{m} f_rest properties numbered {[i for i, _ in rest][:6]}...",
            path=path, field="f_rest_*")
    k = m // 3 + 1

    raw: dict = {}

    def column(name, to_memory=_identity_f32):
        col = cols[name]
        if to_memory is not _identity_f32 or col.dtype != np.float32:
            raw[RAW_PREFIX + name] = col
        return to_memory(col)

    means = np.stack([column(c) for c in _XYZ], axis=1)
    opacities = column("opacity", _opacity_from_logit)
    scales = np.stack([column(c, _scale_from_log) for c in _SCALE], axis=1)
    for j, c in enumerate(_SCALE):
        bad = ~(np.isfinite(scales[:, j]) & (scales[:, j] > 0))
        if bad.any():
            i = int(np.argmax(bad))
            raise ClearsplatError(f"log scale {cols[c][i]} (vertex {i}) gives a scale outside "
                                  "the float32 range", path=path, field=c)
    quats = np.stack([column(c) for c in _ROT], axis=1)
    if n:
        zero = ~(quats != 0).any(axis=1)        # finite: |q| > 0 iff a component is not 0
        if zero.any():
            raise ClearsplatError(f"zero quaternion (first at vertex {int(np.argmax(zero))})",
                                  path=path, field="rot_0..3")
    sh = np.empty((n, k, 3), dtype=np.float32)
    for c in range(3):
        sh[:, 0, c] = column(_DC[c])
        for j in range(1, k):
            sh[:, j, c] = column(f"f_rest_{c * (k - 1) + j - 1}")

    index = {}
    for name in _INDEX:
        if name in cols:
            col = cols[name]
            if col.dtype.kind == "f" and not (col == np.round(col)).all():
                i = int(np.argmax(col != np.round(col)))
                raise ClearsplatError(f"must hold integers, got {col[i]} at vertex {i}",
                                      path=path, field=name)
            if col.dtype == np.uint64 and (col > np.iinfo(np.int64).max).any():
                raise ClearsplatError("value too large", path=path, field=name)
            values = col.astype(np.int64)
            if name == "view_id":                       # -1: shared by several views
                bad = (values < -1) | (values > np.iinfo(np.int32).max)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise ClearsplatError(f"view id {values[i]} at vertex {i} is below -1 or "
                                          "too large", path=path, field=name)
            raw[RAW_PREFIX + name] = col
            index[name] = values.astype(np.int32) if name == "view_id" else values

    known = set(_REQUIRED) | set(_INDEX) | {name for _, name in rest}
    extra = {name: col for name, col in cols.items() if name not in known}
    extra.update(raw)
    g = Gaussians(means, scales, quats, opacities, sh, extra)
    g.validate(path=path)
    # Property order, type spellings and comments, for a byte-identical rewrite of an
    # unchanged set (lost with a copy, in which case the canonical 3DGS order is used).
    g._ply_layout = (tuple(cols), dict(types), tuple(comments))
    return g, index.get("view_id"), index.get("pixel_id")


# ------------------------------------------------------------------------------------------------
# writing
# ------------------------------------------------------------------------------------------------
def _binary_header(n: int, comments: list, properties: list) -> bytes:
    """The header of a little-endian binary PLY of ``n`` vertices with ``properties`` ((type
    token, name) pairs, in order) and ``comments`` (whole header lines)."""
    lines = ["ply", "format binary_little_endian 1.0", *comments, f"element vertex {n}"]
    lines += [f"property {token} {name}" for token, name in properties]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(path, gaussians: Gaussians, *, view_id=None, pixel_id=None) -> None:
    """Write Gaussians as a binary little-endian 3DGS-layout PLY (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; written to a temporary file beside it, then renamed over it.
    gaussians : Gaussians
        Validated first. Public ``extra`` entries must be (N,) numeric arrays; they are
        written with their dtype. Raw columns kept by :func:`read_ply` are reused where the
        in-memory value is unchanged (see the module docstring).
    view_id : (N,) array_like of int, optional
        Written as the ``view_id`` property when given (-1: shared by several views).
    pixel_id : (N,) array_like of int, optional
        Written as the ``pixel_id`` property when given (-1: not pixel-aligned).

    Raises
    ------
    ClearsplatError
        If the Gaussians are invalid, an extra property cannot be stored in a PLY, or
        ``view_id``/``pixel_id`` have the wrong shape or values.
    """
    path = Path(path)
    g = gaussians
    g.validate(path=path)
    n, k = len(g), g.sh.shape[1]
    cols: dict = {}
    for j, c in enumerate(_XYZ):
        cols[c] = _reuse_raw(g, c, g.means[:, j], _identity_f32, g.means[:, j])
    public = {name: v for name, v in g.extra.items() if not name.startswith(RAW_PREFIX)}
    for name, v in public.items():
        _check_extra(name, v, n, path)
    for c in _NORMALS:
        if c in public:
            cols[c] = public[c]
    for c in range(3):
        cols[_DC[c]] = _reuse_raw(g, _DC[c], g.sh[:, 0, c], _identity_f32, g.sh[:, 0, c])
    for c in range(3):
        for j in range(1, k):
            name = f"f_rest_{c * (k - 1) + j - 1}"
            cols[name] = _reuse_raw(g, name, g.sh[:, j, c], _identity_f32, g.sh[:, j, c])
    cols["opacity"] = _reuse_raw(g, "opacity", g.opacities, _opacity_from_logit,
                                 lambda: _logit_from_opacity(g.opacities))
    for j, c in enumerate(_SCALE):
        cols[c] = _reuse_raw(g, c, g.scales[:, j], _scale_from_log,
                             lambda j=j: _log_from_scale(g.scales[:, j]))
    for j, c in enumerate(_ROT):
        cols[c] = _reuse_raw(g, c, g.quats[:, j], _identity_f32, g.quats[:, j])
    for name, v in public.items():
        if name not in _NORMALS:
            cols[name] = v
    for name, values, low in (("view_id", view_id, -1), ("pixel_id", pixel_id, -1)):
        if values is not None:
            cols[name] = _index_column(g, name, values, n, low, path)

    order = list(cols)
    tokens = {name: _CANONICAL[cols[name].dtype.str[1:]] for name in order}
    comments: tuple = ()
    layout = getattr(g, "_ply_layout", None)
    if layout is not None and set(layout[0]) == set(order):
        order = list(layout[0])
        comments = layout[2]
        for name, token in layout[1].items():
            if _TYPES.get(token) == cols[name].dtype.str[1:]:
                tokens[name] = token

    header = _binary_header(n, comments, [(tokens[name], name) for name in order])
    dtype = np.dtype([(name, "<" + cols[name].dtype.str[1:]) for name in order])
    # Fill the file's bytes in place, block by block (no table copy, no concatenation).
    data = bytearray(len(header) + n * dtype.itemsize)
    data[:len(header)] = header
    table = np.frombuffer(data, dtype=dtype, count=n, offset=len(header))
    for a in range(0, n, _BLOCK_ROWS):
        block = table[a:a + _BLOCK_ROWS]
        for name in order:
            block[name] = cols[name][a:a + _BLOCK_ROWS]
    atomic_write_bytes(path, data)


def _reuse_raw(g: Gaussians, name: str, memory: np.ndarray, to_memory, fresh) -> np.ndarray:
    """The column to write: raw on-disk values where ``memory`` still equals their image."""
    memory = np.ascontiguousarray(memory, dtype=np.float32)
    raw = g.extra.get(RAW_PREFIX + name)
    if raw is None or raw.shape != memory.shape:
        return fresh() if callable(fresh) else memory
    same = to_memory(raw).view(np.uint32) == memory.view(np.uint32)
    if same.all():
        return raw
    new = fresh() if callable(fresh) else memory
    if raw.dtype.kind != "f":
        return new
    out = raw.copy()
    out[~same] = new[~same]
    return out


def _index_column(g, name, values, n, low, path) -> np.ndarray:
    arr = np.asarray(values)
    if arr.shape != (n,):
        raise ClearsplatError(f"expected {n} values, got shape {arr.shape}", path=path,
                              field=name)
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind != "f" or not (np.isfinite(arr) & (arr == np.round(arr))).all():
            raise ClearsplatError("must hold integers", path=path, field=name)
    arr = arr.astype(np.int64)
    if n and arr.min() < low:
        raise ClearsplatError(f"values must be >= {low}, got {arr.min()}", path=path,
                              field=name)
    raw = g.extra.get(RAW_PREFIX + name)
    if raw is not None and raw.shape == (n,) and (raw.astype(np.int64) == arr).all():
        return raw
    if n and arr.max() > np.iinfo(np.int32).max:
        return arr
    return arr.astype(np.int32)


def _check_extra(name: str, v: np.ndarray, n: int, path) -> None:
    reserved = set(_REQUIRED) | set(_INDEX)
    if name in reserved or _REST_RE.match(name):
        raise ClearsplatError("an extra property may not reuse the name of a 3DGS property",
                              path=path, field=name)
    if not name or not _NAME_RE.match(name) or not name.isascii():
        raise ClearsplatError("an extra property name must be non-empty ASCII without spaces",
                              path=path, field=repr(name))
    if v.shape != (n,) or v.dtype.str[1:] not in _CANONICAL:
        raise ClearsplatError(f"an extra property must be an ({n},) array of a PLY number "
                              f"type, got shape {v.shape} and dtype {v.dtype}",
                              path=path, field=name)


def atomic_write_bytes(path, data) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as e:
        raise ClearsplatError(f"cannot write here ({e.strerror})", path=path,
                              field="file") from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# ------------------------------------------------------------------------------------------------
# a large file in pieces
# ------------------------------------------------------------------------------------------------
#: Rows per piece when a column or a selection is read from a :class:`PlyRows` file.
PIECE_ROWS = 1 << 20


class PlyRows:
    """The vertex rows of a binary PLY file, read in pieces: never the whole file at once.

    What a long capture's filter needs to hold one window of views (:mod:`clearsplat.batch.
    windows`): one column of every row (``view_id``), the Gaussians of chosen rows, and a copy
    of chosen rows into a new file, each within :data:`PIECE_ROWS` rows of the file at a time.
    Rows are decoded exactly as :func:`read_ply` decodes them, and :meth:`write_rows` writes
    the chosen rows' bytes as :func:`write_ply` writes them after :func:`read_ply` (the same
    header, little-endian).

    Parameters
    ----------
    path : str or os.PathLike
        A ``binary_little_endian`` or ``binary_big_endian`` 3DGS PLY (an ASCII file cannot be
        read in pieces: :func:`read_ply` reads it whole).

    Attributes
    ----------
    count : int
        The number of vertices.
    dtype : numpy.dtype
        One vertex record as the file stores it.
    """

    def __init__(self, path):
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                head = f.read(1 << 16)
                while b"end_header" not in head and len(head) < (1 << 24):
                    more = f.read(1 << 16)
                    if not more:
                        break
                    head += more
            size = self.path.stat().st_size
        except FileNotFoundError:
            raise ClearsplatError("file not found", path=self.path, field="gaussians") from None
        except OSError as e:
            raise ClearsplatError(f"cannot read file ({e.strerror})", path=self.path,
                                  field="gaussians") from None
        header = _parse_header(head, self.path)
        if header.fmt == "ascii":
            raise ClearsplatError("an ASCII PLY cannot be read in pieces; convert it to a "
                                  "binary one", path=self.path, field="header")
        order = _FORMATS[header.fmt]
        offset = header.body_offset
        for el in header.elements:
            if el.name == "vertex":
                break
            if any(p.is_list for p in el.props):
                raise ClearsplatError(
                    f"cannot skip element {el.name!r} with list properties that comes before "
                    "the vertex element in a binary file; move the vertex element first",
                    path=self.path, field=el.name)
            offset += el.count * sum(np.dtype(p.dtype).itemsize for p in el.props)
        self._props = el.props
        self._types = {p.name: p.token for p in el.props}
        self._comments = header.comments
        self.count = el.count
        self.dtype = np.dtype([(p.name, order + p.dtype) for p in el.props])
        self._offset = offset
        if size - offset < self.count * self.dtype.itemsize:
            raise ClearsplatError(
                f"file too short: the header promises {self.count} vertices of "
                f"{self.dtype.itemsize} bytes but only {size - offset} bytes follow "
                "(truncated file, or the count in the header is wrong)",
                path=self.path, field="vertex")

    def __len__(self) -> int:
        return self.count

    def _records(self, start: int, stop: int) -> np.ndarray:
        with open(self.path, "rb") as f:
            f.seek(self._offset + start * self.dtype.itemsize)
            rows = np.fromfile(f, dtype=self.dtype, count=stop - start)
        if rows.shape[0] != stop - start:
            raise ClearsplatError("file shorter than its header says", path=self.path,
                                  field="vertex")
        return rows

    def _pieces(self, rows: np.ndarray):
        """``(records, local)`` per block of :data:`PIECE_ROWS` file rows that holds any of
        ``rows`` (increasing int64): the block's records and the places of those rows in it."""
        if rows.size == 0:
            return
        first = int(rows[0]) // PIECE_ROWS * PIECE_ROWS
        for a in range(first, int(rows[-1]) + 1, PIECE_ROWS):
            lo, hi = np.searchsorted(rows, [a, a + PIECE_ROWS])
            if hi > lo:
                part = rows[lo:hi]
                yield self._records(int(part[0]), int(part[-1]) + 1), part - part[0]

    def column(self, name: str) -> np.ndarray:
        """(count,) one property of every vertex, native byte order (read a piece at a time)."""
        if name not in self.dtype.names:
            raise ClearsplatError("property is missing", path=self.path, field=name)
        out = np.empty(self.count, self.dtype[name].newbyteorder("="))
        for a in range(0, self.count, PIECE_ROWS):
            b = min(a + PIECE_ROWS, self.count)
            out[a:b] = self._records(a, b)[name]
        return out

    def select(self, rows) -> np.ndarray:
        """The records of ``rows`` ((M,) increasing int indices) in that order."""
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size and (rows[0] < 0 or rows[-1] >= self.count or (np.diff(rows) <= 0).any()):
            raise ValueError("rows must be increasing indices of the file's vertices")
        out = np.empty(rows.size, self.dtype)
        at = 0
        for records, local in self._pieces(rows):
            picked = records[local]
            out[at:at + picked.shape[0]] = picked
            at += picked.shape[0]
        return out

    def read(self, rows) -> tuple[Gaussians, np.ndarray | None, np.ndarray | None]:
        """The Gaussians of ``rows`` ((M,) increasing indices), ``view_id`` and ``pixel_id``,
        exactly as :func:`read_ply` decodes those rows."""
        records = self.select(rows)
        cols = _split_columns(records, self._props)
        del records
        return _columns_to_gaussians(cols, self._types, self._comments, self.path)

    def write_rows(self, path, rows, *, zero_opacity=None) -> None:
        """Write ``rows`` ((M,) increasing indices) into a new PLY at ``path``, a piece at a
        time: the bytes :func:`write_ply` writes for those rows after :func:`read_ply`.
        ``zero_opacity``: (M,) bool, rows written with opacity 0 (the logit of
        :data:`OPACITY_EPS`, as :func:`write_ply` writes it)."""
        rows = np.asarray(rows, dtype=np.int64)
        little = np.dtype([(n, "<" + self.dtype[n].str[1:]) for n in self.dtype.names])
        header = _binary_header(rows.size, self._comments,
                                [(self._types[p.name], p.name) for p in self._props])
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            with open(tmp, "wb") as f:
                f.write(header)
                for a in range(0, rows.size, PIECE_ROWS):
                    part = rows[a:a + PIECE_ROWS]
                    block = self.select(part).astype(little)
                    if zero_opacity is not None:
                        zero = np.asarray(zero_opacity[a:a + part.size], bool)
                        if zero.any():
                            block["opacity"][zero] = _logit_from_opacity(
                                np.zeros(int(zero.sum()), np.float32)
                            ).astype(block["opacity"].dtype)
                    block.tofile(f)
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
