"""The detection pool: bounded admission, a time budget per detection, isolated workers."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

from fastapi import Request
from starlette.requests import ClientDisconnect

from lishield_guard import AppConfig, Verdict
from service.errors import ServiceError
from service.metrics import Metrics
from service.settings import ServiceSettings
from service.workers import DetectionAbandoned, Job, WorkerProcesses

__all__ = ["DISCONNECT_POLL_S", "DetectFn", "DetectPool"]

DetectFn = Callable[[bytes, AppConfig], Verdict]
DISCONNECT_POLL_S = 0.25  # how often a waiting detection checks that its client is still there


class DetectPool:
    """Runs detections in a thread pool with bounded admission and a time budget per media.

    Parameters
    ----------
    detect_fn : callable
        ``detect_fn(data, config) -> Verdict``, normally `lishield_guard.video.detect_media`
        (a video when the bytes are one, else an image).
    config : AppConfig
        Config handed to every call.
    settings : ServiceSettings
        ``max_concurrency`` threads run detections; ``max_queue`` more may wait; beyond, 503.
        ``detect_timeout_s`` (an image) or ``video_timeout_s`` (a video) bounds queue wait
        plus detection (`ServiceSettings.time_budget`).
    metrics : Metrics
        Gauges and counters updated here.

    Notes
    -----
    With ``detect_isolation="process"`` (the default) each pool thread hands its detection to
    a worker process (`service.workers`); a detection the service stops waiting for (504
    ``timeout``, or the client went away) is ended by killing that process, so it frees its CPU
    and its admission slot at once and ``lishield_detections_in_flight`` falls. With
    ``"thread"`` (in-process ``detect_fn`` closures, tests) an abandoned detection that already
    runs keeps its slot until its thread finishes; a queued one is cancelled either way. So
    abandoned work can never push more than ``max_concurrency + max_queue`` detections into
    the pool.
    """

    def __init__(self, detect_fn: DetectFn, config: AppConfig, settings: ServiceSettings,
                 metrics: Metrics) -> None:
        self.executor = ThreadPoolExecutor(max_workers=settings.max_concurrency,
                                           thread_name_prefix="lishield-detect")
        self.workers = (WorkerProcesses(detect_fn, config, settings.max_concurrency)
                        if settings.detect_isolation == "process" else None)
        self._detect_fn = detect_fn
        self._config = config
        self._n_threads = settings.max_concurrency
        self._capacity = settings.max_concurrency + settings.max_queue
        self._settings = settings
        self._retry_after_s = settings.retry_after_s
        self._metrics = metrics
        self._admitted = 0
        self._lock = threading.Lock()

    def full(self) -> bool:
        """True when a new detection would be refused (checked before reading a body)."""
        with self._lock:
            return self._admitted >= self._capacity

    def overloaded(self) -> ServiceError:
        """503 ``overloaded`` with ``Retry-After``."""
        self._metrics.rejected_overload.inc()
        return ServiceError(503, "overloaded", f"{self._admitted} detections in flight or "
                            f"queued (max_concurrency + max_queue = {self._capacity}); "
                            "retry later", headers={"Retry-After": str(self._retry_after_s)})

    def _release(self, _fut: Future | None = None) -> None:
        with self._lock:
            self._admitted -= 1
        self._metrics.detections_in_flight.dec()

    def _run(self, data: bytes, job: Job) -> Verdict:
        if self.workers is not None:
            return self.workers.run(data, job)
        if job.abandoned:
            raise DetectionAbandoned("abandoned before it started")
        return self._detect_fn(data, self._config)

    def warmup(self, data: object) -> None:
        """Run one detection on ``data`` in every worker (blocking): the first request does
        not pay for starting a process or for the detector's first-call costs."""
        if self.workers is None:
            import lishield_guard

            lishield_guard.detect(data, self._config)
            return
        self.workers.warmup_data = data
        futs = [self.executor.submit(self.workers.run, data) for _ in range(self._n_threads)]
        for f in futs:
            f.result()

    async def detect(self, data: bytes, *, kind: str = "image",
                     request: Request | None = None) -> Verdict:
        """Detect in a worker; 503 ``overloaded`` when full, 504 ``timeout`` when slow.

        ``kind`` ("image" or "video", as `service.parsing.media_of` tells) picks the time
        budget. With ``request``, a client that goes away while its detection waits or runs
        ends the detection (checked every `DISCONNECT_POLL_S`) and raises
        ``ClientDisconnect``.
        """
        with self._lock:
            if self._admitted >= self._capacity:
                raise self.overloaded()
            self._admitted += 1
        self._metrics.detections_in_flight.inc()
        job = Job()
        try:
            fut = self.executor.submit(self._run, data, job)
        except BaseException:
            self._release()
            raise
        fut.add_done_callback(self._release)
        waiter = asyncio.wrap_future(fut)
        budget, timeout_s = self._settings.time_budget(kind)
        try:
            async with asyncio.timeout(timeout_s):
                while not waiter.done():
                    await asyncio.wait({waiter}, timeout=DISCONNECT_POLL_S)
                    if (not waiter.done() and request is not None
                            and await request.is_disconnected()):
                        raise ClientDisconnect()
            return waiter.result()
        except TimeoutError:
            self._abandon(fut, job, waiter)
            self._metrics.timeouts.inc()
            raise ServiceError(504, "timeout", f"{kind} detection exceeded {budget}="
                               f"{timeout_s}") from None
        except (ClientDisconnect, asyncio.CancelledError):
            self._abandon(fut, job, waiter)
            raise

    @staticmethod
    def _abandon(fut: Future, job: Job, waiter: asyncio.Future) -> None:
        fut.cancel()  # a queued detection never starts
        job.abandon()  # a running one loses its process
        waiter.cancel()

    def shutdown(self) -> None:
        """Stop accepting work; queued detections are cancelled, worker processes ended."""
        self.executor.shutdown(wait=False, cancel_futures=True)
        if self.workers is not None:
            self.workers.close()
