"""Decode image bytes, files or arrays into the planes the detector needs, within input limits.

Luma is decoded first (JPEG straight to gray through libjpeg-turbo via simplejpeg); colour is
decoded only when a caller asks for it. Pixels are never rotated: a camera stores sensor rows as
rows and records display rotation in the EXIF orientation tag, which is reported, not applied.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageFile, UnidentifiedImageError

from lishield_guard.config import Limits
from lishield_guard.errors import (
    CorruptImageError,
    ImageTooLargeError,
    InvalidImageError,
    PayloadTooLargeError,
    UnsupportedImageError,
)

__all__ = ["Decoded", "decode", "validate_image"]

ImageFile.LOAD_TRUNCATED_IMAGES = False
# Pillow's own bomb check fires inside Image.open and surfaces as "unidentified image"; the
# configurable cap (Limits.max_pixels) is enforced on the header before any pixel is decoded.
Image.MAX_IMAGE_PIXELS = None
_HEIF_READY = False
EXIF_ORIENTATION_TAG = 0x0112
_JPEG_MAGIC = b"\xff\xd8\xff"


def _ensure_heif() -> None:
    global _HEIF_READY
    if not _HEIF_READY:
        try:
            import pillow_heif

            pillow_heif.register_heif_opener()
        except ImportError:  # HEIC stays unsupported without pillow-heif
            pass
        _HEIF_READY = True


def validate_image(image: np.ndarray) -> np.ndarray:
    """Check and coerce an image array: (n_rows, n_cols) or (n_rows, n_cols, 1|3|4).

    Integer and boolean arrays are returned as uint8/uint16 or float32; float arrays as float32.
    An alpha channel is dropped. The result is C-contiguous only if the input was.

    Raises
    ------
    InvalidImageError
        If the array has the wrong ndim or channel count, is empty, or holds NaN/inf.
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] in (1, 3, 4):
        arr = arr[:, :, 0] if arr.shape[2] == 1 else arr[:, :, :3]
    if arr.ndim not in (2, 3):
        raise InvalidImageError(f"need an image of shape (n_rows, n_cols) or (n_rows, n_cols, 3),"
                                f" got shape={arr.shape!r}")
    if arr.size == 0:
        raise InvalidImageError(f"image is empty, shape={arr.shape!r}")
    if arr.dtype == bool:
        arr = arr.astype(np.uint8) * 255
    elif arr.dtype.kind in "iu" and arr.dtype not in (np.uint8, np.uint16):
        arr = arr.astype(np.float32)
    elif arr.dtype.kind == "f":
        if arr.dtype != np.float32:
            with np.errstate(over="ignore"):
                arr32 = arr.astype(np.float32)
            if np.isfinite(arr).all() and not np.isfinite(arr32).all():
                raise InvalidImageError("float image exceeds the float32 range")
            arr = arr32
        if not np.isfinite(arr).all():
            raise InvalidImageError("image holds NaN or infinite pixel values")
    elif arr.dtype.kind not in "iu":
        raise InvalidImageError(f"unsupported pixel dtype {arr.dtype!s}")
    return arr


@dataclass
class Decoded:
    """An image decoded for detection.

    Attributes
    ----------
    luma : ndarray of shape (n_rows, n_cols)
        uint8, uint16 or float32 brightness in stored (sensor) orientation.
    format : str
        Container format (``"JPEG"``, ``"PNG"``, ..., ``"array"``).
    n_bytes : int
        Encoded size in bytes (0 for arrays).
    orientation : int
        EXIF orientation tag (1 when absent); 5-8 mean the display is rotated by 90 degrees.
    is_color : bool
        True when the source has colour channels.
    row_scale : float
        Stored rows per decoded row (1, or 2/4/8 after DCT-domain downscaling of a JPEG).
    """

    luma: np.ndarray
    format: str
    n_bytes: int
    orientation: int = 1
    is_color: bool = False
    row_scale: float = 1.0
    _data: bytes | None = field(default=None, repr=False)
    _rgb: np.ndarray | None = field(default=None, repr=False)

    def rgb(self) -> np.ndarray:
        """Colour planes (n_rows, n_cols, 3), decoded on first use (uint8/uint16/float32)."""
        if self._rgb is None:
            if not self.is_color:
                self._rgb = np.repeat(self.luma[:, :, None], 3, axis=2)
            elif self._data is not None:
                rows = self.luma.shape[0] if self.row_scale > 1 else 0
                self._rgb = _decode_pixels(self._data, want_rgb=True, min_rows=rows)[0]
            else:  # pragma: no cover - arrays always keep their rgb
                raise InvalidImageError("colour planes are not available")
        return self._rgb


def _luma_of(rgb: np.ndarray) -> np.ndarray:
    if rgb.dtype == np.uint8:
        return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    weights = np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return (rgb.astype(np.float32, copy=False) @ weights).astype(np.float32, copy=False)


def _pil_to_array(img: Image.Image, *, want_rgb: bool) -> tuple[np.ndarray, bool]:
    """Pixels of a loaded Pillow image as (array, is_color)."""
    mode = img.mode
    if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
        return np.asarray(img, dtype=np.uint16), False
    if mode == "I":
        return validate_image(np.asarray(img, dtype=np.int64).astype(np.float32)), False
    if mode == "F":
        return validate_image(np.asarray(img, dtype=np.float32)), False
    if mode in ("1", "L", "LA"):
        return np.asarray(img.convert("L")), False
    rgb = np.asarray(img.convert("RGB"))  # P, PA, RGBA, CMYK, YCbCr, LAB, HSV...
    if mode == "P" and _is_gray(rgb):
        return rgb[:, :, 0].copy(), False
    return (rgb if want_rgb else _luma_of(rgb)), True


def _is_gray(rgb: np.ndarray) -> bool:
    return bool((rgb[:, :, 0] == rgb[:, :, 1]).all() and (rgb[:, :, 1] == rgb[:, :, 2]).all())


def _open(data: bytes) -> Image.Image:
    _ensure_heif()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            return Image.open(io.BytesIO(data))
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageTooLargeError(f"image declares too many pixels: {exc}") from exc
    except UnidentifiedImageError as exc:
        raise UnsupportedImageError("not an image, or an image format that is not supported"
                                    " (JPEG, PNG, TIFF, WebP, BMP, GIF, HEIC/HEIF are)") from exc
    except (OSError, ValueError, SyntaxError) as exc:
        raise CorruptImageError(f"cannot read image header: {exc}") from exc


def _decode_pixels(data: bytes, *, want_rgb: bool, fast: bool = True,
                   min_rows: int = 0) -> tuple[np.ndarray, bool]:
    if fast and data.startswith(_JPEG_MAGIC):
        import simplejpeg

        try:
            if want_rgb:
                return simplejpeg.decode_jpeg(data, colorspace="RGB", min_height=min_rows), True
            gray = simplejpeg.decode_jpeg(data, colorspace="GRAY", min_height=min_rows)
            return gray[:, :, 0], True
        except ValueError:
            pass  # CMYK, arithmetic coding or a warning: let Pillow decide below
    img = _open(data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            img.seek(0)
            img.load()
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageTooLargeError(f"image declares too many pixels: {exc}") from exc
    except (OSError, ValueError, SyntaxError, EOFError, IndexError, MemoryError) as exc:
        raise CorruptImageError(f"truncated or corrupt {img.format or 'image'} data: "
                                f"{exc}") from exc
    if not fast and not want_rgb and img.mode not in ("I;16", "I;16B", "I;16L", "I;16N", "I",
                                                      "F", "1", "L", "LA"):
        rgb = np.asarray(img.convert("RGB"), dtype=np.float32)
        return _luma_of(rgb), True
    return _pil_to_array(img, want_rgb=want_rgb)


def _orientation(img: Image.Image) -> int:
    try:
        value = int(img.getexif().get(EXIF_ORIENTATION_TAG, 1))
    except Exception:  # noqa: BLE001 - a broken EXIF block must not fail the decode
        return 1
    return value if 1 <= value <= 8 else 1


def decode(source, *, limits: Limits | None = None, want_rgb: bool = False, fast: bool = True,
           max_rows: int = 0) -> Decoded:
    """Decode bytes, a file path or an array into a `Decoded` image.

    Parameters
    ----------
    source : bytes, str, pathlib.Path or ndarray
        Encoded image bytes, a path to an image file, or pixels (n_rows, n_cols[, 3]).
    limits : Limits, optional
        Byte and pixel caps; default `Limits()`.
    want_rgb : bool
        Decode colour planes now (otherwise they are decoded on demand by `Decoded.rgb`).
    fast : bool
        JPEG luma straight to gray with libjpeg-turbo; False decodes full colour with Pillow
        and converts to float32 luma (the reference path).
    max_rows : int
        With ``fast``, a JPEG with at least twice this many rows is decoded at 1/2, 1/4 or
        1/8 scale in the DCT domain, keeping >= max_rows rows (0 disables).

    Raises
    ------
    PayloadTooLargeError
        More than ``limits.max_bytes`` bytes.
    ImageTooLargeError
        More than ``limits.max_pixels`` pixels declared in the header.
    UnsupportedImageError
        Not an image or an unsupported format.
    CorruptImageError
        Truncated or corrupt data.
    InvalidImageError
        An array of the wrong shape, empty, or with NaN/inf.
    """
    limits = limits or Limits()
    if isinstance(source, np.ndarray):
        arr = validate_image(source)
        if arr.shape[0] * arr.shape[1] > limits.max_pixels:
            raise ImageTooLargeError(f"image has {arr.shape[0] * arr.shape[1]} pixels > "
                                     f"max_pixels={limits.max_pixels}")
        if arr.ndim == 3:
            return Decoded(_luma_of(arr), "array", 0, is_color=True, _rgb=arr)
        return Decoded(arr, "array", 0)
    if isinstance(source, str | Path):
        path = Path(source)
        try:
            size = path.stat().st_size
            if size > limits.max_bytes:
                raise PayloadTooLargeError(f"file has {size} bytes > max_bytes="
                                           f"{limits.max_bytes}")
            data = path.read_bytes()
        except OSError as exc:
            raise UnsupportedImageError(f"cannot read {str(path)!r}: {exc.strerror}") from exc
    elif isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
    else:
        raise InvalidImageError(f"cannot detect on a {type(source).__name__}; pass bytes, a "
                                f"path or an ndarray")
    if len(data) > limits.max_bytes:
        raise PayloadTooLargeError(f"input has {len(data)} bytes > max_bytes={limits.max_bytes}")
    if not data:
        raise UnsupportedImageError("empty input: no image bytes")
    img = _open(data)
    n_cols, n_rows = img.size
    if n_rows * n_cols > limits.max_pixels:
        raise ImageTooLargeError(f"image declares {n_cols}x{n_rows} = {n_rows * n_cols} pixels >"
                                 f" max_pixels={limits.max_pixels}")
    if n_rows < 1 or n_cols < 1:
        raise CorruptImageError(f"image declares an empty size {n_cols}x{n_rows}")
    orientation = _orientation(img)
    fmt = img.format or "unknown"
    min_rows = max_rows if fast and max_rows and n_rows >= 2 * max_rows else 0
    pixels, is_color = _decode_pixels(data, want_rgb=want_rgb, fast=fast, min_rows=min_rows)
    row_scale = n_rows / pixels.shape[0]
    if (pixels.shape[:2] != (n_rows, n_cols) and not min_rows) or abs(
            n_cols / pixels.shape[1] - row_scale) > 0.5:
        raise CorruptImageError(f"decoded size {pixels.shape[:2]} differs from the header's "
                                f"{(n_rows, n_cols)}")
    if pixels.ndim == 3:
        return Decoded(_luma_of(pixels), fmt, len(data), orientation, True, row_scale, data,
                       pixels)
    return Decoded(pixels, fmt, len(data), orientation, is_color, row_scale, data)
