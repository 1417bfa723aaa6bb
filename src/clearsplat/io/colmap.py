"""Cameras from a COLMAP sparse model (``cameras`` + ``images``, text or binary).

A model folder (``sparse/0``) holds ``cameras.txt``/``images.txt`` or ``cameras.bin``/
``images.bin``; the binary pair is read when both exist. COLMAP stores, per image, the
world-to-camera rotation as a quaternion ``QW QX QY QZ`` and translation ``TX TY TZ`` in OpenCV
camera axes (x right, y down, z forward), so ``camera_to_world = [R^T | -R^T t]``. COLMAP's
pixel convention (centre of the top-left pixel at (0.5, 0.5)) is clearsplat's.

Camera models
-------------
``PINHOLE`` (fx, fy, cx, cy) and ``SIMPLE_PINHOLE`` (f, cx, cy) are read as they are. Models with
lens distortion (``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``) are refused unless
their distortion coefficients are all zero, because clearsplat's cameras are distortion-free
and the images would not match: undistort first (``colmap image_undistorter`` writes a
``PINHOLE`` model). ``distortion="ignore"`` reads their focal length and principal point
anyway and warns once per camera. Fisheye models are always refused.

Order
-----
Cameras are returned sorted by image name (the order of most 3DGS loaders), or by image id
with ``order="id"``.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError

__all__ = ["read_colmap", "CAMERA_MODELS"]

#: COLMAP camera models: id -> (name, number of parameters).
CAMERA_MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
_BY_NAME = {name: (i, n) for i, (name, n) in CAMERA_MODELS.items()}
# (fx, fy, cx, cy) indices into the parameters, and where the distortion coefficients start.
_PINHOLE_PART = {"SIMPLE_PINHOLE": (0, 0, 1, 2, 3), "PINHOLE": (0, 1, 2, 3, 4),
                 "SIMPLE_RADIAL": (0, 0, 1, 2, 3), "RADIAL": (0, 0, 1, 2, 3),
                 "OPENCV": (0, 1, 2, 3, 4), "FULL_OPENCV": (0, 1, 2, 3, 4)}


def read_colmap(path, *, order: str = "name", distortion: str = "error"):
    """Read the registered images of a COLMAP sparse model as cameras.

    Parameters
    ----------
    path : str or os.PathLike
        The model folder (holding ``cameras.*`` and ``images.*``), or a dataset folder with
        ``sparse/0`` inside.
    order : {"name", "id"}
        Sort by image name or by COLMAP image id.
    distortion : {"error", "ignore"}
        What to do with a camera model that has non-zero lens distortion (see module doc).

    Returns
    -------
    cameras : list of Camera
    names : list of str
        Image names (paths relative to COLMAP's image folder), in the same order.

    Raises
    ------
    ClearsplatError
        Naming the file and the field: missing files, malformed lines, truncated binary
        files, unknown or unsupported camera models, an image that names an unknown camera, a
        zero quaternion, duplicate image names.
    """
    if order not in ("name", "id"):
        raise ClearsplatError(f"must be 'name' or 'id', got {order!r}", field="order")
    if distortion not in ("error", "ignore"):
        raise ClearsplatError(f"must be 'error' or 'ignore', got {distortion!r}",
                              field="distortion")
    folder = Path(path)
    if not any((folder / f"cameras.{e}").exists() for e in ("bin", "txt")) \
            and (folder / "sparse" / "0").is_dir():
        folder = folder / "sparse" / "0"
    if (folder / "cameras.bin").exists() and (folder / "images.bin").exists():
        cams = _read_cameras_bin(folder / "cameras.bin")
        images = _read_images_bin(folder / "images.bin")
        cam_file, img_file = folder / "cameras.bin", folder / "images.bin"
    elif (folder / "cameras.txt").exists() and (folder / "images.txt").exists():
        cams = _read_cameras_txt(folder / "cameras.txt")
        images = _read_images_txt(folder / "images.txt")
        cam_file, img_file = folder / "cameras.txt", folder / "images.txt"
    else:
        raise ClearsplatError("no COLMAP model: expected cameras.bin + images.bin or "
                              "cameras.txt + images.txt", path=folder, field="cameras")
    intrinsics = {cid: _intrinsics(cid, model, w, h, params, cam_file, distortion)
                  for cid, (model, w, h, params) in cams.items()}
    seen = {}
    for image_id, q, t, cid, name in images:
        if name in seen:
            raise ClearsplatError(f"image name {name!r} appears twice (ids {seen[name]} and "
                                  f"{image_id})", path=img_file, field="NAME")
        seen[name] = image_id
    key = (lambda r: r[4]) if order == "name" else (lambda r: r[0])
    cameras, names = [], []
    for image_id, q, t, cid, name in sorted(images, key=key):
        if cid not in intrinsics:
            raise ClearsplatError(f"image {image_id} ({name}) uses camera {cid}, which "
                                  f"{cam_file.name} does not define", path=img_file,
                                  field="CAMERA_ID")
        norm = float(np.linalg.norm(q))
        if not np.isfinite(norm) or norm < 1e-12 or not np.isfinite(t).all():
            raise ClearsplatError(f"image {image_id} ({name}): zero or non-finite pose",
                                  path=img_file, field="QW QX QY QZ TX TY TZ")
        rot = _quat_to_matrix(np.asarray(q, dtype=np.float64) / norm)
        c2w = np.eye(4)
        c2w[:3, :3] = rot.T
        c2w[:3, 3] = -rot.T @ np.asarray(t, dtype=np.float64)
        K, w, h = intrinsics[cid]
        cameras.append(Camera(K=K, camera_to_world=c2w, width=w, height=h))
        names.append(name)
    return cameras, names


# ------------------------------------------------------------------------------------------------
def _quat_to_matrix(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _intrinsics(cid, model, width, height, params, path, distortion):
    field = f"camera {cid}"
    if model not in _PINHOLE_PART:
        raise ClearsplatError(f"camera model {model} is not supported (fisheye or unknown); "
                              "undistort the images to PINHOLE first (colmap "
                              "image_undistorter)", path=path, field=field)
    ifx, ify, icx, icy, dist = _PINHOLE_PART[model]
    coeffs = np.asarray(params[dist:], dtype=np.float64)
    if coeffs.size and np.any(coeffs != 0):
        if distortion == "error":
            raise ClearsplatError(
                f"camera model {model} has lens distortion {coeffs.tolist()}; undistort the "
                "images to PINHOLE first (colmap image_undistorter) or pass "
                "distortion='ignore'", path=path, field=field)
        warnings.warn(f"{path}: {field}: ignoring {model} distortion {coeffs.tolist()}",
                      UserWarning, stacklevel=4)
    if width <= 0 or height <= 0:
        raise ClearsplatError(f"image size must be positive, got {width}x{height}", path=path,
                              field=field)
    K = np.array([[params[ifx], 0.0, params[icx]], [0.0, params[ify], params[icy]],
                  [0.0, 0.0, 1.0]])
    if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        raise ClearsplatError(f"focal lengths must be positive and finite, got {params}",
                              path=path, field=field)
    return K, int(width), int(height)


def _lines(path):
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ClearsplatError("file not found", path=path, field="cameras") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ClearsplatError(f"cannot read file ({e})", path=path, field="cameras") from None
    return text.splitlines()


def _read_cameras_txt(path):
    cams = {}
    for lineno, line in enumerate(_lines(path), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tok = s.split()
        where = f"line {lineno}"
        if len(tok) < 4 or tok[1] not in _BY_NAME:
            raise ClearsplatError(f"expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]' with a "
                                  f"known MODEL, got {s!r}", path=path, field=where)
        nparams = _BY_NAME[tok[1]][1]
        if len(tok) != 4 + nparams:
            raise ClearsplatError(f"model {tok[1]} takes {nparams} parameters, got "
                                  f"{len(tok) - 4}", path=path, field=where)
        try:
            cid, w, h = int(tok[0]), int(tok[2]), int(tok[3])
            params = [float(x) for x in tok[4:]]
        except ValueError:
            raise ClearsplatError(f"malformed number in {s!r}", path=path, field=where) from None
        cams[cid] = (tok[1], w, h, params)
    return cams


def _read_images_txt(path):
    images, expect_points = [], False
    for lineno, line in enumerate(_lines(path), start=1):
        if line.lstrip().startswith("#"):
            continue
        if expect_points:               # the POINTS2D line, possibly empty
            expect_points = False
            continue
        s = line.strip()
        if not s:
            continue
        tok = s.split()
        where = f"line {lineno}"
        if len(tok) < 10:
            raise ClearsplatError("expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', "
                                  f"got {s!r}", path=path, field=where)
        try:
            image_id = int(tok[0])
            q = [float(x) for x in tok[1:5]]
            t = [float(x) for x in tok[5:8]]
            cid = int(tok[8])
        except ValueError:
            raise ClearsplatError(f"malformed number in {s!r}", path=path, field=where) from None
        images.append((image_id, np.array(q), np.array(t), cid, " ".join(tok[9:])))
        expect_points = True
    return images


class _Reader:
    def __init__(self, path):
        try:
            self.data = Path(path).read_bytes()
        except FileNotFoundError:
            raise ClearsplatError("file not found", path=path, field="cameras") from None
        except OSError as e:
            raise ClearsplatError(f"cannot read file ({e.strerror})", path=path,
                                  field="cameras") from None
        self.path, self.pos = path, 0

    def take(self, fmt, what):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise ClearsplatError(f"file ends inside {what} (offset {self.pos}): truncated",
                                  path=self.path, field=what)
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def name(self, what):
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise ClearsplatError("unterminated image name: truncated", path=self.path,
                                  field=what)
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ClearsplatError(f"image name is not UTF-8: {raw!r}", path=self.path,
                                  field=what) from None

    def done(self):
        if self.pos != len(self.data):
            raise ClearsplatError(f"{len(self.data) - self.pos} unexpected bytes at the end",
                                  path=self.path, field="end of file")


def _read_cameras_bin(path):
    r = _Reader(path)
    (count,) = r.take("<Q", "number of cameras")
    cams = {}
    for i in range(count):
        cid, model_id, w, h = r.take("<iiQQ", f"camera {i}")
        if model_id not in CAMERA_MODELS:
            raise ClearsplatError(f"unknown camera model id {model_id}", path=path,
                                  field=f"camera {cid}")
        name, nparams = CAMERA_MODELS[model_id]
        params = list(r.take(f"<{nparams}d", f"camera {cid} parameters"))
        cams[cid] = (name, w, h, params)
    r.done()
    return cams


def _read_images_bin(path):
    r = _Reader(path)
    (count,) = r.take("<Q", "number of images")
    images = []
    for i in range(count):
        rec = r.take("<i7di", f"image {i}")
        image_id, q, t, cid = rec[0], np.array(rec[1:5]), np.array(rec[5:8]), rec[8]
        name = r.name(f"image {image_id} name")
        (npoints,) = r.take("<Q", f"image {image_id} number of points")
        r.take(f"<{npoints * 24}x", f"image {image_id} points")   # (x, y: double, id: int64)
        images.append((image_id, q, t, cid, name))
    r.done()
    return images
