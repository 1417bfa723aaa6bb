"""The two benchmarks of the paper, read from the layouts their authors publish.

RobustNeRF
    ``SCENE/images/`` (and optional downscaled ``images_2/``, ``images_4/``, ``images_8/``) and
    a COLMAP model in ``SCENE/sparse/0`` (text or binary). Images whose file name contains
    ``clutter`` are the training images with distractors, those containing ``extra`` the clean
    test images; any others (RobustNeRF's clean ``train`` views of some scenes) are in neither
    set.
NeRF On-the-go
    ``SCENE/images/``, ``SCENE/transforms.json`` (nerfstudio: OpenGL camera axes, read with
    :func:`clearsplat.io.load_cameras`) and ``SCENE/split.json`` with the lists ``clutter``
    (training) and ``extra`` (test): indices into the images sorted by file name, which for the
    released scenes is also their frame order. A COLMAP model in ``SCENE/sparse/0``, when
    present, gives the sparse points for co-visibility (matched by image file name).

Co-visibility comes from the sparse points' tracks: image ``i`` sees point ``p`` when ``p``'s
track in ``points3D`` lists ``i``. :attr:`Dataset.visibility` holds, per image, the sorted ids
of the points it sees.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cameras import Camera
from ..errors import ClearsplatError
from .bundle import load_cameras
from .colmap import _lines, _Reader, _read_images_bin, _read_images_txt, read_colmap

__all__ = ["Dataset", "read_dataset", "read_robustnerf", "read_onthego", "read_colmap_points",
           "DATASET_KINDS"]

#: The layouts :func:`read_dataset` recognises.
DATASET_KINDS = ("robustnerf", "onthego")


@dataclass
class Dataset:
    """One scene of a benchmark: all its posed images and the training / test split.

    Attributes
    ----------
    kind : {"robustnerf", "onthego"}
    name : str
        The scene (its folder name).
    root : Path
        The scene folder.
    cameras : list of Camera
        One per image, sorted by image file name, sized like the images read.
    image_paths : list of Path
        The image files, in the same order.
    train : list of int
        Indices of the training images (with distractors: ``clutter``).
    test : list of int
        Indices of the clean test images (``extra``).
    visibility : list of (K_i,) int64 arrays, or None
        Per image, the sorted ids of the COLMAP sparse points it sees; None without a model.
    """

    kind: str
    name: str
    root: Path
    cameras: list
    image_paths: list
    train: list
    test: list
    visibility: list | None = field(default=None, repr=False)

    @property
    def names(self) -> list[str]:
        """Image file names (no folder), in image order."""
        return [p.name for p in self.image_paths]


def read_dataset(path, *, images: str = "images") -> Dataset:
    """Read a RobustNeRF or NeRF On-the-go scene, recognised by its files.

    ``split.json`` makes an On-the-go scene; otherwise a COLMAP model in ``sparse/0`` a
    RobustNeRF scene. ``images`` names the image folder (``images_4`` for 4x downscaled
    images: the cameras are scaled to the image size found).
    """
    root = Path(path)
    if (root / "split.json").is_file():
        return read_onthego(root, images=images)
    if (root / "sparse" / "0").is_dir():
        return read_robustnerf(root, images=images)
    raise ClearsplatError("not a RobustNeRF scene (no sparse/0) nor a NeRF On-the-go scene "
                          "(no split.json)", path=root, field="dataset")


def read_robustnerf(path, *, images: str = "images") -> Dataset:
    """Read a RobustNeRF scene (``images/``, ``sparse/0``; ``clutter*`` train, ``extra*`` test).

    Parameters
    ----------
    path : str or os.PathLike
        The scene folder.
    images : str, default "images"
        The image folder inside it.

    Returns
    -------
    Dataset

    Raises
    ------
    ClearsplatError
        A missing or malformed COLMAP model, a registered image missing from the image
        folder, or no ``clutter`` or no ``extra`` image.
    """
    root = Path(path)
    cameras, names = read_colmap(root / "sparse" / "0")
    paths = [root / images / n for n in names]
    cameras = _fit_to_images(cameras, paths, root / images)
    train = [i for i, n in enumerate(names) if "clutter" in Path(n).name.lower()]
    test = [i for i, n in enumerate(names) if "extra" in Path(n).name.lower()]
    for what, idx in (("clutter", train), ("extra", test)):
        if not idx:
            raise ClearsplatError(f"no '{what}' image among the {len(names)} registered images "
                                  "(RobustNeRF names its training images clutter*, its test "
                                  "images extra*)", path=root / "sparse" / "0", field="NAME")
    visibility = _visibility_by_name(root / "sparse" / "0", [Path(n).name for n in names])
    return Dataset("robustnerf", root.resolve().name, root, cameras, paths, train, test,
                   visibility)


def read_onthego(path, *, images: str = "images") -> Dataset:
    """Read a NeRF On-the-go scene (``images/``, ``transforms.json``, ``split.json``).

    Parameters
    ----------
    path : str or os.PathLike
        The scene folder.
    images : str, default "images"
        The image folder inside it; frames of ``transforms.json`` are matched to its files by
        file name.

    Returns
    -------
    Dataset
        ``visibility`` from ``sparse/0`` when the scene has a COLMAP model, else None.

    Raises
    ------
    ClearsplatError
        Malformed ``transforms.json`` or ``split.json``, an index out of range or in both
        lists, an image missing.
    """
    root = Path(path)
    cams, frame_paths = load_cameras(root / "transforms.json")
    split_file = root / "split.json"
    try:
        split = json.loads(split_file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ClearsplatError("file not found", path=split_file, field="split") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise ClearsplatError(f"cannot read JSON ({' '.join(str(e).split())})", path=split_file,
                              field="split") from None
    by_name = {}
    for i, (cam, p) in enumerate(zip(cams, frame_paths)):
        if p is None:
            raise ClearsplatError("a frame without an image", path=root / "transforms.json",
                                  field=f"frames[{i}].file_path")
        by_name[p.name] = cam
    order = sorted(by_name)
    paths = [root / images / n for n in order]
    cameras = _fit_to_images([by_name[n] for n in order], paths, root / images)
    sets = {}
    for key in ("clutter", "extra"):
        idx = split.get(key) if isinstance(split, dict) else None
        if not isinstance(idx, list) or not idx or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in idx):
            raise ClearsplatError("expected a non-empty list of image indices", path=split_file,
                                  field=key)
        bad = [i for i in idx if not 0 <= i < len(order)]
        if bad:
            raise ClearsplatError(f"index {bad[0]} is out of range: transforms.json has "
                                  f"{len(order)} images", path=split_file, field=key)
        sets[key] = sorted(set(idx))
    both = set(sets["clutter"]) & set(sets["extra"])
    if both:
        raise ClearsplatError(f"image {min(both)} is both a training and a test image",
                              path=split_file, field="clutter/extra")
    model = root / "sparse" / "0"
    visibility = _visibility_by_name(model, order) if model.is_dir() else None
    return Dataset("onthego", root.resolve().name, root, cameras, paths, sets["clutter"],
                   sets["extra"], visibility)


def _fit_to_images(cameras, paths, folder) -> list:
    """Check every image exists; scale the cameras to the size of the images found."""
    from PIL import Image
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise ClearsplatError(f"{len(missing)} image(s) missing, e.g. {missing[0].name}",
                              path=folder, field="images")
    out = []
    for cam, p in zip(cameras, paths):
        try:
            with Image.open(p) as im:
                w, h = im.size
        except OSError as e:
            raise ClearsplatError(f"cannot read the image ({e})", path=p, field="image") from None
        if (w, h) == (cam.width, cam.height):
            out.append(cam)
            continue
        sx, sy = w / cam.width, h / cam.height
        if abs(sx - sy) > 0.02 * max(sx, sy):
            raise ClearsplatError(f"image is {w}x{h}, its camera {cam.width}x{cam.height}: not "
                                  "a uniform downscale", path=p, field="image")
        K = np.array(cam.K, dtype=np.float64)
        K[0] *= sx
        K[1] *= sy
        out.append(Camera(K=K, camera_to_world=cam.camera_to_world, width=w, height=h))
    return out


def _visibility_by_name(model: Path, names: list) -> list:
    """Per name (image file name), the sorted ids of the sparse points whose track has it."""
    ids, tracks = read_colmap_points(model)
    per_image: dict = {}
    for pid, track in zip(ids, tracks):
        for image_id in np.unique(track):
            per_image.setdefault(int(image_id), []).append(pid)
    if (model / "images.bin").exists() and (model / "cameras.bin").exists():
        images = _read_images_bin(model / "images.bin")
    else:
        images = _read_images_txt(model / "images.txt")
    name_to_id = {Path(rec[4]).name: rec[0] for rec in images}
    return [np.array(sorted(per_image.get(name_to_id.get(n, -1), [])), dtype=np.int64)
            for n in names]


def read_colmap_points(path) -> tuple[np.ndarray, list]:
    """The sparse points' ids and tracks of a COLMAP model (``points3D.bin`` or ``.txt``).

    Parameters
    ----------
    path : str or os.PathLike
        The model folder (``sparse/0``).

    Returns
    -------
    ids : (P,) int64
        Point ids.
    tracks : list of (L_p,) int64 arrays
        Per point, the ids of the images that observe it (COLMAP image ids).

    Raises
    ------
    ClearsplatError
        No ``points3D`` file, a malformed line or a truncated binary file.
    """
    folder = Path(path)
    binary = folder / "points3D.bin"
    text = folder / "points3D.txt"
    if binary.exists() and ((folder / "images.bin").exists() or not text.exists()):
        r = _Reader(binary)
        (count,) = r.take("<Q", "number of points")
        ids, tracks = [], []
        for i in range(count):
            pid, *_ = r.take("<Q3d3Bd", f"point {i}")
            (length,) = r.take("<Q", f"point {pid} track length")
            flat = np.frombuffer(r.data, dtype="<i4", count=2 * length,
                                 offset=r.pos) if length else np.zeros(0, "<i4")
            r.take(f"<{8 * length}x", f"point {pid} track")
            ids.append(pid)
            tracks.append(flat[0::2].astype(np.int64))
        r.done()
        return np.array(ids, dtype=np.int64), tracks
    if not text.exists():
        raise ClearsplatError("no points3D.bin or points3D.txt: the sparse points are needed "
                              "for co-visibility", path=folder, field="points3D")
    ids, tracks = [], []
    for lineno, line in enumerate(_lines(text), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tok = s.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise ClearsplatError("expected 'POINT3D_ID X Y Z R G B ERROR' and (IMAGE_ID, "
                                  f"POINT2D_IDX) pairs, got {s[:80]!r}", path=text,
                                  field=f"line {lineno}")
        try:
            ids.append(int(tok[0]))
            tracks.append(np.array([int(x) for x in tok[8::2]], dtype=np.int64))
        except ValueError:
            raise ClearsplatError(f"malformed number in {s[:80]!r}", path=text,
                                  field=f"line {lineno}") from None
    return np.array(ids, dtype=np.int64), tracks

