"""FastAPI app factory of the upload-screening service."""

from __future__ import annotations

import asyncio
import dataclasses
from contextlib import asynccontextmanager

import numpy as np
from fastapi import FastAPI

import lishield_guard
from lishield_guard import AppConfig, Limits, load_config
from lishield_guard.threads import one_thread_per_worker
from service.access_log import RequestContextMiddleware, configure_logging
from service.deps import DetectFn, DetectPool, ServiceState
from service.errors import install_error_handlers
from service.metrics import Metrics
from service.routes import ops, policies, screen
from service.settings import ServiceSettings

__all__ = ["create_app", "effective_config"]

WARMUP_SHAPE_ROWS_COLS = (256, 256)


def effective_config(settings: ServiceSettings) -> AppConfig:
    """Load the config file and tighten its limits with the service settings.

    Raises
    ------
    ConfigError
        If the file is unreadable or invalid (the service must not start then).
    """
    cfg = load_config(settings.config_path)
    limits = Limits(max_pixels=settings.max_pixels or cfg.limits.max_pixels,
                    max_bytes=min(cfg.limits.max_bytes, settings.max_upload_bytes))
    return dataclasses.replace(cfg, limits=limits)


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
        ``detect_fn(data, config) -> Verdict``; default `lishield_guard.detect` (tests inject
        slow ones).

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
    pool = DetectPool(detect_fn or lishield_guard.detect, config, settings, metrics)
    state = ServiceState(settings=settings, config=config, metrics=metrics, pool=pool)

    @asynccontextmanager
    async def lifespan(_app: FastAPI):
        one_thread_per_worker()  # detections run side by side in threads: one BLAS thread each
        if settings.warmup:
            loop = asyncio.get_running_loop()
            await loop.run_in_executor(pool.executor, lishield_guard.detect, _warmup_image(),
                                       config)
        state.ready = True
        try:
            yield
        finally:
            state.ready = False
            pool.shutdown()

    app = FastAPI(title="lishield-guard upload screening",
                  version=lishield_guard.__version__,
                  summary="Does an uploaded photo carry a LiShield privacy barcode?",
                  lifespan=lifespan)
    app.state.service = state
    install_error_handlers(app)
    for module in (screen, policies, ops):
        app.include_router(module.router)
    app.add_middleware(RequestContextMiddleware, metrics=metrics)
    return app
