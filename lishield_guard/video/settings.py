"""The video settings: input limits and how a clip is screened (the config's ``[video]`` group)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from lishield_guard.errors import ConfigError

__all__ = ["VideoConfig", "VideoLimits"]


def _need(ok: bool, what: str, value) -> None:
    if not ok:
        raise ConfigError(f"need {what}, got {value!r}")


@dataclass(frozen=True)
class VideoLimits:
    """Limits checked on a video's header before any frame is decoded, and on the decoding.

    max_bytes : int
        Largest encoded video accepted, in bytes.
    max_duration_s : float
        Longest video accepted, in seconds.
    max_frames : int
        Most frames a video may declare.
    max_frame_pixels : int
        Largest frame (width x height) accepted.
    max_decoded_frames : int
        Most frames decoded for one screen (the work bound: a frame between a keyframe and a
        screened frame counts too); the screen stops with what it has when it is reached.
    max_decoded_bytes : int
        Most bytes of decoded frames (YUV 4:2:0, 1.5 bytes per pixel) for one screen: for
        frames over 4K this bounds the decoding before `max_decoded_frames` does.
    """

    max_bytes: int = 512 * 1024 * 1024
    max_duration_s: float = 600.0
    max_frames: int = 36_000
    max_frame_pixels: int = 7680 * 4320
    max_decoded_frames: int = 240
    max_decoded_bytes: int = 1024 * 1024 * 1024

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            _need(v > 0 and (f.name.endswith("_s") or int(v) == v),
                  f"{f.name} > 0" + ("" if f.name.endswith("_s") else " (integer)"), v)


@dataclass(frozen=True)
class VideoConfig:
    """How a video is screened (see `lishield_guard.video.screen`).

    limits : VideoLimits
        Input limits.
    first_frames : int
        Frames screened first, spread over the clip.
    max_frames : int
        Most frames screened; the screen adds `first_frames` at a time (checkpoints) until the
        verdict is certain or this many were screened.
    min_frames : int
        Fewer screened frames than this make the verdict undetermined.
    threshold_logit : float
        The clip is protected when some window's logit, averaged over the screened frames,
        reaches this (checked at every checkpoint; calibrated: ``calibrate --videos``).
    clear_logit : float
        After a run, the clip is clean at once when its clip logit is below this (more frames
        would rarely change the verdict; calibrated with the threshold).
    frame_stride_s : float
        Runs started between keyframes (a clip with few keyframes) are at least this far
        apart, in seconds.
    max_rows : int
        Frames taller than twice this are scaled down by powers of two, keeping at least
        this many rows (0 keeps full size).
    """

    limits: VideoLimits = field(default_factory=VideoLimits)
    first_frames: int = 4
    max_frames: int = 16
    min_frames: int = 2
    threshold_logit: float = 4.3228  # the shipped calibration (data/default.toml)
    clear_logit: float = 1.0
    frame_stride_s: float = 0.1
    max_rows: int = 540

    def __post_init__(self) -> None:
        _need(1 <= self.min_frames <= self.first_frames <= self.max_frames,
              "1 <= min_frames <= first_frames <= max_frames",
              (self.min_frames, self.first_frames, self.max_frames))
        _need(self.clear_logit <= self.threshold_logit, "clear_logit <= threshold_logit",
              (self.clear_logit, self.threshold_logit))
        _need(self.frame_stride_s > 0, "frame_stride_s > 0", self.frame_stride_s)
        _need(int(self.max_rows) == self.max_rows and self.max_rows >= 0,
              "integer max_rows >= 0", self.max_rows)
