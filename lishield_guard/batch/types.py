"""The media kinds registry: what each kind of media is, how to tell it, and how to screen it.

Each kind is one `MediaKind` entry of `KINDS`: its file names, declared media types and
signature test (`kind_of_name`, `kind_of_bytes`, `kind_of_source` tell kinds apart), its
detect function, its size caps (in the config and in the service's settings) and its time
budget (a service setting). The verdict a kind's detect returns carries the kind's typed
evidence, which draws the kind's figure (`lishield_guard.verdict.Evidence.figure`). `scan`,
`calibrate` and `bench` list files by this table, the service sniffs, caps and times uploads
by it, and `lishield_guard.video.detect_media` screens by it: a new kind is one entry here and
its own modules. Detect functions are named by module path and imported on first use, so this
module stays at the bottom of the package.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "IMAGE",
    "IMAGE_MEDIA_TYPES",
    "IMAGE_SUFFIXES",
    "KINDS",
    "SNIFF_BYTES",
    "VIDEO",
    "VIDEO_MEDIA_TYPES",
    "VIDEO_SUFFIXES",
    "MediaKind",
    "is_image_bytes",
    "is_video_bytes",
    "kind_named",
    "kind_of_bytes",
    "kind_of_name",
    "kind_of_source",
]

SNIFF_BYTES = 32  # leading bytes read to recognise a file whose name does not say what it is

# ISO-BMFF brands of still images (HEIF, AVIF; AVIS is an AVIF image sequence): an ftyp box
# with one of these is a photo, never a video (the one brand table of both signature tests)
IMAGE_BRANDS = (b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1",
                b"avif", b"avis")


def is_image_bytes(head: bytes) -> bool:
    """True when leading bytes carry the signature of an image format the decoder reads.

    Examples
    --------
    >>> is_image_bytes(b"\\xff\\xd8\\xff\\xe0"), is_image_bytes(b"# notes")
    (True, False)
    """
    return (head.startswith((b"\xff\xd8\xff", b"\x89PNG\r\n\x1a\n", b"GIF87a", b"GIF89a",
                             b"II*\x00", b"MM\x00*", b"BM"))
            or (head[:4] == b"RIFF" and head[8:12] == b"WEBP")
            or (head[4:8] == b"ftyp" and head[8:12] in IMAGE_BRANDS))


def is_video_bytes(head: bytes) -> bool:
    """True when leading bytes start an MP4/MOV (an ``ftyp`` box of a brand other than a
    still image's) or a Matroska/WebM container.

    Examples
    --------
    >>> is_video_bytes(b"\\0\\0\\0\\x20ftypisom"), is_video_bytes(b"\\0\\0\\0\\x18ftypheic")
    (True, False)
    """
    return ((head[4:8] == b"ftyp" and head[8:12] not in IMAGE_BRANDS)
            or head[:4] == b"\x1a\x45\xdf\xa3")


@dataclass(frozen=True)
class MediaKind:
    """One kind of media that batch work reads.

    Attributes
    ----------
    name : str
        ``"image"`` (the key a record or a listing carries).
    suffixes : tuple of str
        Lower-case file name endings read without sniffing their bytes.
    media_types : tuple of str
        Declared types (HTTP ``Content-Type``, OpenAPI); the bytes still decide.
    sniff : callable
        ``sniff(head) -> bool`` on the first `SNIFF_BYTES` bytes: the kind's signature.
    detector : str
        ``"module:function"`` of its detect function, ``fn(source, config) -> Verdict``.
    config_cap : str
        Dotted attribute of `AppConfig` holding its size cap in bytes.
    upload_cap, time_budget : str
        The service settings that cap one upload (bytes) and one detection (seconds).
    """

    name: str
    suffixes: tuple[str, ...]
    media_types: tuple[str, ...]
    sniff: Callable[[bytes], bool]
    detector: str
    config_cap: str
    upload_cap: str
    time_budget: str

    def has_name(self, name: str) -> bool:
        """True when ``name`` ends with one of `suffixes` (case-insensitive)."""
        return name.lower().endswith(self.suffixes)

    def detect(self, source, config=None):
        """Screen ``source`` as this kind (its detect function, imported on first use)."""
        module, _, fn = self.detector.partition(":")
        return getattr(importlib.import_module(module), fn)(source, config)

    def cap_bytes(self, config) -> int:
        """The config's size cap of this kind (``config_cap``), in bytes."""
        value = config
        for part in self.config_cap.split("."):
            value = getattr(value, part)
        return int(value)


IMAGE = MediaKind(
    "image",
    suffixes=(".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".tif", ".tiff", ".webp", ".bmp", ".gif",
              ".heic", ".heif"),
    media_types=("image/jpeg", "image/png", "image/tiff", "image/webp", "image/bmp", "image/gif",
                 "image/heic", "image/heif"),
    sniff=is_image_bytes, detector="lishield_guard.detector:detect",
    config_cap="limits.max_bytes", upload_cap="max_upload_bytes",
    time_budget="detect_timeout_s")

VIDEO = MediaKind(
    "video",
    suffixes=(".mp4", ".m4v", ".mov", ".webm", ".mkv"),
    media_types=("video/mp4", "video/quicktime", "video/webm", "video/x-matroska",
                 "video/x-m4v"),
    sniff=is_video_bytes, detector="lishield_guard.video:detect_video",
    config_cap="video.limits.max_bytes", upload_cap="max_video_upload_bytes",
    time_budget="video_timeout_s")

#: Every kind batch work reads, in the order they are tried (an image brand of ISO-BMFF is an
#: image before it could be a video).
KINDS: tuple[MediaKind, ...] = (IMAGE, VIDEO)

#: Names found in folders and archives that are read without sniffing their bytes.
IMAGE_SUFFIXES = IMAGE.suffixes
#: Image types the decoder reads, as declared media types.
IMAGE_MEDIA_TYPES = IMAGE.media_types
#: Video file name endings and declared media types (`lishield_guard.video`).
VIDEO_SUFFIXES = VIDEO.suffixes
VIDEO_MEDIA_TYPES = VIDEO.media_types


def kind_of_name(name: str, kinds: tuple[MediaKind, ...] | None = None) -> MediaKind | None:
    """The kind whose suffix ``name`` ends with, or None.

    Examples
    --------
    >>> kind_of_name("A.JFIF").name, kind_of_name("clip.MOV").name, kind_of_name("notes.txt")
    ('image', 'video', None)
    """
    return next((k for k in (KINDS if kinds is None else kinds) if k.has_name(name)), None)


def kind_of_bytes(head: bytes, kinds: tuple[MediaKind, ...] | None = None) -> MediaKind | None:
    """The kind whose signature the leading bytes carry, or None (``kinds``: default `KINDS`,
    in order)."""
    return next((k for k in (KINDS if kinds is None else kinds) if k.sniff(head)), None)


def kind_named(name: str, kinds: tuple[MediaKind, ...] | None = None) -> MediaKind:
    """The kind called ``name`` (``"image"``, ``"video"``).

    Raises
    ------
    KeyError
        When no kind has that name.
    """
    kinds = KINDS if kinds is None else kinds
    for k in kinds:
        if k.name == name:
            return k
    raise KeyError(f"no media kind {name!r}; known: {', '.join(k.name for k in kinds)}")


def kind_of_source(source, kinds: tuple[MediaKind, ...] | None = None) -> MediaKind:
    """The kind to screen ``source`` as: by its first bytes (bytes, or a file's), or, for a
    file that cannot be read here, by its name; an image when nothing says otherwise (an
    array of pixels, unknown bytes: the image decoder then says what is wrong)."""
    kinds = KINDS if kinds is None else kinds
    head = None
    if isinstance(source, bytes | bytearray | memoryview):
        head = bytes(source[:SNIFF_BYTES])
    elif isinstance(source, str | os.PathLike):
        from lishield_guard.files import read_head  # never blocks on a FIFO (issue 41)

        head = read_head(source, SNIFF_BYTES)
        if head is None:
            return kind_of_name(Path(os.fspath(source)).name, kinds) or kinds[0]
    if head is None:
        return kinds[0]
    return kind_of_bytes(head, kinds) or kinds[0]
