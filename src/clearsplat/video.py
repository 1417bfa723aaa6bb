"""Before | after videos along a camera path through the input cameras.

:func:`comparison_frames` renders the scene without and with a keep mask side by side, with a
label on each half; :func:`write_video` encodes frames as H.264 MP4 through imageio-ffmpeg
(which ships its own ffmpeg binary), or, only where that cannot be done, as an animated GIF;
:func:`make_video` does both along :func:`clearsplat.camera_path.interpolate_cameras`.
"""

from __future__ import annotations

import os
import secrets
import warnings
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .camera_path import interpolate_cameras
from .errors import ClearsplatError
from .render import render

__all__ = ["comparison_frames", "label_image", "write_video", "make_video", "default_size"]

_GAP = 4            # pixels between the two halves
_GAP_COLOUR = 255


def label_image(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with ``text`` in a dark box at its top-left corner."""
    pic = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    draw = ImageDraw.Draw(pic, "RGBA")
    size = max(10, min(28, pic.height // 14))
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:                  # Pillow < 10.1: fixed-size bitmap font
        font = ImageFont.load_default()
    box = draw.textbbox((0, 0), text, font=font)
    pad = max(3, size // 3)
    w, h = box[2] - box[0], box[3] - box[1]
    draw.rectangle([0, 0, w + 2 * pad, h + 2 * pad], fill=(0, 0, 0, 170))
    draw.text((pad - box[0], pad - box[1]), text, fill=(255, 255, 255, 255), font=font)
    return np.asarray(pic)


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def comparison_frames(scene, keep, cameras: Sequence, *,
                      labels: tuple[str, str] = ("before", "after"),
                      background=(0.0, 0.0, 0.0), progress=None) -> Iterator[np.ndarray]:
    """Render each camera twice, all Gaussians left and ``keep`` right, with labels.

    Parameters
    ----------
    scene : Scene or Gaussians
    keep : (N,) bool
        The Gaussians of the right half (for a filter result: ``result.keep``).
    cameras : sequence of Camera
        All of one size ``(W, H)``.
    labels : (str, str)
        Written at the top-left of each half.
    background : 3 floats
    progress : callable(stage, done, total), optional

    Yields
    ------
    (H', 2 W + 4, 3) uint8
        ``H'`` is ``H`` rounded up to even (H.264 needs even sizes); a 4-pixel white bar
        separates the halves.
    """
    cameras = list(cameras)
    total = len(cameras)
    for i, cam in enumerate(cameras):
        before = _to_uint8(render(scene, cam, background=background).rgb)
        after = _to_uint8(render(scene, cam, keep=keep, background=background).rgb)
        h, w = before.shape[:2]
        frame = np.full((h + h % 2, 2 * w + _GAP, 3), _GAP_COLOUR, np.uint8)
        frame[:h, :w] = label_image(before, labels[0])
        frame[:h, w + _GAP:] = label_image(after, labels[1])
        if progress is not None:
            progress("video", i + 1, total)
        yield frame


def _temp_beside(path: Path) -> Path:
    return path.with_name(f".{path.stem}.{secrets.token_hex(6)}.tmp{path.suffix}")


def write_video(path, frames: Iterable[np.ndarray], *, fps: float = 24.0,
                fallback_gif: bool = True) -> Path:
    """Encode frames as an H.264 MP4 (yuv420p), written atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mp4`` to write; written to a temporary file beside it, then renamed over it.
    frames : iterable of (H, W, 3) uint8
        All of one size, ``H`` and ``W`` even.
    fps : float
    fallback_gif : bool, default True
        Where the MP4 cannot be written (imageio-ffmpeg missing, or its ffmpeg failing), write
        an animated GIF beside it (same name, ``.gif``) and warn.

    Returns
    -------
    pathlib.Path
        The file written: ``path``, or the GIF.

    Raises
    ------
    ClearsplatError
        On no frames, frames of different or odd sizes, a non-positive ``fps``, or (without
        ``fallback_gif``) an MP4 that cannot be written.
    """
    path = Path(path)
    if not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise ClearsplatError(f"must be a positive number, got {fps}", field="fps")
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise ClearsplatError("no frames to write", path=path, field="frames")
    h, w = first.shape[:2]
    if first.ndim != 3 or first.shape[2] != 3 or h % 2 or w % 2:
        raise ClearsplatError(f"frames must be (H, W, 3) with even H and W, got {first.shape}",
                              path=path, field="frames")
    done: list[np.ndarray] = []       # kept only for a fallback after a failure

    def all_frames():
        yield first
        for f in frames:
            if f.shape != first.shape:
                raise ClearsplatError(f"frame of shape {f.shape} after {first.shape}",
                                      path=path, field="frames")
            yield f

    tmp = _temp_beside(path)
    try:
        import imageio_ffmpeg
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (w, h), fps=float(fps), codec="libx264", pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p", quality=None, bitrate=None,
            output_params=["-crf", "20", "-preset", "medium", "-movflags", "+faststart"],
            macro_block_size=2, ffmpeg_log_level="error")
        writer.send(None)
        try:
            for f in all_frames():
                if fallback_gif:
                    done.append(f)
                writer.send(np.ascontiguousarray(f, dtype=np.uint8))
        finally:
            writer.close()
        os.replace(tmp, path)
        return path
    except ClearsplatError:
        tmp.unlink(missing_ok=True)
        raise
    except (ImportError, OSError, RuntimeError, ValueError, BrokenPipeError) as e:
        tmp.unlink(missing_ok=True)
        if not fallback_gif:
            raise ClearsplatError(f"cannot write the MP4 ({' '.join(str(e).split())[:200]})",
                                  path=path, field="video") from None
        done.extend(all_frames())      # whatever the writer had not consumed
        gif = path.with_suffix(".gif")
        warnings.warn(f"cannot write an MP4 ({type(e).__name__}: "
                      f"{' '.join(str(e).split())[:120]}); wrote an animated GIF {gif} instead",
                      stacklevel=2)
        write_gif(gif, done, fps=fps)
        return gif
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_gif(path, frames: Sequence[np.ndarray], *, fps: float = 24.0) -> Path:
    """Write frames as a looping animated GIF (atomically, through Pillow)."""
    path = Path(path)
    pics = [Image.fromarray(f) for f in frames]
    tmp = _temp_beside(path)
    try:
        pics[0].save(tmp, format="GIF", save_all=True, append_images=pics[1:],
                     duration=int(round(1000 / fps)), loop=0)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def default_size(camera, *, max_width: int = 640) -> tuple[int, int]:
    """Each half's size: the camera's, scaled down to ``max_width``, both even."""
    w = min(camera.width, max_width)
    h = camera.height * w / camera.width
    return w - w % 2 or 2, max(2, int(round(h / 2)) * 2)


def make_video(path, scene, keep, *, cameras=None, num_frames: int = 96, fps: float = 24.0,
               size: tuple[int, int | None] | None = None,
               labels: tuple[str, str] | None = None, background=(0.0, 0.0, 0.0),
               progress=None, fallback_gif: bool = True) -> Path:
    """A before | after video along a smooth path through the cameras.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mp4`` to write.
    scene : Scene
    keep : (N,) bool
        The Gaussians kept by the filter (``result.keep``).
    cameras : sequence of Camera, optional
        Key cameras of the path; default the scene's input cameras, in order.
    num_frames : int, default 96
        Frames on the path (see :func:`clearsplat.camera_path.interpolate_cameras`).
    fps : float, default 24
    size : (width, height or None), optional
        Each half's size; default the first camera's, at most 640 wide.
    labels : (str, str), optional
        Default ``"before: N Gaussians"``, ``"after: M removed"``.
    background, progress, fallback_gif
        As in :func:`comparison_frames` and :func:`write_video`.

    Returns
    -------
    pathlib.Path
        The file written (the MP4, or the GIF fallback).
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.shape != (len(scene),):
        raise ClearsplatError(f"expected {len(scene)} values, got shape {keep.shape}",
                              field="keep")
    cameras = list(scene.cameras if cameras is None else cameras)
    if size is None:
        width, height = default_size(cameras[0])
    else:
        width, height = size
        if height is None:
            height = int(round(cameras[0].height * width / cameras[0].width))
        width, height = width + width % 2, height + height % 2
    path_cams = interpolate_cameras(cameras, num_frames, width=width, height=height)
    if labels is None:
        labels = (f"before: {len(keep):,} Gaussians",
                  f"after: {int((~keep).sum()):,} removed")
    frames = comparison_frames(scene, keep, path_cams, labels=labels, background=background,
                               progress=progress)
    return write_video(path, frames, fps=fps, fallback_gif=fallback_gif)
