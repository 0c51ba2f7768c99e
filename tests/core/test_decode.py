"""Decoding: formats, modes, orientation and the typed errors for bad input."""

from __future__ import annotations

import io
import struct
import sys
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
    SpecialFileError,
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


def _pillow_luma(data: bytes) -> np.ndarray:
    """Reference luma: Pillow's own decode, as 8-bit L or BT.601 of its RGB (OpenCV's
    rounding, as `decode` uses for 8-bit colour)."""
    import cv2

    img = Image.open(io.BytesIO(data))
    if img.mode in ("L", "LA"):
        return np.asarray(img.convert("L"))
    return cv2.cvtColor(np.asarray(img.convert("RGB")), cv2.COLOR_RGB2GRAY)


def _max_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    assert a.shape == b.shape, (a.shape, b.shape)
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64))))


@pytest.mark.parametrize("fmt, lossless", [("JPEG", False), ("PNG", True), ("TIFF", True),
                                           ("WEBP", False), ("BMP", True), ("GIF", True)])
def test_formats_decode_to_luma(gray, fmt, lossless):
    """Each format decodes to the right pixels, not just the right shape: lossless formats
    give the source back exactly; lossy ones equal Pillow's decode within 1 level (the fast
    JPEG path decodes luma with libjpeg-turbo directly)."""
    data = _encode(gray, fmt)
    d = decode(data)
    assert d.format == fmt
    assert d.luma.shape == (120, 160) and d.luma.dtype == np.uint8
    if lossless:
        np.testing.assert_array_equal(d.luma, np.asarray(gray))
    else:
        assert _max_abs_diff(d.luma, _pillow_luma(data)) <= 1
        assert _max_abs_diff(d.luma, np.asarray(gray)) > 0  # really lossy: the check above


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "P", "CMYK", "LA", "I;16", "F"])
def test_modes(gray, mode):
    """Every pixel mode decodes to the luma of the source: exactly for grey stored as RGB,
    RGBA, palette, LA, 16-bit (x 257) and float; within 1 level of Pillow's decode for a
    CMYK JPEG (lossy)."""
    g = np.asarray(gray)
    img = gray.convert(mode) if mode not in ("I;16", "F") else Image.fromarray(
        (g.astype(np.uint16) * 257) if mode == "I;16" else g.astype(np.float32))
    fmt = {"CMYK": "JPEG", "F": "TIFF"}.get(mode, "PNG")
    data = _encode(img, fmt)
    d = decode(data)
    assert d.luma.shape == (120, 160)
    if mode == "CMYK":
        assert _max_abs_diff(d.luma, _pillow_luma(data)) <= 1
    elif mode == "I;16":
        assert d.luma.dtype == np.uint16
        np.testing.assert_array_equal(d.luma, g.astype(np.uint16) * 257)
    elif mode == "F":
        assert d.luma.dtype == np.float32
        np.testing.assert_array_equal(d.luma, g.astype(np.float32))
    else:
        np.testing.assert_array_equal(d.luma, g)


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
    data = _encode(gray.convert("RGB"), "JPEG", exif=exif)
    assert _max_abs_diff(d.luma, _pillow_luma(data)) <= 1  # not rotated either


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


# --- #22 item 7: truncated JPEGs beyond a small tolerance and memory bombs; item 9: narrow
# JPEGs; item 4: only regular files are read


def jpeg_declaring(n_cols: int, n_rows: int) -> bytes:
    """A complete 16x16 JPEG whose SOF0 header claims n_cols x n_rows (a few hundred bytes)."""
    data = bytearray(_encode(Image.new("RGB", (16, 16), (128, 90, 60)), "JPEG", quality=90))
    i = data.find(b"\xff\xc0")
    struct.pack_into(">HH", data, i + 5, n_rows, n_cols)
    return bytes(data)


def _jpeg(rng, shape, quality=90) -> bytes:
    return _encode(Image.fromarray(rng.integers(0, 256, shape, dtype=np.uint8)), "JPEG",
                   quality=quality)


@pytest.mark.parametrize("fast", [True, False])
def test_jpeg_declaring_a_huge_size_over_a_few_bytes_is_undecodable(fast):
    data = jpeg_declaring(10_000, 10_000)
    assert len(data) < 1000
    with pytest.raises(CorruptImageError) as info:
        decode(data, fast=fast, max_rows=1536)
    assert info.value.code == "undecodable_image"


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.99])
def test_truncated_jpeg_is_undecodable(rng, keep):
    data = _jpeg(rng, (480, 640, 3))
    with pytest.raises(CorruptImageError, match="truncated"):
        decode(data[: int(len(data) * keep)])


def test_jpeg_missing_only_its_eoi_marker_is_tolerated(rng):
    data = _jpeg(rng, (240, 320))
    assert data.endswith(b"\xff\xd9")
    assert decode(data[:-2]).luma.shape == (240, 320)


def test_memory_budget_is_checked_before_decoding(rng, monkeypatch):
    dec = sys.modules["lishield_guard.decode"]  # the package's `decode` is the function

    data = _jpeg(rng, (600, 800))
    calls = []
    monkeypatch.setattr(dec, "_decode_pixels", lambda *a, **k: calls.append(1))
    with pytest.raises(ImageTooLargeError, match="max_decode_bytes"):
        decode(data, limits=Limits(max_decode_bytes=dec.DECODE_BASE_BYTES + 600 * 800))
    assert not calls  # refused from the header alone
    monkeypatch.undo()
    png = _encode(Image.new("L", (800, 600)), "PNG")
    with pytest.raises(ImageTooLargeError, match="max_decode_bytes"):  # Pillow path too
        decode(png, limits=Limits(max_decode_bytes=dec.DECODE_BASE_BYTES + 600 * 800))


def test_memory_budget_counts_dct_downscaling(rng):
    dec = sys.modules["lishield_guard.decode"]  # the package's `decode` is the function

    data = _jpeg(rng, (4000, 200))
    budget = dec.DECODE_BASE_BYTES + 4000 * 200 * dec.FAST_JPEG_BYTES_PER_PIXEL // 2
    with pytest.raises(ImageTooLargeError):
        decode(data, limits=Limits(max_decode_bytes=budget))
    d = decode(data, limits=Limits(max_decode_bytes=budget), max_rows=2000)
    assert d.row_scale == 2 and d.luma.shape == (2000, 100)


@pytest.mark.parametrize("shape", [(65000, 1), (6200, 17), (4000, 3), (3073, 9)])
def test_narrow_tall_jpegs_decode_at_reduced_scale(rng, shape):
    d = decode(_jpeg(rng, shape), max_rows=1536)
    s = round(d.row_scale)
    assert s in (1, 2, 4, 8)
    assert d.luma.shape == (-(-shape[0] // s), -(-shape[1] // s))
    # decodable, but 1-17 pixels across cannot fill the column blocks: undetermined, not clean
    v = detect(_jpeg(rng, shape))
    assert v.status == "undetermined" and "pixels long" in v.undetermined


def test_fifo_and_device_paths_are_refused_without_reading(tmp_path):
    import os
    import threading

    fifo = tmp_path / "x.jpg"
    os.mkfifo(fifo)
    out = []
    t = threading.Thread(target=lambda: out.append(pytest.raises(
        SpecialFileError, decode, str(fifo))), daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive(), "decoding a FIFO blocked"
    assert "not a regular file" in str(out[0].value)
    assert out[0].value.code == "special_member"  # the code scan records for a FIFO
    with pytest.raises(SpecialFileError, match="not a regular file"):
        decode("/dev/zero")


def test_the_default_profile_decodes_a_colour_jpeg_once_when_an_rgb_spec_is_configured():
    """With an RGB spec configured every ordinary photo needs its colour planes, so they come
    from the first decode; with mono specs only the colour planes are never decoded."""
    from dataclasses import replace

    import cv2
    from skimage import data

    from lishield_guard import default_config
    from lishield_guard.profiles.detect import decode_for

    ok, buf = cv2.imencode(".jpg", data.coffee()[:, :, ::-1])
    assert ok
    base = default_config()  # the cascade decodes colour only when an RGB spec needs it
    cfg = replace(base, detector=base.detector.replace(profile="cascade"))
    assert any(s.is_rgb for p in cfg.policies for s in p.specs)
    both = decode_for(buf.tobytes(), cfg)
    assert both._rgb is not None and both.rgb().shape == (*both.luma.shape, 3)
    mono = [replace(p, specs=tuple(s for s in p.specs if not s.is_rgb)) for p in cfg.policies]
    luma_only = decode_for(buf.tobytes(), replace(cfg, policies=tuple(mono)))
    assert luma_only._rgb is None
    assert np.abs(luma_only.luma.astype(int) - both.luma.astype(int)).mean() < 0.05
