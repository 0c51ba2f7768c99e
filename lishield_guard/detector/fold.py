"""Pattern folding: read a barcode from its exact repetition when slots are too short to tune.

A barcode's light repeats exactly every M/f_B seconds (spec.py slot semantics). In one period
slot k lasts 1/f_B and holds c_n = f_n / f_B cycles of its tone n, so ratios of cycles per slot
are the tone ratios, whatever the row rate. When a slot holds only one or two cycles no
frequency estimator can tell its tone (per-slot resolution is ~f_B), but a frame usually holds
many periods: the period is found from the autocorrelation of the common row signal, the
signal is folded (averaged modulo the period), and the folded pattern is correlated, at every
circular shift, with the spec's template over a grid of c_1 = f_1 / f_B and exposure smoothing.

Evidence is the normalised correlation rho of the best template, plus repeatability: the folded
pattern's power over the power its bins' scatter across periods predicts (an F-like ratio; the
LED repeats exactly, scene texture does not). Stationary look-alikes fold to shapes no template
of distinct cycle counts fits (a |sin| arch, or k equal PWM cycles).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft
from scipy.ndimage import gaussian_filter1d, uniform_filter1d

from lishield_guard.detector.emitters import cycles_range, phase_mode
from lishield_guard.detector.numerics import HIGHPASS_CYCLES
from lishield_guard.detector.profiles import gaussian_smooth
from lishield_guard.detector.results import FoldMatch
from lishield_guard.spec import BarcodeSpec

__all__ = ["FoldMatch", "candidate_periods", "fold", "fold_match", "refine_period"]

N_PHASE_BINS = 96
N_CYCLE_STEPS = 160
EXPOSURE_FRACTIONS = (0.0, 0.03, 0.08, 0.16)  # box smoothing, as a fraction of one slot
MIN_PERIODS = 2.0
MAX_TONE_CPR = 0.45  # a tone above this is aliased or lost in the JPEG grid


def candidate_periods(x: np.ndarray, *, min_rows: float, max_rows: float, n: int = 4
                      ) -> list[float]:
    """Periods (rows) at the strongest local maxima of the normalised autocorrelation."""
    size = x.size
    max_rows = min(max_rows, size / MIN_PERIODS)
    if max_rows <= min_rows + 2 or size < 8:
        return []
    y = x - x.mean()
    spec = np.fft.rfft(y, 2 * size)
    ac = np.fft.irfft(np.abs(spec) ** 2)[:size]
    if not ac[0] > 0:
        return []
    ac = ac / ac[0] * size / np.maximum(size - np.arange(size), 1)  # unbiased
    lo, hi = int(math.ceil(min_rows)), int(math.floor(max_rows))
    seg = ac[lo - 1: hi + 2]
    peak = (seg[1:-1] > seg[:-2]) & (seg[1:-1] >= seg[2:]) & (seg[1:-1] > 0.1)
    idx = np.flatnonzero(peak) + lo
    if idx.size == 0:
        return []
    idx = idx[np.argsort(ac[idx])[::-1][:n]]
    out = []
    for k in idx:
        a, b, c = ac[k - 1], ac[k], ac[k + 1]
        den = a - 2 * b + c
        out.append(float(k + (0.5 * (a - c) / den if den < 0 else 0.0)))
    return out


def _phase_sums(xh: np.ndarray, period_rows: float, n_bins: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per phase bin of a period: the sum of xh and the row count; and each row's bin."""
    phase = (np.arange(xh.size) / period_rows) % 1.0
    b = np.minimum((phase * n_bins).astype(int), n_bins - 1)
    return (np.bincount(b, weights=xh, minlength=n_bins),
            np.bincount(b, minlength=n_bins).astype(float), b)


def fold(x: np.ndarray, period_rows: float, n_bins: int = N_PHASE_BINS
         ) -> tuple[np.ndarray, np.ndarray, float]:
    """Fold x at a period.

    Returns
    -------
    means : ndarray of shape (n_bins,)
        Mean of x per phase bin.
    counts : ndarray of shape (n_bins,)
        Rows per bin.
    within_var : float
        Variance of rows around their bin's mean (what does not repeat), per row.
    """
    sums, counts, b = _phase_sums(x, period_rows, n_bins)
    means = np.divide(sums, counts, out=np.zeros(n_bins), where=counts > 0)
    dof = max(x.size - int((counts > 0).sum()), 1)
    within = float(((x - means[b]) ** 2).sum()) / dof
    return means, counts, within


@lru_cache(maxsize=64)
def _lookalike_templates(n_bins: int) -> np.ndarray:
    """Stationary alternatives folded at the period: k equal square cycles, any duty/smoothing.

    PWM dimming, periodic texture (blinds, bricks) and mains flicker all fold to k identical
    cycles per period; a barcode must fit its own template better than any of these.
    """
    sub = 8
    phase = (np.arange(n_bins * sub) + 0.5) / (n_bins * sub)
    ks = np.arange(1, max(2, n_bins // 4) + 1)
    duties = np.linspace(0.1, 0.9, 9)
    cyc = (ks[:, None, None] * phase[None, None, :]) % 1.0
    on = (cyc < duties[None, :, None]).astype(np.float32).reshape(-1, n_bins * sub)
    sine = 0.5 + 0.5 * np.cos(2 * np.pi * ks[:, None] * phase[None, :])
    waves = np.concatenate([on, sine.astype(np.float32)], axis=0)
    out = []
    for frac in EXPOSURE_FRACTIONS:
        width = max(1, int(round(frac * n_bins * sub / 3)))
        sm = uniform_filter1d(waves, size=width, axis=1, mode="wrap") if width > 1 else waves
        out.append(sm.reshape(waves.shape[0], n_bins, sub).mean(axis=2))
    return np.stack(out, axis=1)


def _prepared(tpl: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """High-passed, zero-mean templates: their spectra, norms and the spectra of their squares
    (cached per bank)."""
    key = (id(tpl), n_bins)
    hit = _PREPARED.get(key)
    if hit is not None and hit[0] is tpl:
        return hit[1]
    t = tpl - gaussian_filter1d(tpl, n_bins / (2 * math.pi * HIGHPASS_CYCLES), axis=-1,
                                mode="wrap")
    t = t - t.mean(axis=-1, keepdims=True)
    # single precision spectra: correlations need ~1e-4, and batched inverse FFTs run ~2.5x faster
    out = (np.fft.rfft(t, axis=-1).astype(np.complex64), np.sqrt((t ** 2).sum(axis=-1)),
           np.fft.rfft(t * t, axis=-1).astype(np.complex64))
    if len(_PREPARED) > 512:
        _PREPARED.clear()
    _PREPARED[key] = (tpl, out)
    return out


_PREPARED: dict = {}


def _best_rho(tpl: np.ndarray, y: np.ndarray, n_bins: int) -> tuple[float, tuple]:
    """Best normalised circular correlation of templates (..., n_bins) with y (zero mean)."""
    spec, norm, _ = _prepared(tpl, n_bins)
    cc = scipy.fft.irfft(spec * np.conj(np.fft.rfft(y)).astype(np.complex64), n=n_bins, axis=-1)
    rho = cc.max(axis=-1) / np.maximum(norm, 1e-12) / math.sqrt(float(y @ y))
    k = np.unravel_index(int(np.argmax(rho)), rho.shape)
    return float(rho[k]), k


def refine_period(x: np.ndarray, period_rows: float, *, span: float = 0.03,
                  steps: int = 61) -> float:
    """The period near ``period_rows`` (within +-span, relative) whose fold repeats best.

    An autocorrelation peak is only as precise as one lag; over many periods a 1% error smears
    the fold, so the period maximising folded power over within-bin scatter is taken.
    """
    n_bins = int(min(N_PHASE_BINS, max(12, period_rows // 1)))
    sigma_rows = period_rows / (2 * math.pi * HIGHPASS_CYCLES)
    xh = x - gaussian_smooth(x, sigma_rows=sigma_rows)
    best_p, best_f = period_rows, -1.0
    for p in period_rows * np.linspace(1 - span, 1 + span, steps):
        if x.size < MIN_PERIODS * p:
            continue
        y, counts, within = fold(xh, float(p), n_bins)
        y = y - y.mean()
        f = float(y @ y) / max(within * float(np.sum(1.0 / np.maximum(counts, 1))), 1e-30)
        if f > best_f:
            best_p, best_f = float(p), f
    return best_p


def _cycle_grid(spec: BarcodeSpec) -> np.ndarray:
    """c_1 = f_1 / f_B values searched, geometric over `emitters.cycles_range`."""
    c_lo, c_hi = cycles_range(spec.f1_hz)
    return np.exp(np.linspace(math.log(c_lo), math.log(c_hi), N_CYCLE_STEPS))


@lru_cache(maxsize=256)
def _templates(spec: BarcodeSpec, channel: str, n_bins: int,
               cycles_f1: tuple[float, ...] | None = None,
               exposures: tuple[float, ...] = EXPOSURE_FRACTIONS) -> np.ndarray:
    """Templates (n_cycles, n_exposures, n_bins): ON/OFF per phase bin, box-smoothed.

    ``cycles_f1`` defaults to `_cycle_grid`; ``exposures`` are box widths as fractions of a
    slot (row integration: t_e x f_B).
    """
    cyc = np.asarray(_cycle_grid(spec) if cycles_f1 is None else cycles_f1, dtype=np.float64)
    fs = np.array(dict(spec.channels)[channel])
    order = np.array(spec.slot_order())
    m = spec.n_tones
    sub = 8
    phase = (np.arange(n_bins * sub) + 0.5) / (n_bins * sub)
    slot = np.minimum((phase * m).astype(int), m - 1)
    within = phase * m - slot  # position inside the slot, [0, 1)
    ratio = fs[order[slot]] / spec.f1_hz  # f_n / f_1 per sample
    # slots since the tone's timer started: its own slot, or the pattern start (continuous)
    elapsed = within + slot if phase_mode(spec) == "continuous" else within
    on = (((cyc[:, None] * ratio[None, :] * elapsed[None, :]) % 1.0) < spec.duty
          ).astype(np.float32)  # (n_cycles, n_bins * sub)
    out = np.empty((cyc.size, len(exposures), n_bins), np.float32)
    slot_samples = n_bins * sub / m
    for j, frac in enumerate(exposures):
        width = max(1, int(round(frac * slot_samples)))
        sm = uniform_filter1d(on, size=width, axis=1, mode="wrap") if width > 1 else on
        out[:, j] = sm.reshape(cyc.size, n_bins, sub).mean(axis=2)
    out.setflags(write=False)
    return out


def fold_match(x: np.ndarray, spec: BarcodeSpec, channel: str, *,
               period_range_rows: tuple[float, float], periods: list[float] | None = None,
               refine: bool = True,
               scale_range_cpr_per_hz: tuple[float, float] | None = None) -> FoldMatch | None:
    """Best correlation of the spec's channel template with x folded at candidate periods.

    Parameters
    ----------
    x : ndarray of shape (n_rows,)
        Common log-contrast row signal.
    spec : BarcodeSpec
        Spec whose ``channel`` template is fitted.
    period_range_rows : (float, float)
        Physically possible pattern periods in rows.
    periods : list of float, optional
        Candidate periods (rows); found from x when None.
    refine : bool
        Refine each candidate with `refine_period` (callers that share periods between specs
        refine once themselves).
    scale_range_cpr_per_hz : (float, float), optional
        Row time x downscale range: f_1 must appear at c_1 M / period cycles per row within
        it. None leaves c_1 bounded only by MAX_TONE_CPR for the fastest tone.
    """
    lo, hi = period_range_rows
    if periods is None:
        periods = candidate_periods(x, min_rows=lo, max_rows=hi)
    cycles = _cycle_grid(spec)
    best: FoldMatch | None = None
    for coarse in periods:
        if not lo <= coarse <= hi or x.size < MIN_PERIODS * coarse:
            continue
        period = refine_period(x, coarse) if refine else coarse
        n_bins = int(min(N_PHASE_BINS, max(12, period // 1)))
        # the pattern's content lies at >= M / period cycles per row; scene structure below
        # that would only blur the fold
        sigma_rows = period / (2 * math.pi * HIGHPASS_CYCLES)
        xh = x - gaussian_smooth(x, sigma_rows=sigma_rows)
        y, counts, within = fold(xh, period, n_bins)
        y = y - y.mean()
        power = float(y @ y)
        if power <= 0:
            continue
        # repeatability: power of the folded pattern over what its bins' scatter predicts
        fold_noise = within * float(np.sum(1.0 / np.maximum(counts, 1)))
        snr = power / max(fold_noise, 1e-30)
        # c_1 such that f_1 lands at c_1 M / period cycles per row within the scale range
        # and the fastest tone stays below MAX_TONE_CPR
        f1_cpr = cycles * spec.n_tones / period
        ok = f1_cpr * (max(spec.all_freqs_hz) / spec.f1_hz) <= MAX_TONE_CPR
        if scale_range_cpr_per_hz is not None:
            s_lo, s_hi = scale_range_cpr_per_hz
            ok &= (f1_cpr >= spec.f1_hz * s_lo) & (f1_cpr <= spec.f1_hz * s_hi)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            continue
        tpl = _templates(spec, channel, n_bins)[idx]
        r, k = _best_rho(tpl, y, n_bins)  # one polarity only: more light is brighter
        if best is None or r > best.rho:
            r_alt, _ = _best_rho(_lookalike_templates(n_bins), y, n_bins)
            best = FoldMatch(spec.name, r, float(period), float(cycles[idx[k[0]]]),
                             float(snr), float(x.size / period), r_alt)
    return best
