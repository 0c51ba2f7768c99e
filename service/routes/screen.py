"""``POST /v1/screen`` and ``POST /v1/screen/batch``: image bytes in, verdicts out."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request
from starlette.datastructures import UploadFile
from starlette.requests import ClientDisconnect

from lishield_guard import Verdict
from lishield_guard.batch.types import IMAGE
from service.deps import ServiceState, get_service, require_token
from service.errors import ServiceError, describe
from service.parsing import MULTIPART, read_form, read_image, release_body, upload_bytes
from service.schemas import BatchEntry, BatchResult, ErrorBody, ScreenResult

__all__ = ["router"]

router = APIRouter(prefix="/v1", tags=["screening"], dependencies=[Depends(require_token)])

#: Image types the decoder reads; the bytes decide, whatever the declared type says.
IMAGE_MEDIA_TYPES = IMAGE.media_types  # the one type table (lishield_guard.batch.types)
_IMAGE = {"type": "string", "format": "binary", "contentMediaType": "image/*", "minLength": 1,
          "description": "Image bytes: " + ", ".join(IMAGE_MEDIA_TYPES) + " (judged by the "
          "bytes; anything else is answered 415 or 422)."}
_BINARY = {"schema": _IMAGE}
_IMAGE_PART = {"contentType": ", ".join(IMAGE_MEDIA_TYPES)}
_SCREEN_BODY = {"requestBody": {"required": True, "content": {
    MULTIPART: {"schema": {"type": "object", "required": ["file"],
                           "properties": {"file": _IMAGE}},
                "encoding": {"file": _IMAGE_PART}},
    "application/octet-stream": _BINARY, **{t: _BINARY for t in IMAGE_MEDIA_TYPES}}}}
# maxItems is set from the running settings by service.app (max_batch_files)
_BATCH_BODY = {"requestBody": {"required": True, "content": {
    MULTIPART: {"schema": {"type": "object", "required": ["files"], "properties": {
        "files": {"type": "array", "minItems": 1, "items": _IMAGE}}},
        "encoding": {"files": _IMAGE_PART}}}}}


def _errors(*statuses: int) -> dict:
    return {s: {"model": ErrorBody} for s in statuses}


_EXPLAIN = Query(False, description="Include the detector's evidence (tones, ratios, blocks).")


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
             summary="Screen one image", openapi_extra=_SCREEN_BODY,
             responses=_errors(400, 401, 408, 413, 415, 422, 503, 504))
async def screen(request: Request, explain: bool = _EXPLAIN,
                 svc: ServiceState = Depends(get_service)) -> ScreenResult:
    """Screen one image sent as multipart field ``file`` or as the raw body (any type).

    ``status`` is protected, clean or undetermined (the detector could not look at the
    image, e.g. under 64 lines on every axis; ``undetermined_reason`` says why).
    """
    try:
        data = await read_image(request, svc.settings)
        verdict = await svc.pool.detect(data, request=request)
    finally:
        release_body(request)
    return _result(request, svc, verdict, explain)


@router.post("/screen/batch", response_model=BatchResult, response_model_exclude_unset=True,
             summary="Screen several images", openapi_extra=_BATCH_BODY,
             responses=_errors(400, 401, 408, 413, 415, 422, 503))
async def screen_batch(request: Request, explain: bool = _EXPLAIN,
                       svc: ServiceState = Depends(get_service)) -> BatchResult:
    """Screen multipart files ``files`` (or ``file``); a bad file gets its own error entry."""
    s = svc.settings
    if not request.headers.get("content-type", "").lower().startswith(MULTIPART):
        raise ServiceError(415, "unsupported_media_type", "batch needs multipart/form-data "
                           "with one or more file fields named 'files'")
    if svc.pool.full():
        raise svc.pool.overloaded()
    try:
        form = await read_form(request, s.max_batch_bytes, max_files=s.max_batch_files + 1)
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
        entries = []
        for i, part in enumerate(parts):
            entry = BatchEntry(index=i, filename=part.filename, status=200)
            try:
                verdict = await svc.pool.detect(await upload_bytes(part, s.max_upload_bytes),
                                              request=request)
                entry.result = _result(request, svc, verdict, explain, record=False)
            except ClientDisconnect:
                raise  # the client left: the remaining files are not screened
            except Exception as exc:  # noqa: BLE001 - typed errors become per-file entries
                status, code, message, _ = describe(exc)
                if code == "internal_error":
                    raise
                entry.status, entry.error = status, ErrorBody(code=code, message=message)
            entries.append(entry)
    finally:
        await form.close()
        release_body(request)
    return BatchResult(request_id=request.state.request_id, results=entries)
