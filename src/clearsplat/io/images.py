"""Input images: PNG and JPEG files to float32 RGB arrays in [0, 1], and back to 8-bit PNG.

Conversions on reading (documented in ``docs/errors.md``):

- 8-bit RGB: ``value / 255``.
- Grayscale (``L``, bilevel ``1``), 16-bit grayscale PNG (``value / 65535``): copied to R, G, B.
- Alpha (``RGBA``, ``LA``, palette with transparency) is dropped, not composited: the colour
  channels are used as they are.
- Palette (``P``) images are expanded through their palette; CMYK/YCbCr JPEGs converted to RGB.
- 16-bit colour PNGs are read at 8-bit precision (Pillow keeps the high byte of each sample).
- Other formats (TIFF, BMP, ...) and modes (32-bit float, ...) are refused.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..errors import ClearsplatError
from .ply import atomic_write_bytes

__all__ = ["read_image", "write_image"]

_FORMATS = ("PNG", "JPEG", "MPO")   # MPO: multi-picture JPEG written by many cameras


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
        im = Image.open(path)
    except FileNotFoundError:
        raise ClearsplatError("image file not found", path=path, field="image") from None
    except UnidentifiedImageError:
        raise ClearsplatError("not an image Pillow can read (expected PNG or JPEG)",
                              path=path, field="image") from None
    except Image.DecompressionBombError as e:
        raise ClearsplatError(f"image too large ({e})", path=path, field="image") from None
    except (OSError, ValueError, SyntaxError) as e:
        raise ClearsplatError(f"cannot read the image ({e})", path=path, field="image") from None
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
            return _to_rgb(im, path)
        except (OSError, SyntaxError, ValueError) as e:
            if isinstance(e, ClearsplatError):
                raise
            raise ClearsplatError(f"cannot decode the image ({e})", path=path,
                                  field="image") from None


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
