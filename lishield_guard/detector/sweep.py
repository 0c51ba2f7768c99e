"""Period sweep: tile a spec's pattern over the frame when it holds too few periods to fold.

With fewer than two pattern periods in the frame there is no repetition to fold on. The
template is then slid over the frame itself: for each period on a grid (coarse, then refined
around the best few), rows are binned by phase and the bin *sums* are circularly correlated
with the template bank. Because bins of a frame holding 1.3 periods are unevenly filled, the
template's energy is computed per shift from the bin counts (correlation of t and t^2 with the
counts), which makes rho the exact normalised correlation of the tiled template with the rows.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft

from lishield_guard.detector.emitters import cycles_range
from lishield_guard.detector.fold import (
    N_PHASE_BINS,
    _lookalike_templates,
    _phase_sums,
    _prepared,
    _templates,
)
from lishield_guard.detector.numerics import (
    HIGHPASS_CYCLES,
    START_SEPARATION,
    block_coherence_t,
    highpass_gain,
    mirror_rfft,
    quiet_weights,
)
from lishield_guard.detector.results import SweepMatch
from lishield_guard.spec import BarcodeSpec

__all__ = ["sweep_match"]

SWEEP_EXPOSURES = (0.0, 0.1, 0.3, 0.6, 1.0, 1.5)  # box widths t_e x f_B, in slots
SWEEP_CYCLE_STEP = 0.08  # c_1 grid step: a slot with c cycles drifts < 1/8 cycle between steps
SWEEP_MAX_PERIODS = 4.0  # the sweep covers periods >= n_rows / this (folding covers the rest)
SWEEP_DRIFT = 1 / 12  # grid step: the last row's phase moves <= this fraction of a period
SWEEP_REFINE_STEPS = 7  # around each target's best grid period, within +- half a step
SWEEP_MIN_ROWS = 32  # fewer rows hold no pattern worth tiling
VAR_FLOOR = 1e-3  # template variance over rows, relative to its energy, below which rho is 0


@lru_cache(maxsize=64)
def _sweep_cycles(f1_hz: float, n_tones: int) -> tuple[float, ...]:
    """c_1 values swept over `emitters.cycles_range` in steps of SWEEP_CYCLE_STEP."""
    c_lo, c_hi = cycles_range(f1_hz)
    n = max(2, int(math.ceil((c_hi - c_lo) / SWEEP_CYCLE_STEP)) + 1)
    return tuple(np.linspace(c_lo, c_hi, n).tolist())


def _period_grid(n_rows: int, lo: float, hi: float, drift: float) -> np.ndarray:
    """Periods from lo to hi whose steps move the last row's phase by <= drift of a period."""
    out, p = [], lo
    while p <= hi:
        out.append(p)
        p *= 1.0 + max(drift * p / n_rows, 0.002)
    return np.array(out)


def _highpass_fn(x: np.ndarray):
    """A function of the period returning x minus its Gaussian trend of sigma
    period / (2 pi HIGHPASS_CYCLES) rows, along the last axis (mirror-extended, in the
    frequency domain). Sigma is rounded to a 5 % grid and results are reused: neighbouring
    periods of a sweep share one trend."""
    n = x.shape[-1]
    spec = mirror_rfft(x)
    memo: dict[int, np.ndarray] = {}

    def highpassed(period_rows: float) -> np.ndarray:
        key = int(round(math.log(period_rows / (2 * math.pi * HIGHPASS_CYCLES)) / 0.05))
        hit = memo.get(key)
        if hit is None:
            gain = highpass_gain(n, math.exp(key * 0.05))
            hit = memo[key] = np.fft.irfft(spec * gain, n=2 * n, axis=-1)[..., :n]
        return hit

    return highpassed


class _Phased:
    """One period's view of the rows: high-passed energy and phase-bin sums/counts spectra."""

    def __init__(self, highpassed, period_rows: float, n_rows: int) -> None:
        xh = highpassed(period_rows)
        xh = xh - xh.mean()
        self.period_rows = period_rows
        self.energy = float(xh @ xh)
        self.sums, self.counts, self.bins = _phase_sums(xh, period_rows, N_PHASE_BINS)
        self.s_conj = np.conj(np.fft.rfft(self.sums)).astype(np.complex64)
        self.c_conj = np.conj(np.fft.rfft(self.counts)).astype(np.complex64)
        self.n_rows = n_rows

    def rho(self, prep: tuple) -> np.ndarray:
        """Normalised correlation of every template of ``prep``, tiled at every shift."""
        spec, _, spec_sq = prep
        num = scipy.fft.irfft(spec * self.s_conj, n=N_PHASE_BINS, axis=-1)
        m1 = scipy.fft.irfft(spec * self.c_conj, n=N_PHASE_BINS, axis=-1)
        m2 = scipy.fft.irfft(spec_sq * self.c_conj, n=N_PHASE_BINS, axis=-1)
        var = m2 - m1 * m1 / self.n_rows
        # a template (nearly) constant on the bins the rows fill has no shape to correlate;
        # in single precision its variance is rounding noise, so such fits count as rho 0
        flat = var <= VAR_FLOOR * np.maximum(m2, 1e-30)
        rho = np.where(flat, 0.0, num / np.sqrt(np.where(flat, 1.0, var) * self.energy))
        return np.clip(rho, -1.0, 1.0)  # a correlation; beyond +-1 is rounding


class _Target:
    """One (spec, channel) to sweep: its template bank and the periods it allows."""

    def __init__(self, spec: BarcodeSpec, channel: str, period_range_rows, scale_range,
                 n_rows: int) -> None:
        self.spec, self.channel = spec, channel
        self.range_lo = period_range_rows[0]
        self.lo = max(period_range_rows[0], n_rows / SWEEP_MAX_PERIODS)
        self.hi = period_range_rows[1]
        self.cycles = np.array(_sweep_cycles(spec.f1_hz, spec.n_tones))
        self.scale = scale_range
        bank = _templates(spec, channel, N_PHASE_BINS, tuple(self.cycles.tolist()),
                          SWEEP_EXPOSURES)
        self.prep = _prepared(bank, N_PHASE_BINS)
        self.best: tuple | None = None  # (rho, _Phased, (c index, exposure index, shift))
        self.per_period: list[tuple] = []  # (rho, period, c index, exposure index, shift)

    def fit(self, ph: _Phased, *, start_only: bool = False) -> None:
        """Fit every template at one period (if possible there); keep the best so far.

        ``start_only`` periods (repetition periods found by autocorrelation, which may lie
        below n_rows / SWEEP_MAX_PERIODS) only offer refinement starts: they never become
        the sweep's own best fit."""
        p = ph.period_rows
        lo = self.range_lo if start_only else self.lo
        if not lo <= p <= self.hi or not ph.energy > 0:
            return
        m, f1 = self.spec.n_tones, self.spec.f1_hz
        i0 = int(np.searchsorted(self.cycles, f1 * self.scale[0] * p / m))
        i1 = int(np.searchsorted(self.cycles, f1 * self.scale[1] * p / m, side="right"))
        if i1 <= i0:
            return
        rho = ph.rho(tuple(a[i0:i1] for a in self.prep))
        k = np.unravel_index(int(np.argmax(rho)), rho.shape)
        self.per_period.append((float(rho[k]), p, i0 + int(k[0]), int(k[1]), int(k[2]),
                                start_only))
        if start_only:
            return
        if self.best is None or float(rho[k]) > self.best[0]:
            self.best = (float(rho[k]), ph, (i0 + int(k[0]), int(k[1]), int(k[2])))

    def starts(self, k: int) -> tuple[tuple[float, float, float, float, float], ...]:
        """The ``k`` best grid fits at periods >= START_SEPARATION apart (relative), as
        (rho, period_rows, c_1, phase_slots, exposure_slots): starting points for
        `fit.refine`."""
        out: list[tuple] = []
        ranked = sorted(self.per_period, key=lambda r: -r[0])
        # the k best grid periods, then the best repetition period (if distinct)
        for pool, quota in (([r for r in ranked if not r[5]], k), ([r for r in ranked if r[5]],
                                                                     k + 1)):
            for rho, p, ci, ei, shift, _ in pool:
                if len(out) >= quota:
                    break
                if all(abs(p / q[1] - 1.0) > START_SEPARATION for q in out):
                    out.append((rho, p, float(self.cycles[ci]),
                                _phase_slots(self.spec, shift, ei), float(SWEEP_EXPOSURES[ei])))
        return tuple(out)


def _phase_slots(spec: BarcodeSpec, shift: int, exposure_index: int) -> float:
    """Row 0's position in the pattern (slots) of a grid fit, for a forward box of the
    exposure's width starting at each row (the bank's box is centred on the bin)."""
    m = spec.n_tones
    return (m * shift / N_PHASE_BINS - 0.5 * SWEEP_EXPOSURES[exposure_index]) % m


def sweep_match(blocks: np.ndarray, targets, *, period_range_rows,
                scale_range_cpr_per_hz: tuple[float, float], n_starts: int = 0,
                start_periods: tuple[float, ...] = (), weighted: bool = False
                ) -> list[SweepMatch | None]:
    """Best fit of each target's template tiled over the frame, at any period.

    Parameters
    ----------
    blocks : ndarray of shape (n_blocks, n_rows)
        Log contrast per column block; their mean is the common LED estimate.
    targets : sequence of (BarcodeSpec, channel)
        Templates fitted to the same rows (they share the period grid and its phase sums).
    period_range_rows : sequence of (float, float)
        Per target, the physically possible pattern periods M / f_B in rows; only periods of
        at least n_rows / SWEEP_MAX_PERIODS are swept.
    scale_range_cpr_per_hz : (float, float)
        Row time x downscale range; bounds c_1 for each period (f_1 appears at c_1 M / period
        cycles per row).
    n_starts : int
        How many of the best grid fits at distinct periods to return in ``starts`` (for the
        exact-model refinement, `fit.refine`); 0 returns none.
    start_periods : tuple of float
        Extra periods (rows; e.g. the repetition periods `candidate_periods` found) whose grid
        fits are offered as starts, at any number of periods in the frame. The grid's step
        drifts 1/12 of a period over the frame, a whole tone cycle for templates of many
        cycles, so a measured repetition period is a far better start there.
    weighted : bool
        Estimate the LED from the `quiet_weights` mean of the blocks (and weight the
        coherence t alike) instead of their plain mean.

    Returns
    -------
    list of SweepMatch or None
        Per target; None when no period is possible. ``coherence_t`` is the t statistic of the
        fitted template's amplitude across column blocks (the LED is common to all of them;
        scene structure is not).
    """
    blocks = np.asarray(blocks, dtype=np.float64)
    weights = (quiet_weights(blocks) if weighted
               else np.full(blocks.shape[0], 1.0 / max(blocks.shape[0], 1)))
    x = weights @ blocks
    n = x.size
    if n < SWEEP_MIN_ROWS or blocks.shape[0] < 2 or not targets:
        return [None] * len(targets)
    tg = [_Target(spec, ch, pr, scale_range_cpr_per_hz, n)
          for (spec, ch), pr in zip(targets, period_range_rows, strict=True)]
    live = [t for t in tg if t.lo <= t.hi]
    highpassed = _highpass_fn(x)
    if live:
        # anchored at n / SWEEP_MAX_PERIODS whatever the targets: a target's fit must not
        # depend on which other targets share the sweep
        grid = _period_grid(n, n / SWEEP_MAX_PERIODS, max(t.hi for t in live), SWEEP_DRIFT)
        for p in grid:
            ph = _Phased(highpassed, float(p), n)
            for t in live:
                t.fit(ph)
    for p in start_periods if n_starts else ():
        ph = _Phased(highpassed, float(p), n)
        for t in tg:
            t.fit(ph, start_only=True)
    block_hp = None
    out: list[SweepMatch | None] = []
    for t in tg:
        if t.best is None:
            # no period of the grid's range: only repetition periods offer (refinement) starts
            starts = t.starts(n_starts) if t.per_period else ()
            out.append(SweepMatch(t.spec.name, 0.0, 0.0, starts[0][1], starts[0][2], 0.0, 0.0,
                                  n / starts[0][1], starts=starts) if starts else None)
            continue
        p0 = t.best[1].period_rows
        half = 0.5 * p0 * max(SWEEP_DRIFT * p0 / n, 0.002)
        for p in np.linspace(p0 - half, p0 + half, SWEEP_REFINE_STEPS):
            if p != p0 and t.lo <= p <= t.hi:
                t.fit(_Phased(highpassed, float(p), n))
        rho, ph, (ci, ei, shift) = t.best
        period = ph.period_rows
        rho_alt = float(ph.rho(_prepared(_lookalike_templates(N_PHASE_BINS), N_PHASE_BINS))
                        .max())
        # the fitted template, row by row, and its amplitude in each column block
        t_bins = np.fft.irfft(t.prep[0][ci, ei].astype(np.complex128), n=N_PHASE_BINS)
        tr = t_bins[(ph.bins + shift) % N_PHASE_BINS]
        tr = tr - tr.mean()
        if block_hp is None:
            block_hp = _highpass_fn(blocks)
        xb = block_hp(period)
        xb = xb - xb.mean(axis=1, keepdims=True)
        f_b = t.spec.f1_hz / float(t.cycles[ci])
        out.append(SweepMatch(t.spec.name, float(rho), rho_alt, float(period),
                              float(t.cycles[ci]), float(SWEEP_EXPOSURES[ei]),
                              block_coherence_t(xb, tr, weights), n / period, f_b,
                              period * f_b / t.spec.n_tones, t.starts(n_starts)))
    return out
