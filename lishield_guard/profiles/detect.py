"""Detect on one image with the configured profile: resolve the config, decode, measure, decide."""

from __future__ import annotations

import dataclasses

from lishield_guard.config import AppConfig, DetectorConfig, default_config
from lishield_guard.decode import Decoded
from lishield_guard.profiles import of
from lishield_guard.threads import native_threads
from lishield_guard.verdict import (
    Timer,
    Verdict,
    looked_at_image,
    nothing_to_look_for,
    undetermined,
)

__all__ = ["decode_for", "detect", "detect_decoded", "resolve_config"]


def resolve_config(config) -> AppConfig:
    """``config`` as an `AppConfig`: None is the shipped one; a bare `DetectorConfig` takes
    the shipped policies, limits and video settings.

    Raises
    ------
    TypeError
        For any other type.
    """
    if config is None:
        return default_config()
    if isinstance(config, AppConfig):
        return config
    if isinstance(config, DetectorConfig):
        return dataclasses.replace(default_config(), detector=config)
    raise TypeError(f"config must be AppConfig, DetectorConfig or None, not "
                    f"{type(config).__name__}")


def detect(source, config: AppConfig | DetectorConfig | None = None) -> Verdict:
    """Decide whether an image carries a barcode of a configured policy.

    Parameters
    ----------
    source : bytes, str, pathlib.Path or ndarray
        Encoded image bytes, a path, or pixels of shape (n_rows, n_cols[, 3]).
    config : AppConfig or DetectorConfig, optional
        Detector settings, policies and limits; default the shipped config. A bare
        DetectorConfig uses the shipped policies and limits.

    Returns
    -------
    Verdict
        "No barcode" is a verdict, not an error.

    Raises
    ------
    ImageDecodeError, ImageTooLargeError, PayloadTooLargeError, InvalidImageError
        When the input cannot be turned into pixels.

    Notes
    -----
    Runs with one native (BLAS, OpenCV) thread, or the process's own pin, restored after
    the call (`lishield_guard.threads.native_threads`).
    """
    cfg = resolve_config(config)
    timer = Timer()
    with native_threads():
        with timer("decode"):
            decoded = decode_for(source, cfg)
        return detect_decoded(decoded, cfg, _timer=timer)


def decode_for(source, config: AppConfig) -> Decoded:
    """``source`` decoded as the configured profile analyses it (its ``decode``)."""
    return of(config).decode(source, config)


def detect_decoded(decoded: Decoded, config: AppConfig, *, _timer: Timer | None = None
                   ) -> Verdict:
    """`detect` on an already decoded image: the profile's ``measure``, then its ``decide``."""
    timer = _timer or Timer()
    profile = of(config)
    if (why := nothing_to_look_for(config)) is not None:
        return undetermined(why, looked_at=looked_at_image(decoded),
                            profile=config.detector.profile,
                            required=profile.required(config), timings_ms=timer.ms)
    return profile.decide(profile.measure(decoded, config, timer), config, timer)

