"""uvicorn's HTTP/1.1 protocol answering requests it cannot parse with the service's JSON errors.

A request whose framing is broken (a ``Content-Length: abc``, a malformed request line or
header) never reaches the app: uvicorn's h11 protocol answers it with a plain-text 400 of its
own. `JSONErrorH11Protocol` answers the same 400 as every other error of the service,
``{"code", "message"}`` JSON: ``invalid_request`` for a bad ``Content-Length`` (the code the
app gives one that reaches it), ``bad_request`` for anything else h11 refuses. Such an answer
has no ``X-Request-ID`` (no request was made) and closes the connection, as uvicorn's does.
Every way of starting the server (``lishield-guard serve``, ``make run``, the tests) passes
`UVICORN_HTTP` as uvicorn's ``http`` setting.
"""

from __future__ import annotations

import json
import sys

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

__all__ = ["UVICORN_HTTP", "JSONErrorH11Protocol", "parse_error_body"]


def parse_error_body(exc: BaseException | None) -> tuple[str, bytes]:
    """``(code, JSON body)`` of the 400 for a request h11 could not parse (``exc``, its
    `h11.RemoteProtocolError`; None when unknown).

    Examples
    --------
    >>> parse_error_body(h11.RemoteProtocolError("bad Content-Length"))[0]
    'invalid_request'
    >>> parse_error_body(None)
    ('bad_request', b'{"code": "bad_request", "message": "malformed HTTP request"}')
    """
    detail = str(exc) if exc is not None and str(exc) else ""
    if "content-length" in detail.lower():
        code, message = "invalid_request", f"bad Content-Length header ({detail})"
    else:
        code = "bad_request"
        message = "malformed HTTP request" + (f" ({detail})" if detail else "")
    return code, json.dumps({"code": code, "message": message}).encode()


class JSONErrorH11Protocol(H11Protocol):
    """`H11Protocol` whose parse-error 400 is JSON with a stable ``code`` (module docstring)."""

    def send_400_response(self, msg: str) -> None:
        """Send the 400 as ``{"code", "message"}`` JSON and close the connection; ``msg`` is
        uvicorn's plain-text reason, replaced by h11's own (the exception being handled)."""
        exc = sys.exc_info()[1]
        _, body = parse_error_body(exc if isinstance(exc, h11.RemoteProtocolError) else None)
        headers = [(b"content-type", b"application/json"), (b"connection", b"close"),
                   (b"content-length", str(len(body)).encode())]
        for event in (h11.Response(status_code=400, headers=headers, reason=b"Bad Request"),
                      h11.Data(data=body), h11.EndOfMessage()):
            self.transport.write(self.conn.send(event))
        self.transport.close()


#: uvicorn's ``http`` setting for this service.
UVICORN_HTTP = JSONErrorH11Protocol
