"""Rolling-shutter camera model shared by synth and detector, and the Hz-to-rows bridge."""

from __future__ import annotations

import math
from dataclasses import dataclass

from lishield_guard.errors import ConfigError

__all__ = ["CameraModel", "cpr_to_hz", "hz_to_cpr"]

MIN_ROW_RATE_HZ = 30_000.0  # DESIGN.md: phones read rows at roughly 30-120 kHz
MAX_ROW_RATE_HZ = 120_000.0


@dataclass(frozen=True)
class CameraModel:
    """Sensor timing of a rolling-shutter camera (paper Eq. 1).

    Parameters
    ----------
    row_time_s : float
        Readout interval t_s between successive rows, in seconds (> 0).
    n_rows : int
        Sensor rows read per frame (>= 1).
    exposure_s : float
        Exposure t_e of each row, in seconds (> 0).
    """

    row_time_s: float
    n_rows: int
    exposure_s: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.row_time_s) and self.row_time_s > 0):
            raise ConfigError(f"need row_time_s > 0, got row_time_s={self.row_time_s!r}")
        if int(self.n_rows) != self.n_rows or self.n_rows < 1:
            raise ConfigError(f"need n_rows >= 1, got n_rows={self.n_rows!r}")
        if not (math.isfinite(self.exposure_s) and self.exposure_s > 0):
            raise ConfigError(f"need exposure_s > 0, got exposure_s={self.exposure_s!r}")

    @property
    def row_rate_hz(self) -> float:
        """Rows read per second, 1 / row_time_s."""
        return 1.0 / self.row_time_s

    @property
    def readout_s(self) -> float:
        """Time from the first row's start to the last row's start, in seconds."""
        return (self.n_rows - 1) * self.row_time_s


def hz_to_cpr(freq_hz: float, *, row_time_s: float) -> float:
    """Convert a light frequency in Hz to a stripe frequency in cycles per row.

    >>> hz_to_cpr(400.0, row_time_s=1 / 40_000)
    0.01
    """
    return freq_hz * row_time_s


def cpr_to_hz(freq_cpr: float, *, row_time_s: float) -> float:
    """Convert a stripe frequency in cycles per row back to Hz for a known row time."""
    return freq_cpr / row_time_s
