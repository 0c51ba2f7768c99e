"""Shared numerics of the detector stages: high-pass filters, linear light, the steady look-alike.

Every stage that fits a pattern to a plane's rows high-passes both the same way (content below
`HIGHPASS_CYCLES` cycles per pattern period is ignored), works in linear light, and asks how
well a steady square wave (a PWM-dimmed or mains-flickering light, a periodic texture) explains
the rows: `steady_rho`, `lookalike_rho`. The screen uses the look-alike to clear planes
(`LOOKALIKE_DOMINANT_RHO`), the sweep and the exact fit to weigh their fits against it. This
module imports no stage, so every stage may import it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DISPLAY_GAMMA", "HIGHPASS_CYCLES", "LOOKALIKE_DOMINANT_RHO", "START_SEPARATION",
           "block_coherence_t", "highpass_gain", "highpass_gain_at", "linear_common",
           "linearise", "lookalike_fit", "lookalike_rho", "mirror_rfft", "quiet_weights",
           "square_candidates", "square_rows", "steady_rho"]

DISPLAY_GAMMA = 2.2  # stored value ~ linear light ** (1 / gamma) (sRGB, unitless)
HIGHPASS_CYCLES = 1.5  # cycles per pattern period below which content is ignored (as fold.py)
MIN_BOX = 1e-3  # exposures shorter than this (slots or cycles) are treated as this
MAX_EVALS = 160  # Nelder-Mead evaluations per start
LOOKALIKE_DOMINANT_RHO = 0.99  # rows a steady square wave fits this well are not refined
#                       positives (160: partial coverage + 60 full) +6 detected, none lost
SQUARE_DUTIES = np.arange(1, 20) / 20.0  # look-alike start grid: duty 0.05 ... 0.95
SQUARE_EXPOSURES = np.array([0.0, 0.15, 0.3, 0.5, 0.75, 1.5])  # box widths, look-alike cycles
SQUARE_HARMONICS = 48  # harmonics of a candidate frequency in the start grid's Fourier series
SQUARE_MIN_PHASES = 64  # phases per look-alike cycle scanned (more when the harmonics need it)
SQUARE_PEAKS = 3
SQUARE_REFINES = 4  # look-alike grid starts (best per candidate frequency) refined
START_SEPARATION = 0.04  # refinement starts differ in period by more than this (relative)


def mirror_rfft(x: np.ndarray) -> np.ndarray:
    """Spectrum of x mirror-extended to twice its length along the last axis (no edge jump)."""
    return np.fft.rfft(np.concatenate([x, x[..., ::-1]], axis=-1), axis=-1)


def highpass_gain_at(freqs_cpr: np.ndarray, sigma_rows: float) -> np.ndarray:
    """Gain at ``freqs_cpr`` (cycles per row) of x minus its Gaussian trend of sigma
    ``sigma_rows``."""
    return 1.0 - np.exp(-2.0 * math.pi ** 2 * sigma_rows ** 2 * np.square(freqs_cpr))


def highpass_gain(n_rows: int, sigma_rows: float) -> np.ndarray:
    """`highpass_gain_at` on `mirror_rfft`'s bins."""
    return highpass_gain_at(np.fft.rfftfreq(2 * n_rows), sigma_rows)


def quiet_weights(blocks: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Weights (summing to 1) combining column blocks into the least noisy common row signal.

    Every block carries the same LED signal plus its own scene and noise; the best linear
    combination weights each block by the inverse of its non-common power, estimated from its
    residual against the current weighted mean (a few fixed-point iterations from equal
    weights; each block's own mean is removed first). A block of sky then counts more than a
    block of gravel.
    """
    y = np.asarray(blocks, dtype=np.float64)
    y = y - y.mean(axis=-1, keepdims=True)
    k = y.shape[0]
    w = np.full(k, 1.0 / max(k, 1))
    for _ in range(iterations if k > 2 else 0):
        resid = np.mean((y - w @ y) ** 2, axis=1)
        floor = max(float(resid.max()), 1e-300) * 1e-6
        inv = 1.0 / np.maximum(resid, floor)
        w = inv / inv.sum()
    return w


def block_coherence_t(blocks_hp: np.ndarray, template_hp: np.ndarray,
                      weights: np.ndarray | None = None) -> float:
    """t statistic (unitless, capped at 1e6) of a zero-mean template's least-squares amplitude
    across column blocks (rows of ``blocks_hp``, zero mean): the LED adds the same light to
    every block, scene structure does not. 0 for a flat template or fewer than 2 blocks.

    With ``weights`` (inverse noise powers, any scale) the amplitude is their weighted mean and
    its standard error the weighted one; equal weights give the ordinary one-sample t.
    """
    tt = float(template_hp @ template_hp)
    k = blocks_hp.shape[0]
    if not tt > 0 or k < 2:
        return 0.0
    amp = blocks_hp @ template_hp / tt
    w = np.ones(k) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mean = float(w @ amp)
    spread = math.sqrt(max(float(w @ (amp - mean) ** 2), 0.0) / (k - 1))
    return float(min(mean / max(spread, 1e-12 * max(abs(mean), 1e-30)), 1e6))


def linearise(log_contrast: np.ndarray, gamma: float = DISPLAY_GAMMA) -> np.ndarray:
    """Relative linear light ``expm1(gamma * x)`` of log contrast x (unitless, float64).

    Values are clipped to |gamma x| <= 20 so that no overflow can occur.
    """
    x = np.asarray(log_contrast, dtype=np.float64)
    return np.expm1(np.clip(gamma * x, -20.0, 20.0))


def square_rows(u_cycles: np.ndarray, duty: float, exposure_cycles: float) -> np.ndarray:
    """Mean ON fraction of a square wave of the given duty over [u, u + exposure] (cycles)."""
    e = max(float(exposure_cycles), MIN_BOX)

    def cum(v):
        fl = np.floor(v)
        return fl * duty + np.minimum(v - fl, duty)

    return (cum(u_cycles + e) - cum(u_cycles)) / e


class _HighPass:
    """x minus its Gaussian trend of sigma ``sigma_rows`` (mirror-extended, by FFT) along the
    last axis of ``n_rows``; `gain_at` is its gain at a frequency (cycles per row)."""

    def __init__(self, n_rows: int, sigma_rows: float):
        self.sigma_rows = float(sigma_rows)
        self._gain = highpass_gain(n_rows, sigma_rows)
        self._n = n_rows

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out = np.fft.irfft(mirror_rfft(x) * self._gain, n=2 * self._n, axis=-1)[..., :self._n]
        return out - out.mean(axis=-1, keepdims=True)

    def gain_at(self, freqs_cpr: np.ndarray) -> np.ndarray:
        """Gain at ``freqs_cpr`` (cycles per row), away from the ends of the rows."""
        return highpass_gain_at(freqs_cpr, self.sigma_rows)


def _highpass(n_rows: int, sigma_rows: float) -> _HighPass:
    """x minus its Gaussian trend (mirror-extended, by FFT) along the last axis."""
    return _HighPass(n_rows, sigma_rows)


def _corr(t: np.ndarray, y: np.ndarray, yy: float) -> float:
    tt = float(t @ t)
    if not (tt > 1e-18 and yy > 0):
        return 0.0
    return float(t @ y) / math.sqrt(tt * yy)


def _nelder_mead(fun, x0: np.ndarray, steps: np.ndarray, *, max_evals: int = 0
                 ) -> tuple[float, np.ndarray]:
    from scipy.optimize import minimize  # lazy: the default profile never fits

    simplex = np.vstack([x0] + [x0 + np.diag(steps)[k] for k in range(x0.size)])
    res = minimize(fun, x0, method="Nelder-Mead",
                   options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-5,
                            "maxfev": max_evals or MAX_EVALS})
    return float(res.fun), np.asarray(res.x)


def linear_common(blocks_log: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The LED's common row signal in linear light: (`quiet_weights` mean of the blocks'
    `linearise`d rows, the weights, the linearised blocks)."""
    blocks_lin = linearise(np.asarray(blocks_log, dtype=np.float64))
    weights = quiet_weights(blocks_lin)
    return weights @ blocks_lin, weights, blocks_lin


def _harmonics(y: np.ndarray, k: np.ndarray, step: complex) -> np.ndarray:
    """Y_k = sum_i y_i exp(k i step) of the rows ``y``; ``step = -2 pi j f`` for harmonics of
    a fundamental of f cycles per row."""
    return np.exp(np.outer(k, np.arange(y.size)) * step) @ y


def _box_transfer(widths: np.ndarray, k: np.ndarray, period: float = 1.0) -> np.ndarray:
    """(n_widths, K): mean over [u, u + e] of exp(2 pi j k u / period), an exposure box's
    transfer at harmonic k (widths e in the units of ``period``; below `MIN_BOX` as MIN_BOX)."""
    w = np.outer(np.maximum(widths, MIN_BOX), k) * (2j * math.pi / period)
    return np.expm1(w) / w


def _best_phase(cross_k: np.ndarray, power_k: np.ndarray, n_rows: int, yy: float,
                min_phases: int) -> tuple[float, int, float]:
    """Best correlation over templates and every phase, from Fourier series: (rho, template
    index, phase in cycles of the fundamental).

    ``cross_k`` (T, K) holds each template's high-passed harmonic k (k = 1..K) times the rows'
    conj(Y_k), ``power_k`` (T, K) its squared magnitude; the correlation at phase phi is
    2 Re sum_k cross_k exp(2 pi i k phi) over sqrt(2 n sum_k power_k * yy), one inverse FFT for
    every phase (exact for whole cycles over the rows, close otherwise).
    """
    k_max = cross_k.shape[1]
    n_phases = 1 << int(math.ceil(math.log2(max(min_phases, 4 * k_max))))
    z = np.zeros((cross_k.shape[0], n_phases), dtype=np.complex128)
    z[:, 1:k_max + 1] = cross_k
    num = np.fft.ifft(z, axis=1).real * (2.0 * n_phases)
    norms = np.sqrt(np.maximum(2.0 * n_rows * power_k.sum(axis=1), 1e-30) * yy)
    rho = num / norms[:, None]
    i, j = np.unravel_index(int(np.argmax(rho)), rho.shape)
    return float(rho[i, j]), int(i), j / n_phases


def square_candidates(y: np.ndarray) -> list[float]:
    """Fundamentals (cycles per row) a steady square wave behind the rows ``y`` may have: the
    SQUARE_PEAKS strongest spectral lines and their halves and thirds."""
    n = y.size
    nfft = 8 * n
    power = np.abs(np.fft.rfft(y * np.hanning(n), nfft)) ** 2
    freqs = np.arange(power.size) / nfft
    power[(freqs < 1.0 / n) | (freqs > 0.45)] = 0.0
    cands: list[float] = []
    for _ in range(SQUARE_PEAKS):
        k = int(np.argmax(power))
        if not power[k] > 0:
            break
        cands += [freqs[k], freqs[k] / 2, freqs[k] / 3]
        power[max(0, k - 8): k + 9] = 0.0
    return cands


def steady_rho(blocks_log: np.ndarray, period_rows: float) -> float:
    """How well a steady square wave (`lookalike_rho`) fits a plane's rows, high-passed for
    patterns of ``period_rows``: the rows a fit of any barcode must explain better.

    Rows it fits at rho >= `LOOKALIKE_DOMINANT_RHO` are not worth an exact fit: to pass even
    the laxest gain rule (0.5) a barcode would have to fit them at rho >= 0.993. On
    development captures no passing fit had a look-alike above 0.9, while PWM light,
    periodic textures and plain sinusoids reach 0.98-0.999.
    """
    blocks_log = np.asarray(blocks_log, dtype=np.float64)
    if blocks_log.ndim != 2 or blocks_log.shape[1] < 8 or not period_rows > 0:
        return 0.0
    x = linear_common(blocks_log)[0]
    hp = _highpass(blocks_log.shape[1], period_rows / (2 * math.pi * HIGHPASS_CYCLES))
    return lookalike_rho(hp(x), hp)


def lookalike_rho(y_hp: np.ndarray, hp) -> float:
    """Best correlation of a stationary square wave with high-passed rows (`lookalike_fit`)."""
    return lookalike_fit(y_hp, hp)[0]


def lookalike_fit(y_hp: np.ndarray, hp) -> tuple[float, tuple[float, float, float, float] | None]:
    """Best correlation of a stationary square wave (any frequency, duty, phase, exposure)
    with high-passed rows ``y_hp`` (``hp`` high-passes a template the same way), and its
    parameters (frequency in cycles per row, duty, phase and exposure in cycles; None when
    nothing was fitted).

    Candidate fundamentals are the periodogram's strongest peaks and their half and third (a
    square wave's fundamental is not always its strongest line after the high-pass). For each
    candidate, `_square_start` scores every duty and exposure of a grid at every phase at
    once; the best start of each of the `SQUARE_REFINES` best candidates is refined with
    Nelder-Mead on the exact, high-passed template, and the best refined fit is returned.

    The earlier start grid had 8 phases: a high-duty light's short dark pulse fell between
    them, so the search often started at a harmonic and stopped there (a 213 Hz PWM of duty
    0.84 scored 0.735 where the square wave fits at 0.985); `benchmarks/lookalike_search.py`
    measures the misses.
    """
    y = np.asarray(y_hp, dtype=np.float64)
    n = y.size
    yy = float(y @ y)
    if n < 8 or not yy > 0:
        return 0.0, None
    cands = square_candidates(y)
    if not cands:
        return 0.0, None
    rows = np.arange(n, dtype=np.float64)
    gain_at = getattr(hp, "gain_at", None)
    starts = sorted((_square_start(y, yy, f0, gain_at) for f0 in cands), key=lambda s: -s[0])

    def loss(th):
        f, d, ph, e = th
        if not (f > 0 and 0.02 <= d <= 0.98 and 0.0 <= e <= 3.0):
            return 1.0
        return -_corr(hp(square_rows(f * rows + ph, d, e)), y, yy)

    best, params = 0.0, None
    for _, x0 in starts[:SQUARE_REFINES]:
        val, th = _nelder_mead(loss, x0, np.array([0.01 * x0[0], 0.05, 0.05, 0.05]))
        if params is None or -val > best:
            best, params = -val, tuple(float(v) for v in th)
    return float(min(max(best, 0.0), 1.0)), params


def _square_start(y: np.ndarray, yy: float, f0_cpr: float, gain_at) -> tuple[float, np.ndarray]:
    """Best (approximate rho, [frequency, duty, phase, exposure]) of a square wave of
    fundamental ``f0_cpr`` over the grid of `SQUARE_DUTIES` x `SQUARE_EXPOSURES` x every phase.

    A square wave of duty d, box-smoothed over e cycles, has Fourier coefficients
    S_k = (1 - exp(-2 pi i k d)) / (2 pi i k) times the box's (exp(2 pi i k e) - 1) /
    (2 pi i k e); row i sits at u_i = f0 i + phi, so its correlation with the rows is
    2 Re sum_k g_k S_k B_k conj(Y_k) exp(2 pi i k phi), Y_k = sum_i y_i exp(-2 pi i k f0 i),
    g_k the high-pass gain (``gain_at``; 1 when None): `_best_phase` scores every phase with
    one inverse FFT, as for `_scan_start`'s barcode templates.
    """
    k_max = int(max(1, min(SQUARE_HARMONICS, math.floor(0.5 / f0_cpr))))
    k = np.arange(1, k_max + 1, dtype=np.float64)
    g = gain_at(k * f0_cpr) if gain_at is not None else np.ones(k_max)
    s_k = -np.expm1(np.outer(SQUARE_DUTIES, k) * (-2j * math.pi)) / (2j * math.pi * k)
    box = _box_transfer(SQUARE_EXPOSURES, k)
    t_k = (s_k[:, None, :] * box[None, :, :] * g).reshape(-1, k_max)
    y_k = _harmonics(y, k, -2j * math.pi * f0_cpr)
    rho, i, phase = _best_phase(t_k * np.conj(y_k), np.abs(t_k) ** 2, y.size, yy,
                                SQUARE_MIN_PHASES)
    d = SQUARE_DUTIES[i // SQUARE_EXPOSURES.size]
    e = SQUARE_EXPOSURES[i % SQUARE_EXPOSURES.size]
    return rho, np.array([f0_cpr, d, phase, e])
