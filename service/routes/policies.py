"""``GET /v1/policies``: the loaded policies, detector thresholds and limits (read-only)."""

from __future__ import annotations

import dataclasses

from fastapi import APIRouter, Depends

from service.deps import ServiceState, get_service, require_token
from service.schemas import ErrorBody, PoliciesInfo, PolicyInfo

__all__ = ["router"]

router = APIRouter(prefix="/v1", tags=["config"], dependencies=[Depends(require_token)])


@router.get("/policies", response_model=PoliciesInfo, responses={401: {"model": ErrorBody}})
async def policies(svc: ServiceState = Depends(get_service)) -> PoliciesInfo:
    """Policies the service screens for, with detector thresholds and input limits (images'
    and videos')."""
    cfg = svc.config
    detector = dataclasses.asdict(cfg.detector)  # one table per stage, None: stage off
    return PoliciesInfo(config_source=cfg.source, detector=detector,
                        limits=dataclasses.asdict(cfg.limits),
                        video_limits=dataclasses.asdict(cfg.video.limits),
                        policies=[PolicyInfo(**p.to_dict()) for p in cfg.policies])
