"""Detection worker processes: an abandoned detection is ended by ending its process.

A detection runs in a long-lived child process (one per pool thread, started on first use from
a fork server that has already imported the detector). When the service stops waiting for it
(``detect_timeout_s`` passed, or the client went away), `Job.abandon` kills that process: its
CPU is freed at once, and the next detection gets a fresh process. A thread cannot be stopped
from outside; a process can.
"""

from __future__ import annotations

import multiprocessing
import pickle
import signal
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["DetectionAbandoned", "Job", "WorkerCrashed", "WorkerProcesses", "check_picklable"]

#: Modules the fork server imports once, so that a new worker starts in milliseconds.
PRELOAD = ("lishield_guard", "lishield_guard.profiles.learned", "lishield_guard.video.screen",
           "av", "service.workers")
JOIN_TIMEOUT_S = 5.0  # wait for a killed process to be reaped

_context_lock = threading.Lock()
_context: Any = None


def _mp_context():
    """The fork-server context, preloaded once per process."""
    global _context
    with _context_lock:
        if _context is None:
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(list(PRELOAD))
            _context = ctx
        return _context


class DetectionAbandoned(Exception):  # noqa: N818 - a state, not a fault
    """The detection was abandoned (timed out or the client left) and its process ended."""


class WorkerCrashed(RuntimeError):
    """A worker process died on its own during a detection (a bug: answered 500)."""


def check_picklable(detect_fn: Callable, config: object) -> None:
    """Raise ``TypeError`` when ``detect_fn`` or ``config`` cannot reach a worker process."""
    try:
        pickle.dumps((detect_fn, config))
    except Exception as exc:
        raise TypeError(f"detect_isolation='process' needs a picklable detect_fn and config "
                        f"(a module-level function), not {detect_fn!r}: {exc}; use "
                        f"detect_isolation='thread' for closures") from None


def _serve(conn, detect_fn: Callable, config: object) -> None:  # pragma: no cover - child
    """Worker loop: image bytes (or an array) in, pickled (ok, verdict or exception) out, until
    EOF."""
    from lishield_guard.threads import one_thread_per_worker

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent ends workers, not Ctrl-C
    one_thread_per_worker()
    while True:
        try:
            data = conn.recv()
        except (EOFError, OSError):
            return
        try:
            result: tuple[bool, Any] = (True, detect_fn(data, config))
        except Exception as exc:  # noqa: BLE001 - sent to the parent, which raises it
            result = (False, exc)
        try:
            payload = pickle.dumps(result)
        except Exception:  # noqa: BLE001 - an exception that does not pickle
            exc = result[1]
            payload = pickle.dumps((False, RuntimeError(f"{type(exc).__name__}: {exc}")))
        conn.send_bytes(payload)


class _DeadBeforeStart(Exception):  # noqa: N818 - internal signal
    """The worker process was gone before it received the job (not the job's fault)."""


class _Worker:
    """One child process and the parent's end of its pipe."""

    def __init__(self, detect_fn: Callable, config: object) -> None:
        ctx = _mp_context()
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, args=(child, detect_fn, config), daemon=True,
                                name="lishield-detect")
        self.proc.start()
        child.close()

    def run(self, data: Any) -> Any:
        try:
            self.conn.send(data)
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise _DeadBeforeStart from exc
        ok, value = pickle.loads(self.conn.recv_bytes())
        if ok:
            return value
        raise value

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()

    def close(self) -> None:
        self.kill()
        self.proc.join(JOIN_TIMEOUT_S)
        self.conn.close()


class Job:
    """One detection's handle: `abandon` ends it wherever it is (queued or running)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._worker: _Worker | None = None
        self.abandoned = False

    def _attach(self, worker: _Worker) -> bool:
        with self._lock:
            if self.abandoned:
                return False
            self._worker = worker
            return True

    def _detach(self) -> bool:
        """Forget the worker; True when the job was abandoned meanwhile (its worker may
        have been killed after it answered: it must not serve another job)."""
        with self._lock:
            self._worker = None
            return self.abandoned

    def abandon(self) -> None:
        """Stop the detection: kill its process if it runs (idempotent)."""
        with self._lock:
            self.abandoned = True
            if self._worker is not None:
                self._worker.kill()


class WorkerProcesses:
    """Up to ``n_workers`` detection processes, started on first use.

    Parameters
    ----------
    detect_fn : callable
        ``detect_fn(data, config) -> Verdict``, picklable (a module-level function).
    config : object
        Passed to every call; picklable.
    n_workers : int
        Most processes alive at once (the pool's thread count), >= 1.
    """

    def __init__(self, detect_fn: Callable, config: object, n_workers: int) -> None:
        check_picklable(detect_fn, config)
        self._detect_fn = detect_fn
        self._config = config
        self._n = int(n_workers)
        self._idle: list[_Worker] = []
        self._all: set[_Worker] = set()
        self._lock = threading.Lock()
        self._freed = threading.Condition(self._lock)  # a worker became idle, or a slot free
        self._closed = False
        self.warmup_data: Any = None  # run by a replacement before it serves (first-call costs)

    def _take(self) -> _Worker:
        while True:
            with self._lock:
                if self._closed:
                    raise DetectionAbandoned("the service is shutting down")
                # a full pool without an idle worker is a replacement still starting
                self._freed.wait_for(lambda: self._closed or self._idle
                                     or len(self._all) < self._n)
                if self._closed:
                    raise DetectionAbandoned("the service is shutting down")
                worker = self._idle.pop() if self._idle else None
                if worker is None:
                    worker = _Worker(self._detect_fn, self._config)
                    self._all.add(worker)
                    return worker
            if worker.proc.is_alive():
                return worker
            self._give_back(worker, healthy=False)  # died while idle: take another

    def _give_back(self, worker: _Worker, *, healthy: bool) -> None:
        with self._lock:
            if healthy and not self._closed:
                self._idle.append(worker)
                self._freed.notify()
                return
            self._all.discard(worker)
            self._freed.notify()
            replace = not self._closed
        worker.close()
        if replace:  # the next detection finds a started (and warmed) process
            threading.Thread(target=self._replace, name="lishield-detect-respawn",
                             daemon=True).start()

    def _replace(self) -> None:
        with self._lock:
            if self._closed or len(self._all) >= self._n:
                return
            worker = _Worker(self._detect_fn, self._config)
            self._all.add(worker)
        healthy = True
        if self.warmup_data is not None:
            try:
                worker.run(self.warmup_data)
            except Exception:  # noqa: BLE001 - a worker that cannot warm up is not kept
                healthy = False
        self._give_back(worker, healthy=healthy)

    def run(self, data: Any, job: Job | None = None) -> Any:
        """``detect_fn(data, config)`` in a worker process (blocking; call from a thread).

        Raises
        ------
        DetectionAbandoned
            When ``job`` was abandoned before or during the detection.
        WorkerCrashed
            When the process died on its own.
        Exception
            Whatever ``detect_fn`` raised, re-raised here.
        """
        job = job or Job()
        for _attempt in range(2):  # a worker found dead before it started is replaced once
            worker = self._take()
            if not job._attach(worker):
                self._give_back(worker, healthy=True)
                raise DetectionAbandoned("abandoned before it started")
            try:
                result = worker.run(data)
            except _DeadBeforeStart:
                job._detach()
                self._give_back(worker, healthy=False)
                continue
            except (EOFError, OSError, pickle.UnpicklingError):
                abandoned = job._detach()
                self._give_back(worker, healthy=False)
                if abandoned:
                    raise DetectionAbandoned("detection abandoned; its process was ended"
                                             ) from None
                worker.proc.join(JOIN_TIMEOUT_S)
                raise WorkerCrashed(f"detection worker process died (exit code "
                                    f"{worker.proc.exitcode})") from None
            except BaseException:
                abandoned = job._detach()
                self._give_back(worker, healthy=not abandoned)
                raise
            abandoned = job._detach()
            self._give_back(worker, healthy=not abandoned)  # killed after answering: replace
            return result
        raise WorkerCrashed("detection worker processes die before they start")

    def pids(self, *, busy: bool = False) -> list[int]:
        """Process ids of the live workers, or of those running a detection (``busy``)."""
        with self._lock:
            return [w.proc.pid for w in self._all
                    if w.proc.is_alive() and not (busy and w in self._idle)]

    def close(self) -> None:
        """End every worker process."""
        with self._lock:
            self._closed = True
            workers, self._all, self._idle = list(self._all), set(), []
            self._freed.notify_all()
        for w in workers:
            w.close()
