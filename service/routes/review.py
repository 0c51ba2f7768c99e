"""The reviewer's page and the verdict figure: ``GET /review``, ``POST /v1/review`` and
``POST /v1/screen/plot``.

A trust-and-safety reviewer opens ``/review`` in a browser, drops an image or a video clip,
and sees the verdict, its reason in words, and the figure of what decided it
(`lishield_guard.plot`; for a clip, the deciding frame and the per-frame scores, which the
page also lists as a table). The page and its two assets are served from
``service/static/review/`` (no CDN: it works offline) and carry no data, so they need no
token; the page sends the bearer token the reviewer types (kept in the tab's sessionStorage)
with every ``/v1`` request, as any other client does.

Plotting decodes the image (or a clip's deciding frame) a second time and runs in the
detection pool's threads, after the detection itself was admitted by the pool; at most
``max_concurrency`` figures are drawn at once.
"""

from __future__ import annotations

import asyncio
import base64
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import FileResponse, HTMLResponse, Response
from pydantic import BaseModel, Field

from lishield_guard import Verdict
from service.deps import ServiceState, get_service, require_token
from service.errors import ServiceError
from service.parsing import Media, read_media, release_body
from service.routes.screen import SCREEN_BODY
from service.schemas import ErrorBody

__all__ = ["ReviewResult", "router"]

STATIC_DIR = Path(__file__).resolve().parent.parent / "static" / "review"
ASSETS = {"review.js": "text/javascript", "review.css": "text/css"}  # the only files served

router = APIRouter(tags=["review"])

_ERRORS = {s: {"model": ErrorBody} for s in (400, 401, 408, 413, 415, 422, 503, 504)}


class ReviewResult(BaseModel):
    """What the reviewer's page shows for one image or video."""

    status: str = Field(description="protected, clean or undetermined.")
    title: str = Field(description="The verdict in words.")
    reason: str = Field(description="Why, in words (the deciding stage's reason).")
    verdict: dict[str, Any] = Field(description="Verdict.to_dict(), evidence included.")
    figure_png_base64: str | None = Field(
        default=None, description="The figure of what decided the verdict, PNG, base64.")
    figure_error: str | None = None
    figure_caption: str = Field(default="", description="What the figure shows for this "
                                "verdict: it follows the deciding stage and the status.")
    request_id: str | None = None


def _status(verdict) -> str:
    return str(getattr(verdict, "status", None)
               or ("protected" if verdict.protected else "clean"))


def _reason(verdict) -> str:
    ev = verdict.evidence or {}
    return str(ev.get("reason") or getattr(verdict, "undetermined", None) or "no reason given")


def _verdict_label(verdict) -> str:
    """The ``lishield_verdicts_total`` label, as `/v1/screen` counts it."""
    return "undetermined" if _status(verdict) == "undetermined" else (verdict.policy or "none")


def _plot_slots(svc: ServiceState) -> asyncio.Semaphore:
    if svc.plot_slots is None:
        svc.plot_slots = asyncio.Semaphore(svc.settings.max_concurrency)
    return svc.plot_slots


async def _screen(request: Request, svc: ServiceState) -> tuple[Media, Verdict]:
    """Read the upload, screen it in the pool and record its verdict (log and metrics)."""
    media = await read_media(request, svc.settings)
    verdict = await svc.pool.detect(media.data, kind=media.kind.name, request=request)
    request.state.protected = verdict.protected
    request.state.policy = verdict.policy
    request.state.verdict_status = _status(verdict)
    svc.metrics.verdicts.labels(_verdict_label(verdict)).inc()
    return media, verdict


async def _figure(svc: ServiceState, data: bytes, verdict) -> bytes:
    from lishield_guard.plot import verdict_png  # lazy: matplotlib only when a figure is asked

    async with _plot_slots(svc):
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(svc.pool.executor, verdict_png, data, verdict,
                                          svc.config)


async def _figure_base64(svc: ServiceState, data: bytes, verdict) -> tuple[str | None,
                                                                         str | None]:
    """``(figure PNG as base64, None)``, or ``(None, why)`` when it cannot be drawn."""
    try:
        return base64.b64encode(await _figure(svc, data, verdict)).decode("ascii"), None
    except Exception as exc:  # noqa: BLE001 - the verdict is the answer; the figure is extra
        return None, f"{type(exc).__name__}: {exc}"


@router.get("/review", response_class=HTMLResponse, include_in_schema=False)
async def review_page() -> FileResponse:
    """The reviewer's page: drop an image or a clip, see the verdict, its reason and its
    figure."""
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html")


@router.get("/review/static/{name}", include_in_schema=False)
async def review_asset(name: str) -> FileResponse:
    """The page's script and style sheet (a fixed list; nothing else is served)."""
    if name not in ASSETS:
        raise ServiceError(404, "not_found", f"no asset {name!r}")
    return FileResponse(STATIC_DIR / name, media_type=ASSETS[name])


@router.post("/v1/review", response_model=ReviewResult, summary="Screen one image or video "
             "for a reviewer: verdict, reason and figure", openapi_extra=SCREEN_BODY,
             responses=_ERRORS, dependencies=[Depends(require_token)])
async def review(request: Request, svc: ServiceState = Depends(get_service)) -> ReviewResult:
    """Screen one image or video (multipart field ``file`` or the raw body) and draw its
    figure (a video's: its deciding frame and per-frame scores).

    A figure that cannot be drawn leaves ``figure_png_base64`` null and says why in
    ``figure_error``; the verdict still stands.
    """
    from lishield_guard.plot import figure_caption, verdict_title

    try:
        media, verdict = await _screen(request, svc)
        figure, error = await _figure_base64(svc, media.data, verdict)
    finally:
        release_body(request)
    return ReviewResult(status=_status(verdict), title=verdict_title(verdict),
                        reason=_reason(verdict), verdict=verdict.to_dict(explain=True),
                        figure_png_base64=figure, figure_error=error,
                        figure_caption=figure_caption(verdict),
                        request_id=request.state.request_id)


@router.post("/v1/screen/plot", response_class=Response, summary="Screen one image or video "
             "and return the figure of what decided its verdict (PNG)",
             openapi_extra=SCREEN_BODY,
             responses={200: {"content": {"image/png": {}}}, **_ERRORS},
             dependencies=[Depends(require_token)])
async def screen_plot(request: Request, svc: ServiceState = Depends(get_service)) -> Response:
    """The figure of ``lishield-guard detect --plot`` for an uploaded image or video, as PNG.

    The verdict travels in headers: ``X-Lishield-Status`` (protected, clean or undetermined)
    and ``X-Lishield-Policy`` (the matched policy, or empty).
    """
    try:
        media, verdict = await _screen(request, svc)
        png = await _figure(svc, media.data, verdict)
    finally:
        release_body(request)
    return Response(png, media_type="image/png", headers={
        "X-Lishield-Status": _status(verdict), "X-Lishield-Policy": verdict.policy or "",
        "Cache-Control": "no-store"})
