"""The one place where errors become HTTP statuses and ``{"code", "message"}`` JSON bodies.

Detection errors take their code from `lishield_guard.errors.classify`, the mapping ``detect``
and ``scan`` use too, and their status from the code table (`ERROR_CODES`).
"""

from __future__ import annotations

import logging
from enum import StrEnum

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from lishield_guard.errors import ERROR_CODES, ConfigError, LishieldError, classify, error_code

__all__ = ["CLIENT_CLOSED_REQUEST", "ErrorCode", "ServiceError", "describe",
           "install_error_handlers"]

log = logging.getLogger("lishield_guard.service")

# A ConfigError at request time is a bug (config is loaded at startup): 500 ``internal_error``.

_HTTP_CODES = {400: "bad_request", 401: "unauthorized", 403: "forbidden", 404: "not_found",
               405: "method_not_allowed", 406: "not_acceptable", 413: "payload_too_large",
               415: "unsupported_media_type", 422: "invalid_request", 429: "too_many_requests",
               503: "unavailable"}
CLIENT_CLOSED_REQUEST = 499  # nginx's status for a client that went away: never sent, logged

#: Every ``code`` an error answer can carry (the OpenAPI schema lists them as an enum): the
#: codes of `lishield_guard.errors.ERROR_CODES` that have an HTTP status, and ``http_error``.
ErrorCode = StrEnum("ErrorCode", [(e.code, e.code) for e in ERROR_CODES
                                  if e.http_statuses or e.code == "http_error"])


class ServiceError(Exception):
    """An error the service raises itself (auth, limits, overload, timeout).

    Parameters
    ----------
    status : int
        HTTP status.
    code : str
        Stable machine-readable code, e.g. ``"overloaded"``.
    message : str
        Human-readable explanation.
    headers : dict of str to str, optional
        Extra response headers (``Retry-After``, ``WWW-Authenticate``).
    """

    def __init__(self, status: int, code: str, message: str, *,
                 headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.headers = headers or {}


def describe(exc: BaseException) -> tuple[int, str, str, dict[str, str]]:
    """Map any exception to ``(status, code, message, headers)``.

    Parameters
    ----------
    exc : BaseException
        The error to describe.

    Returns
    -------
    status : int
        HTTP status; 500 for anything that is not an expected, typed error.
    code, message : str
        Stable code and human-readable message of the JSON body.
    headers : dict of str to str
        Extra response headers.
    """
    if isinstance(exc, ServiceError):
        return exc.status, exc.code, exc.message, exc.headers
    if isinstance(exc, ClientDisconnect):  # a client event, not a bug: no 500, no traceback
        return (CLIENT_CLOSED_REQUEST, ErrorCode.client_disconnected.value,
                "the client closed the connection before its request was read", {})
    if isinstance(exc, LishieldError) and not isinstance(exc, ConfigError):
        code, message = classify(exc)
        statuses = error_code(code).http_statuses
        if statuses:  # codes without one (files, config) cannot come from an upload: a bug
            return statuses[0], code, message, {}
    if isinstance(exc, RequestValidationError):
        fields = "; ".join(f"{'.'.join(str(p) for p in e.get('loc', ()))}: {e.get('msg', '')}"
                           for e in exc.errors())
        return 422, "invalid_request", f"invalid request: {fields}", {}
    if isinstance(exc, StarletteHTTPException):
        code = _HTTP_CODES.get(exc.status_code, ErrorCode.http_error.value)
        return exc.status_code, code, str(exc.detail), dict(exc.headers or {})
    return 500, "internal_error", "internal error; the request id is in the X-Request-ID header", {}


def error_response(request: Request, exc: BaseException) -> JSONResponse:
    """JSON error response for ``exc``; records the code for the access log and metrics."""
    status, code, message, headers = describe(exc)
    request.state.error_code = code
    if code == ErrorCode.client_disconnected.value:
        log.info("client disconnected during %s %s (request_id=%s)", request.method,
                 request.url.path, getattr(request.state, "request_id", None))
    elif status >= 500 and code == "internal_error":
        log.error("unhandled error on %s %s (request_id=%s)", request.method, request.url.path,
                  getattr(request.state, "request_id", None), exc_info=exc)
    return JSONResponse({"code": code, "message": message}, status_code=status, headers=headers)


async def _handle(request: Request, exc: Exception) -> JSONResponse:
    return error_response(request, exc)


def install_error_handlers(app: FastAPI) -> None:
    """Register the handlers that turn every error into ``{"code", "message"}`` JSON."""
    for cls in (ServiceError, LishieldError, RequestValidationError, StarletteHTTPException,
                ClientDisconnect, Exception):
        app.add_exception_handler(cls, _handle)
