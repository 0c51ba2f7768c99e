"""Small valid files of every supported format and a seeded byte mutator, for the decode-boundary
tests (fuzz and the same-bad-input tests across detect, scan, the Python API and HTTP)."""

from __future__ import annotations

import io
import random

import numpy as np
from PIL import Image

SHAPE_ROWS_COLS = (96, 128)
IMAGE_FORMATS = {"jpeg": ("JPEG", ".jpg"), "png": ("PNG", ".png"), "webp": ("WEBP", ".webp"),
                 "tiff": ("TIFF", ".tif"), "gif": ("GIF", ".gif"), "heic": ("HEIF", ".heic")}
VIDEO_FORMATS = {"mp4": ("mp4", "h264", ".mp4"), "webm": ("webm", "libvpx", ".webm")}
SUFFIX = {**{k: v[1] for k, v in IMAGE_FORMATS.items()},
          **{k: v[2] for k, v in VIDEO_FORMATS.items()}}


def _frame(seed: int) -> np.ndarray:
    """A smooth scene with faint row stripes and a little noise (small files, real content)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:SHAPE_ROWS_COLS[0], 0:SHAPE_ROWS_COLS[1]]
    base = 90 + 60 * np.sin(cols / 17.0 + seed) + 20 * np.sin(2 * np.pi * rows / 11.0)
    rgb = np.stack([base, base * 0.9 + 10, base * 0.8 + 20], axis=2)
    return np.clip(rgb + rng.normal(0, 3, rgb.shape), 0, 255).astype(np.uint8)


def image_bytes(fmt: str, seed: int = 0) -> bytes:
    """One valid image of ``fmt`` (a key of `IMAGE_FORMATS`)."""
    if fmt == "heic":
        import pillow_heif

        pillow_heif.register_heif_opener()
    buf = io.BytesIO()
    Image.fromarray(_frame(seed)).save(buf, IMAGE_FORMATS[fmt][0])
    return buf.getvalue()


def video_bytes(fmt: str, seed: int = 0, n_frames: int = 8) -> bytes:
    """One valid clip of ``fmt`` (a key of `VIDEO_FORMATS`): ``n_frames`` frames at 30 fps."""
    import av

    container, codec, _ = VIDEO_FORMATS[fmt]
    buf = io.BytesIO()
    with av.open(buf, "w", format=container) as out:
        stream = out.add_stream(codec, rate=30)
        stream.height, stream.width = SHAPE_ROWS_COLS
        stream.pix_fmt = "yuv420p"
        for i in range(n_frames):
            frame = av.VideoFrame.from_ndarray(_frame(seed + i), format="rgb24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return buf.getvalue()


def sample_bytes(fmt: str, seed: int = 0) -> bytes:
    """A valid file of any supported format (image or video)."""
    return video_bytes(fmt, seed) if fmt in VIDEO_FORMATS else image_bytes(fmt, seed)


def mutate(data: bytes, seed: int) -> bytes:
    """``data`` with a few bytes changed, a run zeroed, bytes inserted or the end cut, by a
    seeded draw; half of the edits fall in the first 512 bytes, where the headers are."""
    rng = random.Random(seed)
    out = bytearray(data)

    def where() -> int:
        limit = min(len(out), 512) if rng.random() < 0.5 else len(out)
        return rng.randrange(max(limit, 1))

    kind = rng.choice(("bytes", "bytes", "bytes", "zero", "insert", "cut"))
    if kind == "bytes":
        for _ in range(rng.randint(1, 8)):
            out[where()] = rng.randrange(256)
    elif kind == "zero":
        at, n = where(), rng.randint(2, 64)
        out[at:at + n] = bytes(len(out[at:at + n]))
    elif kind == "insert":
        at = where()
        out[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
    else:
        del out[rng.randrange(16, max(len(out), 17)):]
    return bytes(out)
