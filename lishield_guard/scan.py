"""Batch scan: detect on every input `lishield_guard.batch` lists, in parallel; build records.

Inputs come from `lishield_guard.batch.listing` (re-exported here), workers from
`lishield_guard.batch.pool`; this module turns verdicts into records and writes them.
"""

from __future__ import annotations

import csv
import io
import json
import os
import stat
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lishield_guard.batch.listing import (  # noqa: F401 - re-exported: the scan's inputs
    ARCHIVE_SUFFIXES,
    CODE_CORRUPT_MEMBER,
    CODE_ENCRYPTED_MEMBER,
    CODE_LINK_MEMBER,
    CODE_NOT_FOUND,
    CODE_PAYLOAD_TOO_LARGE,
    CODE_READ_ERROR,
    CODE_SPECIAL_MEMBER,
    CODE_TRUNCATED_ARCHIVE,
    CODE_UNREADABLE_ARCHIVE,
    CODE_UNSAFE_NAME,
    ScanItem,
    _printable,
    escape_name,
    iter_items,
    unsafe_member_reason,
)
from lishield_guard.batch.pool import WorkerCrashed, run_pool, worker_state
from lishield_guard.batch.types import IMAGE_SUFFIXES, is_image_bytes  # noqa: F401
from lishield_guard.config import AppConfig
from lishield_guard.errors import classify
from lishield_guard.threads import one_thread_per_worker

__all__ = [
    "DaskUnreachable",
    "ScanTally",
    "dask_client",
    "is_stream",
    "scan_to_output",
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

CODE_INTERNAL = "internal_error"
CODE_WORKER_CRASHED = "worker_crashed"

# --------------------------------------------------------------------------- detection

def scan_source(source: str | bytes, config: AppConfig) -> dict[str, Any]:
    """Screen one input (an image with `lishield_guard.detect`, a video with
    `lishield_guard.video.detect_video`) and return the verdict fields of a record.

    Never raises for a bad image: every exception becomes ``error`` plus a stable ``code``
    (`lishield_guard.errors.classify`: the LishieldError code, or ``"internal_error"`` for a
    bug).

    Returns
    -------
    fields : dict
        ``status``, ``protected`` (null unless clean or protected), ``policy``, ``matches``,
        ``required``, ``score``, ``error``, ``code``, ``undetermined_reason``, ``reason`` (the
        verdict's reason in words), ``skipped`` (work not done, and why) and ``elapsed_ms``
        (wall time of the detection, in milliseconds).
    """
    from lishield_guard.video import detect_media

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = detect_media(source, config)
        reason = v.evidence.reason  # the typed evidence's reason (`verdict.Evidence`)
        out: dict[str, Any] = {"status": v.status, "protected": v.protected_or_none,
                               "policy": v.policy,
                               "matches": int(v.matches), "required": int(v.required),
                               "score": round(float(v.score), 6), "error": None, "code": None,
                               "undetermined_reason": v.undetermined,
                               "reason": _printable(str(reason or v.undetermined or "")) or None,
                               "skipped": [_printable(str(s)) for s in v.skipped]}
    except Exception as exc:  # noqa: BLE001 - one bad file never stops a scan
        out = _error_fields(*reversed(classify(exc)))  # the mapping detect and HTTP use
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


def _scan_in_worker(source: str | bytes) -> dict[str, Any]:
    return scan_source(source, worker_state())


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
    results = run_pool(_scan_in_worker, items, jobs=jobs, state=config,
                       work=lambda item: item.source, max_in_flight=max_in_flight,
                       preload=("lishield_guard.scan", "lishield_guard.detector"))
    for item, fields in results:
        if isinstance(fields, WorkerCrashed):
            fields = {**_error_fields(str(fields), CODE_WORKER_CRASHED), "elapsed_ms": 0.0}
        yield build_record(item, fields)


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


# --------------------------------------------------------------------------- one scan, end to end

def is_stream(path: str) -> bool:
    """True for outputs that are written as they are, never checked, resumed or re-read:
    ``-``, ``/dev/stdout`` and other device paths, pipes and terminals."""
    if path == "-" or path.startswith(("/dev/", "/proc/")):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except FileNotFoundError:
        return False
    except OSError:
        return True


class DaskUnreachable(Exception):  # noqa: N818 - a state of the cluster, not a bug
    """The Dask scheduler could not be reached (or the local cluster not started)."""


@contextmanager
def dask_client(*, local: bool, scheduler: str | None, jobs: int) -> Iterator[Any]:
    """A Dask client (a LocalCluster of ``jobs`` workers, or one on ``scheduler``), closed
    on exit; None when neither is asked for.

    Raises
    ------
    DaskUnreachable
        When the scheduler cannot be reached.
    """
    if not (local or scheduler):
        yield None
        return
    import logging

    from distributed import Client, LocalCluster

    cluster = None
    try:
        if local:
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.ERROR)
            client = Client(cluster)
        else:
            client = Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise DaskUnreachable(str(exc)) from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@dataclass(frozen=True)
class ScanTally:
    """What one `scan_to_output` did.

    Attributes
    ----------
    counts, codes : Counter
        Records written by status (`STATUSES`), and error records by code.
    n_resumed, n_ignored : int
        Inputs already recorded (``resume``), and non-image files passed over.
    elapsed_s : float
        Wall time, in seconds.
    whole : Counter or None
        Records of the whole output file by status (earlier runs' too); None for a stream.
    """

    counts: Counter
    codes: Counter
    n_resumed: int
    n_ignored: int
    elapsed_s: float
    whole: Counter | None


def scan_to_output(inputs: list[str], *, output: str, fmt: str, config: AppConfig, jobs: int,
                   resume: bool = False, include: Iterable[str] = (),
                   exclude: Iterable[str] = (), client: Any = None,
                   progress: bool = False) -> ScanTally:
    """Scan ``inputs`` and write one record per input to ``output`` as results arrive.

    Parameters
    ----------
    inputs : list of str
        Files, folders and archives (`iter_items`).
    output : str
        Output file, or ``"-"`` for stdout.
    fmt : {"jsonl", "csv"}
        Output format.
    config : AppConfig
        Detector settings.
    jobs : int
        Worker processes (ignored with ``client``).
    resume : bool
        Append to ``output``, skipping inputs already recorded there.
    include, exclude : iterable of str
        Globs (`iter_items`).
    client : distributed.Client, optional
        Run on a Dask cluster.
    progress : bool
        A progress bar on stderr (its total counted while the scan runs).

    Returns
    -------
    ScanTally

    Raises
    ------
    OSError
        When the output cannot be written (records written so far stay whole lines).
    """
    done: set[str] = read_done_keys(output, fmt) if resume else set()
    n_resumed = n_ignored = 0
    bar = None

    def on_skip(_item) -> None:
        nonlocal n_resumed
        n_resumed += 1
        if bar is not None:  # counted in the total, so the bar still reaches 100 %
            bar.update(1)

    def on_ignored(_label: str) -> None:
        nonlocal n_ignored
        n_ignored += 1

    kw = {"include": include, "exclude": exclude, "max_bytes": config.limits.max_bytes}
    items = filter_new(iter_items(inputs, **kw, on_ignored=on_ignored), done, on_skip)
    if progress:
        bar = _counted_bar(inputs, kw)
    counts: Counter = Counter()
    codes: Counter = Counter()
    t0 = time.perf_counter()
    try:
        with RecordWriter(None if output == "-" else output, fmt) as writer:
            for rec in run_scan(items, config=config, jobs=jobs, client=client):
                writer.write(rec)
                status = record_status(rec)
                counts[status] += 1
                if status == "error":
                    codes[rec["code"]] += 1
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    elapsed_s = time.perf_counter() - t0
    whole = None
    if not is_stream(output) and os.path.isfile(output):  # earlier runs' records too
        whole = tally_file(output, fmt)
    return ScanTally(counts, codes, n_resumed, n_ignored, elapsed_s, whole)


def _counted_bar(inputs: list[str], kw: dict):
    """A progress bar whose total is counted in a thread while the scan already runs."""
    from lishield_guard.batch.pool import progress_bar

    bar = progress_bar(total=None, smoothing=0.05)

    def count() -> None:
        bar.total = sum(1 for _ in iter_items(inputs, **{**kw, "read_data": False}))
        bar.refresh()

    threading.Thread(target=count, daemon=True).start()
    return bar
