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
    "MediaKind",
    "is_image_bytes",
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

#: Every kind batch work reads, in the order they are tried.
KINDS: tuple[MediaKind, ...] = (IMAGE,)

#: Names found in folders and archives that are read without sniffing their bytes.
IMAGE_SUFFIXES = IMAGE.suffixes
#: Image types the decoder reads, as declared media types.
IMAGE_MEDIA_TYPES = IMAGE.media_types


def kind_of_name(name: str, kinds: tuple[MediaKind, ...] = KINDS) -> MediaKind | None:
    """The kind whose suffix ``name`` ends with, or None.

    Examples
    --------
    >>> kind_of_name("A.JFIF").name, kind_of_name("notes.txt")
    ('image', None)
    """
    return next((k for k in kinds if k.has_name(name)), None)


def kind_of_bytes(head: bytes, kinds: tuple[MediaKind, ...] = KINDS) -> MediaKind | None:
    """The kind whose signature the leading bytes carry, or None."""
    return next((k for k in kinds if k.sniff(head)), None)
