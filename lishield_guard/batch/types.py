"""The one table of media types batch work reads: names, signatures and declared media types.

`scan`, `calibrate` and `bench` list files by it, and the service describes what it accepts by
it. Each kind of media is one `MediaKind` entry of `KINDS`: a second kind (video, say) is a
second entry with its own suffixes, media types and signature test, and `kind_of_name` /
`kind_of_bytes` then tell the two apart; nothing else changes shape.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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
    "kind_of_bytes",
    "kind_of_name",
]

SNIFF_BYTES = 32  # leading bytes read to recognise a file whose name does not say what it is


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
            or (head[4:8] == b"ftyp" and head[8:12] in (b"heic", b"heix", b"heim", b"heis",
                                                         b"hevc", b"hevx", b"mif1", b"msf1",
                                                         b"avif")))


# ISO-BMFF brands of still images (HEIF, AVIF): an ftyp box with one of these is a photo
_IMAGE_BRANDS = (b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1",
                 b"avif", b"avis")


def is_video_bytes(head: bytes) -> bool:
    """True when leading bytes start an MP4/MOV (an ``ftyp`` box of a brand other than a
    still image's) or a Matroska/WebM container.

    Examples
    --------
    >>> is_video_bytes(b"\\0\\0\\0\\x20ftypisom"), is_video_bytes(b"\\0\\0\\0\\x18ftypheic")
    (True, False)
    """
    return ((head[4:8] == b"ftyp" and head[8:12] not in _IMAGE_BRANDS)
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
    """

    name: str
    suffixes: tuple[str, ...]
    media_types: tuple[str, ...]
    sniff: Callable[[bytes], bool]

    def has_name(self, name: str) -> bool:
        """True when ``name`` ends with one of `suffixes` (case-insensitive)."""
        return name.lower().endswith(self.suffixes)


IMAGE = MediaKind(
    "image",
    suffixes=(".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".tif", ".tiff", ".webp", ".bmp", ".gif",
              ".heic", ".heif"),
    media_types=("image/jpeg", "image/png", "image/tiff", "image/webp", "image/bmp", "image/gif",
                 "image/heic", "image/heif"),
    sniff=is_image_bytes)

VIDEO = MediaKind(
    "video",
    suffixes=(".mp4", ".m4v", ".mov", ".webm", ".mkv"),
    media_types=("video/mp4", "video/quicktime", "video/webm", "video/x-matroska",
                 "video/x-m4v"),
    sniff=is_video_bytes)

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


def kind_of_name(name: str, kinds: tuple[MediaKind, ...] = KINDS) -> MediaKind | None:
    """The kind whose suffix ``name`` ends with, or None.

    Examples
    --------
    >>> kind_of_name("A.JFIF").name, kind_of_name("clip.MOV").name, kind_of_name("notes.txt")
    ('image', 'video', None)
    """
    return next((k for k in kinds if k.has_name(name)), None)


def kind_of_bytes(head: bytes, kinds: tuple[MediaKind, ...] = KINDS) -> MediaKind | None:
    """The kind whose signature the leading bytes carry, or None."""
    return next((k for k in kinds if k.sniff(head)), None)
