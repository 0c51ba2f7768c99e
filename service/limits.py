"""Limits on what a request may hold: the receiving budget and the size caps' errors."""

from __future__ import annotations

import threading

from fastapi import Request

from lishield_guard import PayloadTooLargeError
from service.errors import ServiceError

__all__ = ["BodyBudget", "too_large"]


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


def too_large(n_bytes: int | None, cap_bytes: int, *, setting: str,
              what: str = "request body") -> ServiceError:
    """413 ``payload_too_large``: ``what`` has ``n_bytes`` bytes, past the setting ``setting``.

    Parameters
    ----------
    n_bytes : int or None
        The size, in bytes; None when the body was cut off once past the cap (its size is
        unknown then).
    cap_bytes : int
        The cap, in bytes.
    setting : str
        The `ServiceSettings` field(s) that set the cap (``"max_batch_bytes"``,
        ``"max_upload_bytes + multipart_overhead_bytes"``): the message names them and their
        environment variables, so the operator knows what to raise.

    Examples
    --------
    >>> err = too_large(None, 1024, setting="max_batch_bytes")
    >>> print(err.message)  # doctest: +NORMALIZE_WHITESPACE
    request body has more than 1024 bytes: the limit is max_batch_bytes = 1024 bytes
    (LISHIELD_MAX_BATCH_BYTES)
    """
    size = f"more than {cap_bytes} bytes" if n_bytes is None else f"{n_bytes} bytes"
    env = " + ".join(f"LISHIELD_{name.strip().upper()}" for name in setting.split("+"))
    return ServiceError(413, PayloadTooLargeError.code, f"{what} has {size}: the limit is "
                        f"{setting} = {cap_bytes} bytes ({env})")
