"""Per-image evidence of calibration and every setting's verdicts on it.

The grids of swept parameters, the per-image records (computed once, cached by
`lishield_guard.batch.cache`) and the vectorised verdicts of every setting on them.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

from lishield_guard.config import AppConfig, DetectorConfig
from lishield_guard.decode import decode
from lishield_guard.detector.paper import block_peaks_hz, count_ratio_matches, required_matches
from lishield_guard.detector.results import SweepResult
from lishield_guard.detector.rules import fit_rule, fold_rule, grid_rule, tone_check_on, tone_rule
from lishield_guard.detector.search import scaled_detector, screen_specs, spec_planes
from lishield_guard.detector.tones import match_spec
from lishield_guard.profiles import cascade, learned, paper
from lishield_guard.verdict import Timer

#: The profiles calibration sweeps, in the order reports list them (registry names).
PROFILES = (learned.NAME, cascade.NAME, paper.NAME)
# candidate table columns
N_MATCHED, PURITY, SWITCHES, CH_HIT, IS_RGB, VALID = range(6)
AXES = ("rows", "columns")

# ----------------------------------------------------------------------------- grids


SWEEP_KEYS = ("sweep.min_rho", "sweep.min_margin", "sweep.min_coherence", "fit.min_rho",
              "fit.min_gain", "fit.min_rho_rgb", "fit.min_gain_rgb", "fit.max_leak_rgb",
              "fit.min_rho_periodic", "fit.min_gain_periodic")
COUNT_KEYS = ("paper.max_peaks", "tones.min_tones", "tones.min_tones_rgb")


@dataclass(frozen=True)
class CascadeGrid:
    """Values swept for the cascade profile (all unitless), named after the settings they
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
    """Thresholds swept for the learned profile (`profiles.learned`).

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

    settings = [Setting(learned.NAME, (("learned.threshold_logit", float(t)),))
                for t in thresholds]
    return (settings, rule_at(np.asarray(logits_clean)[None, :], thresholds[:, None]),
            rule_at(np.asarray(logits_pos)[None, :], thresholds[:, None]))


def learned_record(source, config: AppConfig) -> dict:
    """The learned profile's per-image measurement for calibration (its own `decode` and
    `measure`, luma first as detection decodes it when the first look is on): the image logit,
    its first look (`detector.firstlook`: ``first_look`` the peak, ln units, -inf when none;
    ``first_look_usable``), measured in the same pass for `calibration.firstlook`, and the
    milliseconds decode + measurement took (``logit`` is None for an undetermined image)."""
    t0 = time.perf_counter()
    rec = learned.measure(learned.decode(source, config, luma_first=True), config, Timer(),
                          full=True)
    look = rec.first_look
    return {"logit": None if rec.why else rec.decision.logit,
            "first_look": float("-inf") if look is None else look.peak,
            "first_look_usable": bool(look is not None and look.usable),
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

    As `cascade.decide_record`: a spec goes on when any plane carrying its channels passes
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


def candidate_table(evidence, config: AppConfig, grid: CascadeGrid
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Match results of every (axis, spec) candidate for every match combo of ``grid``.

    Parameters
    ----------
    evidence : CascadeRecord
        From `cascade.collect_record` (any peak_false_prob; it is re-judged per combo).
    config : AppConfig
        Base config (policies, fixed detector fields).
    grid : CascadeGrid
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
    Mirrors `cascade.decide_record`: a candidate is protected when n_matched >= need,
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
        det = config.detector.with_values({"profile": paper.NAME, "paper.n_block_rows": n_b,
                                           "paper.n_block_cols": n_b, "paper.max_peaks": m_p})
        found = [block_peaks_hz(p, det) for p in planes]
        peaks[(n_b, m_p)] = np.unique(np.concatenate(found)) if found else np.zeros(0)
        ms[(n_b, m_p)] = (time.perf_counter() - t0) * 1e3
    return peaks, ms


def image_record(source, config: AppConfig, *, paper_grid: PaperGrid | None = None) -> dict:
    """The expensive per-image part: the cascade's record and paper peak frequencies.

    Returns
    -------
    dict
        ``evidence`` (`profiles.cascade.CascadeRecord`), ``evidence_ms``, ``paper_peaks``
        {(n_b, M_p): Hz array}, ``paper_ms`` {(n_b, M_p): ms}, ``paper_decode_ms``.
    """
    det = config.detector
    t0 = time.perf_counter()
    decoded = cascade.decode(source, config)
    evidence = cascade.collect_record(decoded, config)
    # fits of specs the first stage clears never decide (cascade.decide_record skips them)
    screened = screened_candidates(evidence, config)
    folds = [f for axis, _, f in cascade.fold_fits(evidence, config)
             if screened[_candidate_index(axis, f.spec, config)]]
    sweeps = [(e, i) for axis, _, e in (cascade.sweep_fits(evidence, config)
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


def cascade_scores(tables: np.ndarray, grid: CascadeGrid, folds: list[np.ndarray] | None = None,
                   det: DetectorConfig | None = None,
                   fold_min_rho: tuple[float, ...] = FOLD_MIN_RHO,
                   sweeps: list[np.ndarray] | None = None
                   ) -> tuple[list[Setting], np.ndarray, np.ndarray, np.ndarray]:
    """Verdicts of every default-profile setting from stacked candidate tables.

    Parameters
    ----------
    tables : ndarray of shape (n_images, n_combos, n_candidates, 6)
        Stacked `candidate_table` outputs.
    grid : CascadeGrid
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
                settings.append(Setting(cascade.NAME, (
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

    Returns the same four items as `cascade_scores`; ``cand_hits`` counts false ratio matches
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
                settings.append(Setting(paper.NAME, (("paper.n_b", n_b), ("paper.max_peaks", m_p),
                                                  ("paper.ratio_tol", tol),
                                                  ("paper.gamma", g))))
                prot.append((m_b >= need[None, :]).any(axis=1))
                hits.append(m_b.sum(axis=1).astype(float))
    # cand_total differs per (n_b, M_p); return it per setting
    per_setting_total = np.repeat(total, len(grid.ratio_tol) * len(grid.gamma), axis=0)
    return settings, np.array(prot), np.array(hits), per_setting_total
