"""Request ids, one structured JSON access-log line per request, and request metrics."""

from __future__ import annotations

import functools
import json
import logging
import re
import sys
import time
import uuid
from typing import Any

import pythonjsonlogger.core
import pythonjsonlogger.json
from starlette.requests import Request

from service.errors import error_response
from service.metrics import Metrics

__all__ = ["ACCESS_LOGGER", "JsonFormatter", "RequestContextMiddleware", "configure_logging"]

ACCESS_LOGGER = "lishield_guard.service.access"
_REQUEST_ID_RE = re.compile(r"^[A-Za-z0-9._:\-]{1,128}$")


class JsonFormatter(pythonjsonlogger.json.JsonFormatter):
    """One JSON object per record (python-json-logger): ``ts`` (UTC, milliseconds), ``level``,
    ``logger``, ``msg``, then the record's ``fields`` (``extra={"fields": {...}}``) and ``exc``
    when an exception is logged; compact separators, anything else as ``str``."""

    def __init__(self) -> None:
        super().__init__("%(levelname)s %(name)s %(message)s",
                         rename_fields={"levelname": "level", "name": "logger",
                                        "message": "msg", "exc_info": "exc"},
                         reserved_attrs=[*pythonjsonlogger.core.RESERVED_ATTRS, "fields"],
                         json_serializer=functools.partial(json.dumps, separators=(",", ":")),
                         json_default=str)

    def add_fields(self, log_data: dict[str, Any], record: logging.LogRecord,
                   message_dict: dict[str, Any]) -> None:
        log_data["ts"] = (time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
                          + f".{int(record.msecs):03d}Z")
        super().add_fields(log_data, record, message_dict)
        log_data["level"] = str(log_data["level"]).lower()
        exc = log_data.pop("exc", None)
        log_data.update(getattr(record, "fields", {}))
        if exc is not None:
            log_data["exc"] = exc


def configure_logging(level: str = "INFO") -> None:
    """Send the service's loggers to stderr as JSON lines (idempotent; root logger untouched)."""
    logger = logging.getLogger("lishield_guard.service")
    logger.setLevel(level.upper())
    if not any(getattr(h, "_lishield", False) for h in logger.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(JsonFormatter())
        handler._lishield = True  # type: ignore[attr-defined]
        logger.addHandler(handler)
        logger.propagate = False


def _request_id(scope: dict) -> str:
    for name, value in scope.get("headers", ()):
        if name == b"x-request-id":
            text = value.decode("latin-1")
            if _REQUEST_ID_RE.match(text):
                return text
    return uuid.uuid4().hex


class RequestContextMiddleware:
    """Pure ASGI middleware: request id, in-flight gauge, access log line and request metrics.

    Parameters
    ----------
    app : ASGI app
        The wrapped application.
    metrics : Metrics
        Where request counts, latency and bytes go.
    """

    def __init__(self, app, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics
        self.log = logging.getLogger(ACCESS_LOGGER)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        state = scope.setdefault("state", {})
        rid = state["request_id"] = _request_id(scope)
        status = 500
        started = False

        async def send_wrapper(message) -> None:
            nonlocal status, started
            if message["type"] == "http.response.start":
                status, started = message["status"], True
                message.setdefault("headers", [])
                message["headers"] = [*message["headers"], (b"x-request-id", rid.encode())]
            await send(message)

        self.metrics.in_flight.inc()
        try:
            await self.app(scope, receive, send_wrapper)
        except Exception as exc:
            status = 500
            state.setdefault("error_code", "internal_error")
            if started:  # the response is on its way: nothing left to answer with
                raise
            # answer here, inside the request's context: the 500 carries its X-Request-ID,
            # is logged once, and the connection stays usable
            await error_response(Request(scope, receive), exc)(scope, receive, send_wrapper)
        finally:
            self.metrics.in_flight.dec()
            self._record(scope, state, status, time.perf_counter() - t0)

    def _record(self, scope: dict, state: dict, status: int, elapsed_s: float) -> None:
        route = getattr(scope.get("route"), "path", "unmatched")
        code = state.get("error_code")
        outcome = "ok" if status < 400 else (code or f"http_{status}")
        received = int(state.get("bytes_received", 0))
        m = self.metrics
        m.requests.labels(route, scope["method"], outcome).inc()
        m.latency.labels(route).observe(elapsed_s)
        if received:
            m.bytes_received.labels(route).inc(received)
        self.log.info("request", extra={"fields": {
            "event": "access", "request_id": state.get("request_id"), "method": scope["method"],
            "path": scope["path"], "route": route, "status": status, "outcome": outcome,
            "code": code, "verdict": state.get("verdict_status"),
            "protected": state.get("protected"), "policy": state.get("policy"),
            "bytes": received, "duration_ms": round(elapsed_s * 1e3, 3)}})
