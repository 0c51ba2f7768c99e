"""Decode image bytes, files or arrays into the planes the detector needs, within input limits.

Luma is decoded first (JPEG straight to gray through libjpeg-turbo via simplejpeg); colour is
decoded only when a caller asks for it. Pixels are never rotated: a camera stores sensor rows as
rows and records display rotation in the EXIF orientation tag, which is reported, not applied.
"""

from __future__ import annotations

import io
import os
import stat
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageFile, UnidentifiedImageError

from lishield_guard.config import Limits
from lishield_guard.errors import (
    CorruptImageError,
    EmptyImageError,
    ImageTooLargeError,
    InvalidImageError,
    PayloadTooLargeError,
    SpecialFileError,
    UnsupportedImageError,
    input_file_error,
)

__all__ = ["Decoded", "archive_kind", "check_budget", "decode", "jpeg_scale",
           "read_regular_file", "validate_image"]

ImageFile.LOAD_TRUNCATED_IMAGES = False
# Pillow's own bomb check fires inside Image.open and surfaces as "unidentified image"; the
# configurable cap (Limits.max_pixels) is enforced on the header before any pixel is decoded.
Image.MAX_IMAGE_PIXELS = None
_HEIF_READY = False
EXIF_ORIENTATION_TAG = 0x0112
_JPEG_MAGIC = b"\xff\xd8\xff"
_JPEG_SOS = b"\xff\xda"
_JPEG_EOI = b"\xff\xd9"
# Peak memory of one detection, for the budget check (Limits.max_decode_bytes). Measured with
# ru_maxrss on 12 MP noise images (the costly path: luma not decisive, colour planes analysed):
# JPEG through libjpeg-turbo 7.0 bytes per decoded pixel, PNG through Pillow 17.5.
DECODE_BASE_BYTES = 32 * 1024 * 1024  # fixed cost of a detection beyond the pixels
FAST_JPEG_BYTES_PER_PIXEL = 8
# A progressive (multi-scan) JPEG keeps every DCT coefficient of the full-size image, whatever
# the output scale: 2 bytes per sample, up to 3 samples per pixel (4:4:4).
PROGRESSIVE_COEF_BYTES_PER_PIXEL = 6
_JPEG_MULTI_SCAN_SOF = (b"\xff\xc2", b"\xff\xc6", b"\xff\xca", b"\xff\xce")
PILLOW_BYTES_PER_PIXEL = 20
WIDE_MODES = ("I;16", "I;16B", "I;16L", "I;16N", "I", "F")  # more than 8 bits per sample
JPEG_SCALES = (1, 2, 4, 8)  # DCT-domain downscaling factors of libjpeg-turbo


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
    _limits: Limits | None = field(default=None, repr=False)
    _planes: tuple | None = field(default=None, repr=False)

    def rgb(self) -> np.ndarray:
        """Colour planes (n_rows, n_cols, 3), decoded on first use (uint8/uint16/float32)."""
        if self._rgb is None:
            if not self.is_color:
                self._rgb = np.repeat(self.luma[:, :, None], 3, axis=2)
            elif self._data is not None:
                rows = self.luma.shape[0] if self.row_scale > 1 else 0
                self._rgb = _decode_pixels(self._data, want_rgb=True, min_rows=rows,
                                           limits=self._limits)[0]
            else:  # pragma: no cover - arrays always keep their rgb
                raise InvalidImageError("colour planes are not available")
        return self._rgb

    def colour_planes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The R, G, B planes (`rgb`) as contiguous arrays, split once: row profiles of a
        strided channel view cost about twice as much."""
        if self._planes is None:
            rgb = self.rgb()
            self._planes = tuple(np.ascontiguousarray(rgb[:, :, i]) for i in range(3))
        return self._planes


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
        archive = archive_kind(data)
        if archive:
            raise UnsupportedImageError(
                f"a {archive} archive, not an image or a video: `lishield-guard scan` reads "
                f"the images and clips inside archives") from exc
        raise UnsupportedImageError("not an image, or an image format that is not supported"
                                    " (JPEG, PNG, TIFF, WebP, BMP, GIF, HEIC/HEIF are)") from exc
    except (OSError, ValueError, SyntaxError) as exc:
        raise CorruptImageError(f"cannot read image header: {exc}") from exc


def archive_kind(data: bytes) -> str | None:
    """``"ZIP"`` or ``"tar"`` when ``data`` is an archive `lishield-guard scan` reads (by the
    standard library's own tests), else None.

    Examples
    --------
    >>> archive_kind(b"PK\\x05\\x06" + bytes(18)), archive_kind(b"\\xff\\xd8\\xff")
    ('ZIP', None)
    """
    import tarfile
    import zipfile

    try:
        if zipfile.is_zipfile(io.BytesIO(data)):
            return "ZIP"
        if tarfile.is_tarfile(io.BytesIO(data)):
            return "tar"
    except Exception:  # noqa: BLE001 - only a hint for a message: never fail here
        return None
    return None


def jpeg_scale(n_rows: int, min_rows: int) -> int:
    """DCT-domain downscaling factor libjpeg-turbo applies for ``min_height=min_rows``.

    The largest of 1, 2, 4, 8 that still leaves at least ``min_rows`` rows (1 when
    ``min_rows`` is 0).

    Examples
    --------
    >>> jpeg_scale(65000, 1536), jpeg_scale(3000, 1536), jpeg_scale(3000, 0)
    (8, 1, 1)
    """
    if min_rows <= 0:
        return 1
    return max(s for s in JPEG_SCALES if -(-n_rows // s) >= min_rows or s == 1)


def check_budget(n_rows: int, n_cols: int, *, bytes_per_pixel: float, scale: int = 1,
                 limits: Limits) -> int:
    """Estimated peak bytes of decoding and detecting on an image; raise past the budget.

    Parameters
    ----------
    n_rows, n_cols : int
        Size declared by the header, in pixels.
    bytes_per_pixel : float
        Measured peak bytes per decoded pixel of the decode path (see the module constants).
    scale : int
        DCT-domain downscaling factor (decoded size is ceil(n / scale) on both axes).
    limits : Limits
        ``max_decode_bytes`` is the budget.

    Returns
    -------
    int
        The estimate, in bytes.

    Raises
    ------
    ImageTooLargeError
        When the estimate exceeds ``limits.max_decode_bytes``.
    """
    px = -(-n_rows // scale) * -(-n_cols // scale)
    need = int(DECODE_BASE_BYTES + px * bytes_per_pixel)
    if need > limits.max_decode_bytes:
        at = f" at 1/{scale} scale" if scale > 1 else ""
        raise ImageTooLargeError(f"decoding {n_cols}x{n_rows}{at} needs about {need} bytes > "
                                 f"max_decode_bytes={limits.max_decode_bytes}")
    return need


def jpeg_is_progressive(data: bytes) -> bool:
    """True when a JPEG's frame header (before its first scan) is progressive."""
    head = data[: data.find(_JPEG_SOS)] if _JPEG_SOS in data else data
    return any(m in head for m in _JPEG_MULTI_SCAN_SOF)


def _jpeg_complete(data: bytes) -> bool:
    """True when an EOI marker follows the last start-of-scan (entropy-coded data never holds
    ``FF DA`` or ``FF D9``: a 0xFF byte there is followed by 0x00 or a restart marker)."""
    sos = data.rfind(_JPEG_SOS)
    return sos >= 0 and data.find(_JPEG_EOI, sos) >= 0


def _simplejpeg(data: bytes, *, want_rgb: bool, min_rows: int):
    import simplejpeg

    space = "RGB" if want_rgb else "GRAY"
    return simplejpeg.decode_jpeg(data, colorspace=space, min_height=min_rows, strict=True)


def _corrupt_jpeg(message: str) -> bool:
    low = message.lower()
    return "corrupt jpeg" in low or "premature end" in low or "bogus" in low or \
        "invalid" in low or "truncated" in low


def _decode_fast_jpeg(data: bytes, *, want_rgb: bool, min_rows: int):
    """libjpeg-turbo decode that refuses truncated or corrupt data (None: let Pillow try).

    A file that lacks only its final EOI marker is tolerated; extraneous bytes before a
    marker (a warning many cameras trigger) are tolerated, and where libjpeg-turbo cannot
    read past them (a broken marker in the header), Pillow decides; any other corruption,
    including a premature end of the entropy-coded data that libjpeg would fill with grey,
    raises.
    """
    try:
        return _simplejpeg(data, want_rgb=want_rgb, min_rows=min_rows)
    except ValueError as exc:
        msg = str(exc)
    if "extraneous bytes" in msg.lower():
        import simplejpeg

        space = "RGB" if want_rgb else "GRAY"
        try:
            return simplejpeg.decode_jpeg(data, colorspace=space, min_height=min_rows,
                                          strict=False)
        except ValueError:  # libjpeg-turbo stops at them in a header: Pillow decides
            return None
    if not _corrupt_jpeg(msg):
        return None  # CMYK, arithmetic coding, ...: Pillow decides
    if not _jpeg_complete(data):
        try:  # tolerance: only the final EOI marker is missing
            return _simplejpeg(data + _JPEG_EOI, want_rgb=want_rgb, min_rows=min_rows)
        except ValueError:
            pass
        raise CorruptImageError(f"truncated JPEG data: {msg}")
    raise CorruptImageError(f"corrupt JPEG data: {msg}")


def _decode_pixels(data: bytes, *, want_rgb: bool, fast: bool = True,
                   min_rows: int = 0, limits: Limits | None = None) -> tuple[np.ndarray, bool]:
    if data.startswith(_JPEG_MAGIC):
        # The fast decoder doubles as the truncation check of the Pillow paths (at 1/8 scale).
        probe = _decode_fast_jpeg(data, want_rgb=want_rgb and fast,
                                  min_rows=min_rows if fast else 1)
        if probe is not None and fast:
            return (probe, True) if want_rgb else (probe[:, :, 0], True)
    img = _open(data)
    n_cols, n_rows = img.size
    per_px = PILLOW_BYTES_PER_PIXEL * (2 if img.mode in WIDE_MODES else 1)
    check_budget(n_rows, n_cols, bytes_per_pixel=per_px, limits=limits or Limits())
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
        data = read_regular_file(source, max_bytes=limits.max_bytes)
    elif isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
    else:
        raise InvalidImageError(f"cannot detect on a {type(source).__name__}; pass bytes, a "
                                f"path or an ndarray")
    if len(data) > limits.max_bytes:
        raise PayloadTooLargeError(f"input has {len(data)} bytes > max_bytes={limits.max_bytes}")
    if not data:
        raise EmptyImageError("empty input: no image bytes")
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
    if fast and data.startswith(_JPEG_MAGIC):
        scale = jpeg_scale(n_rows, min_rows)
        per_px = FAST_JPEG_BYTES_PER_PIXEL
        if jpeg_is_progressive(data):  # coefficients of the full image, at any scale
            per_px += PROGRESSIVE_COEF_BYTES_PER_PIXEL * scale * scale
        check_budget(n_rows, n_cols, bytes_per_pixel=per_px, scale=scale, limits=limits)
    pixels, is_color = _decode_pixels(data, want_rgb=want_rgb, fast=fast, min_rows=min_rows,
                                      limits=limits)
    row_scale = n_rows / pixels.shape[0]
    # libjpeg-turbo scales by M/8 (M = 1..8): ceil(size * M / 8) rows and columns
    eighths = max(1, min(8, round(8 * pixels.shape[0] / n_rows)))
    expected = (-(-n_rows * eighths // 8), -(-n_cols * eighths // 8))
    if pixels.shape[:2] != (n_rows, n_cols) and (not min_rows or pixels.shape[:2] != expected):
        raise CorruptImageError(f"decoded size {pixels.shape[:2]} differs from the header's "
                                f"{(n_rows, n_cols)}")
    if pixels.ndim == 3:
        return Decoded(_luma_of(pixels), fmt, len(data), orientation, True, row_scale, data,
                       pixels, limits)
    return Decoded(pixels, fmt, len(data), orientation, is_color, row_scale, data, None, limits)


def read_regular_file(path: str | Path, *, max_bytes: int) -> bytes:
    """The bytes of a regular file (or of a link to one), at most ``max_bytes`` of them.

    FIFOs, devices, sockets and folders are refused without reading (opening a FIFO does not
    block: it is opened non-blocking and checked with fstat first).

    Raises
    ------
    InputNotFoundError
        No such file, or a link whose target is gone (``not_found``).
    SpecialFileError
        A FIFO, device, socket or folder (``special_member``).
    InputFileError
        Unreadable: permissions, a loop of links, an I/O error (``read_error``).
    PayloadTooLargeError
        More than ``max_bytes`` bytes.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    shown = os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise input_file_error(exc, shown) from exc
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise SpecialFileError(f"cannot read {shown!r}: not a regular file")
        if st.st_size > max_bytes:
            raise PayloadTooLargeError(f"file has {st.st_size} bytes > max_bytes={max_bytes}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)
    except SpecialFileError:
        raise
    except OSError as exc:
        raise input_file_error(exc, shown) from exc
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise PayloadTooLargeError(f"file has more than max_bytes={max_bytes} bytes")
    return data
