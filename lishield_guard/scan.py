"""Batch scan: enumerate files, folders, lists and archives; detect in parallel; build records."""

from __future__ import annotations

import csv
import fnmatch
import io
import json
import os
import re
import stat
import tarfile
import time
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lishield_guard.config import AppConfig
from lishield_guard.errors import LishieldError
from lishield_guard.threads import one_thread_per_worker

__all__ = [
    "ARCHIVE_SUFFIXES",
    "RECORD_FIELDS",
    "RecordWriter",
    "ScanItem",
    "build_record",
    "filter_new",
    "format_record",
    "iter_items",
    "read_done_keys",
    "run_scan",
    "scan_source",
    "unsafe_member_reason",
]

ARCHIVE_SUFFIXES = (".zip", ".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")

#: Record fields in output order (the DESIGN.md scan contract plus the resume key).
RECORD_FIELDS = ("path", "protected", "policy", "matches", "required", "score", "error", "code",
                 "size_bytes", "elapsed_ms", "key")

# Stable codes of the scanner's own skip reasons (detector errors keep their LishieldError.code).
CODE_UNSAFE_NAME = "unsafe_member_name"
CODE_LINK_MEMBER = "link_member"
CODE_SPECIAL_MEMBER = "special_member"
CODE_ENCRYPTED_MEMBER = "encrypted_member"
CODE_CORRUPT_MEMBER = "corrupt_member"
CODE_UNREADABLE_ARCHIVE = "unreadable_archive"
CODE_NOT_FOUND = "not_found"
CODE_READ_ERROR = "read_error"
CODE_PAYLOAD_TOO_LARGE = "payload_too_large"
CODE_INTERNAL = "internal_error"
CODE_WORKER_CRASHED = "worker_crashed"

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _printable(text: str) -> str:
    """Escape control characters so a label always fits on one output line."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


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
    """

    label: str
    key: str
    size_bytes: int | None
    source: str | bytes | None
    error: str | None = None
    code: str | None = None


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
    name = re.split(r"[/!\\]", label)[-1]

    def hit(pats: tuple[str, ...]) -> bool:
        return any(fnmatch.fnmatch(label, p) or fnmatch.fnmatch(name, p) for p in pats)

    if exclude and hit(exclude):
        return False
    return not (leaf and include and not hit(include))


def _file_key(path: str, st: os.stat_result) -> str:
    return f"{_printable(os.path.abspath(path))}|{st.st_size}|{st.st_mtime_ns}"


def _file_item(path: str) -> ScanItem:
    label = _printable(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return ScanItem(label, f"{_printable(os.path.abspath(path))}|missing", None, None,
                        "no such file", CODE_NOT_FOUND)
    except OSError as exc:
        return ScanItem(label, f"{_printable(os.path.abspath(path))}|unreadable", None, None,
                        f"cannot stat: {exc.strerror}", CODE_READ_ERROR)
    if not stat.S_ISREG(st.st_mode):
        return ScanItem(label, _file_key(path, st), None, None, "not a regular file",
                        CODE_SPECIAL_MEMBER)
    return ScanItem(label, _file_key(path, st), st.st_size, path)


def _iter_zip(path: str, *, max_bytes: int, include, exclude,
              read_data: bool) -> Iterator[ScanItem]:
    base = _printable(path)
    abs_base = _printable(os.path.abspath(path))
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename
            if info.is_dir():
                continue
            label = f"{base}!{_printable(name)}"
            if not _selected(label, include, exclude):
                continue
            key = f"{abs_base}!{_printable(name)}|{info.CRC:08x}"
            mode = info.external_attr >> 16
            reason = unsafe_member_reason(name)
            if reason:
                yield ScanItem(label, key, info.file_size, None, f"skipped: {reason}",
                               CODE_UNSAFE_NAME)
            elif stat.S_ISLNK(mode):
                yield ScanItem(label, key, info.file_size, None,
                               "skipped: symbolic link member (never followed)", CODE_LINK_MEMBER)
            elif mode and stat.S_IFMT(mode) and not stat.S_ISREG(mode):
                yield ScanItem(label, key, info.file_size, None,
                               "skipped: not a regular file member", CODE_SPECIAL_MEMBER)
            elif info.flag_bits & 0x1:
                yield ScanItem(label, key, info.file_size, None, "skipped: encrypted member",
                               CODE_ENCRYPTED_MEMBER)
            elif info.file_size > max_bytes:
                yield ScanItem(label, key, info.file_size, None,
                               f"member has {info.file_size} bytes > max_bytes={max_bytes}",
                               CODE_PAYLOAD_TOO_LARGE)
            elif not read_data:
                yield ScanItem(label, key, info.file_size, None)
            else:
                try:
                    with zf.open(info) as fh:
                        data = fh.read(max_bytes + 1)
                except (zipfile.BadZipFile, zlib.error, OSError, EOFError,
                        NotImplementedError, RuntimeError) as exc:
                    yield ScanItem(label, key, info.file_size, None,
                                   f"cannot read member: {exc}", CODE_CORRUPT_MEMBER)
                    continue
                if len(data) > max_bytes:
                    yield ScanItem(label, key, len(data), None,
                                   f"member has > max_bytes={max_bytes} bytes",
                                   CODE_PAYLOAD_TOO_LARGE)
                    continue
                yield ScanItem(label, key, len(data), data)


def _iter_tar(path: str, *, max_bytes: int, include, exclude,
              read_data: bool) -> Iterator[ScanItem]:
    base = _printable(path)
    abs_base = _printable(os.path.abspath(path))
    # Stream mode: headers and data are read once, in order; nothing is ever extracted.
    with tarfile.open(path, mode="r|*") as tf:
        for m in tf:
            if m.isdir():
                continue
            label = f"{base}!{_printable(m.name)}"
            if not _selected(label, include, exclude):
                continue
            key_stem = f"{abs_base}!{_printable(m.name)}"
            reason = unsafe_member_reason(m.name)
            if reason:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"skipped: {reason}", CODE_UNSAFE_NAME)
            elif m.issym() or m.islnk():
                kind = "symbolic" if m.issym() else "hard"
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"skipped: {kind} link member (never followed)", CODE_LINK_MEMBER)
            elif not m.isfile():
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               "skipped: not a regular file member", CODE_SPECIAL_MEMBER)
            elif m.size > max_bytes:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None,
                               f"member has {m.size} bytes > max_bytes={max_bytes}",
                               CODE_PAYLOAD_TOO_LARGE)
            elif not read_data:
                yield ScanItem(label, f"{key_stem}|{m.size}", m.size, None)
            else:
                fh = tf.extractfile(m)
                data = fh.read() if fh is not None else b""
                if len(data) != m.size:
                    raise tarfile.ReadError(f"member {m.name!r} is truncated")
                yield ScanItem(label, f"{key_stem}|{zlib.crc32(data):08x}", len(data), data)


def _iter_archive(path: str, **kw) -> Iterator[ScanItem]:
    label = _printable(path)
    try:
        st = os.stat(path)
        key = _file_key(path, st) + "!<archive>"
    except OSError as exc:
        yield ScanItem(label, f"{_printable(os.path.abspath(path))}|missing!<archive>", None,
                       None, f"cannot open archive: {exc.strerror}", CODE_NOT_FOUND)
        return
    opener = _iter_zip if path.lower().endswith(".zip") else _iter_tar
    try:
        yield from opener(path, **kw)
    except (zipfile.BadZipFile, tarfile.TarError, zlib.error, EOFError, OSError,
            ValueError) as exc:
        yield ScanItem(label, key, st.st_size, None, f"cannot read archive: {exc}",
                       CODE_UNREADABLE_ARCHIVE)


def _walk(folder: str, include, exclude) -> Iterator[str]:
    """Files under folder, depth first, entries sorted by name; symlinked folders not entered."""
    try:
        with os.scandir(folder) as it:
            entries = sorted(it, key=lambda e: e.name)
    except OSError:
        return
    for e in entries:
        if e.is_dir(follow_symlinks=False):
            if _selected(e.path, (), exclude, leaf=False):
                yield from _walk(e.path, include, exclude)
        elif is_archive(e.name):
            if _selected(e.path, (), exclude, leaf=False):
                yield e.path
        elif _selected(e.path, include, exclude):
            yield e.path


def iter_items(paths: Iterable[str | Path], *, include: Iterable[str] = (),
               exclude: Iterable[str] = (), max_bytes: int = 64 * 1024 * 1024,
               read_data: bool = True) -> Iterator[ScanItem]:
    """Every scan input under ``paths``, lazily, in a deterministic order.

    Parameters
    ----------
    paths : iterable of str or Path
        Files, folders (walked recursively, sorted; symlinked folders not followed) and
        archives (``.zip``, ``.tar``, ``.tar.gz``/``.tgz``, ``.tar.bz2``, ``.tar.xz``).
    include, exclude : iterable of str
        Shell globs matched against the whole label and against its last name. ``include``
        keeps only matching images found in folders and archives; ``exclude`` drops files,
        folders and archives. Paths named explicitly are never dropped by ``include``.
    max_bytes : int
        Archive members larger than this are recorded as too large without being read, in bytes.
    read_data : bool
        Read archive members (False counts inputs cheaply; ``source`` is then None).

    Yields
    ------
    ScanItem
        Archive members carry their bytes (read one at a time, in memory, never extracted);
        hostile names, links and special members are yielded with ``source=None`` and a reason.
    """
    include, exclude = tuple(include), tuple(exclude)
    kw = {"max_bytes": max_bytes, "include": include, "exclude": exclude,
          "read_data": read_data}
    for raw in paths:
        p = str(raw)
        if os.path.isdir(p):
            for f in _walk(p, include, exclude):
                yield from (_iter_archive(f, **kw) if is_archive(f) else (_file_item(f),))
        elif is_archive(p) and os.path.isfile(p):
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
        ``protected``, ``policy``, ``matches``, ``required``, ``score``, ``error``, ``code``
        and ``elapsed_ms`` (wall time of the detection, in milliseconds).
    """
    from lishield_guard.detect import detect

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = detect(source, config)
        out: dict[str, Any] = {"protected": bool(v.protected), "policy": v.policy,
                               "matches": int(v.matches), "required": int(v.required),
                               "score": round(float(v.score), 6), "error": None, "code": None}
    except LishieldError as exc:
        out = _error_fields(str(exc), exc.code)
    except Exception as exc:  # noqa: BLE001 - one bad file never stops a scan
        out = _error_fields(f"{type(exc).__name__}: {exc}", CODE_INTERNAL)
    out["elapsed_ms"] = round((time.perf_counter() - t0) * 1e3, 3)
    return out


def _error_fields(message: str, code: str) -> dict[str, Any]:
    return {"protected": None, "policy": None, "matches": None, "required": None,
            "score": None, "error": _printable(message), "code": code}


def build_record(item: ScanItem, fields: dict[str, Any] | None = None) -> dict[str, Any]:
    """One output record (keys in `RECORD_FIELDS` order) from an item and its verdict fields.

    ``fields`` is the result of `scan_source`; None records the item's own skip reason.
    """
    if fields is None:
        fields = {**_error_fields(item.error or "skipped", item.code or CODE_INTERNAL),
                  "elapsed_ms": 0.0}
    rec = {"path": item.label, **fields, "size_bytes": item.size_bytes,
           "elapsed_ms": fields.get("elapsed_ms", 0.0), "key": item.key}
    return {k: rec.get(k) for k in RECORD_FIELDS}


_WORKER_CONFIG: AppConfig | None = None


def _init_worker(config: AppConfig) -> None:
    global _WORKER_CONFIG
    _WORKER_CONFIG = config
    one_thread_per_worker()
    import lishield_guard.detect  # noqa: F401 - warm the imports once per worker


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
    ctx.set_forkserver_preload(["lishield_guard.scan", "lishield_guard.detect"])
    return ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker,
                               initargs=(config,))


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
    row = ["" if record.get(k) is None else
           (str(record[k]).lower() if isinstance(record[k], bool) else record[k])
           for k in RECORD_FIELDS]
    csv.writer(buf, lineterminator="\n").writerow(row)
    return buf.getvalue()


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
