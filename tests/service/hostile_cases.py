"""A hostile-input corpus for the screening service (issue #22): image bombs, truncations,
lies about size and format, and plain junk. Shared by the tests and benchmarks/soak_service.py."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
from PIL import Image

__all__ = ["BOMB_CASES", "hostile_bodies", "jpeg_declaring"]


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return (struct.pack(">I", len(body)) + kind + body
            + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))


def png_declaring(n_cols: int, n_rows: int, *, depth: int = 8, colour: int = 0) -> bytes:
    """A PNG whose IHDR declares n_cols x n_rows (valid CRCs, a tiny IDAT)."""
    ihdr = struct.pack(">IIBBBBB", n_cols, n_rows, depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
            + _png_chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + _png_chunk(b"IEND", b""))


def jpeg_declaring(n_cols: int, n_rows: int, *, progressive: bool = False) -> bytes:
    """A complete 16x16 JPEG whose SOF header claims n_cols x n_rows (under 1 kB)."""
    buf = io.BytesIO()
    Image.new("RGB", (16, 16), (128, 90, 60)).save(buf, "JPEG", quality=90,
                                                    progressive=progressive)
    data = bytearray(buf.getvalue())
    i = data.find(b"\xff\xc2" if progressive else b"\xff\xc0")
    struct.pack_into(">HH", data, i + 5, n_rows, n_cols)
    return bytes(data)


def _encode(arr: np.ndarray | Image.Image, fmt: str, **kw) -> bytes:
    img = arr if isinstance(arr, Image.Image) else Image.fromarray(arr)
    buf = io.BytesIO()
    img.save(buf, fmt, **kw)
    return buf.getvalue()


def _noise(shape, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


#: (name, bytes) of decompression and memory bombs: small files that declare huge images.
BOMB_CASES: list[tuple[str, bytes]] = [
    ("jpeg_10000x10000_in_700_bytes", jpeg_declaring(10_000, 10_000)),
    ("jpeg_65535x65535", jpeg_declaring(65_535, 65_535)),
    ("progressive_jpeg_10000x10000", jpeg_declaring(10_000, 10_000, progressive=True)),
    ("jpeg_65000x1", jpeg_declaring(65_000, 1)),
    ("png_declaring_100000x100000", png_declaring(100_000, 100_000)),
    ("png_declaring_9000x9000_rgb16", png_declaring(9_000, 9_000, depth=16, colour=2)),
    ("png_6000x6000_blank", _encode(Image.new("L", (6000, 6000)), "PNG", optimize=True)),
    ("gif_declaring_65535x65535", b"GIF89a" + struct.pack("<HH", 65535, 65535)
     + b"\x00\x00\x00,\x00\x00\x00\x00\xff\xff\xff\xff\x00\x02\x02D\x01\x00;"),
]


def hostile_bodies() -> list[tuple[str, bytes]]:
    """(name, body) of every hostile input the service must answer without a 5xx."""
    jpeg = _encode(_noise((480, 640, 3)), "JPEG", quality=90)
    png = _encode(_noise((200, 300)), "PNG")
    cases: list[tuple[str, bytes]] = [
        ("empty", b""),
        ("one_byte", b"\xff"),
        ("random_4k", np.random.default_rng(1).bytes(4096)),
        ("text", b"hello, this is not an image\n" * 20),
        ("html", b"<html><body><img src=x onerror=alert(1)></body></html>"),
        ("json", b'{"file": "x.jpg"}'),
        ("pdf_header", b"%PDF-1.7\n%\xe2\xe3\xcf\xd3\n1 0 obj\n"),
        ("zip_header", b"PK\x03\x04" + b"\x00" * 100),
        ("jpeg_magic_only", b"\xff\xd8\xff"),
        ("jpeg_soi_eoi", b"\xff\xd8\xff\xd9"),
        ("png_magic_only", b"\x89PNG\r\n\x1a\n"),
        ("png_bad_crc", png[:20] + b"\x00\x00\x00\x00" + png[24:]),
        ("png_zero_size", png_declaring(0, 0)),
        ("gif_header_only", b"GIF89a\x10\x00\x10\x00"),
        ("tiff_bogus_ifd", b"II*\x00\xff\xff\xff\x7f"),
        ("bmp_header_only", b"BM" + b"\x00" * 50),
        ("webp_header_only", b"RIFF\x10\x00\x00\x00WEBPVP8 "),
        ("heic_ftyp_only", b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic"),
        ("tiny_1x1_png", _encode(_noise((1, 1)), "PNG")),
        ("small_40x40_png_undetermined", _encode(_noise((40, 40)), "PNG")),
        ("narrow_1x65000_jpeg", _encode(_noise((65000, 1)), "JPEG")),
        ("narrow_17x6200_jpeg", _encode(_noise((6200, 17)), "JPEG")),
        ("wide_6200x17_jpeg", _encode(_noise((17, 6200)), "JPEG")),
        ("png_16bit", _encode(Image.fromarray(_noise((100, 100)).astype(np.uint16) * 257),
                              "PNG")),
        ("tiff_float_nan", _encode(Image.fromarray(np.full((80, 80), np.nan, np.float32)),
                                   "TIFF")),
        ("cmyk_jpeg", _encode(Image.fromarray(_noise((120, 160, 3))).convert("CMYK"), "JPEG")),
        ("gif_two_frames", _gif_two_frames()),
        ("jpeg_missing_eoi", jpeg[:-2]),
        ("jpeg_trailing_garbage", jpeg + b"\x00garbage" * 100),
        *[(f"jpeg_cut_at_{int(k * 100)}pct", jpeg[: int(len(jpeg) * k)])
          for k in (0.05, 0.5, 0.9, 0.99)],
        *[(f"png_cut_at_{int(k * 100)}pct", png[: int(len(png) * k)]) for k in (0.5, 0.99)],
        ("jpeg_bit_flips", _flip(jpeg)),
        *BOMB_CASES,
    ]
    return cases


def _gif_two_frames() -> bytes:
    frames = [Image.fromarray(_noise((90, 90), s)).convert("P") for s in (1, 2)]
    buf = io.BytesIO()
    frames[0].save(buf, "GIF", save_all=True, append_images=frames[1:])
    return buf.getvalue()


def _flip(data: bytes) -> bytes:
    b = bytearray(data)
    rng = np.random.default_rng(3)
    for i in rng.integers(600, len(b), 40):
        b[int(i)] ^= 0x55
    return bytes(b)
