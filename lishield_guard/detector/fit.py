"""Exact-model fit: the barcode's light, integrated over each row's exposure, fitted continuously.

The period sweep (`sweep.sweep_match`) correlates the rows with a bank of binned, box-smoothed
templates on a grid of (period, c_1, exposure, shift). A grid is coarse where it matters: a
slot holding seven cycles of its tone drifts a whole cycle between neighbouring periods, and a
log-domain template misfits strong stripes (the log of a box-smoothed square is not a box-smoothed
square). This module takes the sweep's best grid points as starting points and refines them with
the exact physics of the capture:

- Linear light. The camera's stored value is about (ambient + LED)^(1/gamma) times the scene, so
  ``expm1(gamma * log_contrast)`` is, up to gain and offset, the ambient plus the LED's light
  integrated over each row's exposure (paper Eq. 1): linear in the template for any ambient.
- Exact template. Row i starts its exposure at u_i = M i / P + phi slots into the pattern and
  integrates for e slots, so its value is (F(u_i + e) - F(u_i)) / e, with F the cumulative ON
  time of the spec's pattern (each slot restarts its tone at the start of an ON half-period;
  `spec.py`). Parameters: period P (rows), c_1 = f_1 / f_B (cycles of f_1 per slot), phase phi
  and exposure e (slots).
- Look-alike. The same refinement fits the best stationary square wave (PWM, mains-like,
  periodic texture: frequency, duty, phase, exposure). The evidence is how much more of the
  rows' energy the barcode explains than the look-alike, over what the barcode leaves
  unexplained: ``gain = (rho^2 - rho_lookalike^2) / (1 - rho^2)``.
- Coherence. The fitted template's amplitude is estimated in every column block; the LED adds
  the same light to all of them, scene structure does not (a t statistic across blocks, with
  the quiet-block weights).
- Partial light. An LED lighting part of the frame shows in some column blocks only, and the
  quietest blocks (which lead the first fit) may be unlit ones. The fit is repeated once on
  the blocks re-combined with matched-filter weights for the fitted template, and the better
  fit is kept (`_matched_refit`).
"""

from __future__ import annotations

import math

import numpy as np

from lishield_guard.config import FIT_RHO_FLOOR
from lishield_guard.detector.emitters import cycles_range, phase_mode
from lishield_guard.detector.freerun import free_running_starts
from lishield_guard.detector.numerics import (
    HIGHPASS_CYCLES,
    MIN_BOX,
    START_SEPARATION,
    _best_phase,
    _box_transfer,
    _corr,
    _harmonics,
    _highpass,
    _nelder_mead,
    block_coherence_t,
    highpass_gain_at,
    linear_common,
    lookalike_fit,
)
from lishield_guard.detector.results import ModelFit
from lishield_guard.spec import BarcodeSpec

__all__ = ["chroma_leak", "pattern_knots", "refine", "render_rows"]

MAX_EXPOSURE_SLOTS = 4.0  # t_e x f_B: 1/500 s at f_B = 1600 Hz is 3.2 slots; the attack <= 3
FREE_MAX_EVALS = 300  # the same with each tone's phase free (7 parameters for M = 3)
FREE_SUBPERIODS = 3  # continuous variants also start at 1/2 .. 1/this of the best period
FREE_REFINES = 2  # continuous variants: the best fixed-phase fits whose tone phases are freed
FREE_RUN_CANDIDATES = 12  # continuous variants: demodulated timing hypotheses (`freerun`)...
FREE_RUN_STARTS = 3  # ... of which the exact model's best at distinct periods are refined
FREE_RUN_EXPOSURES = (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)  # their exposures tried (slots)
SCAN_CYCLE_STEP = 1.015  # c_1 scanned on a geometric grid of this ratio over its whole range
SCAN_EXPOSURE_STEP_SLOTS = 0.1  # exposures scanned from 0 to M slots (e and e + M fit alike)
SCAN_MIN_PHASES = 256  # phases per pattern period scanned (more when the template needs them)
SCAN_HARMONICS_PER_CYCLE = 4  # template harmonics kept per cycle of the fastest tone per slot


class _KnotMaker:
    """`pattern_knots` of one spec channel as a function of c_1 (the tone ratios and slot
    order are looked up once, not at each of the fit's evaluations)."""

    def __init__(self, spec: BarcodeSpec, channel: str) -> None:
        fs = np.asarray(dict(spec.channels)[channel], dtype=np.float64)
        self.rel = fs[list(spec.slot_order())] / spec.f1_hz
        self.duty = spec.duty
        self.m = spec.n_tones
        self.continuous = phase_mode(spec) == "continuous"

    def __call__(self, cycles_f1: float) -> tuple[np.ndarray, np.ndarray]:
        starts, ends = [], []
        for k, r in enumerate(self.rel):
            c = cycles_f1 * r
            if self.continuous:  # the tone's timer ran since the pattern start: c k cycles
                j = np.arange(math.floor(c * k) - 1, math.ceil(c * (k + 1)) + 1)
                a = np.maximum(j / c, float(k))
                b = np.minimum((j + self.duty) / c, k + 1.0)
                keep = b > a
                a, b = a[keep], b[keep]
            else:
                a = k + np.arange(int(math.ceil(c))) / c
                b = np.minimum(a + self.duty / c, k + 1.0)
            starts.append(a)
            ends.append(b)
        a, b = np.concatenate(starts), np.concatenate(ends)
        cum = np.concatenate([[0.0], np.cumsum(b - a)])
        u = np.empty(2 * a.size + 2)
        on = np.empty_like(u)
        u[0], on[0] = 0.0, 0.0
        u[1:-1:2], u[2:-1:2] = a, b
        on[1:-1:2], on[2:-1:2] = cum[:-1], cum[1:]
        u[-1], on[-1] = float(self.m), cum[-1]
        return u, on

    def on_intervals(self, cycles_f1: float) -> tuple[np.ndarray, np.ndarray]:
        """Starts and ends (slots) of the ON intervals of one pattern period."""
        inner = self(cycles_f1)[0][1:-1]
        return inner[0::2], inner[1::2]


def pattern_knots(spec: BarcodeSpec, channel: str, cycles_f1: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative ON time of one pattern period, as knots of a piecewise-linear function.

    Parameters
    ----------
    spec : BarcodeSpec
        The barcode (slot order, tones, duty).
    channel : str
        Which channel's tones.
    cycles_f1 : float
        c_1 = f_1 / f_B, cycles of the first tone per slot (> 0).

    Returns
    -------
    u_slots : ndarray
        Knot positions in slots, from 0 to M (non-decreasing).
    on_slots : ndarray
        ON time accumulated from the period's start to each knot, in slots.
    """
    if not cycles_f1 > 0:
        raise ValueError(f"need cycles_f1 > 0, got {cycles_f1!r}")
    return _KnotMaker(spec, channel)(float(cycles_f1))


def _cumulative(u_knots: np.ndarray, on_knots: np.ndarray, u: np.ndarray) -> np.ndarray:
    period = u_knots[-1]
    q = np.floor(u / period)
    return q * on_knots[-1] + np.interp(u - q * period, u_knots, on_knots)


def render_rows(u_knots: np.ndarray, on_knots: np.ndarray, u_slots: np.ndarray,
                exposure_slots: float) -> np.ndarray:
    """Mean ON fraction each row integrates over [u, u + exposure] (slots; exact).

    Parameters
    ----------
    u_knots, on_knots : ndarray
        `pattern_knots` of the spec channel.
    u_slots : ndarray
        Exposure start of each row, slots into the pattern (any real value; periodic).
    exposure_slots : float
        t_e x f_B; values below 1e-3 are treated as 1e-3 (an instantaneous sample).
    """
    e = max(float(exposure_slots), MIN_BOX)
    return (_cumulative(u_knots, on_knots, u_slots + e)
            - _cumulative(u_knots, on_knots, u_slots)) / e


class _Objective:
    """The exact model's rows and fit loss for parameters (period_rows, c_1, phase, exposure),
    with the physical bounds (`refine`)."""

    def __init__(self, knots: _KnotMaker, n_rows: int, period_range_rows: tuple[float, float],
                 c_range: tuple[float, float], scale_range_cpr_per_hz: tuple[float, float],
                 f1_hz: float) -> None:
        self.knots, self.m = knots, knots.m
        self.index = np.arange(n_rows, dtype=np.float64)
        self.p_range, self.c_range = period_range_rows, c_range
        self.s_range, self.f1_hz = scale_range_cpr_per_hz, f1_hz

    def rows(self, th) -> np.ndarray:
        """Linear-light rows (before high-pass) of the template at parameters ``th``."""
        if len(th) > 4:
            return self._free_rows(th)
        p, c1, phi, e = th
        return render_rows(*self.knots(float(c1)), self.m * self.index / p + phi, e)

    def _free_rows(self, th) -> np.ndarray:
        """Rows of a free-running emitter: parameters (p, c_1, phi, e, theta_1..theta_M), tone
        n ON while frac(c_1 r_n u + theta_n) < duty at u slots (never restarted, so the
        pattern need not repeat)."""
        p, c1, phi, e = (float(v) for v in th[:4])
        e = max(e, MIN_BOX)
        u = self.m * self.index / p + phi
        slots = np.arange(math.floor(u[0]), math.ceil(u[-1] + e), dtype=np.float64)
        n = slots.astype(np.int64) % self.m
        c = c1 * self.knots.rel[n]
        theta = np.asarray(th[4:], dtype=np.float64)[n]
        width = int(math.ceil(c.max())) + 3  # ON intervals a slot can hold, with margins
        jj = np.floor(c * slots + theta)[:, None] - 1 + np.arange(width)[None, :]
        lo, hi = slots[:, None], slots[:, None] + 1.0
        a = np.clip((jj - theta[:, None]) / c[:, None], lo, hi)
        b = np.clip((jj + self.knots.duty - theta[:, None]) / c[:, None], lo, hi)
        b = np.maximum(a, b)
        cum = np.cumsum((b - a).ravel())
        ku = np.empty(2 * cum.size + 1)
        ko = np.empty_like(ku)
        ku[0], ko[0] = slots[0], 0.0
        ku[1::2], ku[2::2] = a.ravel(), b.ravel()
        ko[2::2] = cum
        ko[1::2] = cum - (b - a).ravel()
        return (np.interp(u + e, ku, ko) - np.interp(u, ku, ko)) / e

    def allowed(self, th) -> bool:
        """Whether ``th`` lies within the period, c_1, exposure and scale bounds."""
        p, c1, _, e = th[:4]
        return bool(self.p_range[0] <= p <= self.p_range[1]
                    and self.c_range[0] <= c1 <= self.c_range[1]
                    and 0.0 <= e <= MAX_EXPOSURE_SLOTS
                    and self.s_range[0] <= c1 * self.m / (p * self.f1_hz) <= self.s_range[1])

    def loss(self, hp, y: np.ndarray):
        """Minus the correlation of the high-passed template with ``y`` (1 out of bounds)."""
        yy = float(y @ y)
        return lambda th: -_corr(hp(self.rows(th)), y, yy) if self.allowed(th) else 1.0


def refine(blocks_log: np.ndarray, spec: BarcodeSpec, channel: str, starts, *,
           period_range_rows: tuple[float, float], scale_range_cpr_per_hz: tuple[float, float],
           colour_blocks: dict[str, np.ndarray] | None = None,
           matched_refit: bool = True) -> ModelFit | None:
    """Refine grid starts of one spec channel with the exact model; fit the look-alike.

    Parameters
    ----------
    blocks_log : ndarray of shape (n_blocks, n_rows)
        Log contrast per column block (`tracks.PlaneAnalysis.blocks`).
    spec, channel : BarcodeSpec, str
        The template to fit.
    starts : sequence of (rho, period_rows, cycles_f1, phase_slots, exposure_slots)
        Grid fits to start from (`sweep.SweepMatch.starts`).
    period_range_rows : (float, float)
        Physically possible pattern periods M / f_B, rows.
    scale_range_cpr_per_hz : (float, float)
        Row time x downscale range: f_1 must appear at c_1 M / period cycles per row within
        f_1 times this range.
    colour_blocks : dict, optional
        ``"R"``, ``"G"``, ``"B"`` -> log contrast per column block of each colour plane (same
        rows); given, the fit's `chroma_leak` is measured (when rho reaches FIT_RHO_FLOOR).
    matched_refit : bool
        Refit on matched-filter block weights (`_matched_refit`; `FitConfig.matched_refit`).

    Returns
    -------
    ModelFit or None
        None without starts or rows.

    Notes
    -----
    The fit is made in linear light (`linearise`): there the LED's light is the template
    itself for any ambient level, while the log of a deep ON/OFF is not. Fitting in the log
    domain as well, and keeping the better, was tried on development data: +1 detection in
    143 positives for twice the time, and higher look-alike-free gains on clean images.

    A continuous variant frees the tone phases from its `FREE_REFINES` best fixed-phase fits
    only (on development captures, freeing them from every start found no detection more, at
    twice the time), and from timing hypotheses its demodulated tones give
    (`_free_running_fits`): a free-running LED's pattern does not repeat, so the grid's starts
    are often at the wrong period.
    """
    blocks_log = np.asarray(blocks_log, dtype=np.float64)
    p_lo, p_hi = period_range_rows
    if not len(starts) or blocks_log.ndim != 2 or blocks_log.shape[1] < 8 or p_lo > p_hi:
        return None
    x, weights, blocks_lin = linear_common(blocks_log)
    n = blocks_log.shape[1]
    m = spec.n_tones
    s_lo, s_hi = scale_range_cpr_per_hz
    c_lo, c_hi = cycles_range(spec.f1_hz)
    best: tuple | None = None
    knots = _KnotMaker(spec, channel)
    model = _Objective(knots, n, (p_lo, p_hi), (c_lo, c_hi), scale_range_cpr_per_hz,
                       spec.f1_hz)
    if phase_mode(spec) == "continuous" and len(starts):
        # tones that run on repeat only after several patterns (c_n M / j whole for all n):
        # the autocorrelation and the grid then favour a multiple of the pattern period
        top = max(starts, key=lambda st: st[0])
        starts = list(starts) + [(top[0], top[1] / j, top[2], top[3], top[4])
                                 for j in range(2, FREE_SUBPERIODS + 1)
                                 if top[1] / j >= max(p_lo, 8.0)]
    free = phase_mode(spec) == "continuous"
    base: list[tuple[float, np.ndarray, object, np.ndarray, object]] = []
    for _, p0, c0, phi0, e0 in starts:
        hp = _highpass(n, p0 / (2 * math.pi * HIGHPASS_CYCLES))
        p0 = min(max(p0, p_lo), p_hi)
        grid_start = np.array([p0, min(max(c0, c_lo), c_hi), phi0,
                               min(max(e0, 0.0), MAX_EXPOSURE_SLOTS)])
        y = hp(x)
        # c_1 such that f_1 lands at c_1 M / p0 cycles per row within the scale range
        c_scan = (max(c_lo, s_lo * p0 * spec.f1_hz / m), min(c_hi, s_hi * p0 * spec.f1_hz / m))
        scanned = np.array([p0, *_scan_start(knots, y, m, p0, c_scan,
                                             p0 / (2 * math.pi * HIGHPASS_CYCLES))])
        loss = model.loss(hp, y)
        # a timer that runs on need not repeat with the pattern, so the periodic scan may
        # rank the wrong start first: a continuous variant refines both
        for x0 in (grid_start, scanned) if free else (min((grid_start, scanned), key=loss),):
            val, th = _nelder_mead(loss, x0, np.array([0.01 * p0, 0.05, 0.1, 0.05]))
            base.append((val, th, hp, y, loss))
    base.sort(key=lambda b: b[0])
    val, th, hp, y, _ = base[0]
    best = (-val, th, hp, y)
    if free:  # free each tone's phase (theta = 0 reproduces the first period) from the best
        for _, th, hp, y, loss in base[:FREE_REFINES]:
            val_f, th_f = _nelder_mead(
                loss, np.concatenate([th, np.zeros(m)]),
                np.array([0.005 * th[0], 0.02, 0.05, 0.05] + [0.1] * m),
                max_evals=FREE_MAX_EVALS)
            if -val_f > best[0]:
                best = (-val_f, th_f, hp, y)
        for fit in _free_running_fits(x, knots, model, (p_lo, p_hi), (c_lo, c_hi),
                                      (s_lo * spec.f1_hz, s_hi * spec.f1_hz)):
            if fit[0] > best[0]:
                best = fit
    rho, th, hp, y = best
    if not rho > 0:
        return None
    blocks_hp = hp(blocks_lin)
    if matched_refit:
        rho, th, y = _matched_refit(blocks_lin, blocks_hp, hp, model, rho, th, y)
    p, c1, phi, e = th[:4]
    tr = hp(model.rows(th))
    rho = float(min(rho, 1.0))
    alt, square = lookalike_fit(y, hp) if rho >= FIT_RHO_FLOOR else (None, None)
    leak = None
    if colour_blocks is not None and rho >= FIT_RHO_FLOOR:
        amps = [float(hp(linear_common(colour_blocks[c])[0]) @ tr) for c in "RGB"]
        leak = chroma_leak(np.array(amps), channel)
    return ModelFit(spec.name, channel, rho, alt,
                    float(p), float(c1), float(phi % m), float(e),
                    block_coherence_t(blocks_hp, tr, weights), n / float(p), leak,
                    lookalike=square)


def _free_running_fits(x: np.ndarray, knots: _KnotMaker, model: _Objective,
                       period_range_rows: tuple[float, float], c_range: tuple[float, float],
                       k1_range_cpr: tuple[float, float]) -> list[tuple]:
    """Fits of a free-running variant started from its tones (`freerun`): (rho, parameters,
    high-pass, high-passed rows) each.

    The demodulated tones' fundamentals rank `FREE_RUN_CANDIDATES` timing hypotheses roughly;
    the exact model, at each of `FREE_RUN_EXPOSURES`, picks the `FREE_RUN_STARTS` best at
    distinct periods, and Nelder-Mead refines all M + 4 parameters from those."""
    if not FREE_RUN_STARTS:
        return []
    n, m = x.size, knots.m
    ranked = []
    for st in free_running_starts(x, knots.rel, knots.duty, period_range_rows=period_range_rows,
                                  c_range=c_range, k1_range_cpr=k1_range_cpr,
                                  n_best=FREE_RUN_CANDIDATES):
        hp = _highpass(n, st.period_rows / (2 * math.pi * HIGHPASS_CYCLES))
        y = hp(x)
        loss = model.loss(hp, y)
        ranked += [(loss(th), th, hp, y, loss) for th in map(st.params, FREE_RUN_EXPOSURES)]
    ranked.sort(key=lambda r: r[0])
    out = []
    for _, x0, hp, y, loss in _distinct_periods(ranked, FREE_RUN_STARTS):
        val, th = _nelder_mead(loss, x0,
                               np.array([0.005 * x0[0], 0.02, 0.05, 0.05] + [0.1] * m),
                               max_evals=FREE_MAX_EVALS)
        out.append((-val, th, hp, y))
    return out


def _distinct_periods(ranked: list[tuple], k: int) -> list[tuple]:
    """The first ``k`` entries of ``ranked`` (loss, parameters, ...) whose periods differ by
    more than `sweep.START_SEPARATION` (relative) from every earlier one kept."""
    out: list[tuple] = []
    for r in ranked:
        if len(out) >= k:
            break
        if all(abs(r[1][0] / o[1][0] - 1.0) > START_SEPARATION for o in out):
            out.append(r)
    return out


def _matched_refit(blocks_lin: np.ndarray, blocks_hp: np.ndarray, hp, model: _Objective,
                   rho: float, th: np.ndarray, y: np.ndarray
                   ) -> tuple[float, np.ndarray, np.ndarray]:
    """Re-combine the blocks with matched-filter weights for the fitted template and refit.

    A partly lit frame carries the LED in some column blocks only; `quiet_weights` favours the
    quietest blocks, which may be the unlit ones. With the fit's template t, block b's
    amplitude a_b and residual power s_b^2 give the matched weights max(a_b, 0) / s_b^2; the
    fit restarts from its parameters on the re-combined rows and the better of the two is
    kept (rho, parameters, high-passed rows).
    """
    if blocks_lin.shape[0] < 3:
        return rho, th, y
    tr = hp(model.rows(th))
    tt = float(tr @ tr)
    if not tt > 0:
        return rho, th, y
    yb = blocks_hp
    amp = yb @ tr / tt
    resid = np.mean((yb - amp[:, None] * tr[None, :]) ** 2, axis=1)
    r_max = float(resid.max())
    if not (math.isfinite(r_max) and r_max > 0):
        return rho, th, y
    w = np.maximum(amp, 0.0) * (r_max / np.maximum(resid, 1e-6 * r_max))
    if not (math.isfinite(float(w.sum())) and w.sum() > 0):
        return rho, th, y
    y2 = hp((w / w.sum()) @ blocks_lin)
    steps = np.array([0.002 * th[0], 0.01, 0.02, 0.02] + [0.02] * (len(th) - 4))
    val, th2 = _nelder_mead(model.loss(hp, y2), np.asarray(th, dtype=np.float64), steps)
    if -val > rho:
        return -val, th2, y2
    return rho, th, y


def chroma_leak(amplitudes_rgb: np.ndarray, channel: str) -> float:
    """How far a fitted template's amplitudes in the R, G, B planes stray from the colour of
    the light it models (unitless, capped at 1e6; 0 = exactly the LED's colour).

    A white LED ("W") modulates every plane's linear light alike, (1, 1, 1); an RGB barcode's
    channel c modulates only its own plane. The leak is the amplitude orthogonal to that
    direction over the amplitude along it (tan of the angle between them): a grey scene's
    structure fitted by a red channel's template shows in every plane (leak sqrt 2), and a
    coloured scene's edge fitted by a white template differs between planes. The cap applies
    when the amplitude along the LED's colour is not positive.
    """
    a = np.asarray(amplitudes_rgb, dtype=np.float64)
    chi = np.ones(3) if channel == "W" else np.array([float(c == channel) for c in "RGB"])
    chi /= np.linalg.norm(chi)
    along = float(a @ chi)
    if not along > 0:
        return 1e6
    return float(min(np.linalg.norm(a - along * chi) / along, 1e6))


def _scan_start(knots, y: np.ndarray, m: int, period_rows: float,
                c_range: tuple[float, float], sigma_rows: float) -> tuple[float, float, float]:
    """Best (c_1, phase, exposure) at a start's period, over the whole c_1 range, every
    exposure and every phase, from the template's Fourier series (a ranking for Nelder-Mead).

    A pattern period's template is t(u) = sum_k T_k exp(2 pi i k u / M) with T_k the ON
    intervals' Fourier coefficients times the exposure box's transfer; row i sits at
    u_i = M i / P + phi. Its correlation with the high-passed rows y is
    2 Re sum_k g_k T_k conj(Y_k) exp(2 pi i k phi / M), Y_k = sum_i y_i exp(-2 pi i k i / P)
    and g_k the high-pass gain at k / P: one inverse FFT gives every phase at once, and the
    template's high-passed power is n sum_k |g_k T_k|^2 * 2 (`_best_phase`). The c_1 grid's
    ratio steps keep the fastest tone's drift over a slot small.
    """
    yy = float(y @ y)
    c_lo, c_hi = c_range
    if not yy > 0 or c_lo > c_hi:
        return c_lo, 0.0, 0.0
    k_max = int(max(1, min(period_rows / 2.0 - 1.0,
                           SCAN_HARMONICS_PER_CYCLE * m * c_hi * knots.rel.max() + 8)))
    k = np.arange(1, k_max + 1, dtype=np.float64)
    g = highpass_gain_at(k / period_rows, sigma_rows)
    gy_k = g * np.conj(_harmonics(y, k, -2j * math.pi / period_rows))
    exposures = np.arange(0.0, m + 1e-9, SCAN_EXPOSURE_STEP_SLOTS)
    box = _box_transfer(exposures, k, m)  # (n_exposures, K); exposures and u in slots
    n_c = int(math.floor(math.log(c_hi / c_lo) / math.log(SCAN_CYCLE_STEP))) + 1
    best = (-2.0, c_lo, 0.0, 0.0)
    for c in c_lo * SCAN_CYCLE_STEP ** np.arange(n_c):
        a, b = knots.on_intervals(float(c))
        ka = np.outer(k, a) * (-2j * math.pi / m)
        kb = np.outer(k, b) * (-2j * math.pi / m)
        t_k = box * ((np.exp(ka) - np.exp(kb)).sum(axis=1) / (2j * math.pi * k))
        rho, i_e, phase = _best_phase(t_k * gy_k, np.abs(t_k * g) ** 2, y.size, yy,
                                      SCAN_MIN_PHASES)
        if rho > best[0]:
            best = (rho, float(c), m * phase, float(exposures[i_e]))
    return best[1:]
