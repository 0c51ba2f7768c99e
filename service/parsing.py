"""Request parsing: capped body reading, multipart forms, the media (image or video) of a
request."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

from fastapi import Request
from starlette.datastructures import FormData, UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException

from lishield_guard.batch.types import IMAGE, SNIFF_BYTES, MediaKind, kind_of_bytes
from service.deps import ServiceState
from service.errors import ServiceError
from service.limits import too_large
from service.settings import ServiceSettings

__all__ = ["MULTIPART", "Media", "empty_body", "media_of", "read_body", "read_form",
           "read_media", "release_body", "upload_bytes"]

MULTIPART = "multipart/form-data"


async def read_body(request: Request, cap_bytes: int, *, setting: str) -> bytes:
    """Read the request body, refusing it as soon as it exceeds ``cap_bytes``.

    The bytes held count against the service's `BodyBudget` until `release_body`, and the
    whole body must arrive within ``body_timeout_s``.

    Parameters
    ----------
    request : Request
        The incoming request; a ``Content-Length`` above the cap is refused before reading.
    cap_bytes : int
        Largest body accepted, in bytes.
    setting : str
        The settings that make ``cap_bytes``, named by the 413 (`service.limits.too_large`).

    Returns
    -------
    bytes

    Raises
    ------
    ServiceError
        413 ``payload_too_large`` past the cap, 400 ``invalid_request`` for a bad
        ``Content-Length``, 408 ``body_timeout`` for a body slower than ``body_timeout_s``,
        503 ``overloaded`` when the body would not fit the receiving budget.
    starlette.requests.ClientDisconnect
        When the client goes away mid-body (answered as 499 ``client_disconnected``).
    """
    svc: ServiceState = request.app.state.service
    budget = svc.bodies
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.isdigit():
            raise ServiceError(400, "invalid_request", f"bad Content-Length {declared!r}")
        if int(declared) > cap_bytes:
            raise too_large(int(declared), cap_bytes, setting=setting)
        if budget is not None:
            budget.take(request, int(declared))
    timeout_s = svc.settings.body_timeout_s
    chunks: list[bytes] = []
    n = 0
    try:
        async with asyncio.timeout(timeout_s):
            async for chunk in request.stream():
                if not chunk:
                    continue
                n += len(chunk)
                request.state.bytes_received = n
                if n > cap_bytes:
                    raise too_large(None, cap_bytes, setting=setting)
                if budget is not None and declared is None:
                    budget.take(request, len(chunk))
                chunks.append(chunk)
    except TimeoutError:
        raise ServiceError(408, "body_timeout", f"request body not received within "
                           f"body_timeout_s={timeout_s} ({n} bytes arrived)",
                           headers={"Connection": "close"}) from None
    return b"".join(chunks)


def release_body(request: Request) -> None:
    """Give the bytes a request's body held back to the receiving budget."""
    budget = request.app.state.service.bodies
    if budget is not None:
        budget.give_back(request)


async def read_form(request: Request, cap_bytes: int, *, setting: str, max_files: int
                    ) -> FormData:
    """Read a multipart body under ``cap_bytes`` (while streaming), then parse it.

    Raises
    ------
    ServiceError
        413 ``payload_too_large`` past the cap; 400 ``invalid_multipart`` when the multipart
        framing is broken or holds more than ``max_files`` files.
    """
    body = await read_body(request, cap_bytes, setting=setting)
    sent = False

    async def replay() -> dict:
        nonlocal sent
        if sent:
            return {"type": "http.disconnect"}
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    try:
        return await Request(request.scope, replay).form(max_files=max_files, max_fields=100)
    except StarletteHTTPException as exc:
        raise ServiceError(400, "invalid_multipart", f"cannot parse multipart body: "
                           f"{exc.detail}") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ServiceError(400, "invalid_multipart", f"cannot parse multipart body: {exc}"
                           ) from None


def empty_body() -> ServiceError:
    """400 ``empty_body``: there is nothing to screen."""
    return ServiceError(400, "empty_body", "no image or video bytes: send the file as "
                        "multipart field 'file' or as the raw request body")


@dataclass(frozen=True)
class Media:
    """The bytes of one upload and the kind they are (`lishield_guard.batch.types`)."""

    data: bytes
    kind: MediaKind


def media_of(data: bytes, settings: ServiceSettings) -> Media:
    """Tell an upload's kind by its bytes and hold it to that kind's size cap.

    A video is what `VIDEO.sniff` recognises (MP4/MOV, WebM/Matroska); anything else is
    screened as an image, as `lishield_guard.video.detect_media` does. The declared
    content type does not decide.

    Raises
    ------
    ServiceError
        400 ``empty_body`` for no bytes; 413 ``payload_too_large`` past the kind's cap
        (``max_upload_bytes`` or ``max_video_upload_bytes``).
    """
    if not data:
        raise empty_body()
    kind = kind_of_bytes(data[:SNIFF_BYTES]) or IMAGE  # the media kinds registry
    name, cap = settings.upload_cap(kind.name)
    if len(data) > cap:
        raise too_large(len(data), cap, setting=name, what=f"the {kind.name}")
    return Media(data, kind)


async def upload_bytes(upload: UploadFile, cap_bytes: int, *, setting: str) -> bytes:
    """Bytes of one multipart file part, at most ``cap_bytes`` (set by ``setting``)."""
    data = await upload.read(cap_bytes + 1)
    if len(data) > cap_bytes:
        raise too_large(None, cap_bytes, setting=setting, what="the file")
    if not data:
        raise empty_body()
    return data


async def read_media(request: Request, settings: ServiceSettings) -> Media:
    """The upload of ``/v1/screen``: multipart field ``file``, or else the raw body.

    Up to `ServiceSettings.max_media_bytes` are read; `media_of` then holds the bytes to
    their kind's cap.
    """
    svc: ServiceState = request.app.state.service
    if svc.pool.full():  # refuse before receiving megabytes that could not be screened
        raise svc.pool.overloaded()
    name, cap = settings.media_cap()
    if request.headers.get("content-type", "").lower().startswith(MULTIPART):
        form = await read_form(request, cap + settings.multipart_overhead_bytes,
                               setting=f"{name} + multipart_overhead_bytes", max_files=1)
        try:
            upload = form.get("file")
            if upload is None:
                raise ServiceError(422, "invalid_request", "multipart body needs a file field "
                                   "named 'file'")
            if not isinstance(upload, UploadFile):
                raise ServiceError(422, "invalid_request", "multipart field 'file' must be a "
                                   "file part (with a filename)")
            return media_of(await upload_bytes(upload, cap, setting=name), settings)
        finally:
            await form.close()
    return media_of(await read_body(request, cap, setting=name), settings)
