"""Bounds on a false-alarm rate: exact one-sided bounds, what a part can show, the null model.

See `lishield_guard.calibration` for the derivations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lishield_guard.calibration.evidence import _specs
from lishield_guard.config import AppConfig, DetectorConfig
from lishield_guard.detector.search import scaled_detector
from lishield_guard.detector.tones import scale_range_cpr_per_hz

CONFIDENCE = 0.95

# ----------------------------------------------------------------------------- bounds


def far_upper_bound(k: int, n: int, confidence: float = CONFIDENCE) -> float:
    """Exact one-sided Clopper-Pearson upper bound of a binomial proportion.

    Parameters
    ----------
    k, n : int
        False alarms and clean images, 0 <= k <= n.
    confidence : float, optional
        One-sided confidence, unitless. Default 0.95.

    Returns
    -------
    float
        p_hi with P(Bin(n, p_hi) <= k) = 1 - confidence (scipy's
        ``binomtest(k, n, alternative="less").proportion_ci(method="exact")``, through
        `lishield_guard.stats.upper_bound`); 1 when n = 0 or k = n.

    Raises
    ------
    ValueError
        If not 0 <= k <= n.

    Examples
    --------
    >>> round(far_upper_bound(0, 10), 4)
    0.2589
    """
    from lishield_guard.stats import upper_bound

    return upper_bound(k, n, confidence)


def two_sided_upper(k: int, n: int, level: float = CONFIDENCE) -> float:
    """Upper end of the two-sided Clopper-Pearson interval (`lishield_guard.stats`)."""
    from lishield_guard.stats import clopper_pearson

    return clopper_pearson(k, n, level)[1]


def images_needed(target_far: float, confidence: float = CONFIDENCE, *,
                  false_alarms: int = 0) -> int:
    """Clean images needed for a one-sided bound <= target_far with a given false-alarm count.

    Parameters
    ----------
    target_far : float
        Target image false-alarm rate in (0, 1), unitless.
    confidence : float, optional
        One-sided confidence, unitless. Default 0.95.
    false_alarms : int, optional
        False alarms k >= 0 among them. Default 0.

    Returns
    -------
    int
        The smallest n with ``far_upper_bound(k, n) <= target_far``.

    Raises
    ------
    ValueError
        If target_far is outside (0, 1) or false_alarms < 0.

    Notes
    -----
    With k = 0 the bound is 1 - (1 - confidence)^(1/n), so n = ceil(ln(1 - confidence) /
    ln(1 - target_far)); for k > 0 the bound falls monotonically in n, and the smallest n is
    found by doubling, then bisection.

    Examples
    --------
    >>> images_needed(1e-3)
    2995
    >>> images_needed(1e-3, false_alarms=1)
    4742
    """
    if not 0 < target_far < 1:
        raise ValueError(f"need 0 < target_far < 1, got target_far={target_far!r}")
    k = int(false_alarms)
    if k < 0:
        raise ValueError(f"need false_alarms >= 0, got false_alarms={k}")
    lo = max(k + 1, math.ceil(math.log(1 - confidence) / math.log1p(-target_far)))
    hi = lo
    while far_upper_bound(k, hi, confidence) > target_far:
        lo, hi = hi, 2 * hi
    while lo < hi:  # smallest n in [lo, hi] meeting the target
        mid = (lo + hi) // 2
        if far_upper_bound(k, mid, confidence) <= target_far:
            hi = mid
        else:
            lo = mid + 1
    return hi


# ----------------------------------------------------------------------------- certification


@dataclass(frozen=True)
class Claim:
    """What k false alarms on n clean images can show about a target false-alarm rate.

    Attributes
    ----------
    false_alarms, n_clean : int
        k and n.
    far_upper : float
        Exact one-sided Clopper-Pearson upper bound, unitless (`far_upper_bound`).
    far_upper_two_sided : float
        Upper end of the two-sided interval at the same confidence, unitless.
    target_far : float
        The target image false-alarm rate, unitless.
    images_needed : int
        Clean images with no false alarm needed to show the target (`images_needed`).
    met : bool
        ``far_upper <= target_far``: the only way a target is called met.
    reason : str
        One sentence saying why it is or is not met.
    """

    false_alarms: int
    n_clean: int
    far_upper: float
    far_upper_two_sided: float
    target_far: float
    images_needed: int
    met: bool
    reason: str


def claim(false_alarms: int, n_clean: int, target_far: float,
          confidence: float = CONFIDENCE) -> Claim:
    """Judge a target FAR from k false alarms on n clean images (exact one-sided bound).

    A target is met only when the bound is <= the target; when n is below `images_needed`,
    no outcome could show it, and the reason says how many images it needs.

    Examples
    --------
    >>> c = claim(0, 1500, 1e-3)
    >>> c.met, c.images_needed
    (False, 2995)
    >>> claim(0, 3000, 1e-3).met
    True
    """
    k, n = int(false_alarms), int(n_clean)
    bound = far_upper_bound(k, n, confidence)
    two = two_sided_upper(k, n, confidence)
    need = images_needed(target_far, confidence)
    pct = f"{100 * confidence:g}%"
    if bound <= target_far:
        why = (f"{k}/{n} false alarms: FAR <= {bound:.3g} at {pct} (one-sided), within "
               f"the target {target_far:g}")
    elif n < need:
        why = (f"{n} clean images cannot show FAR <= {target_far:g} at {pct} even with no false "
               f"alarm (the smallest bound they can give is "
               f"{far_upper_bound(0, n, confidence):.3g}); the target needs >= {need} with none")
    else:
        why = (f"{k}/{n} false alarms: FAR bound {bound:.3g} at {pct} is above the target "
               f"{target_far:g}")
    return Claim(false_alarms=k, n_clean=n, far_upper=bound, far_upper_two_sided=two,
                 target_far=float(target_far), images_needed=need, met=bound <= target_far,
                 reason=why)


# ----------------------------------------------------------------------------- null model


def _chance_match_prob(n_frames: int, q: float, band_log: float, tone_logs: np.ndarray,
                       det: DetectorConfig, *, cap: int = 30) -> float:
    """P1 of the module docstring: a chance match of one spec at one scale on one track."""
    from scipy.stats import poisson

    m_tones = tone_logs.size
    a = 2 * math.log1p(det.tones.rel_tol)
    if band_log <= 0 or q <= 0 or n_frames < 2:
        return 0.0
    lam_t = n_frames * q * min(1.0, a / band_log)
    lam_o = n_frames * q * max(0.0, 1 - m_tones * a / band_log)
    k_min = max(math.ceil(det.tones.min_occupancy * n_frames - 1e-9), 2)
    k_max = math.floor(det.tones.max_occupancy * n_frames + 1e-9)
    c = np.arange(cap + 1)
    pmf = poisson.pmf(c, lam_t)
    grids = np.meshgrid(*([c] * m_tones), indexing="ij")
    counts = np.stack([g.ravel() for g in grids])  # (M, cap^M)
    prob = np.prod(pmf[counts], axis=0)
    hit = (counts >= k_min) & (counts <= k_max)
    enough = hit.sum(axis=0) >= min(det.tones.min_tones, m_tones)
    hit_sum = (counts * hit).sum(axis=0)
    all_sum = counts.sum(axis=0)
    if det.tones.min_purity > 0:
        o_max = np.floor(hit_sum / det.tones.min_purity - all_sum + 1e-9)
    else:
        o_max = np.full(all_sum.shape, np.inf)
    p_o = np.where(o_max >= 0, poisson.cdf(np.minimum(o_max, 1e9), lam_o), 0.0)
    return float((prob * enough * p_o).sum())


def null_model_far(evidence, config: AppConfig, *, q: float | None = None) -> dict:
    """Expected chance tone matches E and image false-alarm probability 1 - exp(-E).

    Parameters
    ----------
    evidence : Evidence
        Supplies the tracks (frames, band) of the luma plane on each axis; judged at
        ``config.detector.tones.peak_false_prob``.
    config : AppConfig
        Detector settings and policies (monochrome specs only; see module docstring).
    q : float, optional
        Fraction of frames with a significant peak; None uses each track's measured
        significant fraction.

    Returns
    -------
    dict
        ``expected_matches`` (E), ``far`` (1 - exp(-E)), ``p_candidate`` (chance that one
        candidate reaches min_tones without the purity test, union over scales and tracks).
    """
    det = config.detector
    ev = evidence.with_false_prob(det.tones.peak_false_prob)
    sdet = scaled_detector(det, ev.row_scale)
    s_lo, s_hi = scale_range_cpr_per_hz(sdet)
    a = 2 * math.log1p(det.tones.rel_tol)
    mono = [s for s in _specs(config) if not s.is_rgb]
    e_total, p_cands = 0.0, []
    no_purity = det.with_values({"tones.min_purity": 0.0})
    for planes in ev.axes.values():
        lum = planes.get("L")
        if lum is None:
            continue
        for spec in mono:
            logs = np.log(np.array(spec.all_freqs_hz, dtype=float))
            e_cand = 0.0
            for t in lum.tracks:
                band = math.log(t.hi_cpr / t.lo_cpr)
                span = float(logs.max() - logs.min())
                d = min(math.log(s_hi / s_lo), band - span - a)
                if d < 0:
                    continue
                n_s = d / a + 1
                qq = t.significant_fraction if q is None else q
                f = int(t.freq_cpr.size)
                e_total += n_s * _chance_match_prob(f, qq, band, logs, det)
                e_cand += n_s * _chance_match_prob(f, qq, band, logs, no_purity)
            p_cands.append(1 - math.exp(-e_cand))
    return {"expected_matches": e_total, "far": 1 - math.exp(-e_total),
            "p_candidate": float(np.mean(p_cands)) if p_cands else 0.0}
