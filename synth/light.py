"""Light sources as exact cumulative integrals of intensity per channel (paper Eq. 1)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from lishield_guard.errors import ConfigError

__all__ = [
    "IMAGE_CHANNELS",
    "LightSource",
    "MainsFlicker",
    "PwmLight",
    "SequenceLight",
    "SteadyLight",
    "SumLight",
    "SwitchedLight",
    "coverage_map",
    "light_to_rgb",
    "mean_rgb",
    "row_means",
]

IMAGE_CHANNELS = ("R", "G", "B")


@runtime_checkable
class LightSource(Protocol):
    """Anything that can say how much light it emitted up to time t, per channel.

    ``cumulative(t_s)`` returns the antiderivative F(t) = integral of the intensity from 0 to t,
    shape ``t_s.shape + (len(channels),)``, in (intensity units) x seconds. A row exposed over
    [t, t + t_e] sees (F(t + t_e) - F(t)) / t_e on average.
    """

    channels: tuple[str, ...]

    def cumulative(self, t_s: np.ndarray) -> np.ndarray: ...

    def mean_level(self) -> np.ndarray: ...


def _as_time(t_s) -> np.ndarray:
    t = np.asarray(t_s, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise ConfigError("light times t_s must be finite")
    return t


@dataclass(frozen=True)
class SteadyLight:
    """Non-flickering light with a constant intensity per channel.

    Parameters
    ----------
    level : float or tuple of float
        Intensity per channel (arbitrary linear units, >= 0). Default 1.0.
    channels : tuple of str
        Channel names, ``("W",)`` for white light or ``("R", "G", "B")``.
    """

    level: float | tuple[float, ...] = 1.0
    channels: tuple[str, ...] = ("W",)

    def __post_init__(self) -> None:
        lv = np.broadcast_to(np.asarray(self.level, dtype=np.float64), (len(self.channels),))
        if np.any(lv < 0) or not np.all(np.isfinite(lv)):
            raise ConfigError(f"need finite level >= 0, got level={self.level!r}")

    def mean_level(self) -> np.ndarray:
        """Time-averaged intensity per channel, shape (n_channels,)."""
        return np.broadcast_to(np.asarray(self.level, dtype=np.float64),
                               (len(self.channels),)).copy()

    def cumulative(self, t_s) -> np.ndarray:
        """Exact integral of the intensity from 0 to ``t_s``, shape ``t_s.shape + (n_ch,)``."""
        t = _as_time(t_s)
        return t[..., None] * self.mean_level()


@dataclass(frozen=True)
class PwmLight:
    """PWM-dimmed LED (or on-off keying when ``depth == 1``): a square wave starting ON at t=0.

    Parameters
    ----------
    freq_hz : float
        PWM frequency in Hz (> 0).
    duty : float
        ON fraction of each period, unitless, in (0, 1].
    depth : float
        Modulation depth, unitless, in [0, 1]: the OFF level is ``(1 - depth)`` times the ON
        level. 1 is full on-off keying (paper Eq. 2).
    mean : float
        Time-averaged intensity (>= 0). The ON level I_p follows from it.
    phase_s : float
        Time shift in seconds: the wave is ON on [phase_s + k/f, phase_s + (k + duty)/f).
    channels : tuple of str
        Channel names; every channel carries the same wave.
    """

    freq_hz: float
    duty: float = 0.5
    depth: float = 1.0
    mean: float = 1.0
    phase_s: float = 0.0
    channels: tuple[str, ...] = ("W",)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.freq_hz) and self.freq_hz > 0):
            raise ConfigError(f"need freq_hz > 0, got freq_hz={self.freq_hz!r}")
        if not 0.0 < self.duty <= 1.0:
            raise ConfigError(f"need 0 < duty <= 1, got duty={self.duty!r}")
        if not 0.0 <= self.depth <= 1.0:
            raise ConfigError(f"need 0 <= depth <= 1, got depth={self.depth!r}")
        if not self.mean >= 0:
            raise ConfigError(f"need mean >= 0, got mean={self.mean!r}")

    @property
    def on_level(self) -> float:
        """Intensity while ON (I_p)."""
        return self.mean / (self.duty + (1.0 - self.depth) * (1.0 - self.duty))

    @property
    def off_level(self) -> float:
        """Intensity while OFF, ``(1 - depth) * on_level``."""
        return (1.0 - self.depth) * self.on_level

    def mean_level(self) -> np.ndarray:
        """Time-averaged intensity per channel, shape (n_channels,)."""
        return np.full(len(self.channels), float(self.mean))

    def cumulative(self, t_s) -> np.ndarray:
        """Exact integral of the square wave from 0 to ``t_s``, shape ``t_s.shape + (n_ch,)``."""
        t = _as_time(t_s)
        period = 1.0 / self.freq_hz
        t_on = self.duty * period
        hi, lo = self.on_level, self.off_level

        def prim(u):  # integral from 0 of the wave that starts ON at 0
            n = np.floor(u / period)
            r = u - n * period
            return n * self.mean * period + hi * np.minimum(r, t_on) + lo * np.maximum(r - t_on,
                                                                                        0.0)

        f = prim(t - self.phase_s) - prim(np.asarray(-self.phase_s))
        return np.repeat(f[..., None], len(self.channels), axis=-1)


@dataclass(frozen=True)
class MainsFlicker:
    """Lamp on an AC supply: intensity follows the rectified sine |sin(2 pi f_supply t)|.

    The flicker frequency is twice the supply frequency (100 Hz on 50 Hz mains, 120 Hz on 60 Hz).
    Intensity is ``mean * ((1 - depth) + depth * (pi / 2) * |sin(2 pi f_supply t)|)``, so its
    time average is ``mean`` for every depth.

    Parameters
    ----------
    supply_hz : float
        Mains frequency in Hz, usually 50 or 60 (> 0).
    depth : float
        Unitless in [0, 1]; 1 dims to zero at each zero crossing, 0 is steady.
    mean : float
        Time-averaged intensity (>= 0).
    phase_s : float
        Time shift in seconds.
    channels : tuple of str
        Channel names; every channel carries the same wave.
    """

    supply_hz: float = 50.0
    depth: float = 1.0
    mean: float = 1.0
    phase_s: float = 0.0
    channels: tuple[str, ...] = ("W",)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.supply_hz) and self.supply_hz > 0):
            raise ConfigError(f"need supply_hz > 0, got supply_hz={self.supply_hz!r}")
        if not 0.0 <= self.depth <= 1.0:
            raise ConfigError(f"need 0 <= depth <= 1, got depth={self.depth!r}")
        if not self.mean >= 0:
            raise ConfigError(f"need mean >= 0, got mean={self.mean!r}")

    @property
    def flicker_hz(self) -> float:
        """Flicker frequency, twice the supply frequency, in Hz."""
        return 2.0 * self.supply_hz

    def mean_level(self) -> np.ndarray:
        """Time-averaged intensity per channel, shape (n_channels,)."""
        return np.full(len(self.channels), float(self.mean))

    def cumulative(self, t_s) -> np.ndarray:
        """Exact integral from 0 to ``t_s``, shape ``t_s.shape + (n_ch,)``.

        Notes
        -----
        With w = 2 pi f_supply and half period T = pi / w, the integral of |sin(w u)| over
        [0, t] is ``2 n / w + (1 - cos(w r)) / w`` with n = floor(t / T), r = t - n T.
        """
        t = _as_time(t_s)
        w = 2.0 * math.pi * self.supply_hz
        half = math.pi / w

        def prim(u):
            n = np.floor(u / half)
            r = u - n * half
            return 2.0 * n / w + (1.0 - np.cos(w * r)) / w

        s = prim(t - self.phase_s) - prim(np.asarray(-self.phase_s))
        f = self.mean * ((1.0 - self.depth) * t + self.depth * (math.pi / 2.0) * s)
        return np.repeat(f[..., None], len(self.channels), axis=-1)


@dataclass(frozen=True)
class SequenceLight:
    """The LED playing a firmware `Sequence` (piecewise constant, looped forever).

    Parameters
    ----------
    sequence : firmware.sequence.Sequence
        Compiled LED sequence; its step durations and unit levels define the light exactly.
    scale : float
        Intensity of a unit level (> 0). Default 1.0.
    phase_s : float
        Time of the sequence start, in seconds.
    rise_s : float
        LED rise and fall time in seconds, >= 0 and shorter than the loop. Default 0 (ideal
        steps). The LED's output is the driven waveform averaged over the preceding ``rise_s``
        seconds (a causal box filter): every step becomes a linear ramp lasting ``rise_s``.
        Real LEDs and drivers take up to ~5% of the shortest half-period.

    Notes
    -----
    With F the exact cumulative integral of the driven (step) waveform and G its integral
    (piecewise quadratic, exact), the output's cumulative integral is
    ``Y(t) = (G(t) - G(t - rise_s)) / rise_s - (G(0) - G(-rise_s)) / rise_s``. G is evaluated
    as ``m t^2 / 2 + floor(t / P) * Gp + Gr(t mod P)`` (m: mean level, P: loop period), so
    the differences that matter never subtract large numbers.
    """

    sequence: object
    scale: float = 1.0
    phase_s: float = 0.0
    rise_s: float = 0.0
    _starts_s: np.ndarray = field(init=False, repr=False, compare=False)
    _levels: np.ndarray = field(init=False, repr=False, compare=False)
    _cum: np.ndarray = field(init=False, repr=False, compare=False)
    _cum2: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ConfigError(f"need scale > 0, got scale={self.scale!r}")
        starts = np.asarray(self.sequence.step_starts_s(), dtype=np.float64)
        levels = np.asarray(self.sequence.levels_unit(), dtype=np.float64) * self.scale
        cum = np.zeros((starts.size, levels.shape[1]))
        np.cumsum(levels * np.diff(starts)[:, None], axis=0, out=cum[1:])
        if not (math.isfinite(self.rise_s) and 0.0 <= self.rise_s < starts[-1]):
            raise ConfigError(f"need 0 <= rise_s < the loop period {starts[-1]:.6g} s, got "
                              f"rise_s={self.rise_s!r}")
        # Integral of the detrended cumulative F(u) - m u over [0, starts[k]] (exact).
        d = np.diff(starts)[:, None]
        mean = cum[-1] / starts[-1]
        seg = cum[:-1] * d + levels * d**2 / 2 - mean * (starts[1:, None]**2
                                                         - starts[:-1, None]**2) / 2
        cum2 = np.zeros_like(cum)
        np.cumsum(seg, axis=0, out=cum2[1:])
        object.__setattr__(self, "_starts_s", starts)
        object.__setattr__(self, "_levels", levels)
        object.__setattr__(self, "_cum", cum)
        object.__setattr__(self, "_cum2", cum2)

    @property
    def channels(self) -> tuple[str, ...]:
        """Channel names of the sequence (``("W",)`` or R/G/B)."""
        return tuple(self.sequence.channels)

    @property
    def period_s(self) -> float:
        """Loop period of the sequence, in seconds."""
        return float(self._starts_s[-1])

    def mean_level(self) -> np.ndarray:
        """Time-averaged intensity per channel, shape (n_channels,)."""
        return self._cum[-1] / self.period_s

    def intensity(self, t_s) -> np.ndarray:
        """Instantaneous intensity per channel (for plots only), ``t_s.shape + (n_ch,)``."""
        t = _as_time(t_s) - self.phase_s
        if self.rise_s > 0:
            return (self._prim(t) - self._prim(t - self.rise_s)) / self.rise_s
        r = np.mod(t, self.period_s)
        k = np.clip(np.searchsorted(self._starts_s, r, side="right") - 1, 0,
                    self._levels.shape[0] - 1)
        return self._levels[k]

    def _split(self, u: np.ndarray):
        period = self.period_s
        n = np.floor(u / period)
        r = u - n * period
        k = np.clip(np.searchsorted(self._starts_s, r, side="right") - 1, 0,
                    self._levels.shape[0] - 1)
        return n, r, k

    def _prim(self, u: np.ndarray) -> np.ndarray:
        """Exact integral of the driven (step) waveform from sequence time 0 to ``u``."""
        n, r, k = self._split(u)
        return (n[..., None] * self._cum[-1] + self._cum[k]
                + self._levels[k] * (r - self._starts_s[k])[..., None])

    def _prim2_detrended(self, u: np.ndarray) -> np.ndarray:
        """Exact integral of ``_prim(v) - m v`` from 0 to ``u`` (m: mean level)."""
        n, r, k = self._split(u)
        s0 = self._starts_s[k]
        tau = (r - s0)[..., None]
        mean = self._cum[-1] / self.period_s
        within = (self._cum2[k] + self._cum[k] * tau + self._levels[k] * tau**2 / 2
                  - mean * ((r**2 - s0**2) / 2)[..., None])
        return n[..., None] * self._cum2[-1] + within

    def _smoothed(self, u: np.ndarray) -> np.ndarray:
        """``(G(u) - G(u - rise_s)) / rise_s``, G the double integral of the driven wave."""
        rho = self.rise_s
        mean = self._cum[-1] / self.period_s
        trend = (u - rho / 2)[..., None] * mean
        return trend + (self._prim2_detrended(u) - self._prim2_detrended(u - rho)) / rho

    def cumulative(self, t_s) -> np.ndarray:
        """Exact integral from 0 to ``t_s`` (cumsum over steps plus whole periods).

        With ``rise_s > 0`` it integrates the ramped output exactly (see Notes of the class).
        Returns an array of shape ``t_s.shape + (n_channels,)``.
        """
        t = _as_time(t_s)
        u0 = np.asarray(-self.phase_s, dtype=np.float64)
        if self.rise_s > 0:
            return self._smoothed(t - self.phase_s) - self._smoothed(u0)
        return self._prim(t - self.phase_s) - self._prim(u0)


@dataclass(frozen=True)
class SumLight:
    """Several lights at once (a barcode LED beside a PWM lamp, two dimmed lamps): their
    intensities, and so their cumulative integrals, add; the sum is in image R, G, B.

    Parameters
    ----------
    parts : tuple of LightSource
        The lights; each may be white (``"W"``) or coloured.
    """

    parts: tuple
    channels: tuple[str, ...] = IMAGE_CHANNELS

    def cumulative(self, t_s) -> np.ndarray:
        """Sum of the parts' exact integrals in R, G, B, shape ``t_s.shape + (3,)``."""
        return sum(light_to_rgb(p.cumulative(t_s), tuple(p.channels)) for p in self.parts)

    def mean_level(self) -> np.ndarray:
        """Sum of the parts' time-averaged intensities in R, G, B, shape (3,)."""
        return sum(mean_rgb(p) for p in self.parts)


@dataclass(frozen=True)
class SwitchedLight:
    """A light that changes at ``switch_s``: ``before`` until then, ``after`` from then on (a
    dimmer moved, a PWM driver changing duty or frequency mid-frame).

    The time average is taken over the two parts equally (a normalised capture sees the
    average light of a frame near the switch, not of one part only).
    """

    before: object
    after: object
    switch_s: float

    @property
    def channels(self) -> tuple[str, ...]:
        """Channel names of the parts (they must agree)."""
        return tuple(self.before.channels)

    def mean_level(self) -> np.ndarray:
        """Mean of the parts' time-averaged intensities, shape (n_channels,)."""
        return 0.5 * (np.asarray(self.before.mean_level()) + np.asarray(self.after.mean_level()))

    def cumulative(self, t_s) -> np.ndarray:
        """Exact integral from 0 to ``t_s``: ``before`` up to the switch, ``after`` past it."""
        t = _as_time(t_s)
        ts = np.asarray(self.switch_s, dtype=np.float64)
        head = self.before.cumulative(np.minimum(t, ts))
        tail = self.after.cumulative(np.maximum(t, ts)) - self.after.cumulative(ts)
        return head + tail


def row_means(light: LightSource, start_s, exposure_s: float) -> np.ndarray:
    """Mean intensity each row sees over its exposure window (paper Eq. 1 divided by t_e).

    Parameters
    ----------
    light : LightSource
        The source, queried only through its exact ``cumulative``.
    start_s : ndarray of shape (n_rows,)
        Exposure start t_i of each row, in seconds.
    exposure_s : float
        Exposure t_e in seconds (> 0).

    Returns
    -------
    ndarray of shape (n_rows, n_channels), float64
        ``(F(t_i + t_e) - F(t_i)) / t_e``.
    """
    if not exposure_s > 0:
        raise ConfigError(f"need exposure_s > 0, got exposure_s={exposure_s!r}")
    t = np.asarray(start_s, dtype=np.float64)
    return (light.cumulative(t + exposure_s) - light.cumulative(t)) / exposure_s


def light_to_rgb(values: np.ndarray, channels: tuple[str, ...]) -> np.ndarray:
    """Map light channels to image R, G, B: ``W`` lights all three, R/G/B light their own.

    Parameters
    ----------
    values : ndarray of shape (..., n_channels)
        Intensities in the light's channel order.
    channels : tuple of str
        The light's channel names.

    Returns
    -------
    ndarray of shape (..., 3)
    """
    v = np.asarray(values)
    out = np.zeros(v.shape[:-1] + (3,), dtype=v.dtype)
    for i, c in enumerate(channels):
        if c == "W":
            out += v[..., i : i + 1]
        elif c in IMAGE_CHANNELS:
            out[..., IMAGE_CHANNELS.index(c)] += v[..., i]
        else:
            raise ConfigError(f"unknown light channel {c!r}")
    return out


def mean_rgb(light: LightSource) -> np.ndarray:
    """Time-averaged intensity of a light in image R, G, B, shape (3,)."""
    return light_to_rgb(light.mean_level(), tuple(light.channels))


def coverage_map(n_rows: int, n_cols: int, *, fraction: float, centre_rc=(0.5, 0.5),
                 softness: float = 0.25) -> np.ndarray:
    """Smooth map in [0, 1] of where the LED lights the frame (1 = fully lit).

    A radial falloff around ``centre_rc``: 1 inside a disc, a raised-cosine edge, 0 outside.
    The disc radius is solved so that the map's mean is ``fraction`` (unitless).

    Parameters
    ----------
    n_rows, n_cols : int
        Frame size.
    fraction : float
        Mean of the map (lit fraction of the frame), in (0, 1].
    centre_rc : (float, float)
        Centre as fractions of (n_rows, n_cols); may lie outside [0, 1].
    softness : float
        Width of the falloff edge as a fraction of the frame diagonal (>= 0).

    Returns
    -------
    ndarray of shape (n_rows, n_cols), float32
    """
    if not 0.0 < fraction <= 1.0:
        raise ConfigError(f"need 0 < fraction <= 1, got fraction={fraction!r}")
    if fraction >= 1.0:
        return np.ones((n_rows, n_cols), dtype=np.float32)
    diag = math.hypot(n_rows, n_cols)
    edge = max(softness * diag, 1.0)
    # Solve the radius on a coarse grid (fast), then render at full size.
    sr, sc = max(n_rows // 8, 8), max(n_cols // 8, 8)

    def dist(nr, nc):
        r = (np.arange(nr, dtype=np.float32) + 0.5) / nr - centre_rc[0]
        c = (np.arange(nc, dtype=np.float32) + 0.5) / nc - centre_rc[1]
        return np.sqrt((r[:, None] * n_rows) ** 2 + (c[None, :] * n_cols) ** 2)

    def falloff(d, radius):
        x = np.clip((d - radius) / edge, 0.0, 1.0)
        return (0.5 + 0.5 * np.cos(np.pi * x)).astype(np.float32)

    d_small = dist(sr, sc)
    lo, hi = -edge, 2.0 * diag
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if falloff(d_small, mid).mean() < fraction:
            lo = mid
        else:
            hi = mid
    return falloff(dist(n_rows, n_cols), 0.5 * (lo + hi))
