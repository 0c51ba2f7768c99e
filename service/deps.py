"""Route dependencies: the service state, its accessor and bearer-token auth.

Limits live in `service.limits`, the detection pool in `service.pool`, request parsing in
`service.parsing`.
"""

from __future__ import annotations

import asyncio
import hmac
from dataclasses import dataclass

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from lishield_guard import AppConfig
from service.errors import ServiceError
from service.limits import BodyBudget
from service.metrics import Metrics
from service.pool import DetectPool
from service.settings import ServiceSettings

__all__ = ["ServiceState", "get_service", "require_metrics_token", "require_token"]


@dataclass
class ServiceState:
    """Everything routes need, built once by `service.app.create_app`."""

    settings: ServiceSettings
    config: AppConfig
    metrics: Metrics
    pool: DetectPool
    bodies: BodyBudget | None = None
    ready: bool = False
    plot_slots: asyncio.Semaphore | None = None  # figures drawn at once (review routes)


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
