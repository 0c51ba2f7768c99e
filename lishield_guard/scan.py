"""Batch scan: enumerate files, folders, lists and archives; detect in parallel; build records."""

from __future__ import annotations

import bz2
import csv
import fnmatch
import gzip
import io
import json
import lzma
import os
import re
import stat
import tarfile
import threading
import time
import warnings
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lishield_guard.config import AppConfig
from lishield_guard.errors import LishieldError
from lishield_guard.threads import one_thread_per_worker

__all__ = [
    "ARCHIVE_SUFFIXES",
    "IMAGE_SUFFIXES",
    "RECORD_FIELDS",
    "STATUSES",
    "RecordWriter",
    "ScanItem",
    "build_record",
    "escape_name",
    "filter_new",
    "format_record",
    "is_image_bytes",
    "iter_items",
    "read_done_keys",
    "record_status",
    "run_scan",
    "scan_source",
    "tally_file",
    "unsafe_member_reason",
]

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")
#: Names found in folders and archives that are scanned without sniffing their bytes.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".jpe", ".jfif", ".png", ".tif", ".tiff", ".webp", ".bmp",
                  ".gif", ".heic", ".heif")
SNIFF_BYTES = 32  # leading bytes read to recognise an image whose name does not say so
TAR_TAIL_MAX_BYTES = 64 * 1024 * 1024  # decompressed bytes after a tar's end read to reach
#                                        the compressed stream's own end and checksum

#: Record fields in output order (the DESIGN.md scan contract plus the resume key).
#: ``status`` is "protected", "clean", "undetermined" (the detector could not look; reason in
#: ``undetermined_reason``, ``protected`` null) or "error" (``error`` and ``code`` say why).
#: ``path_escaped`` is true when ``path`` was escaped to be valid one-line UTF-8: then ``\\``
#: stands for a backslash and ``\xNN`` for a byte that is a control character or not UTF-8.
#: ``reason`` is the verdict's reason in words and ``skipped`` its skipped-work notes (a list;
#: joined by "; " in CSV); both null for an error. They come last so that a CSV written
#: before them keeps its columns on resume.
RECORD_FIELDS = ("path", "status", "protected", "policy", "matches", "required", "score",
                 "error", "code", "undetermined_reason", "size_bytes", "elapsed_ms", "key",
                 "path_escaped", "reason", "skipped")
STATUSES = ("protected", "clean", "undetermined", "error")

# Stable codes of the scanner's own skip reasons (detector errors keep their LishieldError.code).
CODE_UNSAFE_NAME = "unsafe_member_name"
CODE_LINK_MEMBER = "link_member"
CODE_SPECIAL_MEMBER = "special_member"
CODE_ENCRYPTED_MEMBER = "encrypted_member"
CODE_CORRUPT_MEMBER = "corrupt_member"
CODE_UNREADABLE_ARCHIVE = "unreadable_archive"
CODE_TRUNCATED_ARCHIVE = "truncated_archive"
CODE_NOT_FOUND = "not_found"
CODE_READ_ERROR = "read_error"
CODE_PAYLOAD_TOO_LARGE = "payload_too_large"
CODE_INTERNAL = "internal_error"
CODE_WORKER_CRASHED = "worker_crashed"

_NEEDS_ESCAPE = re.compile(r"[\x00-\x1f\x7f\ud800-\udfff]")
_ESCAPED = re.compile(r"[\\\x00-\x1f\x7f\ud800-\udfff]")


def _escape_char(m: re.Match) -> str:
    c = m.group()
    if c == "\\":
        return "\\\\"
    code = ord(c)
    if 0xDC80 <= code <= 0xDCFF:  # a byte that was not UTF-8 (os.fsdecode's surrogateescape)
        return f"\\x{code - 0xDC00:02x}"
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def escape_name(name: str) -> tuple[str, bool]:
    """A file or member name as one line of valid UTF-8, and whether it had to be escaped.

    Names that are printable UTF-8 are returned as they are. Otherwise every backslash is
    doubled, control characters become ``\\xNN`` and bytes that are not UTF-8 (held as
    surrogate escapes by ``os.fsdecode``, ``os.scandir`` and ``tarfile``) become ``\\xNN`` of
    the original byte, so the name can be recovered exactly.

    Examples
    --------
    >>> escape_name("a.jpg")
    ('a.jpg', False)
    >>> escape_name(b"b\\xff\\n.jpg".decode("utf-8", "surrogateescape"))
    ('b\\\\xff\\\\x0a.jpg', True)
    """
    if not _NEEDS_ESCAPE.search(name):
        return name, False
    return _ESCAPED.sub(_escape_char, name), True


def _printable(text: str) -> str:
    """`escape_name` without the flag (resume keys)."""
    return escape_name(text)[0]


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


def _has_image_name(name: str) -> bool:
    return name.lower().endswith(IMAGE_SUFFIXES)


def _is_hidden(label: str) -> bool:
    return any(part.startswith(".") and part not in (".", "..")
               for part in re.split(r"[/!\\]", label))


@dataclass(frozen=True)
class ScanItem:
    """One input of a scan: a file, an archive member, or something recorded as skipped.

    Attributes
    ----------
    label : str
        Output ``path``: the file path as found, or ``"archive.zip!dir/a.jpg"`` for a member.
    key : str
        Resume key: ``abspath|size|mtime_ns`` for files, ``abspath!member|crc32`` for members.
    size_bytes : int or None
        Encoded size in bytes (None when unknown).
    source : str, bytes or None
        What the worker decodes: a path for files, the bytes of an archive member, or None
        when the item is recorded without detection (see ``error``).
    error, code : str or None
        Skip reason and its stable code when ``source`` is None.
    escaped : bool
        True when ``label`` had to be escaped (see `escape_name`).
    """

    label: str
    key: str
    size_bytes: int | None
    source: str | bytes | None
    error: str | None = None
    code: str | None = None
    escaped: bool = False


def is_archive(name: str) -> bool:
    """True when a file name ends with one of `ARCHIVE_SUFFIXES` (case-insensitive)."""
    low = name.lower()
    return any(low.endswith(s) for s in ARCHIVE_SUFFIXES)


def unsafe_member_reason(name: str) -> str | None:
    """Why an archive member name is hostile, or None when it is a plain relative name.

    Examples
    --------
    >>> unsafe_member_reason("../x.jpg")
    'parent-directory component in member name'
    >>> unsafe_member_reason("dir/a.jpg") is None
    True
    """
    if not name:
        return "empty member name"
    if "\x00" in name:
        return "NUL character in member name"
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        return "absolute member name"
    if ".." in norm.split("/"):
        return "parent-directory component in member name"
    return None


def _selected(label: str, include: tuple[str, ...], exclude: tuple[str, ...], *,
              leaf: bool = True) -> bool:
    low = label.lower()
    name = re.split(r"[/!\\]", low)[-1]

    def hit(pats: tuple[str, ...]) -> bool:  # case-insensitive: *.jpg matches X.JPG
        return any(fnmatch.fnmatchcase(low, p.lower()) or fnmatch.fnmatchcase(name, p.lower())
                   for p in pats)

    if exclude and hit(exclude):
        return False
    return not (leaf and include and not hit(include))


def _file_key(path: str, st: os.stat_result) -> str:
    return f"{_printable(os.path.abspath(path))}|{st.st_size}|{st.st_mtime_ns}"


def _file_item(path: str) -> ScanItem:
    label, esc = escape_name(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return ScanItem(label, f"{_printable(os.path.abspath(path))}|missing", None, None,
                        "no such file", CODE_NOT_FOUND, esc)
    except OSError as exc:
        return ScanItem(label, f"{_printable(os.path.abspath(path))}|unreadable", None, None,
                        f"cannot stat: {exc.strerror}", CODE_READ_ERROR, esc)
    if not stat.S_ISREG(st.st_mode):
        return ScanItem(label, _file_key(path, st), None, None,
                        f"skipped: not a regular file ({_kind(st.st_mode)}; never read)",
                        CODE_SPECIAL_MEMBER, esc)
    return ScanItem(label, _file_key(path, st), st.st_size, path, escaped=esc)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "folder"), (stat.S_ISFIFO, "FIFO"),
                       (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
                       (stat.S_ISSOCK, "socket")):
        if test(mode):
            return name
    return "special file"


def _sniff_file(path: str) -> bool:
    """Whether a regular file's first bytes are an image signature (non-blocking open)."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return True  # let the scan record why it cannot be read
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return True  # recorded as special
        return is_image_bytes(os.read(fd, SNIFF_BYTES))
    except OSError:
        return True
    finally:
        os.close(fd)


def _member_label(base: str, base_esc: bool, name: str) -> tuple[str, bool]:
    esc_name, esc = escape_name(name)
    return f"{base}!{esc_name}", base_esc or esc


class _Selector:
    """Which names found in folders and archives are scanned.

    ``exclude`` drops; ``include`` (when given) alone decides; otherwise a name with an image
    suffix that is not hidden is scanned, and any other regular file or member only when its
    first bytes are an image signature (sidecars, ``.DS_Store``, AppleDouble ``._x.jpg`` and
    ``manifest.jsonl`` are ignored, an image without a suffix is not). Matching is
    case-insensitive.
    """

    def __init__(self, include: tuple[str, ...], exclude: tuple[str, ...],
                 on_ignored: Callable[[str], None] | None) -> None:
        self.include, self.exclude, self.on_ignored = include, exclude, on_ignored

    def excluded(self, label: str) -> bool:
        return bool(self.exclude) and not _selected(label, (), self.exclude, leaf=False)

    def by_name(self, label: str) -> bool | None:
        """True: scan; False: drop; None: decided by the bytes."""
        if not _selected(label, (), self.exclude, leaf=False):
            return False
        if self.include:
            return _selected(label, self.include, (), leaf=True)
        if _has_image_name(label) and not _is_hidden(label):
            return True
        return None

    def ignore(self, label: str) -> None:
        if self.on_ignored is not None:
            self.on_ignored(label)


def _iter_zip(path: str, *, max_bytes: int, sel: _Selector,
              read_data: bool) -> Iterator[ScanItem]:
    base, base_esc = escape_name(path)
    abs_base = _printable(os.path.abspath(path))
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename
            if info.is_dir():
                continue
            label, esc = _member_label(base, base_esc, name)
            wanted = sel.by_name(label)
            if wanted is False:
                continue
            key = f"{abs_base}!{_printable(name)}|{info.CRC:08x}"
            mode = info.external_attr >> 16
            reason = unsafe_member_reason(name)
            regular = not (stat.S_ISLNK(mode) or (mode and stat.S_IFMT(mode)
                                                  and not stat.S_ISREG(mode)))
            if wanted is None and (reason or not regular or info.flag_bits & 0x1
                                   or info.file_size > max_bytes or not read_data):
                sel.ignore(label)  # not an image by name, and not read to tell: ignored
                continue
            if reason:
                yield ScanItem(label, key, info.file_size, None, f"skipped: {reason}",
                               CODE_UNSAFE_NAME, esc)
            elif stat.S_ISLNK(mode):
                yield ScanItem(label, key, info.file_size, None,
                               "skipped: symbolic link member (never followed)",
                               CODE_LINK_MEMBER, esc)
            elif not regular:
                yield ScanItem(label, key, info.file_size, None,
                               "skipped: not a regular file member", CODE_SPECIAL_MEMBER, esc)
            elif info.flag_bits & 0x1:
                yield ScanItem(label, key, info.file_size, None, "skipped: encrypted member",
                               CODE_ENCRYPTED_MEMBER, esc)
            elif info.file_size > max_bytes:
                yield ScanItem(label, key, info.file_size, None,
                               f"member has {info.file_size} bytes > max_bytes={max_bytes}",
                               CODE_PAYLOAD_TOO_LARGE, esc)
            elif not read_data:
                yield ScanItem(label, key, info.file_size, None, escaped=esc)
            else:
                try:
                    with zf.open(info) as fh:
                        data = fh.read(max_bytes + 1)
                except (zipfile.BadZipFile, zlib.error, OSError, EOFError,
                        NotImplementedError, RuntimeError) as exc:
                    yield ScanItem(label, key, info.file_size, None,
                                   f"cannot read member: {exc}", CODE_CORRUPT_MEMBER, esc)
                    continue
                if wanted is None and not is_image_bytes(data[:SNIFF_BYTES]):
                    sel.ignore(label)
                    continue
                if len(data) > max_bytes:
                    yield ScanItem(label, key, len(data), None,
                                   f"member has > max_bytes={max_bytes} bytes",
                                   CODE_PAYLOAD_TOO_LARGE, esc)
                    continue
                yield ScanItem(label, key, len(data), data, escaped=esc)


class _TruncatedArchiveError(Exception):
    """A tar stream ended without its end-of-archive blocks, or a compressed stream early."""


def _tar_info_class():
    """A TarInfo subclass that notes whether the all-zero end-of-archive block was read."""

    class _EndAware(tarfile.TarInfo):
        end_seen = False

        @classmethod
        def frombuf(cls, buf, encoding, errors):
            if len(buf) == tarfile.BLOCKSIZE and buf.count(tarfile.NUL) == tarfile.BLOCKSIZE:
                cls.end_seen = True
            return super().frombuf(buf, encoding, errors)

    return _EndAware


def _open_decompressed(raw):
    """The decompressed stream of a tar file: gzip, bzip2 and xz readers verify their own end
    and checksum (EOFError on a cut file); plain tars are read as they are."""
    head = raw.read(6)
    raw.seek(0)
    if head.startswith(b"\x1f\x8b"):
        return gzip.GzipFile(fileobj=raw, mode="rb")
    if head.startswith(b"BZh"):
        return bz2.BZ2File(raw, mode="rb")
    if head.startswith(b"\xfd7zXZ\x00"):
        return lzma.LZMAFile(raw, mode="rb")
    return raw


def _iter_tar(path: str, *, max_bytes: int, sel: _Selector,
              read_data: bool) -> Iterator[ScanItem]:
    base, base_esc = escape_name(path)
    abs_base = _printable(os.path.abspath(path))
    info_cls = _tar_info_class()
    # Stream mode: headers and data are read once, in order; nothing is ever extracted.
    with open(path, "rb") as raw, _open_decompressed(raw) as stream, \
            tarfile.open(fileobj=stream, mode="r|", tarinfo=info_cls) as tf:
        for m in tf:
            if m.isdir():
                continue
            label, esc = _member_label(base, base_esc, m.name)
            wanted = sel.by_name(label)
            if wanted is False:
                continue
            key_stem = f"{abs_base}!{_printable(m.name)}"
            reason = unsafe_member_reason(m.name)
            if wanted is None and (reason or not m.isfile() or m.size > max_bytes
                                   or not read_data):
                sel.ignore(label)
                continue
            if reason:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"skipped: {reason}", CODE_UNSAFE_NAME, esc)
            elif m.issym() or m.islnk():
                kind = "symbolic" if m.issym() else "hard"
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"skipped: {kind} link member (never followed)",
                               CODE_LINK_MEMBER, esc)
            elif not m.isfile():
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               "skipped: not a regular file member", CODE_SPECIAL_MEMBER, esc)
            elif m.size > max_bytes:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"member has {m.size} bytes > max_bytes={max_bytes}",
                               CODE_PAYLOAD_TOO_LARGE, esc)
            elif not read_data:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None, escaped=esc)
            else:
                fh = tf.extractfile(m)
                data = fh.read() if fh is not None else b""
                if len(data) != m.size:
                    raise _TruncatedArchiveError(f"member {label!r} is cut after {len(data)} "
                                                 f"of {m.size} bytes")
                if wanted is None and not is_image_bytes(data[:SNIFF_BYTES]):
                    sel.ignore(label)
                    continue
                yield ScanItem(label, f"{key_stem}|{zlib.crc32(data):08x}", len(data), data,
                               escaped=esc)
        if not info_cls.end_seen:
            raise _TruncatedArchiveError("the archive ends without its end-of-archive blocks")
        if stream is raw and os.fstat(raw.fileno()).st_size % tarfile.BLOCKSIZE:
            raise _TruncatedArchiveError(f"the file is not a whole number of "
                                         f"{tarfile.BLOCKSIZE}-byte tar blocks")
        if stream is not raw:  # reach the compressed stream's end: its checksum is verified
            left = TAR_TAIL_MAX_BYTES
            while left > 0 and (chunk := stream.read(min(left, 1 << 20))):
                left -= len(chunk)


def _iter_archive(path: str, **kw) -> Iterator[ScanItem]:
    label, esc = escape_name(path)
    try:
        st = os.stat(path)
        key = _file_key(path, st) + "!<archive>"
    except OSError as exc:
        yield ScanItem(label, f"{_printable(os.path.abspath(path))}|missing!<archive>", None,
                       None, f"cannot open archive: {exc.strerror}", CODE_NOT_FOUND, esc)
        return
    if not stat.S_ISREG(st.st_mode):  # a FIFO would block, a device would never end
        yield ScanItem(label, key, None, None,
                       f"skipped: not a regular file ({_kind(st.st_mode)}; never read)",
                       CODE_SPECIAL_MEMBER, esc)
        return
    opener = _iter_zip if path.lower().endswith(".zip") else _iter_tar
    try:
        yield from opener(path, **kw)
    except _TruncatedArchiveError as exc:
        yield ScanItem(label, key, st.st_size, None, f"truncated archive: {exc}",
                       CODE_TRUNCATED_ARCHIVE, esc)
    except EOFError as exc:
        yield ScanItem(label, key, st.st_size, None, f"truncated archive: {exc}",
                       CODE_TRUNCATED_ARCHIVE, esc)
    except tarfile.ReadError as exc:
        cut = "unexpected end of data" in str(exc) or "truncated" in str(exc)
        yield ScanItem(label, key, st.st_size, None,
                       f"{'truncated' if cut else 'cannot read'} archive: {exc}",
                       CODE_TRUNCATED_ARCHIVE if cut else CODE_UNREADABLE_ARCHIVE, esc)
    except (zipfile.BadZipFile, tarfile.TarError, zlib.error, OSError, ValueError,
            lzma.LZMAError) as exc:
        yield ScanItem(label, key, st.st_size, None, f"cannot read archive: {exc}",
                       CODE_UNREADABLE_ARCHIVE, esc)


def _walk(folder: str, sel: _Selector) -> Iterator[str]:
    """Files under folder, depth first, entries sorted by name; symlinked folders not entered.

    Yields archives, images (by name or by signature) and non-regular entries (recorded as
    special); other files are passed to ``sel.ignore``.
    """
    try:
        with os.scandir(folder) as it:
            entries = sorted(it, key=lambda e: e.name)
    except OSError:
        return
    for e in entries:
        if e.is_dir(follow_symlinks=False):
            if not sel.excluded(e.path):
                yield from _walk(e.path, sel)
        elif is_archive(e.name):
            if not sel.excluded(e.path):
                yield e.path
        else:
            wanted = sel.by_name(e.path)
            if wanted is None:
                try:
                    regular = e.is_file(follow_symlinks=True)
                except OSError:
                    regular = False
                wanted = not regular or _sniff_file(e.path)
                if not wanted:
                    sel.ignore(escape_name(e.path)[0])
            if wanted:
                yield e.path


def iter_items(paths: Iterable[str | Path], *, include: Iterable[str] = (),
               exclude: Iterable[str] = (), max_bytes: int = 64 * 1024 * 1024,
               read_data: bool = True,
               on_ignored: Callable[[str], None] | None = None) -> Iterator[ScanItem]:
    """Every scan input under ``paths``, lazily, in a deterministic order.

    Parameters
    ----------
    paths : iterable of str or Path
        Files, folders (walked recursively, sorted; symlinked folders not followed) and
        archives (``.zip``, ``.tar``, ``.tar.gz``/``.tgz``, ``.tar.bz2``, ``.tar.xz``).
        Only regular files (or links to them) are ever read: FIFOs, devices and sockets are
        recorded as ``special_member`` without being opened.
    include, exclude : iterable of str
        Shell globs, case-insensitive, matched against the whole label and against its last
        name. ``include`` keeps only matching names found in folders and archives (without
        it: images by suffix or by signature, see `_Selector`); ``exclude`` drops files,
        folders and archives. Paths named explicitly are never dropped by ``include``.
    max_bytes : int
        Archive members larger than this are recorded as too large without being read, in bytes.
    read_data : bool
        Read archive members (False counts inputs cheaply; ``source`` is then None).
    on_ignored : callable, optional
        Called with the label of every file or member passed over as not an image.

    Yields
    ------
    ScanItem
        Archive members carry their bytes (read one at a time, in memory, never extracted);
        hostile names, links, special members and truncated archives are yielded with
        ``source=None`` and a reason.
    """
    sel = _Selector(tuple(include), tuple(exclude), on_ignored)
    kw = {"max_bytes": max_bytes, "sel": sel, "read_data": read_data}
    for raw in paths:
        p = os.fsdecode(raw) if isinstance(raw, bytes) else str(raw)
        if os.path.isdir(p):
            for f in _walk(p, sel):
                yield from (_iter_archive(f, **kw) if is_archive(f) else (_file_item(f),))
        elif is_archive(p) and os.path.exists(p):
            yield from _iter_archive(p, **kw)
        else:
            yield _file_item(p)


# --------------------------------------------------------------------------- detection

def scan_source(source: str | bytes, config: AppConfig) -> dict[str, Any]:
    """Run `lishield_guard.detect` on one input and return the verdict fields of a record.

    Never raises for a bad image: every exception becomes ``error`` plus a stable ``code``
    (the LishieldError code, or ``"internal_error"`` for a bug).

    Returns
    -------
    fields : dict
        ``status``, ``protected`` (null unless clean or protected), ``policy``, ``matches``,
        ``required``, ``score``, ``error``, ``code``, ``undetermined_reason``, ``reason`` (the
        verdict's reason in words), ``skipped`` (work not done, and why) and ``elapsed_ms``
        (wall time of the detection, in milliseconds).
    """
    from lishield_guard.detector import detect

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = detect(source, config)
        reason = v.evidence.get("reason") if isinstance(v.evidence, dict) else None
        out: dict[str, Any] = {"status": v.status, "protected": v.protected_or_none,
                               "policy": v.policy,
                               "matches": int(v.matches), "required": int(v.required),
                               "score": round(float(v.score), 6), "error": None, "code": None,
                               "undetermined_reason": v.undetermined,
                               "reason": _printable(str(reason or v.undetermined or "")) or None,
                               "skipped": [_printable(str(s)) for s in v.skipped]}
    except LishieldError as exc:
        out = _error_fields(str(exc), exc.code)
    except Exception as exc:  # noqa: BLE001 - one bad file never stops a scan
        out = _error_fields(f"{type(exc).__name__}: {exc}", CODE_INTERNAL)
    out["elapsed_ms"] = round((time.perf_counter() - t0) * 1e3, 3)
    return out


def _error_fields(message: str, code: str) -> dict[str, Any]:
    return {"status": "error", "protected": None, "policy": None, "matches": None,
            "required": None, "score": None, "error": _printable(message), "code": code,
            "undetermined_reason": None, "reason": None, "skipped": None}


def build_record(item: ScanItem, fields: dict[str, Any] | None = None) -> dict[str, Any]:
    """One output record (keys in `RECORD_FIELDS` order) from an item and its verdict fields.

    ``fields`` is the result of `scan_source`; None records the item's own skip reason.
    """
    if fields is None:
        fields = {**_error_fields(item.error or "skipped", item.code or CODE_INTERNAL),
                  "elapsed_ms": 0.0}
    rec = {"path": item.label, **fields, "size_bytes": item.size_bytes,
           "elapsed_ms": fields.get("elapsed_ms", 0.0), "key": item.key,
           "path_escaped": item.escaped}
    return {k: rec.get(k) for k in RECORD_FIELDS}


def record_status(record: dict[str, Any]) -> str:
    """A record's status (one of `STATUSES`), also for records written before it existed."""
    status = record.get("status")
    if status in STATUSES:
        return status
    if record.get("error") not in (None, ""):
        return "error"
    protected = record.get("protected")
    return "protected" if protected in (True, "true") else "clean"


def tally_file(path: str | Path, fmt: str) -> Counter:
    """Records of an output file by status (a scan's exit code looks at the whole file).

    Lines that are not complete records are ignored (`read_done_keys` repairs a torn end).

    Returns
    -------
    collections.Counter
        Counts keyed by `STATUSES`, and ``codes:<code>`` for each error code.
    """
    counts: Counter = Counter()
    p = Path(path)
    if not p.is_file():
        return counts
    text = p.read_bytes().decode("utf-8", errors="replace")
    if fmt == "jsonl":
        rows = []
        for line in text.splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and "path" in rec:
                rows.append(rec)
    else:
        rows = list(csv.DictReader(io.StringIO(text)))
    for rec in rows:
        status = record_status(rec)
        counts[status] += 1
        if status == "error":
            counts[f"code:{rec.get('code')}"] += 1
    return counts


_WORKER_CONFIG: AppConfig | None = None


def _watch_parent(pid: int, interval_s: float = 0.5) -> None:
    """Exit this worker as soon as process ``pid`` (the scan) is gone, even after SIGKILL.

    Pool workers are children of the forkserver, not of the scan, so they would outlive a
    killed scan; a daemon thread waits on a pidfd of the scan (or polls it) and exits.
    """
    def watch() -> None:
        try:
            import select

            fd = os.pidfd_open(pid)
            select.select([fd], [], [])
        except (AttributeError, OSError):
            while True:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    pass
                time.sleep(interval_s)
        os._exit(1)

    threading.Thread(target=watch, name="lishield-parent-watch", daemon=True).start()


def _init_worker(config: AppConfig, parent_pid: int | None = None) -> None:
    global _WORKER_CONFIG
    _WORKER_CONFIG = config
    if parent_pid is not None:
        _watch_parent(parent_pid)
    one_thread_per_worker()
    import lishield_guard.detector  # noqa: F401 - warm the imports once per worker


def _scan_in_worker(source: str | bytes) -> dict[str, Any]:
    assert _WORKER_CONFIG is not None, "worker not initialised"
    return scan_source(source, _WORKER_CONFIG)


def run_scan(items: Iterable[ScanItem], *, config: AppConfig, jobs: int = 1,
             client: Any = None, max_in_flight: int | None = None) -> Iterator[dict[str, Any]]:
    """Detect on every item in parallel and yield records as they complete.

    Parameters
    ----------
    items : iterable of ScanItem
        Consumed lazily: at most ``max_in_flight`` sources are held at once.
    config : AppConfig
        Detector settings, sent once to each worker.
    jobs : int
        Worker processes of the local pool (ignored with ``client``).
    client : distributed.Client, optional
        Run on a Dask cluster instead of a local process pool.
    max_in_flight : int, optional
        Submitted but unfinished detections; default ``4 * jobs`` (or 4 x the cluster's
        worker threads).

    Yields
    ------
    record : dict
        `build_record` output; order may differ from input order.
    """
    if client is not None:
        yield from _run_dask(items, config=config, client=client, max_in_flight=max_in_flight)
        return
    jobs = max(1, int(jobs))
    limit = max_in_flight or 4 * jobs
    if jobs == 1 and max_in_flight is None:
        for item in items:
            yield build_record(item, None if item.source is None
                               else scan_source(item.source, config))
        return
    yield from _run_pool(items, config=config, jobs=jobs, limit=limit)


def _new_pool(config: AppConfig, jobs: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["lishield_guard.scan", "lishield_guard.detector"])
    return ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker,
                               initargs=(config, os.getpid()))


def _run_pool(items: Iterable[ScanItem], *, config: AppConfig, jobs: int,
              limit: int) -> Iterator[dict[str, Any]]:
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    pool = _new_pool(config, jobs)
    pending: dict[Any, ScanItem] = {}

    def drain(block_until: int) -> Iterator[dict[str, Any]]:
        nonlocal pool
        while len(pending) > block_until:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            broken = False
            for fut in done:
                item = pending.pop(fut)
                try:
                    fields = fut.result()
                except BrokenProcessPool:
                    broken = True
                    fields = {**_error_fields("worker process died while decoding this input "
                                              "(or another in flight)", CODE_WORKER_CRASHED),
                              "elapsed_ms": 0.0}
                yield build_record(item, fields)
            if broken:  # every other in-flight future fails too; then start a fresh pool
                pool.shutdown(wait=False, cancel_futures=True)
                pool = _new_pool(config, jobs)

    try:
        for item in items:
            if item.source is None:
                yield build_record(item)
                continue
            yield from drain(limit - 1)
            try:
                fut = pool.submit(_scan_in_worker, item.source)
            except BrokenProcessPool:
                pool = _new_pool(config, jobs)
                fut = pool.submit(_scan_in_worker, item.source)
            pending[fut] = item
        yield from drain(0)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _scan_on_dask(source: str | bytes, config: AppConfig) -> dict[str, Any]:
    one_thread_per_worker()
    return scan_source(source, config)


def _run_dask(items: Iterable[ScanItem], *, config: AppConfig, client: Any,
              max_in_flight: int | None) -> Iterator[dict[str, Any]]:
    from distributed import as_completed

    if max_in_flight is None:
        n_threads = sum(client.nthreads().values()) or 1
        max_in_flight = 4 * n_threads
    cfg_future = client.scatter(config, broadcast=True)
    pending: dict[Any, ScanItem] = {}
    ac = as_completed()

    def one() -> dict[str, Any]:
        fut = next(ac)
        item = pending.pop(fut)
        try:
            fields = fut.result()
        except Exception as exc:  # noqa: BLE001 - KilledWorker, lost connection, ...
            fields = {**_error_fields(f"dask task failed: {type(exc).__name__}: {exc}",
                                      CODE_WORKER_CRASHED), "elapsed_ms": 0.0}
        fut.release()
        return build_record(item, fields)

    for item in items:
        if item.source is None:
            yield build_record(item)
            continue
        while len(pending) >= max_in_flight:
            yield one()
        fut = client.submit(_scan_on_dask, item.source, cfg_future, pure=False)
        pending[fut] = item
        ac.add(fut)
    while pending:
        yield one()


# --------------------------------------------------------------------------- output

def format_record(record: dict[str, Any], fmt: str) -> str:
    """One complete output line (with newline) for ``fmt`` in {"jsonl", "csv"}."""
    if fmt == "jsonl":
        return json.dumps(record, ensure_ascii=False, allow_nan=False) + "\n"
    buf = io.StringIO()
    row = [_csv_cell(record.get(k)) for k in RECORD_FIELDS]
    csv.writer(buf, lineterminator="\n").writerow(row)
    return buf.getvalue()


def _csv_cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple):
        return "; ".join(map(str, value))
    return value


def read_done_keys(path: str | Path, fmt: str, *, repair: bool = True) -> set[str]:
    """Resume keys already recorded in an output file; a torn last line is truncated away.

    Parameters
    ----------
    path : str or Path
        A previous scan's output (missing or empty: no keys).
    fmt : {"jsonl", "csv"}
    repair : bool
        Truncate the file after its last complete line (a scan killed mid-write).

    Returns
    -------
    keys : set of str
        Keys of every complete, parseable record.
    """
    p = Path(path)
    if not p.exists():
        return set()
    data = p.read_bytes()
    end = data.rfind(b"\n") + 1
    if repair and end != len(data):
        with open(p, "r+b") as fh:
            fh.truncate(end)
            fh.flush()
            os.fsync(fh.fileno())
    text = data[:end].decode("utf-8", errors="replace")
    keys: set[str] = set()
    if fmt == "jsonl":
        for line in text.splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and isinstance(rec.get("key"), str):
                keys.add(rec["key"])
    else:
        for row in csv.DictReader(io.StringIO(text)):
            if row.get("key"):
                keys.add(row["key"])
    return keys


class RecordWriter:
    """Append records to a file (or stdout), one ``write()`` of a complete line each.

    Each line is written with a single unbuffered ``os.write`` on an ``O_APPEND`` descriptor, so
    a killed scan leaves at most one torn last line (repaired by `read_done_keys`); the file is
    fsynced every ``fsync_every`` records and on close.
    """

    def __init__(self, path: str | Path | None, fmt: str, *, fsync_every: int = 64) -> None:
        if fmt not in ("jsonl", "csv"):
            raise ValueError(f"fmt must be 'jsonl' or 'csv', got {fmt!r}")
        self.fmt = fmt
        self.fsync_every = fsync_every
        self._n = 0
        self._stdout = path is None or str(path) == "-"
        if self._stdout:
            import sys

            self._fd = sys.stdout.fileno()
            sys.stdout.flush()
            new = True
        else:
            self._fd = os.open(str(path), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            new = os.fstat(self._fd).st_size == 0
        if fmt == "csv" and new:
            self._write(",".join(RECORD_FIELDS) + "\n")

    def _write(self, line: str) -> None:
        data = line.encode("utf-8")
        while data:  # os.write on a regular file writes all at once; pipes may split
            n = os.write(self._fd, data)
            data = data[n:]

    def write(self, record: dict[str, Any]) -> None:
        """Write one record as a complete line."""
        self._write(format_record(record, self.fmt))
        self._n += 1
        if not self._stdout and self._n % self.fsync_every == 0:
            os.fsync(self._fd)

    def close(self) -> None:
        """fsync and close (stdout is left open)."""
        if not self._stdout:
            os.fsync(self._fd)
            os.close(self._fd)

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def filter_new(items: Iterable[ScanItem], done: set[str],
               on_skip: Callable[[ScanItem], None] | None = None) -> Iterator[ScanItem]:
    """Items whose key is not in ``done``; each yielded key is added (duplicates dropped)."""
    for item in items:
        if item.key in done:
            if on_skip is not None:
                on_skip(item)
            continue
        done.add(item.key)
        yield item
