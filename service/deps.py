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

from lishield_guard import AppConfig, PayloadTooLargeError, Verdict
from service.errors import ServiceError
from service.metrics import Metrics
from service.settings import ServiceSettings

__all__ = ["DetectFn", "DetectPool", "ServiceState", "get_service", "read_body", "read_form",
           "read_image", "require_metrics_token", "require_token"]

DetectFn = Callable[[bytes, AppConfig], Verdict]
MULTIPART = "multipart/form-data"


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
    A detection that times out keeps its admission slot until its thread really finishes, so
    timed-out work can never push more than ``max_concurrency + max_queue`` detections into the
    pool.
    """

    def __init__(self, detect_fn: DetectFn, config: AppConfig, settings: ServiceSettings,
                 metrics: Metrics) -> None:
        self.executor = ThreadPoolExecutor(max_workers=settings.max_concurrency,
                                           thread_name_prefix="lishield-detect")
        self._detect_fn = detect_fn
        self._config = config
        self._capacity = settings.max_concurrency + settings.max_queue
        self._timeout_s = settings.detect_timeout_s
        self._retry_after_s = settings.retry_after_s
        self._metrics = metrics
        self._admitted = 0
        self._lock = threading.Lock()

    def _release(self, _fut: Future | None = None) -> None:
        with self._lock:
            self._admitted -= 1
        self._metrics.detections_in_flight.dec()

    async def detect(self, data: bytes) -> Verdict:
        """Detect in a worker thread; 503 ``overloaded`` when full, 504 ``timeout`` when slow."""
        with self._lock:
            if self._admitted >= self._capacity:
                self._metrics.rejected_overload.inc()
                raise ServiceError(503, "overloaded", f"{self._admitted} detections in flight or "
                                   f"queued (max_concurrency + max_queue = {self._capacity}); "
                                   "retry later", headers={"Retry-After": str(self._retry_after_s)})
            self._admitted += 1
        self._metrics.detections_in_flight.inc()
        try:
            fut = self.executor.submit(self._detect_fn, data, self._config)
        except BaseException:
            self._release()
            raise
        fut.add_done_callback(self._release)
        try:
            return await asyncio.wait_for(asyncio.wrap_future(fut), self._timeout_s)
        except TimeoutError:
            fut.cancel()
            self._metrics.timeouts.inc()
            raise ServiceError(504, "timeout", f"detection exceeded detect_timeout_s="
                               f"{self._timeout_s}") from None

    def shutdown(self) -> None:
        """Stop accepting work; queued detections are cancelled."""
        self.executor.shutdown(wait=False, cancel_futures=True)


@dataclass
class ServiceState:
    """Everything routes need, built once by `service.app.create_app`."""

    settings: ServiceSettings
    config: AppConfig
    metrics: Metrics
    pool: DetectPool
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
        ``Content-Length``.
    """
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise ServiceError(400, "invalid_request", f"bad Content-Length {declared!r}")
        if int(declared) > cap_bytes:
            raise _too_large(declared, cap_bytes)
    buf = bytearray()
    async for chunk in request.stream():
        buf += chunk
        request.state.bytes_received = len(buf)
        if len(buf) > cap_bytes:
            raise _too_large(f"more than {cap_bytes}", cap_bytes)
    return bytes(buf)


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
