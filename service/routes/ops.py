"""Operations endpoints: ``/healthz``, ``/readyz`` and Prometheus ``/metrics``."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Response

from service.deps import ServiceState, get_service, require_metrics_token
from service.errors import ServiceError
from service.metrics import CONTENT_TYPE_LATEST
from service.schemas import ErrorBody, Health

__all__ = ["metrics_router", "router"]

router = APIRouter(tags=["operations"])


@router.get("/healthz", response_model=Health)
async def healthz() -> Health:
    """Liveness: the process answers."""
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": ErrorBody}})
async def readyz(svc: ServiceState = Depends(get_service)) -> Health:
    """Readiness: config loaded and the detector warmed up by one detection."""
    if not svc.ready:
        raise ServiceError(503, "not_ready", "warming up the detector")
    return Health(status="ok")


async def metrics(svc: ServiceState = Depends(get_service)) -> Response:
    """Prometheus text exposition."""
    return Response(svc.metrics.render(), media_type=CONTENT_TYPE_LATEST)


def metrics_router(*, protected: bool) -> APIRouter:
    """The ``/metrics`` route, declared (in OpenAPI) exactly as it is enforced.

    Parameters
    ----------
    protected : bool
        Require the bearer token (``protect_metrics`` with an ``api_token`` set).
    """
    r = APIRouter(tags=["operations"])
    if protected:
        r.get("/metrics", response_class=Response,
              dependencies=[Depends(require_metrics_token)],
              responses={200: {"content": {"text/plain": {}}}, 401: {"model": ErrorBody}})(
            metrics)
    else:
        r.get("/metrics", response_class=Response,
              responses={200: {"content": {"text/plain": {}}}})(metrics)
    return r
