"""``POST /v1/screen`` and ``POST /v1/screen/batch``: image or video bytes in, verdicts out."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request
from starlette.datastructures import UploadFile
from starlette.requests import ClientDisconnect

from lishield_guard import Verdict
from lishield_guard.batch.types import IMAGE, VIDEO
from service.deps import ServiceState, get_service, require_token
from service.errors import ServiceError, describe
from service.parsing import (
    MULTIPART,
    media_of,
    read_form,
    read_media,
    release_body,
    upload_bytes,
)
from service.schemas import BatchEntry, BatchResult, ErrorBody, ScreenResult

__all__ = ["IMAGE_MEDIA_TYPES", "MEDIA_TYPES", "SCREEN_BODY", "VIDEO_MEDIA_TYPES", "router"]

router = APIRouter(prefix="/v1", tags=["screening"], dependencies=[Depends(require_token)])

#: Image types the decoder reads and video types the video screen reads; the bytes decide,
#: whatever the declared type says (the one type table: lishield_guard.batch.types).
IMAGE_MEDIA_TYPES = IMAGE.media_types
VIDEO_MEDIA_TYPES = VIDEO.media_types
MEDIA_TYPES = IMAGE_MEDIA_TYPES + VIDEO_MEDIA_TYPES
_MEDIA = {"type": "string", "format": "binary", "minLength": 1, "description": (
    "Image bytes (" + ", ".join(IMAGE_MEDIA_TYPES) + "; at most max_upload_bytes) or video "
    "bytes (" + ", ".join(VIDEO_MEDIA_TYPES) + "; at most max_video_upload_bytes). The bytes "
    "decide: an MP4/MOV or WebM/Matroska signature is screened as a video, anything else as "
    "an image (answered 415 or 422 when it is none the decoder reads).")}
_BINARY = {"schema": _MEDIA}
_MEDIA_PART = {"contentType": ", ".join(MEDIA_TYPES)}
SCREEN_BODY = {"requestBody": {"required": True, "content": {
    MULTIPART: {"schema": {"type": "object", "required": ["file"],
                           "properties": {"file": _MEDIA}},
                "encoding": {"file": _MEDIA_PART}},
    "application/octet-stream": _BINARY, **{t: _BINARY for t in MEDIA_TYPES}}}}
# maxItems is set from the running settings by service.app (max_batch_files)
_BATCH_BODY = {"requestBody": {"required": True, "content": {
    MULTIPART: {"schema": {"type": "object", "required": ["files"], "properties": {
        "files": {"type": "array", "minItems": 1, "items": _MEDIA}}},
        "encoding": {"files": _MEDIA_PART}}}}}


def _errors(*statuses: int) -> dict:
    return {s: {"model": ErrorBody} for s in statuses}


_EXPLAIN = Query(False, description="Include the detector's evidence (tones, ratios, blocks; "
                 "for a video also evidence.video: per-frame scores and the deciding frames).")


def _result(request: Request, svc: ServiceState, verdict: Verdict, explain: bool,
            *, record: bool = True) -> ScreenResult:
    status = verdict.status
    label = "undetermined" if status == "undetermined" else (verdict.policy or "none")
    svc.metrics.verdicts.labels(label).inc()
    if record:
        request.state.protected = verdict.protected
        request.state.policy = verdict.policy
        request.state.verdict_status = status
    return ScreenResult(**verdict.to_dict(explain=explain),
                        request_id=request.state.request_id)


@router.post("/screen", response_model=ScreenResult, response_model_exclude_unset=True,
             summary="Screen one image or video", openapi_extra=SCREEN_BODY,
             responses=_errors(400, 401, 408, 413, 415, 422, 503, 504))
async def screen(request: Request, explain: bool = _EXPLAIN,
                 svc: ServiceState = Depends(get_service)) -> ScreenResult:
    """Screen one image or video sent as multipart field ``file`` or as the raw body (any
    declared type: the bytes decide).

    ``status`` is protected, clean or undetermined (the detector could not look at the
    image, e.g. under 64 lines on every axis; ``undetermined_reason`` says why). A video is
    held to ``max_video_upload_bytes`` and ``video_timeout_s``, and refused with 422
    ``undecodable_video`` when broken or truncated, 413 ``video_too_long`` past the
    duration or frame cap.
    """
    try:
        media = await read_media(request, svc.settings)
        verdict = await svc.pool.detect(media.data, kind=media.kind.name, request=request)
    finally:
        release_body(request)
    return _result(request, svc, verdict, explain)


async def _batch_entry(request: Request, svc: ServiceState, index: int, part: UploadFile,
                       explain: bool) -> BatchEntry:
    """One file of a batch screened: its verdict, or its own error entry."""
    entry = BatchEntry(index=index, filename=part.filename, status=200)
    try:
        name, cap = svc.settings.media_cap()
        media = media_of(await upload_bytes(part, cap, setting=name), svc.settings)
        verdict = await svc.pool.detect(media.data, kind=media.kind.name, request=request)
        entry.result = _result(request, svc, verdict, explain, record=False)
    except ClientDisconnect:
        raise  # the client left: the remaining files are not screened
    except Exception as exc:  # noqa: BLE001 - typed errors become per-file entries
        status, code, message, _ = describe(exc)
        if code == "internal_error":
            raise
        entry.status, entry.error = status, ErrorBody(code=code, message=message)
    return entry


@router.post("/screen/batch", response_model=BatchResult, response_model_exclude_unset=True,
             summary="Screen several images or videos", openapi_extra=_BATCH_BODY,
             responses=_errors(400, 401, 408, 413, 415, 422, 503))
async def screen_batch(request: Request, explain: bool = _EXPLAIN,
                       svc: ServiceState = Depends(get_service)) -> BatchResult:
    """Screen multipart files ``files`` (or ``file``), images or videos, one after another
    (each under its own kind's size cap and time budget); a bad file gets its own error
    entry."""
    s = svc.settings
    if not request.headers.get("content-type", "").lower().startswith(MULTIPART):
        raise ServiceError(415, "unsupported_media_type", "batch needs multipart/form-data "
                           "with one or more file fields named 'files'")
    if svc.pool.full():
        raise svc.pool.overloaded()
    try:
        form = await read_form(request, s.max_batch_bytes, setting="max_batch_bytes",
                               max_files=s.max_batch_files + 1)
    except BaseException:
        release_body(request)
        raise
    try:
        parts = [p for p in form.getlist("files") + form.getlist("file")
                 if isinstance(p, UploadFile)]
        if not parts:
            raise ServiceError(422, "invalid_request", "no file fields named 'files'")
        if len(parts) > s.max_batch_files:
            raise ServiceError(422, "too_many_files", f"{len(parts)} files > max_batch_files="
                               f"{s.max_batch_files}")
        entries = [await _batch_entry(request, svc, i, part, explain)
                   for i, part in enumerate(parts)]
    finally:
        await form.close()
        release_body(request)
    return BatchResult(request_id=request.state.request_id, results=entries)
