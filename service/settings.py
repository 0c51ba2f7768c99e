"""Service settings from ``LISHIELD_*`` environment variables (pydantic-settings)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from lishield_guard.batch.types import KINDS, kind_named

__all__ = ["ServiceSettings"]


def _default_concurrency() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


class ServiceSettings(BaseSettings):
    """Everything the HTTP service can be told; each field reads ``LISHIELD_<NAME>``.

    Attributes
    ----------
    config_path : Path or None
        Detector/policy TOML file (``LISHIELD_CONFIG_PATH``); None uses the shipped default.
    api_token : SecretStr or None
        Bearer token required on every ``/v1`` route (``LISHIELD_API_TOKEN``); None disables auth.
    protect_metrics : bool
        Also require the token on ``/metrics`` (default True: metrics tell traffic and
        verdict counts; ``LISHIELD_PROTECT_METRICS=false`` opens them). Without
        ``api_token`` nothing is protected; the OpenAPI schema declares what is enforced.
    max_upload_bytes : int
        Largest image accepted, in bytes; the request body of ``/v1/screen`` may exceed it by
        ``multipart_overhead_bytes`` (form boundaries and headers).
    max_video_upload_bytes : int
        Largest video accepted, in bytes (default 128 MiB). A body is read up to the larger of
        the two caps; once its bytes say which kind it is, each kind is held to its own cap.
        The config file's ``video.limits.max_bytes`` is tightened to it.
    multipart_overhead_bytes : int
        Slack for multipart framing on top of ``max_upload_bytes``, in bytes.
    max_batch_files : int
        Most files in one ``/v1/screen/batch`` request.
    max_batch_bytes : int
        Largest request body of ``/v1/screen/batch``, in bytes.
    max_pixels : int or None
        Pixel cap overriding the config file's ``limits.max_pixels``.
    max_decode_bytes : int or None
        Memory budget of one detection, in bytes, overriding the config file's
        ``limits.max_decode_bytes`` (checked from the header before decoding).
    body_timeout_s : float
        Longest time a client may take to send a request body, in seconds; beyond, 408
        ``body_timeout`` (a slow client cannot hold a connection and its buffer forever).
    max_receiving_bytes : int
        Memory budget of request bodies being received or screened across all requests, in
        bytes; a request that would exceed it gets 503 ``overloaded`` with ``Retry-After``.
    max_concurrency : int
        Detections running at once (threads of the detection pool).
    max_queue : int
        Detections allowed to wait for a thread; beyond, requests get 503 ``overloaded``.
    detect_timeout_s : float
        Budget of one image's detection including its queue wait, in seconds; beyond, 504
        ``timeout``.
    video_timeout_s : float
        Budget of one video's screening including its queue wait, in seconds (default 30);
        beyond, 504 ``timeout``.
    detect_isolation : {"process", "thread"}
        Where detections run: ``"process"`` (default) in worker processes that are ended when
        a detection times out or its client leaves, so abandoned work stops at once;
        ``"thread"`` in the pool's threads (``detect_fn`` closures; abandoned work then runs
        to its end).
    retry_after_s : int
        ``Retry-After`` sent with 503 ``overloaded``, in seconds.
    warmup : bool
        Run one detection on a small synthetic array at startup before ``/readyz`` says ready.
    log_level : str
        Level of the JSON access log (``lishield_guard.service.access``).
    """

    model_config = SettingsConfigDict(env_prefix="LISHIELD_", extra="ignore", frozen=True)

    config_path: Path | None = None
    api_token: SecretStr | None = None
    protect_metrics: bool = True
    max_upload_bytes: int = Field(default=32 * 1024 * 1024, ge=1)
    max_video_upload_bytes: int = Field(default=128 * 1024 * 1024, ge=1)
    multipart_overhead_bytes: int = Field(default=64 * 1024, ge=0)
    max_batch_files: int = Field(default=16, ge=1)
    max_batch_bytes: int = Field(default=128 * 1024 * 1024, ge=1)
    max_pixels: int | None = Field(default=None, ge=1)
    max_decode_bytes: int | None = Field(default=None, ge=1)
    body_timeout_s: float = Field(default=60.0, gt=0)
    max_receiving_bytes: int = Field(default=256 * 1024 * 1024, ge=1)
    max_concurrency: int = Field(default_factory=_default_concurrency, ge=1)
    max_queue: int = Field(default=16, ge=0)
    detect_timeout_s: float = Field(default=10.0, gt=0)
    video_timeout_s: float = Field(default=30.0, gt=0)
    detect_isolation: Literal["process", "thread"] = "process"
    retry_after_s: int = Field(default=1, ge=0)
    warmup: bool = True
    log_level: str = "INFO"

    def upload_cap(self, kind: str) -> tuple[str, int]:
        """``(setting name, bytes)``: the size cap of one upload of media ``kind`` (the
        setting its entry of the media kinds registry names, `batch.types.MediaKind`)."""
        name = kind_named(kind).upload_cap
        return name, getattr(self, name)

    def time_budget(self, kind: str) -> tuple[str, float]:
        """``(setting name, seconds)``: the time budget of one detection of media ``kind``."""
        name = kind_named(kind).time_budget
        return name, getattr(self, name)

    @property
    def max_media_bytes(self) -> int:
        """The larger upload cap: how much of a body is read before its kind is known."""
        return self.media_cap()[1]

    def media_cap(self) -> tuple[str, int]:
        """``(setting name, bytes)`` of `max_media_bytes`: the largest upload cap."""
        return max((self.upload_cap(k.name) for k in KINDS), key=lambda c: c[1])
