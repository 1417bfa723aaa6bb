"""Input images: PNG and JPEG files to float32 RGB arrays in [0, 1], and back to 8-bit PNG.

Conversions on reading (documented in ``docs/errors.md``):

- 8-bit RGB: ``value / 255``.
- Grayscale (``L``, bilevel ``1``), 16-bit grayscale PNG (``value / 65535``): copied to R, G, B.
- Alpha (``RGBA``, ``LA``, palette with transparency) is dropped, not composited: the colour
  channels are used as they are.
- Palette (``P``) images are expanded through their palette; CMYK/YCbCr JPEGs converted to RGB.
- 16-bit colour PNGs (RGB, RGBA, grayscale with alpha) keep their full precision
  (``value / 65535``): Pillow decodes them to 8 bits, so the file is decoded twice, once for
  the high and once for the low byte of every sample.
- Other formats (TIFF, BMP, ...) and modes (32-bit float, ...) are refused.
"""

from __future__ import annotations

import io
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError
from .ply import atomic_write_bytes

__all__ = ["read_image", "write_image"]

_FORMATS = ("PNG", "JPEG", "MPO")   # MPO: multi-picture JPEG written by many cameras
#: What a damaged file can make Pillow raise while decoding.
_DECODE_ERRORS = (OSError, SyntaxError, ValueError, EOFError, IndexError, TypeError,
                  struct.error, zlib.error, MemoryError)
#: Pillow's raw modes of 16-bit colour PNG data (big-endian samples), see _png16.
_PNG16 = ("RGB;16B", "RGBA;16B", "LA;16B")


def read_image(path, *, expected_size=None) -> np.ndarray:
    """Read a PNG or JPEG file as float32 RGB in [0, 1].

    Parameters
    ----------
    path : str or os.PathLike
        The image file.
    expected_size : (int, int), optional
        ``(width, height)`` in pixels that the image must have (a camera's
        ``width, height``); checked before decoding.

    Returns
    -------
    image : (H, W, 3) float32
        RGB in [0, 1], indexed ``[row, col]``.

    Raises
    ------
    ClearsplatError
        Naming the file and the field: missing or unreadable file, unsupported format or
        mode, or a size other than ``expected_size`` (field ``width`` or ``height``).
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with warnings.catch_warnings():
            # A size above Pillow's bomb threshold warns on opening; the camera's size is
            # checked below, before anything is decoded.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
    except FileNotFoundError:
        raise ClearsplatError("image file not found", path=path, field="image") from None
    except IsADirectoryError:
        raise ClearsplatError("is a folder, not an image file", path=path,
                              field="image") from None
    except UnidentifiedImageError:
        raise ClearsplatError("not an image Pillow can read (expected PNG or JPEG)",
                              path=path, field="image") from None
    except Image.DecompressionBombError as e:
        raise ClearsplatError(f"image too large ({e})", path=path, field="image") from None
    except _DECODE_ERRORS as e:
        raise ClearsplatError(f"cannot read the image ({_short(e)})", path=path,
                              field="image") from None
    with im:
        if im.format not in _FORMATS:
            raise ClearsplatError(f"unsupported image format {im.format} (expected PNG or JPEG)",
                                  path=path, field="image")
        if expected_size is not None:
            ew, eh = (int(v) for v in expected_size)
            w, h = im.size
            for name, got, want in (("width", w, ew), ("height", h, eh)):
                if got != want:
                    raise ClearsplatError(f"image is {w}x{h} (width x height) but the camera "
                                          f"says {ew}x{eh}", path=path, field=name)
        try:
            tiles = getattr(im, "tile", None) or ()
            if im.format == "PNG" and len(tiles) == 1 and _rawmode(tiles[0]) in _PNG16:
                return _png16(im, path)
            return _to_rgb(im, path)
        except ClearsplatError:
            raise
        except _DECODE_ERRORS as e:
            raise ClearsplatError(f"cannot decode the image ({_short(e)})", path=path,
                                  field="image") from None


def _short(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text[:120]


def _rawmode(tile):
    args = tile[3] if len(tile) > 3 else None
    return args if isinstance(args, str) else None


def _png16(im, path) -> np.ndarray:
    """Full-precision RGB of a 16-bit PNG whose samples Pillow would cut to their high byte.

    Pillow's PNG decoder unfilters the rows and then keeps one byte of each big-endian
    sample: the high one for the raw mode ``RGB;16B``, the other one when told the data is
    little-endian (``RGB;16L``, same bytes per pixel, so the same unfiltering). Decoding the
    file twice gives both bytes. Gray with alpha (``LA;16B``) is decoded as 32-bit integers
    whose high half is the gray sample.
    """
    from PIL import Image

    tile = im.tile[0]
    raw = _rawmode(tile)
    second = Image.open(path)
    with second:
        if raw == "LA;16B":
            _set_mode(second, "I")
            second.tile = [_with_rawmode(tile, "I;32B")]
            gray = np.asarray(second).view(np.uint32) >> 16
            out = (gray.astype(np.float32) / np.float32(65535.0))
            return np.ascontiguousarray(np.repeat(out[:, :, None], 3, axis=2))
        second.tile = [_with_rawmode(tile, raw.replace(";16B", ";16L"))]
        low = np.asarray(second)[..., :3].astype(np.uint16)
    high = np.asarray(im)[..., :3].astype(np.uint16)
    value = (high << 8) | low
    return np.ascontiguousarray(value.astype(np.float32) / np.float32(65535.0))


def _with_rawmode(tile, rawmode: str):
    if hasattr(tile, "_replace"):          # Pillow >= 11: a named tuple
        return tile._replace(args=rawmode)
    return (tile[0], tile[1], tile[2], rawmode)


def _set_mode(im, mode: str) -> None:
    if hasattr(im, "_mode"):               # Pillow >= 10.1: mode is a read-only property
        im._mode = mode
    else:
        im.mode = mode


def _to_rgb(im, path) -> np.ndarray:
    mode = im.mode
    if mode in ("P", "PA"):
        im, mode = im.convert("RGBA"), "RGBA"
    elif mode in ("CMYK", "YCbCr"):
        im, mode = im.convert("RGB"), "RGB"
    elif mode == "1":
        im, mode = im.convert("L"), "L"
    if mode in ("RGB", "RGBA", "RGBX"):
        arr = np.asarray(im)[..., :3]
        scale = 255.0
    elif mode in ("L", "LA"):
        arr = np.asarray(im)
        arr = arr[..., 0] if arr.ndim == 3 else arr
        scale = 255.0
    elif mode.startswith("I;16") or mode == "I":
        arr = np.asarray(im)
        if arr.size and (arr.min() < 0 or arr.max() > 65535):
            raise ClearsplatError(f"mode {mode} values outside 0..65535 (not a 16-bit image)",
                                  path=path, field="image")
        scale = 65535.0
    else:
        raise ClearsplatError(f"unsupported image mode {mode!r} (expected RGB, RGBA, grayscale, "
                              "16-bit grayscale or palette)", path=path, field="image")
    out = arr.astype(np.float32) / np.float32(scale)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    return np.ascontiguousarray(out, dtype=np.float32)


def write_image(path, img) -> None:
    """Write an RGB image as an 8-bit PNG (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    img : (H, W, 3) array_like
        Float RGB in [0, 1] (values outside are clipped; stored as ``round(255 * v)``, so
        ``k / 255`` reads back exactly), or uint8.

    Raises
    ------
    ClearsplatError
        If the array has the wrong shape or non-finite values.
    """
    from PIL import Image

    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ClearsplatError(f"expected an (H, W, 3) image, got shape {arr.shape}",
                              path=path, field="image")
    if arr.dtype != np.uint8:
        if arr.dtype.kind not in "fiub":
            raise ClearsplatError(f"unsupported dtype {arr.dtype}", path=path, field="image")
        f = arr.astype(np.float64)
        if not np.isfinite(f).all():
            raise ClearsplatError("non-finite pixel values", path=path, field="image")
        arr = np.round(np.clip(f, 0.0, 1.0) * 255.0).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(arr)).save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())
