"""Decoding: formats, modes, orientation and the typed errors for bad input."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from lishield_guard import (
    CorruptImageError,
    ImageTooLargeError,
    InvalidImageError,
    Limits,
    PayloadTooLargeError,
    UnsupportedImageError,
    decode,
    detect,
)


def _encode(img: Image.Image, fmt: str, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, fmt, **kw)
    return buf.getvalue()


@pytest.fixture
def gray(rng):
    return Image.fromarray(rng.integers(0, 256, (120, 160), dtype=np.uint8))


@pytest.mark.parametrize("fmt", ["JPEG", "PNG", "TIFF", "WEBP", "BMP", "GIF"])
def test_formats_decode_to_luma(gray, fmt):
    d = decode(_encode(gray, fmt))
    assert d.luma.shape == (120, 160)
    assert d.format == fmt


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "P", "CMYK", "LA", "I;16", "F"])
def test_modes(gray, mode):
    img = gray.convert(mode) if mode not in ("I;16", "F") else Image.fromarray(
        (np.asarray(gray).astype(np.uint16) * 257) if mode == "I;16"
        else np.asarray(gray).astype(np.float32))
    fmt = "TIFF" if mode in ("CMYK", "F") else "PNG"
    if mode == "CMYK":
        fmt = "JPEG"
    d = decode(_encode(img, fmt))
    assert d.luma.shape == (120, 160)
    assert np.isfinite(d.luma.astype(np.float64)).all()


def test_heic_round_trip(gray):
    pillow_heif = pytest.importorskip("pillow_heif")
    pillow_heif.register_heif_opener()
    d = decode(_encode(gray.convert("RGB"), "HEIF"))
    assert d.luma.shape == (120, 160)


def test_exif_orientation_is_reported(gray):
    exif = Image.Exif()
    exif[0x0112] = 6
    d = decode(_encode(gray.convert("RGB"), "JPEG", exif=exif))
    assert d.orientation == 6
    assert d.luma.shape == (120, 160)  # stored (sensor) rows are kept


def test_not_an_image():
    with pytest.raises(UnsupportedImageError):
        decode(b"hello, this is not an image at all")
    with pytest.raises(UnsupportedImageError):
        decode(b"")


def test_truncated_jpeg(gray):
    data = _encode(gray.convert("RGB"), "JPEG")
    with pytest.raises(CorruptImageError):
        decode(data[: len(data) // 2])


def _png_header_only(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    idat = b"IDAT" + zlib.compress(b"\x00" * 64)
    iend = b"IEND"
    return b"\x89PNG\r\n\x1a\n" + b"".join(
        struct.pack(">I", len(c) - 4) + c + struct.pack(">I", zlib.crc32(c))
        for c in (chunk, idat, iend))


def test_pixel_cap_before_decoding():
    with pytest.raises(ImageTooLargeError):
        decode(_png_header_only(100_000, 100_000))
    with pytest.raises(ImageTooLargeError):
        decode(_encode(Image.new("L", (2000, 2000)), "PNG"), limits=Limits(max_pixels=1_000_000))


def test_byte_cap(gray, tmp_path):
    data = _encode(gray, "PNG")
    with pytest.raises(PayloadTooLargeError):
        decode(data, limits=Limits(max_bytes=len(data) - 1))
    path = tmp_path / "a.png"
    path.write_bytes(data)
    with pytest.raises(PayloadTooLargeError):
        decode(path, limits=Limits(max_bytes=len(data) - 1))
    assert decode(path, limits=Limits(max_bytes=len(data))).luma.shape == (120, 160)


@pytest.mark.parametrize("bad", [np.zeros((0, 5)), np.zeros((4, 4, 4, 4)),
                                 np.array([[np.nan, 1.0], [1.0, 1.0]]),
                                 np.array([[np.inf, 1.0], [1.0, 1.0]])])
def test_invalid_arrays(bad):
    with pytest.raises(InvalidImageError):
        detect(bad)


def test_float_tiff_with_nan_is_rejected():
    arr = np.ones((64, 64), np.float32)
    arr[3, 3] = np.nan
    with pytest.raises(InvalidImageError):
        detect(_encode(Image.fromarray(arr), "TIFF"))
