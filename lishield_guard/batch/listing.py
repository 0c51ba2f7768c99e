"""One lister of batch inputs: files, folders, lists and archives, by the one type table.

`iter_items` yields every input of a scan (archive members with their bytes, skipped inputs
with a reason and a stable code); `list_files` lists the media files of a folder for the tools
that need paths on disk (calibration, benchmarks). Both pick files by `batch.types`: a name
with a known suffix, or else a known signature in the first bytes.
"""

from __future__ import annotations

import bz2
import fnmatch
import gzip
import lzma
import os
import re
import stat
import tarfile
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from lishield_guard.batch.types import KINDS, SNIFF_BYTES, MediaKind, kind_of_bytes, kind_of_name
from lishield_guard.errors import input_file_error
from lishield_guard.files import read_head

__all__ = [
    "ARCHIVE_SUFFIXES",
    "ScanItem",
    "escape_name",
    "is_archive",
    "iter_items",
    "list_files",
    "unsafe_member_reason",
]

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")
TAR_TAIL_MAX_BYTES = 64 * 1024 * 1024  # decompressed bytes after a tar's end read to reach
#                                        the compressed stream's own end and checksum

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
    except OSError as exc:  # the code and message `detect` and the Python API give
        err = input_file_error(exc, label)
        state = "missing" if err.code == CODE_NOT_FOUND else "unreadable"
        return ScanItem(label, f"{_printable(os.path.abspath(path))}|{state}", None, None,
                        str(err), err.code, esc)
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


def _sniff_file(path: str, sel: _Selector) -> bool:
    """Whether a regular file's first bytes are a signature ``sel`` reads (non-blocking open);
    True for what cannot be read or is not a regular file, so that the scan records why."""
    head = read_head(path, SNIFF_BYTES)
    return True if head is None else sel.wanted_bytes(head)


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
                 on_ignored: Callable[[str], None] | None,
                 kinds: tuple[MediaKind, ...] = KINDS) -> None:
        self.include, self.exclude, self.on_ignored = include, exclude, on_ignored
        self.kinds = kinds

    def wanted_bytes(self, head: bytes) -> bool:
        """Whether leading bytes carry the signature of one of the kinds read."""
        return kind_of_bytes(head[:SNIFF_BYTES], self.kinds) is not None

    def excluded(self, label: str) -> bool:
        return bool(self.exclude) and not _selected(label, (), self.exclude, leaf=False)

    def by_name(self, label: str) -> bool | None:
        """True: scan; False: drop; None: decided by the bytes."""
        if not _selected(label, (), self.exclude, leaf=False):
            return False
        if self.include:
            return _selected(label, self.include, (), leaf=True)
        if kind_of_name(label, self.kinds) is not None and not _is_hidden(label):
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
                if wanted is None and not sel.wanted_bytes(data):
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
                if wanted is None and not sel.wanted_bytes(data):
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
                wanted = not regular or _sniff_file(e.path, sel)
                if not wanted:
                    sel.ignore(escape_name(e.path)[0])
            if wanted:
                yield e.path


def iter_items(paths: Iterable[str | Path], *, include: Iterable[str] = (),
               exclude: Iterable[str] = (), max_bytes: int = 64 * 1024 * 1024,
               read_data: bool = True,
               on_ignored: Callable[[str], None] | None = None,
               kinds: tuple[MediaKind, ...] = KINDS) -> Iterator[ScanItem]:
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
    kinds : tuple of MediaKind
        The kinds of media read (`lishield_guard.batch.types.KINDS`: images).

    Yields
    ------
    ScanItem
        Archive members carry their bytes (read one at a time, in memory, never extracted);
        hostile names, links, special members and truncated archives are yielded with
        ``source=None`` and a reason.
    """
    sel = _Selector(tuple(include), tuple(exclude), on_ignored, kinds)
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


def list_files(folder: str | Path, *, kinds: tuple[MediaKind, ...] = KINDS) -> list[Path]:
    """The media files under ``folder`` that a scan of it would read, sorted by path.

    The same choice as `iter_items` (a known suffix, or else a known signature; hidden
    non-media files, sidecars and manifests left out; symlinked folders not entered), without
    archives and non-regular files: what is listed is a file on disk.

    Parameters
    ----------
    folder : str or Path
        Folder searched recursively.
    kinds : tuple of MediaKind
        The kinds of media listed (default: every kind of `batch.types.KINDS`).

    Returns
    -------
    list of Path
        Sorted like ``sorted(Path(folder).rglob("*"))``.
    """
    sel = _Selector((), (), None, kinds)
    return [Path(p) for p in _walk(os.fspath(folder), sel)
            if not is_archive(os.path.basename(p)) and os.path.isfile(p)]
