"""Shared request plumbing: service state, bearer auth, capped body reading, detection pool."""

from __future__ import annotations

import asyncio
import hmac
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import FormData, UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from lishield_guard import AppConfig, PayloadTooLargeError, Verdict
from service.errors import ServiceError
from service.metrics import Metrics
from service.settings import ServiceSettings
from service.workers import DetectionAbandoned, Job, WorkerProcesses

__all__ = ["BodyBudget", "DetectFn", "DetectPool", "ServiceState", "get_service", "read_body",
           "read_form", "read_image", "release_body", "require_metrics_token", "require_token"]

DetectFn = Callable[[bytes, AppConfig], Verdict]
MULTIPART = "multipart/form-data"
DISCONNECT_POLL_S = 0.25  # how often a waiting detection checks that its client is still there


class DetectPool:
    """Runs detections in a thread pool with bounded admission and a per-request time budget.

    Parameters
    ----------
    detect_fn : callable
        ``detect_fn(data, config) -> Verdict``, normally `lishield_guard.detect`.
    config : AppConfig
        Config handed to every call.
    settings : ServiceSettings
        ``max_concurrency`` threads run detections; ``max_queue`` more may wait; beyond, 503.
        ``detect_timeout_s`` bounds queue wait plus detection.
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
        self._timeout_s = settings.detect_timeout_s
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

    async def detect(self, data: bytes, *, request: Request | None = None) -> Verdict:
        """Detect in a worker; 503 ``overloaded`` when full, 504 ``timeout`` when slow.

        With ``request``, a client that goes away while its detection waits or runs ends the
        detection (checked every `DISCONNECT_POLL_S`) and raises ``ClientDisconnect``.
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
        try:
            async with asyncio.timeout(self._timeout_s):
                while not waiter.done():
                    await asyncio.wait({waiter}, timeout=DISCONNECT_POLL_S)
                    if (not waiter.done() and request is not None
                            and await request.is_disconnected()):
                        raise ClientDisconnect()
            return waiter.result()
        except TimeoutError:
            self._abandon(fut, job, waiter)
            self._metrics.timeouts.inc()
            raise ServiceError(504, "timeout", f"detection exceeded detect_timeout_s="
                               f"{self._timeout_s}") from None
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


class BodyBudget:
    """Bytes of request bodies held (being received or screened) across all requests.

    Parameters
    ----------
    capacity_bytes : int
        Budget in bytes (``max_receiving_bytes``).
    retry_after_s : int
        ``Retry-After`` of the 503 sent when a body would not fit.
    """

    def __init__(self, capacity_bytes: int, retry_after_s: int) -> None:
        self.capacity_bytes = capacity_bytes
        self.retry_after_s = retry_after_s
        self.held_bytes = 0
        self._lock = threading.Lock()

    def take(self, request: Request, n_bytes: int) -> None:
        """Hold ``n_bytes`` more for ``request`` or raise 503 ``overloaded``."""
        with self._lock:
            if self.held_bytes + n_bytes > self.capacity_bytes:
                raise ServiceError(503, "overloaded", f"request bodies being received hold "
                                   f"{self.held_bytes} bytes; {n_bytes} more would pass "
                                   f"max_receiving_bytes={self.capacity_bytes}; retry later",
                                   headers={"Retry-After": str(self.retry_after_s)})
            self.held_bytes += n_bytes
        request.state.body_held_bytes = getattr(request.state, "body_held_bytes", 0) + n_bytes

    def give_back(self, request: Request) -> None:
        """Return everything ``request`` holds (idempotent)."""
        n = getattr(request.state, "body_held_bytes", 0)
        if n:
            request.state.body_held_bytes = 0
            with self._lock:
                self.held_bytes -= n


@dataclass
class ServiceState:
    """Everything routes need, built once by `service.app.create_app`."""

    settings: ServiceSettings
    config: AppConfig
    metrics: Metrics
    pool: DetectPool
    bodies: BodyBudget | None = None
    ready: bool = False
    extra: dict = field(default_factory=dict)


def get_service(request: Request) -> ServiceState:
    """The app's `ServiceState`."""
    return request.app.state.service


_bearer = HTTPBearer(auto_error=False, description="Required when LISHIELD_API_TOKEN is set.")


def _check_token(svc: ServiceState, creds: HTTPAuthorizationCredentials | None) -> None:
    token = svc.settings.api_token
    if token is None:
        return
    expected = token.get_secret_value().encode()
    given = creds.credentials.encode() if creds is not None else b""
    if creds is None or not hmac.compare_digest(given, expected):
        raise ServiceError(401, "unauthorized", "missing or wrong bearer token",
                           headers={"WWW-Authenticate": 'Bearer realm="lishield-guard"'})


def require_token(svc: ServiceState = Depends(get_service),
                  creds: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    """Dependency of every ``/v1`` route: bearer token when one is configured."""
    _check_token(svc, creds)


def require_metrics_token(svc: ServiceState = Depends(get_service),
                          creds: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    """Dependency of ``/metrics``: bearer token only when ``protect_metrics`` is set."""
    if svc.settings.protect_metrics:
        _check_token(svc, creds)


def _too_large(n_bytes: int | str, cap_bytes: int) -> ServiceError:
    return ServiceError(413, PayloadTooLargeError.code,
                        f"request body has {n_bytes} bytes > limit of {cap_bytes} bytes")


async def read_body(request: Request, cap_bytes: int) -> bytes:
    """Read the request body, refusing it as soon as it exceeds ``cap_bytes``.

    The bytes held count against the service's `BodyBudget` until `release_body`, and the
    whole body must arrive within ``body_timeout_s``.

    Parameters
    ----------
    request : Request
        The incoming request; a ``Content-Length`` above the cap is refused before reading.
    cap_bytes : int
        Largest body accepted, in bytes.

    Returns
    -------
    bytes

    Raises
    ------
    ServiceError
        413 ``payload_too_large`` past the cap, 400 ``invalid_request`` for a bad
        ``Content-Length``, 408 ``body_timeout`` for a body slower than ``body_timeout_s``,
        503 ``overloaded`` when the body would not fit the receiving budget.
    starlette.requests.ClientDisconnect
        When the client goes away mid-body (answered as 499 ``client_disconnected``).
    """
    svc: ServiceState = request.app.state.service
    budget = svc.bodies
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise ServiceError(400, "invalid_request", f"bad Content-Length {declared!r}")
        if int(declared) > cap_bytes:
            raise _too_large(declared, cap_bytes)
        if budget is not None:
            budget.take(request, int(declared))
    timeout_s = svc.settings.body_timeout_s
    chunks: list[bytes] = []
    n = 0
    try:
        async with asyncio.timeout(timeout_s):
            async for chunk in request.stream():
                if not chunk:
                    continue
                n += len(chunk)
                request.state.bytes_received = n
                if n > cap_bytes:
                    raise _too_large(f"more than {cap_bytes}", cap_bytes)
                if budget is not None and declared is None:
                    budget.take(request, len(chunk))
                chunks.append(chunk)
    except TimeoutError:
        raise ServiceError(408, "body_timeout", f"request body not received within "
                           f"body_timeout_s={timeout_s} ({n} bytes arrived)",
                           headers={"Connection": "close"}) from None
    return b"".join(chunks)


def release_body(request: Request) -> None:
    """Give the bytes a request's body held back to the receiving budget."""
    budget = request.app.state.service.bodies
    if budget is not None:
        budget.give_back(request)


async def read_form(request: Request, cap_bytes: int, *, max_files: int) -> FormData:
    """Read a multipart body under ``cap_bytes`` (while streaming), then parse it.

    Raises
    ------
    ServiceError
        413 ``payload_too_large`` past the cap; 400 ``invalid_multipart`` when the multipart
        framing is broken or holds more than ``max_files`` files.
    """
    body = await read_body(request, cap_bytes)
    sent = False

    async def replay() -> dict:
        nonlocal sent
        if sent:
            return {"type": "http.disconnect"}
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    try:
        return await Request(request.scope, replay).form(max_files=max_files, max_fields=100)
    except StarletteHTTPException as exc:
        raise ServiceError(400, "invalid_multipart", f"cannot parse multipart body: "
                           f"{exc.detail}") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ServiceError(400, "invalid_multipart", f"cannot parse multipart body: {exc}"
                           ) from None


def empty_body() -> ServiceError:
    """400 ``empty_body``: there is nothing to screen."""
    return ServiceError(400, "empty_body", "no image bytes: send the image as multipart field "
                        "'file' or as the raw request body")


async def upload_bytes(upload: UploadFile, cap_bytes: int) -> bytes:
    """Bytes of one multipart file part, at most ``cap_bytes``."""
    data = await upload.read(cap_bytes + 1)
    if len(data) > cap_bytes:
        raise ServiceError(413, PayloadTooLargeError.code,
                           f"file has more than {cap_bytes} bytes (max_upload_bytes)")
    if not data:
        raise empty_body()
    return data


async def read_image(request: Request, settings: ServiceSettings) -> bytes:
    """Image bytes of ``/v1/screen``: multipart field ``file``, or else the raw body."""
    svc: ServiceState = request.app.state.service
    if svc.pool.full():  # refuse before receiving megabytes that could not be screened
        raise svc.pool.overloaded()
    cap = settings.max_upload_bytes
    if request.headers.get("content-type", "").lower().startswith(MULTIPART):
        form = await read_form(request, cap + settings.multipart_overhead_bytes, max_files=1)
        try:
            upload = form.get("file")
            if upload is None:
                raise ServiceError(422, "invalid_request", "multipart body needs a file field "
                                   "named 'file'")
            if not isinstance(upload, UploadFile):
                raise ServiceError(422, "invalid_request", "multipart field 'file' must be a "
                                   "file part (with a filename)")
            return await upload_bytes(upload, cap)
        finally:
            await form.close()
    data = await read_body(request, cap)
    if not data:
        raise empty_body()
    return data
