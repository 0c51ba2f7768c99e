"""Compile a barcode spec into an exact, looping, tick-timed LED step sequence.

A `Sequence` is what a microcontroller plays: ``n_steps`` steps, each lasting
``durations_ticks[i]`` timer ticks at ``clock_hz`` with every channel held at
``levels[i, c]`` (0 = off, ``max_level`` = full on). After the last step it starts over.

Slot semantics follow `lishield_guard.spec`: the pattern is M slots of 1/f_B s; in slot k every
channel c plays tone ``channels[c][slot_order()[k]]`` as a square wave (ON for duty/f, OFF for
(1 - duty)/f, repeating), truncated at the slot end. With ``spec.phase == "restart"`` the wave
starts ON at the slot start; with ``"continuous"`` the tone's timer runs on from the loop start,
so the wave is ON on [j/f, (j + duty)/f) for every integer j, t measured from the loop start,
clipped to the slot. Every ideal edge time is measured from the start of the sequence and
rounded to the nearest tick (half up) with exact rational arithmetic, so quantisation never
accumulates drift and the result does not depend on floating-point rounding.
"""

from __future__ import annotations

import hashlib
import hmac
import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from lishield_guard.errors import FirmwareError
from lishield_guard.spec import BarcodeSpec, require_valid

__all__ = [
    "DEFAULT_CLOCK_HZ",
    "DEFAULT_MAX_RATIO_ERROR",
    "DEFAULT_RANDOMIZED_PATTERNS",
    "Sequence",
    "SequenceTable",
    "achieved_report",
    "compile_spec",
]

DEFAULT_CLOCK_HZ = 1_000_000  # 1 MHz: a common prescaled MCU timer clock
DEFAULT_MAX_RATIO_ERROR = 1e-3  # relative; 50x below the detector's T_b = 0.05 (paper Sec. 7.3)
DEFAULT_RANDOMIZED_PATTERNS = 8  # patterns emitted when intensity randomization is on (K > 1)
MAX_DURATION_TICKS = 2**32 - 1  # one step must fit a u32 timer reload value
MAX_LEVEL = 2**16 - 1  # levels are stored as u16
_DRBG_LABEL = b"lishield-guard/intensity/v1"


class _Steps:
    """Methods shared by every tick-timed step table (fields come from the dataclasses)."""

    clock_hz: int
    channels: tuple[str, ...]
    durations_ticks: np.ndarray
    levels: np.ndarray
    max_level: int

    def _check_arrays(self) -> None:
        if int(self.clock_hz) != self.clock_hz or self.clock_hz < 1:
            raise FirmwareError(f"need integer clock_hz >= 1, got clock_hz={self.clock_hz!r}")
        if int(self.max_level) != self.max_level or not 1 <= self.max_level <= MAX_LEVEL:
            raise FirmwareError(f"need 1 <= max_level <= {MAX_LEVEL}, got {self.max_level!r}")
        dur = np.asarray(self.durations_ticks)
        lev = np.asarray(self.levels)
        if dur.ndim != 1 or dur.size == 0:
            raise FirmwareError(f"durations_ticks must be 1-D and non-empty, got shape {dur.shape}")
        if lev.shape != (dur.size, len(self.channels)):
            raise FirmwareError(f"levels must have shape (n_steps, n_channels)="
                                f"{(dur.size, len(self.channels))}, got {lev.shape}")
        if dur.min() < 1 or dur.max() > MAX_DURATION_TICKS:
            raise FirmwareError(f"every duration must be in 1..{MAX_DURATION_TICKS} ticks, got "
                                f"{int(dur.min())}..{int(dur.max())}")
        if lev.size and (lev.min() < 0 or lev.max() > self.max_level):
            raise FirmwareError(f"levels must be in 0..max_level={self.max_level}, got "
                                f"{int(lev.min())}..{int(lev.max())}")
        dur = dur.astype(np.uint32)
        lev = lev.astype(np.uint16)
        dur.setflags(write=False)
        lev.setflags(write=False)
        object.__setattr__(self, "durations_ticks", dur)
        object.__setattr__(self, "levels", lev)
        object.__setattr__(self, "channels", tuple(str(c) for c in self.channels))
        object.__setattr__(self, "clock_hz", int(self.clock_hz))
        object.__setattr__(self, "max_level", int(self.max_level))

    @property
    def n_steps(self) -> int:
        """Number of steps in one loop."""
        return int(self.durations_ticks.size)

    @property
    def period_ticks(self) -> int:
        """Duration of one loop of the whole sequence, in timer ticks."""
        return int(self.durations_ticks.sum(dtype=np.int64))

    @property
    def period_s(self) -> float:
        """Duration of one loop of the whole sequence, in seconds."""
        return self.period_ticks / self.clock_hz

    def step_starts_ticks(self) -> np.ndarray:
        """Start tick of each step, plus the loop end.

        Returns
        -------
        starts_ticks : ndarray of shape (n_steps + 1,), int64
            ``starts_ticks[0] == 0`` and ``starts_ticks[-1] == period_ticks``.
        """
        return np.concatenate([[0], np.cumsum(self.durations_ticks, dtype=np.int64)])

    def step_starts_s(self) -> np.ndarray:
        """Start time of each step, plus the loop end.

        Returns
        -------
        starts_s : ndarray of shape (n_steps + 1,), float64
            Seconds from the loop start; ``starts_s[-1] == period_s``.
        """
        return self.step_starts_ticks() / float(self.clock_hz)

    def levels_unit(self) -> np.ndarray:
        """Levels scaled to [0, 1].

        Returns
        -------
        levels_unit : ndarray of shape (n_steps, n_channels), float64
            ``levels / max_level``, unitless.
        """
        return self.levels.astype(np.float64) / float(self.max_level)

    def edges(self, n_loops: int = 1) -> list[tuple[int, int, int]]:
        """Every change of a channel's level, as a player reports it.

        Parameters
        ----------
        n_loops : int, optional
            Loops to play, >= 1. Default 1.

        Returns
        -------
        edges : list of (tick, channel_index, level)
            At tick 0 every channel reports its initial level; afterwards one entry per change,
            in tick order and channel order within a tick. Ticks count from the first loop start.
        """
        out: list[tuple[int, int, int]] = []
        starts = self.step_starts_ticks()
        period = int(starts[-1])
        lev = self.levels.tolist()
        cur: list[int] | None = None
        for loop in range(n_loops):
            base = loop * period
            for i, row in enumerate(lev):
                for c, v in enumerate(row):
                    if cur is None or cur[c] != v:
                        out.append((base + int(starts[i]), c, v))
                cur = row
        return out


@dataclass(frozen=True, eq=False)
class SequenceTable(_Steps):
    """A step table without its spec, as read back from a binary file.

    Attributes
    ----------
    clock_hz : int
        Timer tick rate in Hz.
    channels : tuple of str
        Channel names, e.g. ``("R", "G", "B")``.
    durations_ticks : ndarray of shape (n_steps,), uint32
        Duration of each step in ticks, every entry >= 1.
    levels : ndarray of shape (n_steps, n_channels), uint16
        Level of each channel during each step, in 0..max_level.
    max_level : int
        Full-on level.
    """

    clock_hz: int
    channels: tuple[str, ...]
    durations_ticks: np.ndarray
    levels: np.ndarray
    max_level: int

    def __post_init__(self) -> None:
        self._check_arrays()

    def same_steps(self, other: _Steps) -> bool:
        """True when ``other`` plays exactly the same steps at the same clock."""
        return (self.clock_hz == other.clock_hz and self.channels == other.channels
                and self.max_level == other.max_level
                and np.array_equal(self.durations_ticks, other.durations_ticks)
                and np.array_equal(self.levels, other.levels))


@dataclass(frozen=True, eq=False)
class Sequence(_Steps):
    """A compiled barcode: tick-timed steps that loop forever.

    Attributes
    ----------
    spec : BarcodeSpec
        The barcode this sequence plays.
    clock_hz : int
        Timer tick rate in Hz.
    channels : tuple of str
        ``spec.channel_names``.
    durations_ticks : ndarray of shape (n_steps,), uint32
        Duration of each step in ticks, every entry >= 1.
    levels : ndarray of shape (n_steps, n_channels), uint16
        Level of each channel during each step, in 0..max_level.
    max_level : int
        Full-on level: ``spec.intensity_levels`` (1 for plain on-off keying).
    n_patterns : int
        Patterns (of M slots each) in one loop; > 1 when intensity randomization is on.
    """

    spec: BarcodeSpec
    clock_hz: int
    channels: tuple[str, ...]
    durations_ticks: np.ndarray
    levels: np.ndarray
    max_level: int
    n_patterns: int = 1

    def __post_init__(self) -> None:
        self._check_arrays()

    def table(self) -> SequenceTable:
        """The step table alone (what the emitters write)."""
        return SequenceTable(self.clock_hz, self.channels, self.durations_ticks, self.levels,
                             self.max_level)

    def same_steps(self, other: _Steps) -> bool:
        """True when ``other`` plays exactly the same steps at the same clock."""
        return self.table().same_steps(other)


# ---------------------------------------------------------------------- helpers
def _round_ticks(x: Fraction) -> int:
    """Nearest integer, ties rounded up (exact)."""
    return (2 * x.numerator + x.denominator) // (2 * x.denominator)


def _seed_key(seed: bytes | str | int) -> bytes:
    if isinstance(seed, bytes | bytearray):
        key = bytes(seed)
    elif isinstance(seed, str):
        key = seed.encode("utf-8")
    elif isinstance(seed, int) and not isinstance(seed, bool):
        key = str(seed).encode("ascii")
    else:
        raise FirmwareError(f"seed must be bytes, str or int, got {type(seed).__name__}")
    if not key:
        raise FirmwareError("seed must not be empty")
    return key


class _HmacDrbg:
    """HMAC-SHA256 in counter mode: block_i = HMAC(seed, label || i) (NIST SP 800-108 style).

    The seed (the venue's secret) is only held as the HMAC key; it is never exposed.
    """

    __slots__ = ("_buf", "_counter", "_key")

    def __init__(self, seed: bytes | str | int) -> None:
        self._key = _seed_key(seed)
        self._counter = 0
        self._buf = b""

    def __repr__(self) -> str:
        return "_HmacDrbg(<secret>)"

    def _u32(self) -> int:
        if len(self._buf) < 4:
            msg = _DRBG_LABEL + self._counter.to_bytes(8, "big")
            self._buf += hmac.new(self._key, msg, hashlib.sha256).digest()
            self._counter += 1
        out, self._buf = int.from_bytes(self._buf[:4], "big"), self._buf[4:]
        return out

    def uniform_int(self, low: int, high: int) -> int:
        """Uniform integer in [low, high] by rejection sampling (no modulo bias)."""
        span = high - low + 1
        limit = 2**32 - (2**32 % span)
        while True:
            u = self._u32()
            if u < limit:
                return low + u % span


def compile_spec(
    spec: BarcodeSpec,
    *,
    clock_hz: int = DEFAULT_CLOCK_HZ,
    seed: bytes | str | int | None = None,
    n_patterns: int | None = None,
    max_ratio_error: float = DEFAULT_MAX_RATIO_ERROR,
    allow=(),
    verify: bool = True,
) -> Sequence:
    """Compile a barcode spec into a tick-timed LED sequence.

    Parameters
    ----------
    spec : BarcodeSpec
        The barcode; checked with `lishield_guard.spec.require_valid` first.
    clock_hz : int, optional
        Timer tick rate in Hz, >= 1. Default 1 MHz.
    seed : bytes, str or int, optional
        The venue's secret for intensity randomization; required when
        ``spec.intensity_levels > 1``, ignored otherwise. Never stored or logged.
    n_patterns : int, optional
        Patterns of M slots in one loop, >= 1. Default 8 when intensity randomization is on,
        1 otherwise.
    max_ratio_error : float, optional
        Largest accepted relative error of any achieved tone ratio, unitless. Default 1e-3.
    allow : iterable of str, optional
        Spec rules compiled with a `lishield_guard.spec.SpecWarning` instead of an error:
        ``"flicker"`` (f_B / M <= 80 Hz, e.g. the paper's f_B = 200 Hz for M = 3) and
        ``"switching"`` (f_B > f_1). Default: none; our own lights keep both rules.
    verify : bool, optional
        Check the achieved tones against the spec (`achieved_report`: every edge kept, every
        ratio within ``max_ratio_error``). Default True; training data, which compiles
        hundreds of thousands of emitters at a 16 MHz clock, turns it off.

    Returns
    -------
    Sequence
        Steps whose durations sum to ``n_patterns * M / f_B`` seconds, rounded to ticks.

    Raises
    ------
    SpecError
        If the spec breaks a hard validation rule.
    FirmwareError
        If ``clock_hz``, ``n_patterns`` or the seed are unusable, or the quantised tones miss
        their ratios by more than ``max_ratio_error``.

    Notes
    -----
    Each channel's ideal edge at time t (seconds from the loop start) is placed at tick
    ``round(t * clock_hz)``; the edges of all channels are merged and run-length encoded.
    With K = ``intensity_levels`` > 1 every ON period gets a level drawn uniformly from 1..K
    by an HMAC-SHA256 counter-mode generator keyed by ``seed``.

    Examples
    --------
    >>> from lishield_guard.spec import PRESETS
    >>> seq = compile_spec(PRESETS["table1-seq1"])
    >>> seq.period_ticks, seq.channels
    (7500, ('W',))
    """
    require_valid(spec, allow=allow)
    if isinstance(clock_hz, bool) or int(clock_hz) != clock_hz or clock_hz < 1:
        raise FirmwareError(f"need integer clock_hz >= 1, got clock_hz={clock_hz!r}")
    clock_hz = int(clock_hz)
    k_levels = int(spec.intensity_levels)
    if k_levels > MAX_LEVEL:
        raise FirmwareError(f"need intensity_levels <= {MAX_LEVEL}, got {k_levels}")
    if n_patterns is None:
        n_patterns = DEFAULT_RANDOMIZED_PATTERNS if k_levels > 1 else 1
    if isinstance(n_patterns, bool) or int(n_patterns) != n_patterns or n_patterns < 1:
        raise FirmwareError(f"need integer n_patterns >= 1, got n_patterns={n_patterns!r}")
    n_patterns = int(n_patterns)
    if not (math.isfinite(max_ratio_error) and max_ratio_error > 0):
        raise FirmwareError(f"need max_ratio_error > 0, got {max_ratio_error!r}")

    if k_levels > 1:
        if seed is None:
            raise FirmwareError(f"spec {spec.name!r} randomizes intensity (intensity_levels="
                                f"{k_levels}); a secret seed is required")
        drbg = _HmacDrbg(seed)

        def draw() -> int:
            return drbg.uniform_int(1, k_levels)
    else:
        def draw() -> int:
            return 1

    period_ticks = _round_ticks(Fraction(n_patterns * spec.n_tones) / Fraction(spec.f_b_hz)
                                * clock_hz)
    # Draw in (pattern, slot, channel, cycle) order so the level stream is reproducible.
    order = spec.slot_order()
    slot_events = _slot_events_continuous if spec.phase == "continuous" else _slot_events
    per_channel: list[list[tuple[int, int]]] = [[] for _ in spec.channels]
    for p in range(n_patterns):
        for k in range(spec.n_tones):
            for c, (_, tones) in enumerate(spec.channels):
                per_channel[c].extend(slot_events(
                    spec, tones[order[k]], p * spec.n_tones + k, clock_hz=clock_hz,
                    draw=draw))

    durations, levels = _run_length(per_channel, period_ticks)
    if durations.max() > MAX_DURATION_TICKS:
        raise FirmwareError(f"a step lasts {int(durations.max())} ticks, more than a u32 holds; "
                            f"lower clock_hz={clock_hz}")
    seq = Sequence(spec=spec, clock_hz=clock_hz, channels=spec.channel_names,
                   durations_ticks=durations, levels=levels, max_level=k_levels,
                   n_patterns=n_patterns)
    if not verify:
        return seq
    report = achieved_report(seq)
    lost = [t for t in report["tones"] if math.isinf(t["rel_error"])]
    if lost:
        raise FirmwareError(f"clock_hz={clock_hz} cannot play spec {spec.name!r}: tone "
                            f"{lost[0]['channel']}:{lost[0]['spec_hz']:g} Hz loses its edges "
                            f"when rounded to ticks; raise clock_hz")
    if not report["worst_ratio_error"] <= max_ratio_error:
        w = report["worst_ratio"]
        raise FirmwareError(
            f"clock_hz={clock_hz} cannot play spec {spec.name!r} accurately: ratio "
            f"{w['numerator']} / {w['denominator']} (spec {w['spec']:.6g}) is achieved as "
            f"{w['achieved']:.6g}, relative error {report['worst_ratio_error']:.3g} > "
            f"max_ratio_error={max_ratio_error:g}; raise clock_hz")
    return seq


def _slot_events(spec: BarcodeSpec, tone_hz: float, g: int, *, clock_hz: int,
                 draw) -> list[tuple[int, int]]:
    """(tick, level) changes of one channel playing ``tone_hz`` in slot ``g`` of the loop."""
    f_b = Fraction(spec.f_b_hz)
    duty = Fraction(spec.duty)
    clock = Fraction(clock_hz)
    t0 = Fraction(g) / f_b
    t1 = Fraction(g + 1) / f_b
    f = Fraction(tone_hz)
    out: list[tuple[int, int]] = []
    j = 0
    while True:
        t_on = t0 + Fraction(j) / f
        if t_on >= t1:
            return out
        out.append((_round_ticks(t_on * clock), draw()))
        t_off = t_on + duty / f
        if t_off < t1:
            out.append((_round_ticks(t_off * clock), 0))
        j += 1


def _slot_events_continuous(spec: BarcodeSpec, tone_hz: float, g: int, *, clock_hz: int,
                            draw) -> list[tuple[int, int]]:
    """Like `_slot_events`, but the tone runs on from the loop start (``phase="continuous"``).

    The wave is ON on [j/f, (j + duty)/f) for every integer j (seconds from the loop start);
    the slot [g/f_B, (g+1)/f_B) plays it clipped: its level at the slot start, then every ideal
    edge strictly inside the slot.
    """
    f_b = Fraction(spec.f_b_hz)
    duty = Fraction(spec.duty)
    clock = Fraction(clock_hz)
    t0 = Fraction(g) / f_b
    t1 = Fraction(g + 1) / f_b
    f = Fraction(tone_hz)
    j = math.floor(t0 * f)  # the cycle running at the slot start
    on_at_start = t0 * f - j < duty
    out: list[tuple[int, int]] = [(_round_ticks(t0 * clock), draw() if on_at_start else 0)]
    while True:
        t_on = Fraction(j) / f
        if t_on >= t1:
            return out
        if t_on > t0:
            out.append((_round_ticks(t_on * clock), draw()))
        t_off = t_on + duty / f
        if t0 < t_off < t1:
            out.append((_round_ticks(t_off * clock), 0))
        j += 1


def _run_length(per_channel: list[list[tuple[int, int]]],
                period_ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """Merge per-channel (tick, level) events into (durations, levels) steps."""
    bounds = sorted({t for ev in per_channel for t, _ in ev if t < period_ticks} | {0})
    index = {t: i for i, t in enumerate(bounds)}
    n = len(bounds)
    lev = np.zeros((n, len(per_channel)), dtype=np.int64)
    for c, ev in enumerate(per_channel):
        col = np.full(n, -1, dtype=np.int64)
        for t, v in ev:  # later events at the same tick win (a pulse shorter than a tick)
            if t < period_ticks:
                col[index[t]] = v
        # forward-fill: a step without an event of this channel keeps its level
        if col[0] < 0:
            col[0] = 0
        idx = np.where(col >= 0, np.arange(n), 0)
        np.maximum.accumulate(idx, out=idx)
        lev[:, c] = col[idx]
    starts = np.asarray(bounds + [period_ticks], dtype=np.int64)
    keep = np.ones(n, dtype=bool)
    keep[1:] = np.any(lev[1:] != lev[:-1], axis=1)
    kept_starts = np.concatenate([starts[:-1][keep], [period_ticks]])
    return np.diff(kept_starts).astype(np.uint32), lev[keep].astype(np.uint16)


# ---------------------------------------------------------------------- achieved report
def _slot_bounds_ticks(spec: BarcodeSpec, clock_hz: int, n_slots: int) -> list[int]:
    f_b = Fraction(spec.f_b_hz)
    return [_round_ticks(Fraction(g) / f_b * clock_hz) for g in range(n_slots + 1)]


def _slot_edges(spec: BarcodeSpec, tone_hz: float, g: int, s0: int, s1: int,
                rising: np.ndarray, falling: np.ndarray, clock_hz: int
                ) -> list[tuple[Fraction, int]] | None:
    """The genuine edges of one slot as (ideal phase in cycles, played tick), sorted.

    The ideal rising (phase 0) and falling (phase duty) edges of the tone inside the closed
    slot are listed with their phase in cycles; those strictly inside must match the played
    edges one to one (else None: an edge was lost to tick rounding), those on a slot bound are
    timed by the bound's tick. With continuous phase the phases count from t = 0, so the edges
    of different slots of one tone share one time line.
    """
    f_b = Fraction(spec.f_b_hz)
    duty = Fraction(spec.duty)
    f = Fraction(tone_hz)
    t0, t1 = Fraction(g) / f_b, Fraction(g + 1) / f_b
    p0 = f * t0 if spec.phase == "continuous" else Fraction(0)
    p1 = p0 + f * (t1 - t0)
    ideal: list[tuple[Fraction, int]] = []
    j = math.floor(p0)
    while j <= p1:
        for e, kind in ((Fraction(0), 1), (duty, 0)):
            if p0 <= j + e <= p1:
                ideal.append((j + e, kind))
        j += 1
    # an ideal edge that rounds onto a slot bound is played by the bound itself
    ticks = [_round_ticks((t0 + (p - p0) / f) * clock_hz) for p, _ in ideal]
    inner_ideal = [(p, k) for (p, k), t in zip(ideal, ticks, strict=True) if s0 < t < s1]
    played = sorted([(int(t), 1) for t in rising[(rising > s0) & (rising < s1)]]
                    + [(int(t), 0) for t in falling[(falling > s0) & (falling < s1)]])
    if [k for _, k in played] != [k for _, k in inner_ideal]:
        return None
    pts = [(p, min(max(t, s0), s1)) for (p, _), t in zip(ideal, ticks, strict=True)
           if not s0 < t < s1]
    pts += [(p, t) for (p, _), (t, _) in zip(inner_ideal, played, strict=True)]
    return sorted(pts)


def _span_hz(pts: list[tuple[Fraction, int]], clock_hz: int) -> float | None:
    """(phase span in cycles) * clock_hz / (tick span) between the first and last edge; None
    with fewer than two edges at distinct ticks."""
    if len(pts) < 2 or pts[-1][1] == pts[0][1]:
        return None
    return float(pts[-1][0] - pts[0][0]) * clock_hz / (pts[-1][1] - pts[0][1])


def achieved_report(seq: Sequence) -> dict:
    """Frequencies, slot rate and ratio errors that the quantised sequence actually plays.

    Parameters
    ----------
    seq : Sequence
        A compiled sequence.

    Returns
    -------
    report : dict
        JSON-ready. ``tones``: one entry per channel and tone with ``channel``, ``spec_hz``,
        ``achieved_hz`` (mean over its slots), ``min_hz``, ``max_hz`` and ``rel_error``
        (worst over its slots); ``measured`` is False, with NaN values, for a tone none of
        whose slots holds two edges (below about one cycle per slot). ``slot_rate_hz``,
        ``pattern_period_s``, ``period_s``, ``period_ticks``, ``n_patterns``, ``n_steps``,
        ``clock_hz``; ``ratios``: per ratio pair the spec and worst achieved value (NaN when a
        tone is unmeasured);
        ``worst_ratio_error`` (relative, unitless, over the measured pairs, ``inf`` when a tone
        lost its edges) and ``worst_ratio``.

    Notes
    -----
    With ``phase="restart"`` and f >= f_B, in each slot the rising edges of a channel (a level
    change from 0 to > 0, with the slot start counted as one because every slot starts ON) are
    collected together with the next slot start. The n = floor(f / f_B) full cycles of tone f
    span from the slot start to the n-th following rising edge; the achieved frequency is
    n * clock_hz / span_ticks. Otherwise (continuous phase, or a slot shorter than a cycle)
    the slot's first and last edges, rising or falling, whose ideal phases are known, give
    (phase span in cycles) * clock_hz / span_ticks; slots holding fewer than two edges are
    skipped, and a continuous tone none of whose slots holds two edges (fewer than about one
    cycle per slot) is measured from its first to its last edge in the whole sequence.
    """
    spec = seq.spec
    m = spec.n_tones
    n_slots = m * seq.n_patterns
    bounds = _slot_bounds_ticks(spec, seq.clock_hz, n_slots)
    starts = seq.step_starts_ticks()[:-1]
    order = spec.slot_order()
    f_b = spec.f_b_hz
    per_tone: dict[tuple[int, int], list[float]] = {}
    pooled: dict[tuple[int, int], list[tuple[Fraction, int]]] = {}
    for c in range(len(seq.channels)):
        col = seq.levels[:, c].astype(np.int64)
        prev = np.roll(col, 1)
        rising = starts[(col > 0) & (prev == 0)]
        falling = starts[(col == 0) & (prev > 0)]
        on_at = col[np.searchsorted(starts, np.asarray(bounds[:-1]), side="right") - 1] > 0
        for g in range(n_slots):
            s0, s1 = bounds[g], bounds[g + 1]
            tone = order[g % m]
            f = spec.channels[c][1][tone]
            n_full = int(math.floor(f / f_b * (1 + 1e-9)))
            if spec.phase == "restart" and n_full >= 1:
                inner = rising[(rising > s0) & (rising < s1)].tolist()
                edges = sorted(set(([s0] if on_at[g] else []) + inner + [s1]))
                if not on_at[g] or len(edges) <= n_full:
                    hz = float("nan")
                else:
                    hz = n_full * seq.clock_hz / (edges[n_full] - edges[0])
            else:
                pts = _slot_edges(spec, f, g, s0, s1, rising, falling, seq.clock_hz)
                hz = float("nan") if pts is None else _span_hz(pts, seq.clock_hz)
                if pts is not None and spec.phase == "continuous":
                    pooled.setdefault((c, tone), []).extend(pts)
            vals = per_tone.setdefault((c, tone), [])
            if hz is not None:
                vals.append(hz)
    for key, pts in pooled.items():
        # a tone slower than its slots: no slot holds two edges, the whole sequence does
        if not per_tone[key]:
            hz = _span_hz(sorted(pts, key=lambda pt: pt[1]), seq.clock_hz)
            if hz is not None:
                per_tone[key].append(hz)

    tones = []
    achieved: dict[tuple[str, float], tuple[float, float]] = {}
    unmeasured: set[tuple[str, float]] = set()
    for (c, tone), vals in sorted(per_tone.items()):
        ch = seq.channels[c]
        f = spec.channels[c][1][tone]
        arr = np.asarray(vals if vals else [float("nan")])
        bad = bool(np.isnan(arr).any())
        lo = float("nan") if bad else float(arr.min())
        hi = float("nan") if bad else float(arr.max())
        # no edge lost but none of its slots (nor the sequence) holds two edges: unmeasured
        rel = (float("nan") if not vals else float("inf") if bad
               else float(np.max(np.abs(arr / f - 1))))
        tones.append({"channel": ch, "spec_hz": f, "achieved_hz": float(np.mean(arr)),
                      "min_hz": lo, "max_hz": hi, "rel_error": rel, "measured": bool(vals)})
        achieved[(ch, f)] = (lo, hi)
        unmeasured |= {(ch, f)} if not vals else set()

    ratios = []
    worst, worst_entry = 0.0, None
    for r in spec.ratios():
        for (num, den) in r.pairs:
            n_lo, n_hi = achieved[num]
            d_lo, d_hi = achieved[den]
            if num in unmeasured or den in unmeasured:
                err, ach = float("nan"), float("nan")
            elif any(math.isnan(v) for v in (n_lo, n_hi, d_lo, d_hi)):
                err, ach = float("inf"), float("nan")
            else:
                cands = (n_hi / d_lo, n_lo / d_hi)
                errs = [abs(a / r.value - 1) for a in cands]
                err = max(errs)
                ach = cands[int(np.argmax(errs))]
            entry = {"numerator": f"{num[0]}:{num[1]:g} Hz", "denominator":
                     f"{den[0]}:{den[1]:g} Hz", "spec": r.value, "achieved": ach,
                     "rel_error": err}
            ratios.append(entry)
            if not math.isnan(err) and (worst_entry is None or err > worst):
                worst, worst_entry = err, entry
    period_ticks = seq.period_ticks
    return {
        "spec": spec.name,
        "clock_hz": seq.clock_hz,
        "n_steps": seq.n_steps,
        "n_patterns": seq.n_patterns,
        "period_ticks": period_ticks,
        "period_s": seq.period_s,
        "pattern_period_s": seq.period_s / seq.n_patterns,
        "spec_pattern_period_s": spec.pattern_period_s,
        "slot_rate_hz": n_slots * seq.clock_hz / period_ticks,
        "spec_slot_rate_hz": f_b,
        "tones": tones,
        "ratios": ratios,
        "worst_ratio_error": worst,
        "worst_ratio": worst_entry,
    }
