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


def too_large(n_bytes: int | str, cap_bytes: int, *, what: str = "request body") -> ServiceError:
    """413 ``payload_too_large``: ``what`` has ``n_bytes`` bytes > ``cap_bytes``."""
    return ServiceError(413, PayloadTooLargeError.code,
                        f"{what} has {n_bytes} bytes > limit of {cap_bytes} bytes")
