"""False-alarm calibration: sweep decision parameters, bound the false-alarm rate, pick a setting.

Pure core of ``lishield-guard calibrate`` (no file I/O; the command does that).

Flow
----
1. Per image, once (the expensive part): `image_record` decodes and profiles the image
   (`collect_evidence`) and, for the paper profile, caches `block_peaks_hz` per (n_b, M_p).
2. Per image and per *match combo* (peak_false_prob, tone_rel_tol, min_occupancy,
   max_occupancy), `candidate_table` runs the tone matcher on every (axis, spec) candidate and
   keeps (n_matched, purity, switches, colour channels hit). The remaining decision parameters
   (min_purity, min_tones, min_tones_rgb) only gate the final verdict and never move the fitted
   scale, so `default_scores` applies them to these tables in microseconds. `paper_scores`
   sweeps T_b and gamma over the cached peak frequencies.
3. `summarise` turns per-image verdicts into rates: image-level false-alarm rate on the clean set
   with its exact one-sided Clopper-Pearson 95 % upper bound, false candidate matches (paper
   Fig. 21 analogue), detection overall and per group of positives.
4. `select_setting`: highest detection among settings whose FAR upper bound <= target, on the
   *tuning* part only.
5. Certification: the chosen setting alone is scored once on the held-out *certification*
   part, and `claim` calls the target met only when that part's bound reaches it.

Tuning and certification
------------------------
The bound of the setting picked as the most sensitive one whose bound meets the target, computed
on the images it was picked on, is optimistic: among ~10^5 settings the winner sits just above
the highest clean score by construction. So the clean images (and the positives) are split
(`split_parts`): seeded, stratified by `stratum_key` (folder, kind, preset, package), and whole
source photos at a time (`source_keys`, `source_groups`: every variant of one photo, and every
synthetic capture of it, on the same side). Selection sees the tuning part; the certified FAR
bound and detection rate come from the certification part, for one setting, so they are
ordinary binomial estimates. An independent clean folder may replace the clean split.

Bounds
------
``far_upper`` is the exact *one-sided* 95 % upper bound: the p with P(Bin(n, p) <= k) = 0.05,
i.e. ``beta.ppf(0.95, k + 1, n - k)`` (= the upper end of a two-sided 90 % Clopper-Pearson
interval), computed by scipy's ``binomtest(k, n, alternative="less").proportion_ci(
method="exact")`` (`lishield_guard.stats.upper_bound`). With k = 0 it is 1 - 0.05^(1/n), so
showing FAR <= t needs n >= ln(0.05) / ln(1 - t) clean images with no false alarm: 2995 for
t = 1e-3 (n = 2994 gives 1.0003e-3); `images_needed` also answers for k > 0 (4742 with one
false alarm). The two-sided 95 % interval (``level=0.95`` in `lishield_guard.stats`) is also
reported; its upper end needs n >= ln(0.025) / ln(1 - t) = 3688 for t = 1e-3.

Null model (default profile)
----------------------------
Consider one track (window length w, F frames) of one plane whose frames each carry, with
probability q, a significant peak at a frequency uniform in log over the track band of log-width
B = ln(hi / lo). A tone window at a fitted scale has log-width a = 2 ln(1 + tol), so a frame
lands in a given tone window with probability pi = q a / B, and elsewhere-significant with
probability rho = q (1 - M a / B) for a spec of M tones. For F large and pi small the counts
are independent Poisson: c_j ~ Poi(F pi) per tone, o ~ Poi(F rho) outside. A tone *hits* when
k_min <= c_j <= max_occupancy F, k_min = max(ceil(min_occupancy F), 2). A chance candidate at
one scale needs (i) >= m hit tones (m = min_tones) and (ii) purity
sum_hit c_j / (sum_j c_j + o) >= min_purity. Its probability is

    P1 = sum over (c_1..c_M) with >= m hits of prod_j Poi(c_j; F pi)
         x PoiCDF( floor(sum_hit c_j / min_purity - sum_j c_j); F rho ).

The matcher maximises over log-scales (a shift range of width D = min(ln(s_hi/s_lo),
B - ln(f_max/f_min) - a)), tracks and specs; shifts farther apart than a see disjoint frames, so
there are about N_s = D / a + 1 independent scales and the expected number of chance matches of
an image is E = sum over axes, tracks and mono specs of N_s P1 (a union bound; symbol-timing
``switches`` are ignored, which makes it conservative). The image false-alarm probability is
about 1 - exp(-E). For pure noise q = peak_false_prob; `null_model_far` also evaluates it with
each clean image's own measured significant fractions q_t, which is what the report compares
with the measured clean-set rate.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import time
from dataclasses import dataclass, field, fields

import numpy as np

from lishield_guard.config import AppConfig, DetectorConfig
from lishield_guard.decode import decode
from lishield_guard.detector.paper import block_peaks_hz, count_ratio_matches, required_matches
from lishield_guard.detector.pipeline import (
    collect_evidence,
    decode_for,
    fold_fits,
    scaled_detector,
    screen_specs,
    spec_planes,
    sweep_fits,
)
from lishield_guard.detector.results import SweepResult
from lishield_guard.detector.rules import fit_rule, fold_rule, grid_rule, tone_check_on, tone_rule
from lishield_guard.detector.tones import match_spec, scale_range_cpr_per_hz

__all__ = [
    "Claim",
    "DefaultGrid",
    "PaperGrid",
    "Setting",
    "candidate_table",
    "claim",
    "default_scores",
    "fold_protected",
    "sweep_protected",
    "far_upper_bound",
    "group_labels",
    "image_record",
    "images_needed",
    "null_model_far",
    "paper_scores",
    "select_setting",
    "source_groups",
    "source_keys",
    "split_parts",
    "stratum_key",
    "summarise",
]

CONFIDENCE = 0.95
# candidate table columns
N_MATCHED, PURITY, SWITCHES, CH_HIT, IS_RGB, VALID = range(6)
AXES = ("rows", "columns")


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


# ----------------------------------------------------------------------------- grids


SWEEP_KEYS = ("sweep.min_rho", "sweep.min_margin", "sweep.min_coherence", "fit.min_rho",
              "fit.min_gain", "fit.min_rho_rgb", "fit.min_gain_rgb", "fit.max_leak_rgb",
              "fit.min_rho_periodic", "fit.min_gain_periodic")
COUNT_KEYS = ("paper.max_peaks", "tones.min_tones", "tones.min_tones_rgb")


@dataclass(frozen=True)
class DefaultGrid:
    """Values swept for the default profile (all unitless), named after the settings they
    sweep (``peak_false_prob``: ``tones.peak_false_prob``; `SWEEP_KEYS`)."""

    peak_false_prob: tuple[float, ...] = (1e-3, 1e-4, 1e-5)
    tone_rel_tol: tuple[float, ...] = (0.05,)
    min_occupancy: tuple[float, ...] = (0.04, 0.08)
    max_occupancy: tuple[float, ...] = (0.8,)
    min_purity: tuple[float, ...] = (0.3, 0.5)
    min_tones: tuple[int, ...] = (2, 3)
    min_tones_rgb: tuple[int, ...] = (3,)
    sweep_min_rho: tuple[float, ...] = (0.7, 0.8)
    sweep_min_margin: tuple[float, ...] = (0.3,)
    sweep_min_coherence: tuple[float, ...] = (3.0,)
    fit_min_rho: tuple[float, ...] = (0.9, 0.95)
    fit_min_gain: tuple[float, ...] = (2.0, 3.0, 5.0, 8.0, math.inf)
    # (fit_min_rho_rgb, fit_min_gain_rgb, fit_max_leak_rgb); leak 0 turns the path off
    fit_rgb: tuple[tuple[float, float, float], ...] = (
        *itertools.product((0.8, 0.85), (1.0, 2.0, 3.0), (0.3,)), (0.8, 3.0, 0.15),
        (0.9, 4.0, 0.0))
    # (fit_min_rho_periodic, fit_min_gain_periodic); gain inf turns the path off
    fit_periodic: tuple[tuple[float, float], ...] = (
        *itertools.product((0.85, 0.9), (1.0, 2.0, 3.0, 5.0)), (1.0, math.inf))

    def sweep_combos(self) -> list[tuple[float, ...]]:
        """Values of `SWEEP_KEYS` for the period sweep and its exact-model refinement (gain
        inf: no refinement; leak 0: no colour-verified path; periodic gain inf: no
        periodic path)."""
        return [(*a, *b, *c) for a, b, c in itertools.product(
            itertools.product(self.sweep_min_rho, self.sweep_min_margin,
                              self.sweep_min_coherence, self.fit_min_rho, self.fit_min_gain),
            self.fit_rgb, self.fit_periodic)]

    def match_combos(self) -> list[tuple[float, float, float, float]]:
        """(peak_false_prob, tone_rel_tol, min_occupancy, max_occupancy): each needs matching."""
        return list(itertools.product(self.peak_false_prob, self.tone_rel_tol,
                                      self.min_occupancy, self.max_occupancy))

    def gate_combos(self) -> list[tuple[float, int, int]]:
        """(min_purity, min_tones, min_tones_rgb): applied to candidate tables afterwards."""
        return list(itertools.product(self.min_purity, self.min_tones, self.min_tones_rgb))


@dataclass(frozen=True)
class LearnedGrid:
    """Thresholds swept for the default (learned) profile.

    Candidates are every tuning clean logit plus ``nudge`` (each admits one false alarm fewer)
    and ``n_spread`` quantiles of the clean logits, but none below the *tail threshold*: the
    clean logits above their ``tail_quantile`` are fitted with an exponential tail (mean
    excess), and the threshold is where that tail predicts ``tail_far_fraction`` x the target
    FAR. A threshold just above the largest tuning logit would be exceeded by the largest of
    the certification part about half the time (the two parts are exchangeable); the tail
    threshold keeps a margin that is chosen on the tuning part alone.
    """

    n_spread: int = 60
    nudge: float = 1e-4  # logit units above a clean image's logit: that image passes as clean
    tail_quantile: float = 0.99
    tail_far_fraction: float = 0.1


def tail_threshold(clean_logits: np.ndarray, target_far: float, grid: LearnedGrid) -> float:
    """The logit an exponential fit of the clean tail puts at ``grid.tail_far_fraction *
    target_far`` exceedance (see `LearnedGrid`); the largest finite logit when the tail is
    empty."""
    x = np.sort(np.asarray(clean_logits, dtype=float)[np.isfinite(clean_logits)])
    if len(x) < 2:
        return float(x[-1]) if len(x) else 0.0
    u = float(np.quantile(x, grid.tail_quantile))
    excess = x[x > u] - u
    beta = float(excess.mean()) if len(excess) else 0.0
    p_u = (1.0 - grid.tail_quantile)
    want = grid.tail_far_fraction * target_far
    return u + beta * max(math.log(p_u / want), 0.0)


def learned_thresholds(clean_logits: np.ndarray, grid: LearnedGrid, *,
                       target_far: float) -> np.ndarray:
    """Candidate ``learned.threshold_logit`` values, ascending (see `LearnedGrid`)."""
    x = np.sort(np.asarray(clean_logits, dtype=float)[np.isfinite(clean_logits)])
    if not len(x):
        return np.array([0.0])
    floor = tail_threshold(x, target_far, grid)
    spread = np.quantile(x, np.linspace(0.5, 1.0, grid.n_spread, endpoint=False))
    cand = np.unique(np.concatenate([spread, x + grid.nudge, [floor]]))
    return cand[cand >= floor]


def learned_scores(logits_clean: np.ndarray, logits_pos: np.ndarray,
                   thresholds: np.ndarray) -> tuple[list[Setting], np.ndarray, np.ndarray]:
    """Settings and verdicts of the learned profile at every threshold.

    Returns
    -------
    settings : list of Setting
        ``learned.threshold_logit`` = each threshold.
    clean_prot, pos_prot : ndarray of bool, shape (n_thresholds, n_clean / n_pos)
        `detector.decision.rule` applied to every image (one rule for detection and here).
    """
    from lishield_guard.detector.decision import rule_at

    settings = [Setting("default", (("learned.threshold_logit", float(t)),))
                for t in thresholds]
    return (settings, rule_at(np.asarray(logits_clean)[None, :], thresholds[:, None]),
            rule_at(np.asarray(logits_pos)[None, :], thresholds[:, None]))


def learned_record(source, config: AppConfig) -> dict:
    """The default profile's per-image measurement for calibration: the image logit and the
    milliseconds decode + measurement took (``logit`` is None for an undetermined image)."""
    from lishield_guard.detector.decision import measure

    t0 = time.perf_counter()
    decoded = decode_for(source, config)
    rec = measure(decoded.rgb() if decoded.is_color else decoded.luma, config.detector)
    return {"logit": None if rec.undetermined else rec.logit,
            "learned_ms": (time.perf_counter() - t0) * 1e3}


@dataclass(frozen=True)
class PaperGrid:
    """Values swept for the paper profile (Algorithm 1)."""

    n_b: tuple[int, ...] = (2, 4)
    max_peaks: tuple[int, ...] = (2, 3)
    ratio_tol: tuple[float, ...] = (0.01, 0.02, 0.03, 0.05)
    gamma: tuple[float, ...] = (0.1, 0.3, 0.5, 1.0)


@dataclass(frozen=True)
class Setting:
    """One swept point: profile plus the DetectorConfig fields it changes, by dotted name
    (``"fit.min_gain"``; ``"paper.n_b"`` sets both paper block counts)."""

    profile: str
    params: tuple[tuple[str, float], ...]

    @property
    def as_dict(self) -> dict:
        """The changed fields."""
        return dict(self.params)

    def label(self) -> str:
        """Short human-readable form."""
        return f"{self.profile}: " + ", ".join(f"{k}={v:g}" for k, v in self.params)

    def apply(self, det: DetectorConfig) -> DetectorConfig:
        """``det`` with this setting's fields (paper n_b sets both block counts)."""
        changes = dict(self.params)
        if "paper.n_b" in changes:
            n_b = int(changes.pop("paper.n_b"))
            changes["paper.n_block_rows"] = changes["paper.n_block_cols"] = n_b
        for k in COUNT_KEYS:
            if k in changes:
                changes[k] = int(changes[k])
        return det.with_values({"profile": self.profile, **changes})


# ----------------------------------------------------------------------------- per image


def _specs(config: AppConfig) -> list:
    return [s for p in config.policies for s in p.specs]


def screened_candidates(evidence, config: AppConfig) -> np.ndarray:
    """Per `candidate_table` column (axis, spec): does the first stage let it be searched?

    As `pipeline.decide`: a spec goes on when any plane carrying its channels passes
    `screen.screen_plane` at ``screen_false_prob`` / ``screen_min_frames`` (not swept); a spec
    that fails it is never protected, by tone tracks, folding or the period sweep.

    Returns
    -------
    ndarray of bool, shape (2 * n_specs,)
    """
    det = config.detector
    specs = _specs(config)
    out = np.zeros(len(AXES) * len(specs), dtype=bool)
    for ai, axis in enumerate(AXES):
        planes = evidence.axes.get(axis)
        if not planes:
            continue
        _, passed = screen_specs(planes, list(enumerate(specs)), det, evidence.grid_cpr)
        for si, _spec in passed:
            out[ai * len(specs) + si] = True
    return out


def _max_sig_frames(planes: dict) -> int:
    return max((int(t.significant.sum()) for pa in planes.values() for t in pa.tracks),
               default=0)


def candidate_table(evidence, config: AppConfig, grid: DefaultGrid
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Match results of every (axis, spec) candidate for every match combo of ``grid``.

    Parameters
    ----------
    evidence : Evidence
        From `collect_evidence` (any peak_false_prob; it is re-judged per combo).
    config : AppConfig
        Base config (policies, fixed detector fields).
    grid : DefaultGrid
        Swept values.

    Returns
    -------
    table : ndarray of shape (n_combos, 2 * n_specs, 6), float32
        Columns ``n_matched, purity, switches, colour channels hit, is_rgb, valid``; rows of
        axes that were not analysed are all zero.
    match_ms : ndarray of shape (n_combos,)
        Matching wall time per combo, in milliseconds.

    Notes
    -----
    Mirrors `pipeline.decide`: a candidate is protected when n_matched >= need,
    purity >= min_purity, switches >= 1 and, for RGB specs, >= 2 channels are hit.
    A plane whose tracks hold fewer than 2 significant frames cannot hit any tone
    (`tones.MIN_FRAMES`), and a candidate the first stage clears (`screened_candidates`) is
    never protected, so both are recorded as 0 without running the matcher.
    """
    specs = _specs(config)
    screened = screened_candidates(evidence, config)
    combos = grid.match_combos()
    table = np.zeros((len(combos), len(AXES) * len(specs), 6), dtype=np.float32)
    match_ms = np.zeros(len(combos))
    by_fp = {}
    for ci, (fp, tol, occ_lo, occ_hi) in enumerate(combos):
        t0 = time.perf_counter()
        if fp not in by_fp:
            by_fp[fp] = evidence.with_false_prob(fp)
        ev = by_fp[fp]
        det = scaled_detector(config.detector.with_values({
            "tones.peak_false_prob": fp, "tones.rel_tol": tol, "tones.min_occupancy": occ_lo,
            "tones.max_occupancy": occ_hi}), ev.row_scale)
        for ai, axis in enumerate(AXES):
            planes = ev.axes.get(axis)
            if not planes:
                continue
            quiet = _max_sig_frames(planes) < 2
            for si, spec in enumerate(specs):
                chans = spec_planes(spec, planes)
                if chans is None:
                    continue
                row = table[ci, ai * len(specs) + si]
                row[IS_RGB], row[VALID] = float(spec.is_rgb), 1.0
                if quiet or not screened[ai * len(specs) + si]:
                    continue
                m = match_spec(spec, chans, det)
                row[N_MATCHED], row[PURITY], row[SWITCHES] = m.n_matched, m.purity, m.switches
                row[CH_HIT] = sum(1 for v in m.matched.values() if v)
        match_ms[ci] = (time.perf_counter() - t0) * 1e3
    return table, match_ms


def paper_peaks(decoded, config: AppConfig, grid: PaperGrid) -> tuple[dict, dict]:
    """Pooled `block_peaks_hz` per (n_b, M_p) and the time each took (ms)."""
    if decoded.is_color:
        rgb = decoded.rgb()
        planes = [rgb[:, :, i] for i in range(3)]
    else:
        planes = [decoded.luma]
    peaks, ms = {}, {}
    for n_b, m_p in itertools.product(grid.n_b, grid.max_peaks):
        t0 = time.perf_counter()
        det = config.detector.with_values({"profile": "paper", "paper.n_block_rows": n_b,
                                           "paper.n_block_cols": n_b, "paper.max_peaks": m_p})
        found = [block_peaks_hz(p, det) for p in planes]
        peaks[(n_b, m_p)] = np.unique(np.concatenate(found)) if found else np.zeros(0)
        ms[(n_b, m_p)] = (time.perf_counter() - t0) * 1e3
    return peaks, ms


def image_record(source, config: AppConfig, *, paper_grid: PaperGrid | None = None) -> dict:
    """The expensive per-image part: cascade-profile Evidence and paper peak frequencies.

    Returns
    -------
    dict
        ``evidence`` (Evidence), ``evidence_ms``, ``paper_peaks`` {(n_b, M_p): Hz array},
        ``paper_ms`` {(n_b, M_p): ms}, ``paper_decode_ms``.
    """
    det = config.detector
    t0 = time.perf_counter()
    decoded = decode_for(source, config)
    evidence = collect_evidence(decoded, config)
    # fits of specs the first stage clears never decide (pipeline.decide skips them)
    screened = screened_candidates(evidence, config)
    folds = [f for axis, _, f in fold_fits(evidence, config)
             if screened[_candidate_index(axis, f.spec, config)]]
    sweeps = [(e, i) for axis, _, e in (sweep_fits(evidence, config)
                                        if det.sweep is not None else [])
              if screened[i := _candidate_index(axis, e.spec, config)]]
    rec = {"evidence": evidence, "evidence_ms": (time.perf_counter() - t0) * 1e3,
           "folds": np.array([[f.rho, f.rho_lookalike, f.fold_snr] for f in folds],
                             dtype=float).reshape(-1, 3),
           "sweeps": np.array([sweep_row(e, i) for e, i in sweeps],
                              dtype=float).reshape(-1, len(SWEEP_COLUMNS))}
    if paper_grid is not None:
        t0 = time.perf_counter()
        full = decode(source, limits=config.limits, fast=det.profiles.fast_decode, max_rows=0)
        rec["paper_decode_ms"] = (time.perf_counter() - t0) * 1e3
        rec["paper_peaks"], rec["paper_ms"] = paper_peaks(full, config, paper_grid)
    return rec


# ----------------------------------------------------------------------------- sweeps


def _any_fit_passes(fits: list[np.ndarray], passes) -> np.ndarray:
    """Per image: does any row of its fit table (k, c) satisfy ``passes(*columns)``?"""
    return np.array([bool(passes(*f.T).any()) if len(f) else False for f in fits], dtype=bool)


SWEEP_COLUMNS = ("rho", "rho_lookalike", "coherence_t", "fit_rho", "fit_gain", "fit_t",
                 "fit_leak", "candidate", "fit_periods")


def _candidate_index(axis: str, spec: str, config: AppConfig) -> int:
    """Column of `candidate_table` (axis, spec) that a fold or sweep entry belongs to."""
    names = [s.name for s in _specs(config)]
    return AXES.index(axis) * len(names) + names.index(spec)


def sweep_row(entry: SweepResult, candidate: int = -1) -> list[float]:
    """A `sweep_fits` entry as a row of `SWEEP_COLUMNS` (zeros where no exact fit was made;
    ``candidate`` is its `candidate_table` column, -1 when unknown)."""
    grid = [entry.rho, entry.rho_lookalike, entry.coherence_t]
    fit = entry.fit
    if fit is None:
        return [*grid, 0.0, 0.0, 0.0, math.inf, float(candidate), 0.0]
    leak = math.inf if fit.chroma_leak is None else fit.chroma_leak
    return [*grid, fit.rho, fit.gain, fit.coherence_t, leak, float(candidate), fit.n_periods]


def tone_confirmed(sweeps: list[np.ndarray], n_candidates: int, det: DetectorConfig
                   ) -> np.ndarray:
    """Per image and `candidate_table` column: may its tone tracks decide? True everywhere
    when the check is off; else whether an exact fit of that (axis, spec) confirms them (the
    array form of `rules.tone_fit_confirms`)."""
    out = np.zeros((len(sweeps), n_candidates), dtype=bool)
    if not tone_check_on(det):
        out[:] = True
        return out
    for i, f in enumerate(sweeps):
        if not len(f):
            continue
        ok = tone_rule(f[:, 3], f[:, 4], f[:, 5], det) & (f[:, 7] >= 0)
        out[i, f[ok, 7].astype(int)] = True
    return out


def fold_protected(folds: list[np.ndarray], det: DetectorConfig) -> np.ndarray:
    """Per image: does any fold fit (rows of rho, rho_lookalike, fold_snr) pass
    `rules.fold_rule`? The fold stage does not depend on the swept tone parameters."""
    return _any_fit_passes(folds, lambda rho, alt, snr: fold_rule(rho, alt, snr, det))


def sweep_protected(sweeps: list[np.ndarray], det: DetectorConfig) -> np.ndarray:
    """Per image: does any period-sweep fit (rows of `SWEEP_COLUMNS`) pass `rules.grid_rule`,
    or its exact-model fit `rules.fit_rule` (an unmeasured chroma leak is cached as inf, as
    `rules.fit_passes` passes it)? The table form of `rules.sweep_passes`."""
    return _any_fit_passes(sweeps, lambda rho, alt, t, f_rho, f_gain, f_t, leak, _cand, f_np: (
        grid_rule(rho, alt, t, det) | fit_rule(f_rho, f_gain, f_t, f_np, leak, det)))


FOLD_MIN_RHO = (0.85, 0.9, 0.95)  # pattern-folding thresholds swept with every setting


def default_scores(tables: np.ndarray, grid: DefaultGrid, folds: list[np.ndarray] | None = None,
                   det: DetectorConfig | None = None,
                   fold_min_rho: tuple[float, ...] = FOLD_MIN_RHO,
                   sweeps: list[np.ndarray] | None = None
                   ) -> tuple[list[Setting], np.ndarray, np.ndarray, np.ndarray]:
    """Verdicts of every default-profile setting from stacked candidate tables.

    Parameters
    ----------
    tables : ndarray of shape (n_images, n_combos, n_candidates, 6)
        Stacked `candidate_table` outputs.
    grid : DefaultGrid
        The grid the tables were computed for.
    folds : list of ndarray (k, 3), optional
        Per image, the unthresholded fold fits (rho, rho_lookalike, fold_snr); with ``det``
        the pattern-folding stage is OR-ed into every setting, for each ``fold_min_rho``.
    det : DetectorConfig, optional
        Supplies the other fold thresholds (fold_min_snr, fold_min_margin).
    sweeps : list of ndarray (k, 6), optional
        Per image, the unthresholded period-sweep fits (`SWEEP_COLUMNS`); with
        ``det`` (and the sweep on in ``det``) that stage is OR-ed in for every
        ``grid.sweep_combos()``.

    Returns
    -------
    settings : list of Setting
    protected : ndarray of bool, shape (n_settings, n_images)
    cand_hits : ndarray of int32, shape (n_settings, n_images)
        Candidates with >= the required tones (any purity), per image.
    cand_total : ndarray of shape (n_images,)
        Candidates analysed per image.
    """
    n_img = tables.shape[0]
    valid = tables[..., VALID] > 0
    cand_total = valid[:, 0, :].sum(axis=1)
    fold_variants: list[tuple[tuple, np.ndarray | bool]] = [((), False)]
    if folds is not None and det is not None:
        fold_variants = [((("fold.min_rho", r),),
                          fold_protected(folds, det.with_values({"fold.min_rho": r})))
                         for r in fold_min_rho]
    if sweeps is not None and det is not None and det.sweep is not None:
        sweep_variants = [(tuple(zip(SWEEP_KEYS, combo, strict=True)),
                           sweep_protected(sweeps, det.with_values(
                               dict(zip(SWEEP_KEYS, combo, strict=True)))))
                          for combo in grid.sweep_combos()]
        fold_variants = [(fp + sp, fo | so) for fp, fo in fold_variants
                         for sp, so in sweep_variants]
    confirmed = (tone_confirmed(sweeps, tables.shape[2], det)
                 if sweeps is not None and det is not None else True)
    n_settings = len(grid.match_combos()) * len(grid.gate_combos()) * len(fold_variants)
    # preallocated: (n_settings, n_images) grows to gigabytes on a few thousand images
    prot = np.zeros((n_settings, n_img), dtype=bool)
    hits = np.zeros((n_settings, n_img), dtype=np.int32)
    settings = []
    for ci, (fp, tol, occ_lo, occ_hi) in enumerate(grid.match_combos()):
        t = tables[:, ci]
        n, pur, sw, ch, rgb = (t[..., N_MATCHED], t[..., PURITY], t[..., SWITCHES],
                               t[..., CH_HIT], t[..., IS_RGB] > 0)
        for mp, mt, mt_rgb in grid.gate_combos():
            need = np.where(rgb, mt_rgb, mt)
            enough = (n >= need) & valid[:, ci]
            ok = (enough & (pur >= mp - 1e-6) & (sw >= 1) & (~rgb | (ch >= 2)) & confirmed
                  ).any(axis=1)
            n_enough = enough.sum(axis=1)
            for fold_params, fold_ok in fold_variants:
                si = len(settings)
                settings.append(Setting("cascade", (
                    ("tones.peak_false_prob", fp), ("tones.rel_tol", tol),
                    ("tones.min_occupancy", occ_lo), ("tones.max_occupancy", occ_hi),
                    ("tones.min_purity", mp), ("tones.min_tones", mt),
                    ("tones.min_tones_rgb", mt_rgb), *fold_params)))
                prot[si] = ok | fold_ok
                hits[si] = n_enough
    return settings, prot, hits, cand_total


def paper_scores(peaks: list[dict], config: AppConfig, grid: PaperGrid
                 ) -> tuple[list[Setting], np.ndarray, np.ndarray, np.ndarray]:
    """Verdicts of every paper-profile setting from cached per-image peak frequencies.

    Returns the same four items as `default_scores`; ``cand_hits`` counts false ratio matches
    m_b (summed over specs) and ``cand_total`` the tested ratios (pairs x specs) per image.
    """
    specs = _specs(config)
    n_img = len(peaks)
    settings, prot, hits = [], [], []
    total = np.zeros((len(grid.n_b) * len(grid.max_peaks), n_img))
    for bi, (n_b, m_p) in enumerate(itertools.product(grid.n_b, grid.max_peaks)):
        f_list = [p[(n_b, m_p)] for p in peaks]
        n_pairs = np.array([f.size * (f.size - 1) / 2 for f in f_list])
        total[bi] = n_pairs * len(specs)
        for tol in grid.ratio_tol:
            m_b = np.array([[count_ratio_matches(f, s.ratio_values(), tol) for s in specs]
                            for f in f_list]).reshape(n_img, len(specs))
            for g in grid.gamma:
                det = config.detector.with_values({"paper.gamma": g})
                need = np.array([required_matches(s, det) for s in specs])
                settings.append(Setting("paper", (("paper.n_b", n_b), ("paper.max_peaks", m_p),
                                                  ("paper.ratio_tol", tol),
                                                  ("paper.gamma", g))))
                prot.append((m_b >= need[None, :]).any(axis=1))
                hits.append(m_b.sum(axis=1).astype(float))
    # cand_total differs per (n_b, M_p); return it per setting
    per_setting_total = np.repeat(total, len(grid.ratio_tol) * len(grid.gamma), axis=0)
    return settings, np.array(prot), np.array(hits), per_setting_total


# ----------------------------------------------------------------------------- summaries


def _bin(value, edges: tuple[float, ...], fmt: str) -> str:
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        if lo <= value < hi:
            return fmt.format(lo=lo, hi=hi)
    return fmt.format(lo=edges[-2], hi=edges[-1])


def group_labels(row: dict) -> dict[str, str]:
    """Group of a positive (synth manifest row) under each per-kind breakdown."""
    g = {}
    chans = row.get("channels")
    if chans is not None:
        g["channels"] = "RGB" if len(chans) > 1 else "mono"
    if row.get("preset") is not None:
        g["preset"] = str(row["preset"])
    if row.get("attack") is not None:
        g["attack"] = "attack" if row["attack"] else "no attack"
    amb = row.get("ambient_ratio")
    if amb is not None:
        g["ambient"] = "0" if amb == 0 else _bin(float(amb), (0, 0.5, 2, math.inf),
                                                  "({lo:g},{hi:g}]")
    cov = row.get("coverage")
    if isinstance(cov, dict):
        cov = cov.get("fraction")
    if cov is not None:
        g["coverage"] = "full" if cov >= 0.999 else _bin(float(cov), (0, 0.5, 1.0),
                                                          "[{lo:g},{hi:g})")
    ds = row.get("downscale")
    if ds is not None:
        g["downscale"] = "1" if ds <= 1.0 else _bin(float(ds), (1, 2, math.inf),
                                                     "({lo:g},{hi:g}]")
    if row.get("rotation_deg") is not None:
        g["rotation"] = f"{int(row['rotation_deg'])} deg"
    if row.get("kind") is not None:
        g["kind"] = str(row["kind"])
    return g


@dataclass
class Summary:
    """Rates of one setting."""

    setting: Setting
    n_clean: int
    false_alarms: int
    far: float
    far_upper: float
    far_upper_two_sided: float
    false_match_fraction: float
    n_pos: int
    detected: int
    detection: float
    time_ms_per_image: float
    per_group: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}  # asdict deep-copies: slow
        d["setting"] = {"profile": self.setting.profile, **self.setting.as_dict}
        d["label"] = self.setting.label()
        return d


def summarise(settings: list[Setting], clean_prot: np.ndarray, pos_prot: np.ndarray, *,
              clean_hits: np.ndarray, clean_cands, time_ms: np.ndarray,
              pos_groups: list[dict[str, str]] | None = None) -> list[Summary]:
    """Rates, bounds and per-group detection of every setting.

    Parameters
    ----------
    settings : list of Setting
    clean_prot, pos_prot : ndarray of bool, shape (n_settings, n_clean / n_pos)
        Verdicts on clean images and positives.
    clean_hits : ndarray of shape (n_settings, n_clean)
        False candidate (or ratio) matches per clean image.
    clean_cands : ndarray of shape (n_clean,) or (n_settings, n_clean)
        Candidates (or ratios) tested per clean image.
    time_ms : ndarray of shape (n_settings,)
        Mean decision time per image for each setting, in milliseconds.
    pos_groups : list of dict, optional
        `group_labels` of each positive.
    """
    cands = np.asarray(clean_cands)  # may be a broadcast view: never copied
    out = []
    n_clean = clean_prot.shape[1]
    n_pos = pos_prot.shape[1]
    groups: dict[tuple[str, str], list[int]] = {}
    for i, g in enumerate(pos_groups or []):
        for key, val in g.items():
            groups.setdefault((key, val), []).append(i)
    # every setting at once: detections per group, false alarms, and the bounds of each count
    group_hits = {kv: (len(idx), pos_prot[:, idx].sum(axis=1).tolist())
                  for kv, idx in sorted(groups.items())}
    false_alarms = clean_prot.sum(axis=1).tolist()
    detected = pos_prot.sum(axis=1).tolist()
    bounds = {k: (far_upper_bound(k, n_clean), two_sided_upper(k, n_clean))
              for k in set(false_alarms)}
    denoms = (cands.sum(axis=1, dtype=float) if cands.ndim == 2
              else np.full(len(settings), cands.sum(dtype=float))).tolist()
    match_counts = np.asarray(clean_hits).sum(axis=1, dtype=float).tolist()
    for si, s in enumerate(settings):
        k = int(false_alarms[si])
        denom = float(denoms[si])
        det = int(detected[si])
        per: dict = {}
        for (key, val), (n, hits) in group_hits.items():
            per.setdefault(key, {})[val] = {"detected": int(hits[si]), "n": n,
                                            "rate": hits[si] / n}
        out.append(Summary(
            setting=s, n_clean=n_clean, false_alarms=k, far=k / n_clean if n_clean else math.nan,
            far_upper=bounds[k][0], far_upper_two_sided=bounds[k][1],
            false_match_fraction=match_counts[si] / denom if denom else 0.0,
            n_pos=n_pos, detected=det, detection=det / n_pos if n_pos else math.nan,
            time_ms_per_image=float(time_ms[si]), per_group=per))
    return out


def select_setting(summaries: list[Summary], target_far: float) -> tuple[Summary, bool]:
    """The setting with the highest detection whose FAR upper bound meets ``target_far``.

    Ties go to the lower bound, then the faster setting. When no setting meets the target,
    returns the setting with the lowest bound (then highest detection) and False.

    Returns
    -------
    best : Summary
    met : bool
        Whether ``best.far_upper <= target_far``.
    """
    if not summaries:
        raise ValueError("no settings to select from")
    ok = [s for s in summaries if s.far_upper <= target_far]
    if ok:
        return max(ok, key=lambda s: (s.detection, -s.far_upper, -s.time_ms_per_image)), True
    return min(summaries, key=lambda s: (s.far_upper, -s.detection, s.time_ms_per_image)), False


# ----------------------------------------------------------------------------- split


# Manifest fields that name the source photo an image was made from. First tier: an explicit
# group, a checksum, id or path of the source file (build_clean_set.py's real-photo variants:
# ``source_sha256``, ``source_path``), the scene of a synthetic capture (synth's ``scene_name``,
# ``scene_photo``, ``scene: {"scene": ..}``). Second tier, read only when the first names
# nothing, as these fields mean different things in different manifests: ``source`` (a
# scikit-image photo's name in build_clean_set.py's photo variants, but the package of its
# real-photo variants and the registry in the corpus manifest) and the corpus's own ``sha256``.
SOURCE_FIELDS = ("group", "source_group", "source_sha256", "source_id", "source_path",
                 "source_file", "source_photo", "scene_name", "scene_photo", "scene")
SOURCE_FIELDS_GENERIC = ("source", "photo", "sha256")
# values that name where a photo came from, not which photo (the corpus manifest's ``source``)
NOT_A_SOURCE = frozenset({"debian", "pypi", "skimage", "synth", "photo", "real-photo"})
# scikit-image names of one photograph (the stereo pair's two views are one scene)
SOURCE_ALIASES = {"stereo_motorcycle_left": "motorcycle", "stereo_motorcycle_right": "motorcycle",
                  "stereo_motorcycle": "motorcycle"}
_IMAGE_SUFFIX = re.compile(r"\.(jpe?g|png|webp|tiff?|bmp|heic|heif|gif)$", re.IGNORECASE)
# file-name suffixes that mark a variant of one source: "cat__crop2", "cat_v3", "cat-rot90"
_VARIANT_SUFFIX = re.compile(
    r"(?:__.*|[_-](?:v|var|variant|crop|aug|rot|q|scale|down|copy)\d+(?:\.\d+)?)+$")


def source_keys(row: dict, path: str) -> tuple[str, ...]:
    """Every name of the source photo an image was made from, as found in its manifest row.

    Parameters
    ----------
    row : dict
        The image's manifest row (may be empty).
    path : str
        The image's path.

    Returns
    -------
    tuple of str
        One key per `SOURCE_FIELDS` entry present (or, if none, per `SOURCE_FIELDS_GENERIC`
        entry), lower-cased: a path or file name is reduced to its base name without image
        extension, a ``skimage:`` prefix is dropped and `SOURCE_ALIASES` applied, so a
        scikit-image photo variant (``source: astronaut``), a synthetic capture of the same
        photo (``scene: skimage:astronaut``), and a corpus photo's variant (``source_path:
        usr/share/a.jpg``) and synthetic capture (``scene_photo:
        out/photos/images/debian/pkg/usr__share__a.jpg``) share a key. Procedural scenes
        (``texture:...``) and registry names (`NOT_A_SOURCE`, the corpus manifest's ``source:
        debian``) name no source. Without any, a file name ending in a variant marker
        (``__anything``, ``_v3``, ``-crop2``, ``_rot90``, ``_q85``) gives its stem, else the
        image is its own source (its absolute path).

    Examples
    --------
    >>> source_keys({"source": "astronaut"}, "photos/000001.jpg")
    ('src:astronaut',)
    >>> source_keys({"source": "hugin-data", "source_path": "usr/share/hugin/Lake.jpg",
    ...              "source_sha256": "AB12"}, "realphotos/000001.jpg")
    ('src:ab12', 'src:lake')
    >>> source_keys({"scene": {"scene": "skimage:astronaut"}}, "synth/000007.jpg")
    ('src:astronaut',)
    >>> source_keys({}, "clean/cat__crop2.jpg")
    ('name:cat',)
    """
    keys = _named_sources(row, SOURCE_FIELDS) or _named_sources(row, SOURCE_FIELDS_GENERIC)
    if keys:
        return keys
    stem = os.path.splitext(os.path.basename(str(path)))[0].lower()
    base = _VARIANT_SUFFIX.sub("", stem)
    if base and base != stem:
        return ("name:" + base,)
    return ("file:" + os.path.abspath(str(path)),)


def _named_sources(row: dict, names: tuple[str, ...]) -> tuple[str, ...]:
    keys = []
    for field_name in names:
        value = row.get(field_name)
        if isinstance(value, dict):
            value = value.get("scene")
        if value is None or str(value).strip() == "":
            continue
        value = str(value).strip().lower()
        if value.startswith("texture:") or value in NOT_A_SOURCE:
            continue  # a fresh random render per image, or a registry: no shared photo
        value = value.removeprefix("skimage:")
        if "/" in value or "\\" in value or _IMAGE_SUFFIX.search(value):
            # the corpus stores "a/b/c.jpg" as "a__b__c.jpg": both reduce to "c"
            value = value.replace("\\", "/").replace("__", "/")
            value = _IMAGE_SUFFIX.sub("", value.rsplit("/", 1)[-1])
        value = SOURCE_ALIASES.get(value, value)
        if value and "src:" + value not in keys:
            keys.append("src:" + value)
    return tuple(keys)


def source_groups(keys: list[tuple[str, ...]]) -> list[str]:
    """Group label of each image: images sharing any source key, directly or through others,
    form one group (connected components), labelled by the group's smallest key.

    Parameters
    ----------
    keys : list of tuple of str
        Per image, its `source_keys`.

    Returns
    -------
    list of str
        Per image, its group label.

    Examples
    --------
    >>> source_groups([("src:a",), ("src:b", "src:c"), ("src:c",), ("src:a", "src:z")])
    ['src:a', 'src:b', 'src:b', 'src:a']
    """
    parent: dict[str, str] = {}

    def find(k: str) -> str:
        parent.setdefault(k, k)
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for ks in keys:
        roots = sorted({find(k) for k in ks})
        for r in roots[1:]:
            parent[r] = roots[0]
    return [find(ks[0]) for ks in keys]


def stratum_key(row: dict, origin: str) -> str:
    """Stratum of an image for the split: its origin (input folder), kind, preset and package.

    Parameters
    ----------
    row : dict
        Manifest row: ``kind`` (photo, steady, mains, pwm, texture, barcode), ``preset`` for
        positives, ``package`` for photos of the real-photo corpus (and sets made from it).
        Missing fields read as "-"; a missing package is left out.
    origin : str
        Where the image came from, e.g. the input folder's name.

    Examples
    --------
    >>> stratum_key({"kind": "mains"}, "synth")
    'synth/mains/-'
    >>> stratum_key({"package": "hugin-data"}, "photos")
    'photos/-/-/hugin-data'
    """
    key = f"{origin}/{row.get('kind') or '-'}/{row.get('preset') or '-'}"
    return f"{key}/{row['package']}" if row.get("package") else key


def split_parts(groups: list[str], strata: list[str], *, fraction: float, seed: int
                ) -> np.ndarray:
    """Seeded, stratified split into a tuning and a certification part, whole groups at a time.

    Parameters
    ----------
    groups : list of str
        Per item, its `source_groups` label; every item of a group goes to the same part.
    strata : list of str
        Per item, its `stratum_key`; each stratum is split about ``fraction`` : 1 - fraction.
    fraction : float
        Target share of the certification part, in (0, 1), unitless.
    seed : int
        Split seed; the result depends only on (groups, strata, fraction, seed), not on the
        order of the items.

    Returns
    -------
    ndarray of bool, shape (n_items,)
        True for items of the certification part.

    Raises
    ------
    ValueError
        If ``fraction`` is outside (0, 1) or the lists differ in length.

    Notes
    -----
    Groups are visited largest first (ties in a seeded random order); each goes to the part that
    keeps the running per-stratum counts closest, in squared count, to ``fraction`` of the items
    assigned so far (a tie is broken by a seeded draw with probability ``fraction``). With many
    small groups every stratum ends within about one group of its target; a group larger than
    a stratum's share cannot be split and is not.

    Examples
    --------
    >>> split_parts(["a", "a", "b", "c"], ["x"] * 4, fraction=0.5, seed=0).tolist()
    [True, True, False, False]
    """
    if not 0 < fraction < 1:
        raise ValueError(f"need 0 < fraction < 1, got fraction={fraction!r}")
    if len(groups) != len(strata):
        raise ValueError(f"need one stratum per item, got {len(groups)} groups and "
                         f"{len(strata)} strata")
    g_names = sorted(set(groups))
    s_names = sorted(set(strata))
    g_index = {g: i for i, g in enumerate(g_names)}
    s_index = {s: i for i, s in enumerate(s_names)}
    g_of = np.array([g_index[g] for g in groups], dtype=int)
    counts = np.zeros((len(g_names), len(s_names)))
    np.add.at(counts, (g_of, [s_index[s] for s in strata]), 1)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(g_names))
    order = order[np.argsort(-counts[order].sum(axis=1), kind="stable")]
    cert_counts = np.zeros(len(s_names))
    seen = np.zeros(len(s_names))
    to_cert = np.zeros(len(g_names), dtype=bool)
    for g in order:
        c = counts[g]
        goal = fraction * (seen + c)
        cost_cert = float(np.sum((cert_counts + c - goal) ** 2))
        cost_tune = float(np.sum((cert_counts - goal) ** 2))
        draw = rng.random() < fraction
        if cost_cert < cost_tune - 1e-9 or (abs(cost_cert - cost_tune) <= 1e-9 and draw):
            to_cert[g] = True
            cert_counts += c
        seen += c
    return to_cert[g_of]


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
