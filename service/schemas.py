"""Pydantic response models of the HTTP API (separate from the core's dataclasses)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.errors import ErrorCode

__all__ = ["BatchEntry", "BatchResult", "ErrorBody", "Health", "PoliciesInfo", "PolicyInfo",
           "ScreenResult"]


class ErrorBody(BaseModel):
    """Every error answer: a stable machine-readable code and a human-readable message."""

    code: ErrorCode = Field(examples=["unsupported_media_type"])
    message: str


class ScreenResult(BaseModel):
    """One verdict: the fields of ``Verdict.to_dict()`` plus the request id."""

    model_config = ConfigDict(json_schema_extra={"examples": [{
        "status": "protected", "protected": True, "policy": "no-distribution", "matches": 3,
        "required": 2,
        "score": 0.93, "profile": "default", "skipped": ["columns: verdict certain from rows"],
        "timings_ms": {"decode": 9.1, "profile_luma": 4.2, "match": 0.8},
        "undetermined_reason": None,
        "request_id": "7d1c0e5e9a8b4f0c9a3f2f1f0e6d5c4b"}]})

    status: Literal["protected", "clean", "undetermined"] = Field(
        description="undetermined: the detector could not look at this image (too small on "
        "every axis, blank, flat or clipped, or nothing analysable); never read it as clean.")
    protected: bool | None = Field(
        description="true for status protected, false for status clean, null for any other "
        "status (undetermined): null never means 'not protected'.")
    policy: str | None = Field(description="Matched policy id; null when not protected.")
    matches: int = Field(ge=0)
    required: int = Field(ge=0)
    score: float = Field(description="Evidence strength in [0, 1], unitless.")
    profile: str
    skipped: list[str] = Field(description="Work not done, and why.")
    timings_ms: dict[str, float] = Field(description="Wall time per stage, milliseconds.")
    evidence: dict[str, Any] | None = Field(
        default=None, description="Only with ?explain=true. A video's evidence has stage "
        "'video', deciding_frames, best_frame and video: {info, stop, frames_screened, "
        "frames_decoded, clip_logit, threshold_logit, checkpoints, frames: [{index, time_s, "
        "logit, where, keyframe, run}]}.")
    undetermined_reason: str | None = Field(
        default=None, description="Why the detector could not look (status undetermined).")
    request_id: str | None = None


class BatchEntry(BaseModel):
    """One file of a batch: its verdict, or its own error."""

    index: int = Field(ge=0, description="Position of the file in the request.")
    filename: str | None = None
    status: int = Field(description="HTTP status this file alone would have got.")
    result: ScreenResult | None = None
    error: ErrorBody | None = None


class BatchResult(BaseModel):
    """Answer of ``POST /v1/screen/batch``: one entry per file, in request order."""

    request_id: str | None = None
    results: list[BatchEntry]


class PolicyInfo(BaseModel):
    """A loaded policy and the barcodes that signal it."""

    id: str
    description: str
    specs: list[dict[str, Any]]
    ratios: list[float] = Field(description="Union of the specs' frequency ratios, unitless.")


class PoliciesInfo(BaseModel):
    """Loaded policies, detector thresholds and input limits (read-only)."""

    config_source: str
    detector: dict[str, Any]
    limits: dict[str, int] = Field(description="Image input limits (bytes, pixels).")
    video_limits: dict[str, float] = Field(
        default_factory=dict, description="Video input limits: max_bytes, max_duration_s, "
        "max_frames, max_frame_pixels, max_decoded_frames, max_decoded_bytes.")
    policies: list[PolicyInfo]


class Health(BaseModel):
    """Liveness / readiness answer."""

    status: str = Field(examples=["ok"])
