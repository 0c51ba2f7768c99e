"""FastAPI app factory of the upload-screening service."""

from __future__ import annotations

import asyncio
import dataclasses
from contextlib import asynccontextmanager

import numpy as np
from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi_offline import FastAPIOffline

import lishield_guard
from lishield_guard import AppConfig, Limits, load_config
from lishield_guard.threads import one_thread_per_worker
from lishield_guard.video import detect_media
from service.access_log import RequestContextMiddleware, configure_logging
from service.deps import ServiceState
from service.errors import install_error_handlers
from service.limits import BodyBudget
from service.metrics import Metrics
from service.pool import DetectFn, DetectPool
from service.routes import ops, policies, review, screen
from service.settings import ServiceSettings

__all__ = ["create_app", "effective_config"]

WARMUP_SHAPE_ROWS_COLS = (256, 256)


def effective_config(settings: ServiceSettings) -> AppConfig:
    """Load the config file and tighten its limits with the service settings (the image
    limits with ``max_upload_bytes`` and the pixel and decode caps, the video's ``max_bytes``
    with ``max_video_upload_bytes``).

    Raises
    ------
    ConfigError
        If the file is unreadable or invalid (the service must not start then).
    """
    cfg = load_config(settings.config_path)
    limits = Limits(max_pixels=settings.max_pixels or cfg.limits.max_pixels,
                    max_bytes=min(cfg.limits.max_bytes, settings.max_upload_bytes),
                    max_decode_bytes=settings.max_decode_bytes or cfg.limits.max_decode_bytes)
    video_limits = dataclasses.replace(cfg.video.limits, max_bytes=min(
        cfg.video.limits.max_bytes, settings.max_video_upload_bytes))
    video = dataclasses.replace(cfg.video, limits=video_limits)
    return dataclasses.replace(cfg, limits=limits, video=video)


def _tighten_openapi(app: FastAPI, settings: ServiceSettings) -> None:
    """Make the OpenAPI schema as strict as the running server: the batch's file count."""

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, summary=app.summary,
                                 routes=app.routes)
            body = (schema.get("paths", {}).get("/v1/screen/batch", {}).get("post", {})
                    .get("requestBody", {}).get("content", {}).get("multipart/form-data"))
            if body:
                body["schema"]["properties"]["files"]["maxItems"] = settings.max_batch_files
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _warmup_image() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, size=WARMUP_SHAPE_ROWS_COLS, dtype=np.uint8)


def create_app(settings: ServiceSettings | None = None, *, detect_fn: DetectFn | None = None
               ) -> FastAPI:
    """Build the upload-screening app.

    Parameters
    ----------
    settings : ServiceSettings, optional
        Default: read from ``LISHIELD_*`` environment variables.
    detect_fn : callable, optional
        ``detect_fn(data, config) -> Verdict``; default `lishield_guard.video.detect_media`
        (a video when the bytes are one, else an image; tests inject slow ones).

    Returns
    -------
    FastAPI

    Raises
    ------
    ConfigError
        If the configured TOML file is invalid: fail at startup, never per request.
    """
    settings = settings or ServiceSettings()
    configure_logging(settings.log_level)
    config = effective_config(settings)
    metrics = Metrics()
    pool = DetectPool(detect_fn or detect_media, config, settings, metrics)
    bodies = BodyBudget(settings.max_receiving_bytes, settings.retry_after_s)
    state = ServiceState(settings=settings, config=config, metrics=metrics, pool=pool,
                         bodies=bodies)

    @asynccontextmanager
    async def lifespan(_app: FastAPI):
        one_thread_per_worker()  # detections run side by side in threads: one BLAS thread each
        if settings.warmup:
            loop = asyncio.get_running_loop()
            await loop.run_in_executor(None, pool.warmup, _warmup_image())
        state.ready = True
        try:
            yield
        finally:
            state.ready = False
            pool.shutdown()

    # /docs and /redoc with Swagger UI and ReDoc served from the package (fastapi-offline):
    # no CDN, so the docs work on an air-gapped host.
    app = FastAPIOffline(title="lishield-guard upload screening",
                         version=lishield_guard.__version__,
                         summary="Does an uploaded photo or video carry a LiShield privacy "
                         "barcode?",
                         lifespan=lifespan)
    app.state.service = state
    install_error_handlers(app)
    for module in (screen, policies, ops, review):
        app.include_router(module.router)
    app.include_router(ops.metrics_router(
        protected=settings.protect_metrics and settings.api_token is not None))
    _tighten_openapi(app, settings)
    app.add_middleware(RequestContextMiddleware, metrics=metrics)
    return app
