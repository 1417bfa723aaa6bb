"""Scene bundles: a folder with ``cameras.json`` (or ``transforms.json``), images and Gaussians.

Layout::

    bundle/
        cameras.json        frames in view-id order (or a nerfstudio transforms.json)
        images/000.png ...  the input views (optional when loading with require_images=False)
        gaussians.ply       3DGS-layout PLY with view_id (and pixel_id)

``cameras.json``::

    {"frames": [{"image": "images/000.png", "width": W, "height": H,
                 "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                 "camera_to_world": [[...], [...], [...], [0, 0, 0, 1]]}, ...]}

``camera_to_world`` is in OpenCV axes (``docs/conventions.md``). An optional top-level
``"render"`` object holds the scene's :class:`~clearsplat.scene.RenderSettings`, for example
``"render": {"antialiased": true, "eps2d": 0.1}`` (absent: the classic 3DGS rasterizer; fields
in ``docs/conventions.md``, "Render settings"). Image paths are relative to
the bundle; absolute paths, paths with ``..`` and paths that a symbolic link leads out of the
bundle are refused (links that stay inside are followed).

An optional top-level ``"image_root": "../scene"`` (relative to the JSON file's folder, or
absolute) moves the folder that image paths are relative to: the bundles that
``clearsplat filter`` writes use it to read the input's images where they are instead of copying
them. Image paths stay relative to that root and may not leave it.

A nerfstudio ``transforms.json`` is read in its place: ``transform_matrix`` in OpenGL axes,
``fl_x fl_y cx cy w h`` at the top level or per frame (per frame wins), ``file_path`` per
frame. ``fl_y`` defaults to ``fl_x``, ``cx, cy`` to ``w / 2, h / 2``; ``camera_angle_x``
gives ``fl_x = w / (2 tan(camera_angle_x / 2))`` when ``fl_x`` is absent. Only pinhole models
(``OPENCV``, ``PINHOLE``, ``SIMPLE_PINHOLE``) without distortion are accepted.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from ..scene import RenderSettings, Scene, pixel_limits, register_bundle_writer
from .images import read_image, write_image
from .ply import RAW_PREFIX, atomic_write_bytes, read_ply, write_ply

__all__ = ["load_scene", "save_scene", "load_cameras", "save_cameras", "save_bundle_cameras",
           "CAMERAS_FILE", "TRANSFORMS_FILE", "GAUSSIANS_FILE"]

CAMERAS_FILE = "cameras.json"
TRANSFORMS_FILE = "transforms.json"
GAUSSIANS_FILE = "gaussians.ply"
_BUNDLE_MARKERS = (CAMERAS_FILE, TRANSFORMS_FILE, GAUSSIANS_FILE)
_PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
_FLOAT32_MAX = float(np.finfo(np.float32).max)


# ------------------------------------------------------------------------------------------------
# JSON field helpers: every failure names the file and the key path
# ------------------------------------------------------------------------------------------------
def _number(value, path, field, *, positive=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ClearsplatError(f"expected a number, got {json.dumps(value)[:40]}", path=path,
                              field=field)
    try:
        v = float(value)
    except OverflowError:               # a JSON integer beyond the float range
        v = math.inf
    if not math.isfinite(v):
        raise ClearsplatError(f"non-finite value {str(value)[:20]}", path=path, field=field)
    if abs(v) > _FLOAT32_MAX:           # would be inf in the float32 the renderer uses
        raise ClearsplatError(f"value {value:.3g} is outside the float32 range", path=path,
                              field=field)
    if positive and not v > 0:
        raise ClearsplatError(f"must be positive, got {value}", path=path, field=field)
    return v


def _size(value, path, field) -> int:
    v = _number(value, path, field, positive=True)
    if v != int(v):
        raise ClearsplatError(f"must be a whole number of pixels, got {value}", path=path,
                              field=field)
    return int(v)


def _matrix(value, rows, cols, path, field) -> np.ndarray:
    if not (isinstance(value, list) and len(value) in rows
            and all(isinstance(r, list) and len(r) == cols for r in value)):
        shapes = " or ".join(f"{r}x{cols}" for r in rows)
        raise ClearsplatError(f"expected a {shapes} nested list of numbers", path=path,
                              field=field)
    return np.array([[_number(x, path, f"{field}[{i}][{j}]") for j, x in enumerate(r)]
                     for i, r in enumerate(value)], dtype=np.float64)


def _rigid(c2w: np.ndarray, path, field) -> np.ndarray:
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    if not np.array_equal(c2w[3], [0.0, 0.0, 0.0, 1.0]):
        raise ClearsplatError(f"last row must be [0, 0, 0, 1], got {c2w[3].tolist()}",
                              path=path, field=field)
    return c2w


def _camera(path, field, **kwargs) -> Camera:
    """Build a Camera, relabelling its errors with the file and the frame."""
    opengl = kwargs.pop("opengl", False)
    try:
        # Subnormal entries make the rigidity check's determinant warn; the check still decides.
        with np.errstate(all="ignore"):
            return Camera.from_opengl(**kwargs) if opengl else Camera(**kwargs)
    except ClearsplatError as e:
        raise ClearsplatError(e.reason, path=path, field=f"{field}.{e.field}") from None


def _relative_image_path(value, path, field) -> str:
    if not isinstance(value, str) or not value:
        raise ClearsplatError("expected a non-empty relative path string", path=path,
                              field=field)
    if "\x00" in value:
        raise ClearsplatError("path contains a NUL character", path=path, field=field)
    posix, win = PurePosixPath(value), PureWindowsPath(value)
    if posix.is_absolute() or win.is_absolute() or win.drive:
        raise ClearsplatError(f"absolute path {value!r} refused: image paths must be relative "
                              "to the bundle", path=path, field=field)
    if ".." in posix.parts or ".." in win.parts:
        raise ClearsplatError(f"path {value!r} leaves the bundle ('..' refused)", path=path,
                              field=field)
    return value


def _read_json(path: Path):
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ClearsplatError("file not found", path=path, field="cameras") from None
    except UnicodeDecodeError as e:
        raise ClearsplatError(f"not UTF-8 text (byte {e.start})", path=path,
                              field="cameras") from None
    except OSError as e:
        raise ClearsplatError(f"cannot read file ({e.strerror})", path=path,
                              field="cameras") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ClearsplatError(f"malformed JSON: {e.msg}", path=path,
                              field=f"line {e.lineno} column {e.colno}") from None
    except RecursionError:
        raise ClearsplatError("malformed JSON: nested too deeply", path=path,
                              field="cameras") from None


# ------------------------------------------------------------------------------------------------
# cameras
# ------------------------------------------------------------------------------------------------
def load_cameras(path) -> tuple[list, list]:
    """Read the cameras of a bundle.

    Parameters
    ----------
    path : str or os.PathLike
        A ``cameras.json`` or nerfstudio ``transforms.json`` file, or a bundle folder
        (``cameras.json`` is used when both exist). A JSON object holding one frame
        (``width``, ``height``, ``K``, ``camera_to_world``) without ``frames`` is one camera.

    Returns
    -------
    cameras : list of Camera
        In frame order, which gives the view ids 0..N-1.
    image_paths : list of pathlib.Path or None
        Each frame's image, joined to the folder of the JSON file (or to its ``image_root``);
        None for a frame without an image entry.

    Raises
    ------
    ClearsplatError
        Naming the file and the key (``frames[2].K``): malformed JSON, missing key,
        non-finite number, singular / mirrored / scaled rotation, skewed intrinsics,
        distortion, or an image path that leaves the bundle (``..``, absolute, or through a
        symbolic link).
    """
    path = Path(path)
    if path.is_dir():
        for name in (CAMERAS_FILE, TRANSFORMS_FILE):
            if (path / name).is_file():
                path = path / name
                break
        else:
            raise ClearsplatError(f"no {CAMERAS_FILE} or {TRANSFORMS_FILE} in the bundle",
                                  path=path, field="cameras")
    doc = _read_json(path)
    if isinstance(doc, dict) and "frames" not in doc and "camera_to_world" in doc:
        doc = {"frames": [doc]}         # one camera, in the frame format
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise ClearsplatError("expected an object with a 'frames' list", path=path,
                              field="frames")
    frames = doc["frames"]
    if not frames:
        raise ClearsplatError("no frames: a scene needs at least one camera", path=path,
                              field="frames")
    nerfstudio = path.name == TRANSFORMS_FILE or any(
        isinstance(f, dict) and "transform_matrix" in f for f in frames)
    root = path.parent
    if doc.get("image_root") is not None:
        value = doc["image_root"]
        if not isinstance(value, str) or not value or "\x00" in value:
            raise ClearsplatError("expected a non-empty folder path string", path=path,
                                  field="image_root")
        root = path.parent / value
    cameras, images = [], []
    for i, frame in enumerate(frames):
        field = f"frames[{i}]"
        if not isinstance(frame, dict):
            raise ClearsplatError("expected an object", path=path, field=field)
        if nerfstudio:
            cam, image = _nerfstudio_frame(doc, frame, path, field)
        else:
            cam, image = _clearsplat_frame(frame, path, field)
        cameras.append(cam)
        key = "file_path" if nerfstudio else "image"
        images.append(None if image is None
                      else _inside_bundle(root, image, path, f"{field}.{key}"))
    return cameras, images


def _is_file(p: Path) -> bool:
    """``p.is_file()``, False where the name itself is unusable (too long, ...)."""
    try:
        return p.is_file()
    except (OSError, ValueError):
        return False


def _inside_bundle(folder: Path, image: str, path, field) -> Path:
    """``folder / image``, refused when a symbolic link on the way leads out of ``folder``."""
    full = folder / image
    try:
        real, root = full.resolve(), folder.resolve()
    except (OSError, RuntimeError) as e:       # a link loop
        raise ClearsplatError(f"cannot resolve image path {image!r} ({e})", path=path,
                              field=field) from None
    if not real.is_relative_to(root):
        raise ClearsplatError(f"image path {image!r} leads out of the bundle through a "
                              f"symbolic link (to {real}); copy the file into the bundle",
                              path=path, field=field)
    return full


def _require(obj: dict, key: str, path, field):
    if key not in obj:
        raise ClearsplatError(f"missing key {key!r}", path=path, field=f"{field}.{key}")
    return obj[key]


def _clearsplat_frame(frame: dict, path, field):
    width = _size(_require(frame, "width", path, field), path, f"{field}.width")
    height = _size(_require(frame, "height", path, field), path, f"{field}.height")
    K = _matrix(_require(frame, "K", path, field), (3,), 3, path, f"{field}.K")
    if K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise ClearsplatError("expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)",
                              path=path, field=f"{field}.K")
    c2w = _matrix(_require(frame, "camera_to_world", path, field), (3, 4), 4, path,
                  f"{field}.camera_to_world")
    c2w = _rigid(c2w, path, f"{field}.camera_to_world")
    cam = _camera(path, field, K=K, camera_to_world=c2w, width=width, height=height)
    image = frame.get("image")
    if image is not None:
        image = _relative_image_path(image, path, f"{field}.image")
    return cam, image


def _nerfstudio_frame(doc: dict, frame: dict, path, field):
    def get(key):
        return frame[key] if key in frame else doc.get(key)

    def where(key):
        return f"{field}.{key}" if key in frame else key

    model = get("camera_model")
    if model is not None and model not in _PINHOLE_MODELS:
        raise ClearsplatError(f"camera model {model!r} is not supported (only pinhole: "
                              f"{', '.join(_PINHOLE_MODELS)})", path=path,
                              field=where("camera_model"))
    for key in _DISTORTION:
        if get(key) is not None and _number(get(key), path, where(key)) != 0:
            raise ClearsplatError("lens distortion is not supported; undistort the images "
                                  "first", path=path, field=where(key))
    for key in ("w", "h"):
        if get(key) is None:
            raise ClearsplatError(f"missing key {key!r} (at the top level or per frame)",
                                  path=path, field=f"{field}.{key}")
    w = _size(get("w"), path, where("w"))
    h = _size(get("h"), path, where("h"))
    if get("fl_x") is not None:
        fx = _number(get("fl_x"), path, where("fl_x"), positive=True)
    elif get("camera_angle_x") is not None:
        angle = _number(get("camera_angle_x"), path, where("camera_angle_x"), positive=True)
        if not angle < math.pi:
            raise ClearsplatError("field of view must be below pi", path=path,
                                  field=where("camera_angle_x"))
        fx = 0.5 * w / math.tan(0.5 * angle)
    else:
        raise ClearsplatError("missing key 'fl_x' (or 'camera_angle_x')", path=path,
                              field=f"{field}.fl_x")
    fy = fx if get("fl_y") is None else _number(get("fl_y"), path, where("fl_y"),
                                                 positive=True)
    cx = 0.5 * w if get("cx") is None else _number(get("cx"), path, where("cx"))
    cy = 0.5 * h if get("cy") is None else _number(get("cy"), path, where("cy"))
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    gl = _matrix(_require(frame, "transform_matrix", path, field), (3, 4), 4, path,
                 f"{field}.transform_matrix")
    gl = _rigid(gl, path, f"{field}.transform_matrix")
    cam = _camera(path, field, opengl=True, K=K, camera_to_world_gl=gl, width=w, height=h)
    image = frame.get("file_path")
    if image is not None:
        image = _relative_image_path(image, path, f"{field}.file_path")
        if not PurePosixPath(image).suffix and _is_file(path.parent / (image + ".png")):
            image += ".png"     # Blender-style paths without extension
    return cam, image


def load_render_settings(path) -> RenderSettings:
    """The top-level ``"render"`` object of a ``cameras.json`` / ``transforms.json`` file.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file.

    Returns
    -------
    RenderSettings
        The defaults (classic 3DGS) when the file has no ``"render"`` object.

    Raises
    ------
    ClearsplatError
        Naming the field (``render.eps2d``) of an unknown key or a value out of range.
    """
    path = Path(path)
    doc = _read_json(path)
    return RenderSettings.from_json(doc.get("render") if isinstance(doc, dict) else None,
                                    path=path)


def save_cameras(path, cameras, image_paths=None, *, format: str | None = None,
                 render: RenderSettings | None = None) -> None:
    """Write cameras as ``cameras.json`` (or a nerfstudio ``transforms.json``), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The JSON file to write.
    cameras : sequence of Camera
        In view-id order.
    image_paths : sequence of (str, os.PathLike or None), optional
        One per camera: relative to the JSON file's folder, or a path inside that folder
        (as :func:`load_cameras` returns); None for no image.
    format : {"clearsplat", "nerfstudio"}, optional
        Default: ``"nerfstudio"`` when the file is named ``transforms.json``, else
        ``"clearsplat"``.
    render : RenderSettings, optional
        Written as the top-level ``"render"`` object unless it is the classic default.

    Raises
    ------
    ClearsplatError
        If the lists disagree in length, an entry is not a Camera, or an image path lies
        outside the JSON file's folder.
    """
    path = Path(path)
    cameras = list(cameras)
    if format is None:
        format = "nerfstudio" if path.name == TRANSFORMS_FILE else "clearsplat"
    if format not in ("clearsplat", "nerfstudio"):
        raise ClearsplatError(f"format must be 'clearsplat' or 'nerfstudio', got {format!r}",
                              path=path, field="format")
    image_paths = [None] * len(cameras) if image_paths is None else list(image_paths)
    if len(image_paths) != len(cameras):
        raise ClearsplatError(f"{len(image_paths)} image paths for {len(cameras)} cameras",
                              path=path, field="image_paths")
    frames = []
    for i, (cam, image) in enumerate(zip(cameras, image_paths)):
        if not isinstance(cam, Camera):
            raise ClearsplatError(f"expected a Camera, got {type(cam).__name__}", path=path,
                                  field=f"frames[{i}]")
        rel = None if image is None else _relative_to(image, path.parent, path, i)
        if format == "nerfstudio":
            frame = {"fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
                     "w": cam.width, "h": cam.height,
                     "transform_matrix": cam.camera_to_world_opengl().tolist()}
            if rel is not None:
                frame = {"file_path": rel, **frame}
        else:
            frame = {"width": cam.width, "height": cam.height, "K": cam.K.tolist(),
                     "camera_to_world": cam.camera_to_world.tolist()}
            if rel is not None:
                frame = {"image": rel, **frame}
        frames.append(frame)
    doc = {"camera_model": "PINHOLE", "frames": frames} if format == "nerfstudio" \
        else {"frames": frames}
    if render is not None:
        if not isinstance(render, RenderSettings):
            raise ClearsplatError(f"expected RenderSettings, got {type(render).__name__}",
                                  path=path, field="render")
        if not render.is_classic:
            doc["render"] = render.to_json()
    atomic_write_bytes(path, (json.dumps(doc, indent=1) + "\n").encode("utf-8"))


def _relative_to(image, folder: Path, path, i) -> str:
    p = Path(image)
    if p.is_absolute():
        try:
            p = p.relative_to(folder.absolute())
        except ValueError:
            raise ClearsplatError(f"{image} is outside the bundle folder {folder}", path=path,
                                  field=f"frames[{i}].image") from None
    elif p.parts[:len(folder.parts)] == folder.parts and folder.parts:
        p = p.relative_to(folder)
    return _relative_image_path(p.as_posix(), path, f"frames[{i}].image")


def save_bundle_cameras(folder, cameras, image_paths, *, located_at=None,
                        copy_images: bool = False, render: RenderSettings | None = None) -> None:
    """Write ``cameras.json`` into ``folder`` so that it loads as a bundle with the given images.

    Parameters
    ----------
    folder : str or os.PathLike
        An existing folder (usually a temporary folder that is renamed to ``located_at``).
    cameras : sequence of Camera
    image_paths : sequence of (os.PathLike or None)
        The images as :func:`load_cameras` returns them (paths to existing files).
    located_at : str or os.PathLike, optional
        Where ``folder`` will live when it is read; the ``image_root`` is relative to it.
        Default: ``folder``.
    copy_images : bool, default False
        Copy the images into ``folder/images/`` instead of referring to them where they are.
    render : RenderSettings, optional
        Written as in :func:`save_cameras`.

    Notes
    -----
    Without ``copy_images`` the images stay where they are: ``cameras.json`` gets an
    ``image_root`` (the folder that holds them all, relative to ``located_at``, or absolute
    where no relative path exists), so moving the bundle together with its input keeps it
    loadable; moving it alone needs ``--copy-images``.
    """
    folder = Path(folder)
    located_at = Path(located_at if located_at is not None else folder).absolute()
    real = [None if p is None else Path(os.path.realpath(p)) for p in image_paths]
    present = [p for p in real if p is not None]
    target = folder / CAMERAS_FILE
    if copy_images:
        names = []
        if present:
            (folder / "images").mkdir(exist_ok=True)
        digits = max(3, len(str(len(real) - 1)))
        for i, p in enumerate(real):
            if p is None:
                names.append(None)
                continue
            unique = sum(q is not None and q.name == p.name for q in real) == 1
            name = f"images/{p.name}" if unique else f"images/{i:0{digits}d}_{p.name}"
            shutil.copyfile(p, folder / name)
            names.append(name)
        save_cameras(target, cameras, names, format="clearsplat", render=render)
        return
    root = Path(os.path.commonpath([str(p.parent) for p in present])) if present else None
    frames = [None if p is None else p.relative_to(root).as_posix() for p in real]
    if root is None:
        save_cameras(target, cameras, None, format="clearsplat", render=render)
        return
    try:
        rel = os.path.relpath(root, os.path.realpath(located_at))
    except ValueError:                  # another drive
        rel = str(root)
    save_cameras(target, cameras, [folder / f for f in frames], format="clearsplat",
                 render=render)
    doc = json.loads(target.read_text(encoding="utf-8"))
    doc = {"image_root": Path(rel).as_posix(), **doc}
    atomic_write_bytes(target, (json.dumps(doc, indent=1) + "\n").encode("utf-8"))


# ------------------------------------------------------------------------------------------------
# scenes
# ------------------------------------------------------------------------------------------------
def bundle_camera_file(folder) -> Path:
    """The camera file of the bundle ``folder``: ``cameras.json``, else ``transforms.json``
    (``cameras.json`` when neither is there, for the message that names it)."""
    folder = Path(folder)
    return next((folder / n for n in (CAMERAS_FILE, TRANSFORMS_FILE) if (folder / n).is_file()),
                folder / CAMERAS_FILE)


def load_scene(path, *, require_images: bool = True, associate: bool = False,
               progress=None) -> Scene:
    """Load a scene bundle.

    Parameters
    ----------
    path : str or os.PathLike
        The bundle folder (``cameras.json`` or ``transforms.json``, images,
        ``gaussians.ply``). Nothing in it is modified.
    require_images : bool, default True
        The filter needs the input images, so a missing image is an error. With False, a
        bundle whose images are missing (any of them) loads with ``Scene.images = None``;
        images that are present must still be readable and of the camera's size.
    associate : bool, default False
        A PLY without ``view_id`` (a scene from any trainer or model) is refused, unless this
        is set: then each Gaussian's view is recovered from how it reproduces the input
        images (:func:`clearsplat.adapters.associate.associate_fused`; a pixel only where a
        Gaussian lies on one camera's pixel centre), and a ``UserWarning`` says so in one line
        (how many got a view, how many are ambiguous).
    progress : callable(stage, done, total), optional
        Told of the association's progress, one camera at a time (stage ``"associate"``).

    Returns
    -------
    Scene
        Validated with :meth:`Scene.validate`. A PLY with zero Gaussians loads fine.

    Raises
    ------
    ClearsplatError
        Naming the file and field; see ``docs/errors.md``.
    """
    bundle = Path(path)
    if not bundle.is_dir():
        raise ClearsplatError("expected a bundle folder (with cameras.json, images/ and "
                              "gaussians.ply)" + ("" if bundle.exists() else "; not found"),
                              path=bundle, field="bundle")
    cameras, image_paths = load_cameras(bundle)
    camera_file = bundle_camera_file(bundle)
    ply = bundle / GAUSSIANS_FILE
    if not ply.is_file():
        raise ClearsplatError("Gaussians file not found", path=ply, field="gaussians")
    gaussians, view_id, pixel_id = read_ply(ply)
    if view_id is None and not associate:
        raise ClearsplatError("property 'view_id' is missing: every Gaussian needs the index "
                              "of the input view that predicted it (`clearsplat filter` "
                              "recovers it from the images)", path=ply, field="view_id")
    if view_id is not None:
        check_association(view_id, pixel_id, cameras, ply)

    key = "image" if camera_file.name == CAMERAS_FILE else "file_path"
    missing = [i for i, p in enumerate(image_paths) if p is None or not _is_file(p)]
    images = None
    if missing and require_images:
        i = missing[0]
        where = camera_file if image_paths[i] is None else image_paths[i]
        what = "has no image entry" if image_paths[i] is None else "image file not found"
        raise ClearsplatError(f"frame {i} {what} ({len(missing)} of {len(image_paths)} "
                              "missing); the filter needs the input images "
                              "(load with require_images=False to skip them)",
                              path=where, field=f"frames[{i}].{key}")
    if not missing:
        images = []
        for i, (p, cam) in enumerate(zip(image_paths, cameras)):
            try:
                images.append(read_image(p, expected_size=(cam.width, cam.height)))
            except ClearsplatError as e:
                field = f"frames[{i}].{e.field}" if e.field in ("width", "height") else e.field
                raise ClearsplatError(e.reason, path=e.path, field=field) from None
    settings = load_render_settings(camera_file)
    if view_id is None:
        view_id, pixel_id = _associated(gaussians, cameras, images, settings, ply, progress)
    scene = Scene(gaussians, view_id, pixel_id, cameras, images, settings)
    scene.validate(path=bundle)
    return scene


def _associated(gaussians, cameras, images, settings, ply, progress=None) -> tuple:
    """``(view_id, pixel_id)`` of Gaussians without an association, from how they reproduce
    the input images; the one-line summary as a ``UserWarning``."""
    import warnings

    from ..adapters.associate import associate_fused
    if images is None:
        raise ClearsplatError("property 'view_id' is missing and the images are too: the "
                              "association is recovered from the input images", path=ply,
                              field="view_id")
    try:
        found = associate_fused(gaussians, cameras, images, settings=settings,
                                progress=progress)
    except ClearsplatError as e:
        raise ClearsplatError(e.reason, path=ply, field=e.field) from None
    warnings.warn(found.summary() + " (the PLY has no view_id)", stacklevel=3)
    return found.view_id, found.pixel_id


def check_association(view_id, pixel_id, cameras, ply) -> None:
    """One line naming ``ply`` and the field for the first view id past the cameras, or
    pixel id past its view's image (-1 where none; a shared Gaussian, view -1, has none)."""
    v = len(cameras)
    bad = view_id >= v
    if bad.any():
        i = int(np.argmax(bad))
        raise ClearsplatError(f"view id {int(view_id[i])} at vertex {i} is out of range: the "
                              f"bundle has {v} cameras (0..{v - 1})", path=ply, field="view_id")
    if pixel_id is not None and len(pixel_id):
        limit = pixel_limits(cameras, view_id)
        bad = (pixel_id < -1) | (pixel_id >= limit)
        if bad.any():
            i = int(np.argmax(bad))
            expect = f"-1 or 0..{int(limit[i]) - 1}" if limit[i] else "-1: shared, no pixel"
            raise ClearsplatError(f"pixel id {int(pixel_id[i])} at vertex {i} is out of range "
                                  f"for view {int(view_id[i])} ({expect})",
                                  path=ply, field="pixel_id")


def save_scene(scene: Scene, path, *, overwrite: bool = False) -> None:
    """Write a scene bundle: ``cameras.json``, ``images/NNN.png`` (8-bit) and ``gaussians.ply``.

    The bundle is written into a temporary folder beside ``path`` and renamed into place at the
    end, so a failure leaves no half-written bundle.

    Parameters
    ----------
    scene : Scene
        Validated first. Without images (``images=None``) the frames have no image entry.
    path : str or os.PathLike
        The bundle folder. Parent folders are created.
    overwrite : bool, default False
        Replace an existing non-empty folder. Only a folder that looks like a bundle (holds
        cameras.json, transforms.json or gaussians.ply) is replaced, everything in it is
        removed; any other non-empty folder is refused.

    Raises
    ------
    ClearsplatError
        If the scene is invalid or the destination is refused.
    """
    dest = Path(path).absolute()      # also gives "." a name to rename
    scene.validate(path=dest)
    if dest.exists() and not dest.is_dir():
        raise ClearsplatError("exists and is not a folder", path=dest, field="bundle")
    nonempty = dest.is_dir() and any(dest.iterdir())
    if nonempty and not overwrite:
        raise ClearsplatError("folder exists and is not empty (pass overwrite=True to replace "
                              "it)", path=dest, field="bundle")
    if nonempty and not any((dest / m).exists() for m in _BUNDLE_MARKERS):
        raise ClearsplatError("refusing to overwrite a folder that is not a scene bundle (no "
                              "cameras.json, transforms.json or gaussians.ply)", path=dest,
                              field="bundle")
    tmp = _fresh_name(dest, "tmp")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.mkdir(tmp)
    except OSError as e:
        raise ClearsplatError(f"cannot create the bundle folder here ({e.strerror})",
                              path=dest, field="bundle") from None
    try:
        names = None
        if scene.images is not None:
            (tmp / "images").mkdir()
            digits = max(3, len(str(scene.num_views - 1)))
            names = [f"images/{i:0{digits}d}.png" for i in range(scene.num_views)]
            for name, img in zip(names, scene.images):
                write_image(tmp / name, img)
        save_cameras(tmp / CAMERAS_FILE, scene.cameras, names, format="clearsplat",
                     render=scene.render_settings)
        g = scene.gaussians
        keep_pixel = (scene.pixel_id >= 0).any() or (RAW_PREFIX + "pixel_id") in g.extra
        write_ply(tmp / GAUSSIANS_FILE, g, view_id=scene.view_id,
                  pixel_id=scene.pixel_id if keep_pixel else None)
        swap_into_place(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def swap_into_place(src, dest) -> None:
    """Move the finished folder ``src`` to ``dest``, replacing whatever ``dest`` holds.

    An existing ``dest`` (folder, file or link) is first renamed aside, then ``src`` is renamed
    into place and the old one deleted; if the second rename fails the old ``dest`` is put back.
    ``src`` and ``dest`` must be on the same file system (make ``src`` beside ``dest``).
    """
    src, dest = Path(src), Path(dest)
    if not os.path.lexists(dest):
        os.rename(src, dest)
        return
    if dest.is_dir() and not dest.is_symlink() and not any(dest.iterdir()):
        os.replace(src, dest)           # onto an empty folder
        return
    old = _fresh_name(dest, "old")
    os.rename(dest, old)
    try:
        os.rename(src, dest)
    except BaseException:
        os.rename(old, dest)
        raise
    if old.is_dir() and not old.is_symlink():
        shutil.rmtree(old)
    else:
        os.remove(old)


def _fresh_name(dest: Path, what: str) -> Path:
    return dest.with_name(f".{dest.name}.{what}-{secrets.token_hex(6)}")


register_bundle_writer(save_scene)
