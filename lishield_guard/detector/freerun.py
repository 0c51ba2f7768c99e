"""Starting points for a free-running emitter's exact fit: its tones demodulated slot by slot.

An emitter whose tone timers run on through the slots where they are silent (`spec.py`,
``phase="continuous"``) does not repeat its pattern every M / f_B: tone n is one square wave
of f_n, phase-coherent across all of its slots, gated on in every M-th slot. A grid of
repeating templates (`sweep`) then ranks wrong periods first, and the exact model
(`fit.refine`, seven parameters) cannot walk from there to the right one.

Each tone's coherence is the handle. For a hypothesis of f_1 in cycles per row (k_1, from the
rows' spectral peaks, each peak tried as every tone), the rows are demodulated at every tone
k_j = k_1 r_j; for a period P and slot phase phi the tone fundamentals' energy inside their
own slots is a sum of cumulative-sum differences, so every (P, phi) on a grid costs O(slots).
The best hypotheses give P, c_1 = k_1 P / M, phi and each tone's phase theta_j in closed form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

__all__ = ["FreeStart", "free_running_starts"]

PEAKS = 3  # strongest spectral peaks of the rows, each tried as every tone of the spec
K_OFFSETS = 2  # fine k_1 offsets each side of a peak hypothesis, in steps of 1 / (K_STEP n)
K_STEP = 6  # k_1 step 1 / (K_STEP n_rows): a tone drifts < 1/6 cycle over the frame
SLOT_DRIFT = 0.125  # period step: slot edges move < this fraction of a slot over the frame
PHASE_STEPS = 8  # slot phases tried per slot
MIN_SLOT_ROWS = 2.0  # shorter slots cannot be told apart by their tones
MERGE_REL = 0.02  # hypotheses closer than this in period (relative) and k_1 count as one


@dataclass(frozen=True)
class FreeStart:
    """One hypothesis of a free-running emitter's timing, scored by its tones' gated energy.

    Attributes
    ----------
    score : float
        Fraction of the rows' energy that the tone fundamentals explain inside their own
        slots (an estimate of rho^2 from the fundamentals alone; 0..1).
    period_rows : float
        Pattern period M / f_B in rows.
    cycles_f1 : float
        c_1 = f_1 / f_B, cycles of the lowest tone per slot.
    phase_slots : float
        Row 0's position in the pattern, slots (the model's phi).
    tone_phases : tuple of float
        theta_j of each slot position's tone (cycles) for an instantaneous exposure: ON while
        frac(c_j u + theta_j) < duty (`params` adds an exposure).
    rel : tuple of float
        Each slot position's tone over f_1.
    """

    score: float
    period_rows: float
    cycles_f1: float
    phase_slots: float
    tone_phases: tuple[float, ...]
    rel: tuple[float, ...] = ()

    def params(self, exposure_slots: float) -> np.ndarray:
        """The exact model's parameters (period, c_1, phi, e, theta_1..theta_M) for an
        exposure of ``exposure_slots``: a box of e slots delays each tone's fundamental by
        e / 2 slots and scales it by sinc(c_j e), which the tone phases take back (half a
        cycle where that is negative)."""
        c = self.cycles_f1 * np.asarray(self.rel)
        flip = 0.5 * (np.sinc(c * exposure_slots) < 0)
        theta = (np.asarray(self.tone_phases) - 0.5 * exposure_slots * c + flip) % 1.0
        return np.array([self.period_rows, self.cycles_f1, self.phase_slots, exposure_slots,
                         *theta])


def _k1_hypotheses(x: np.ndarray, rel: np.ndarray, k1_range: tuple[float, float]
                   ) -> list[float]:
    """k_1 values (cycles per row) that put one of the spec's tones on one of the rows'
    `PEAKS` strongest spectral peaks, with `K_OFFSETS` fine steps around each."""
    from scipy.signal import find_peaks

    n = x.size
    nfft = 1 << int(math.ceil(math.log2(4 * n)))
    power = np.abs(scipy.fft.rfft(x * np.hanning(n), nfft)) ** 2
    freqs = np.arange(power.size) / nfft
    lo, hi = k1_range[0] * rel.min(), min(0.5, k1_range[1] * rel.max())
    band = (freqs >= lo) & (freqs <= hi)
    if not band.any():
        return []
    idx = np.flatnonzero(band)
    peaks, _ = find_peaks(power[idx])
    top = idx[peaks[np.argsort(power[idx][peaks])[::-1][:PEAKS]]]
    step = 1.0 / (K_STEP * n)
    out: list[float] = []
    for k in freqs[top]:
        for r in rel:
            for d in range(-K_OFFSETS, K_OFFSETS + 1):
                k1 = k / r + d * step
                if (k1_range[0] <= k1 <= k1_range[1] and k1 * rel.max() < 0.5
                        and all(abs(k1 - q) > 0.5 * step for q in out)):
                    out.append(float(k1))
    return out


def _period_grid(lo: float, hi: float, n_rows: int, m: int) -> np.ndarray:
    """Periods from ``lo`` to ``hi`` whose slot edges move < `SLOT_DRIFT` slot over the frame
    between neighbours: step SLOT_DRIFT P^2 / (n_rows M)."""
    out = []
    p = lo
    while p <= hi:
        out.append(p)
        p += max(SLOT_DRIFT * p * p / (n_rows * m), 0.25)
    return np.asarray(out)


def _gated_energy(cum: np.ndarray, m: int, period_rows: float, phases: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per slot phase (rows of the result) and slot position j: the sum of the demodulated
    rows of tone j over its own slots (complex), and the number of those rows.

    ``cum``: (M, n_rows + 1) cumulative sums of the rows demodulated at each slot position's
    tone."""
    n = cum.shape[1] - 1
    slot_rows = period_rows / m
    # row i lies in slot floor(i / slot_rows + phi), phi in [0, M): slots 0 .. n / slot_rows + M
    s = np.arange(0, int(math.ceil(n / slot_rows)) + m + 1)
    edges = np.clip(np.rint((s[None, :] - phases[:, None]) * slot_rows), 0, n).astype(np.int64)
    pos = s[:-1] % m  # slot position of slot s (rows edges[s] .. edges[s + 1])
    sums = np.zeros((phases.size, m), dtype=np.complex128)
    counts = np.zeros((phases.size, m))
    for j in range(m):
        sel = np.flatnonzero(pos == j)
        a, b = edges[:, sel], edges[:, sel + 1]
        sums[:, j] = (cum[j][b] - cum[j][a]).sum(axis=1)
        counts[:, j] = (b - a).sum(axis=1)
    return sums, counts


def free_running_starts(x: np.ndarray, rel: np.ndarray, duty: float, *,
                        period_range_rows: tuple[float, float],
                        c_range: tuple[float, float], k1_range_cpr: tuple[float, float],
                        n_best: int = 3) -> list[FreeStart]:
    """The best timing hypotheses of a free-running emitter for the rows ``x``.

    Parameters
    ----------
    x : ndarray of shape (n_rows,)
        The LED's common row signal (linear light; a slow trend does little harm).
    rel : ndarray of shape (M,)
        Each slot position's tone over f_1 (the slot order applied).
    duty : float
        ON fraction of each tone's square wave.
    period_range_rows, c_range : (float, float)
        Allowed pattern periods (rows) and c_1 values.
    k1_range_cpr : (float, float)
        Allowed f_1 in cycles per row (f_1 times the scale range).
    n_best : int
        How many hypotheses to return, at distinct periods.

    Returns
    -------
    list of FreeStart
        Best first; empty when no hypothesis is possible.
    """
    x = np.asarray(x, dtype=np.float64)
    x = x - x.mean()
    n, m = x.size, rel.size
    xx = float(x @ x)
    if not xx > 0 or n < 16:
        return []
    rows = np.arange(n)
    phases = np.arange(m * PHASE_STEPS) / PHASE_STEPS
    found: list[tuple[float, float, float, float, np.ndarray]] = []
    for k1 in _k1_hypotheses(x, rel, k1_range_cpr):
        k = k1 * rel
        demod = x[None, :] * np.exp(-2j * math.pi * k[:, None] * rows[None, :])
        cum = np.concatenate([np.zeros((m, 1), np.complex128), np.cumsum(demod, axis=1)],
                             axis=1)
        lo = max(period_range_rows[0], c_range[0] * m / k1, MIN_SLOT_ROWS * m)
        hi = min(period_range_rows[1], c_range[1] * m / k1)
        for p in _period_grid(lo, hi, n, m) if lo <= hi else ():
            sums, counts = _gated_energy(cum, m, p, phases)
            score = 2.0 * (np.abs(sums) ** 2 / np.maximum(counts, 1.0)).sum(axis=1) / xx
            i = int(np.argmax(score))
            found.append((float(score[i]), float(p), k1, float(phases[i]), sums[i]))
    found.sort(key=lambda f: -f[0])
    out: list[FreeStart] = []
    for score, p, k1, phi, sums in found:
        if len(out) >= n_best:
            break
        if any(abs(p / o.period_rows - 1.0) < MERGE_REL for o in out):
            continue
        c1 = k1 * p / m
        # tone j ~ cos(2 pi (c_j u + theta_j - duty / 2)) at u = phi + M i / P
        theta = (np.angle(sums) / (2 * math.pi) - c1 * rel * phi + 0.5 * duty) % 1.0
        out.append(FreeStart(min(score, 1.0), p, c1, phi, tuple(theta.tolist()),
                             tuple(rel.tolist())))
    return out
