"""Pass rules of the pattern stages, written once over numbers or arrays, shared with calibration.

The rules (`grid_rule`, `fit_rule`, `tone_rule`, `fold_rule`) are written over numbers or
same-shape arrays (``&`` and ``|`` rather than ``and`` and ``or``): detection applies them to
one typed stage result (`results.SweepResult`, `results.FoldResult`, `fit.ModelFit`; in
`grid_passes`, `fit_passes`, `sweep_passes`, `fold_passes`, `tone_fit_confirms`), calibration
(`calibrate.sweep_protected` and friends) to whole tables of cached fits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lishield_guard.config import FIT_RHO_FLOOR, PERIODIC_MIN_PERIODS, DetectorConfig
from lishield_guard.detector.results import FoldResult, ModelFit, SweepResult

__all__ = ["FitPath", "fit_passes", "fit_paths", "fit_rule", "fold_passes", "fold_rule",
           "grid_passes", "grid_rule", "sweep_passes", "tone_check_on", "tone_fit_confirms",
           "tone_rule"]


def _off(value) -> float | np.ndarray:
    """False everywhere ``value`` is: a rule of a stage that is off passes nothing."""
    return np.zeros(np.shape(value), dtype=bool) if np.ndim(value) else False


def grid_rule(rho, rho_lookalike, coherence_t, det: DetectorConfig):
    """Period-sweep grid fit: rho >= ``sweep.min_rho``, rho beats the stationary look-alike
    by ``sweep.min_margin`` and the column blocks agree (coherence t >= ``sweep.min_coherence``);
    never with the sweep off.
    """
    if det.sweep is None:
        return _off(rho)
    return ((rho >= det.sweep.min_rho) & (rho - rho_lookalike >= det.sweep.min_margin)
            & (coherence_t >= det.sweep.min_coherence))


@dataclass(frozen=True)
class FitPath:
    """One way for an exact-model fit to pass `fit_rule`.

    Attributes
    ----------
    name : str
        In words (``"general"``, ``">= 2 periods"``, ``"colour-verified"``).
    applies : callable
        ``applies(n_periods, chroma_leak)``: whether the path is open to a fit (numbers or
        arrays; ``chroma_leak`` inf when not measured).
    min_rho, min_gain : float
        What rho and the gain over the look-alike must reach on it.
    """

    name: str
    applies: Callable
    min_rho: float
    min_gain: float


def fit_paths(det: DetectorConfig) -> list[FitPath]:
    """The exact fit's ways to pass (an optional path set to None is not listed): the general
    one; with at least `config.PERIODIC_MIN_PERIODS` pattern periods in the frame, the
    ``_periodic`` thresholds; for an RGB channel whose colour was measured and points at its
    own plane (``chroma_leak <= fit.max_leak_rgb``), the ``_rgb`` thresholds."""
    f = det.fit
    paths = [FitPath("general", lambda n_periods, leak: True, f.min_rho, f.min_gain)]
    if f.min_gain_periodic is not None:
        paths.append(FitPath(f">= {PERIODIC_MIN_PERIODS:g} periods",
                             lambda n_periods, leak: n_periods >= PERIODIC_MIN_PERIODS,
                             f.min_rho_periodic, f.min_gain_periodic))
    if f.max_leak_rgb is not None:
        paths.append(FitPath("colour-verified",
                             lambda n_periods, leak: np.isfinite(leak) & (leak <= f.max_leak_rgb),
                             f.min_rho_rgb, f.min_gain_rgb))
    return paths


def fit_rule(rho, gain, coherence_t, n_periods, chroma_leak, det: DetectorConfig):
    """Exact-model fit, with the sweep and the fit on and coherence t >=
    ``sweep.min_coherence``: rho and gain reach ``fit.min_rho`` and ``fit.min_gain``; or the
    frame holds at least `config.PERIODIC_MIN_PERIODS` pattern periods and rho and gain reach
    the ``_periodic`` thresholds; or (an RGB channel whose colour was measured:
    ``chroma_leak`` finite, inf when not measured) the leak is at most ``fit.max_leak_rgb``
    and rho and gain reach the ``_rgb`` thresholds (`fit_paths`). An optional path set to
    None is off."""
    if det.fit is None or det.sweep is None:
        return _off(rho)
    ok = _off(rho)
    for path in fit_paths(det):
        ok = ok | (path.applies(n_periods, chroma_leak) & (rho >= path.min_rho)
                   & (gain >= path.min_gain))
    return (coherence_t >= det.sweep.min_coherence) & ok


def tone_rule(rho, gain, coherence_t, det: DetectorConfig):
    """Exact-model fit confirming tone tracks: rho >= `config.FIT_RHO_FLOOR`, coherence t >=
    ``sweep.min_coherence`` and gain >= ``tones.min_fit_gain`` (the barcode explains the rows
    better than the best steady square wave); never when `tone_check_on` is False."""
    if not tone_check_on(det):
        return _off(rho)
    return ((rho >= FIT_RHO_FLOOR) & (coherence_t >= det.sweep.min_coherence)
            & (gain >= det.tones.min_fit_gain))


def fold_rule(rho, rho_lookalike, fold_snr, det: DetectorConfig):
    """Fold fit: rho >= ``fold.min_rho``, SNR >= ``fold.min_snr`` and rho beats the stationary
    look-alike by ``fold.min_margin``; never with folding off."""
    if det.fold is None:
        return _off(rho)
    return ((rho >= det.fold.min_rho) & (fold_snr >= det.fold.min_snr)
            & (rho - rho_lookalike >= det.fold.min_margin))


def grid_passes(entry: SweepResult, det: DetectorConfig) -> bool:
    """Whether a period-sweep entry's own (binned-grid) fit passes `grid_rule`."""
    return bool(grid_rule(entry.rho, entry.rho_lookalike, entry.coherence_t, det))


def fit_passes(fit: ModelFit | None, det: DetectorConfig) -> bool:
    """Whether an exact-model fit (or None: none made) passes `fit_rule`."""
    if fit is None:
        return False
    leak = fit.chroma_leak
    return bool(fit_rule(fit.rho, fit.gain, fit.coherence_t, fit.n_periods,
                         math.inf if leak is None else leak, det))


def sweep_passes(entry: SweepResult, det: DetectorConfig) -> bool:
    """Whether a period-sweep entry is evidence enough for protected: the grid fit passes
    `grid_rule`, or its exact-model refinement passes `fit_passes`."""
    return grid_passes(entry, det) or fit_passes(entry.fit, det)


def fold_passes(fold: FoldResult, det: DetectorConfig) -> bool:
    """Whether a fold fit passes `fold_rule` (evidence enough for a verdict of protected)."""
    return bool(fold_rule(fold.rho, fold.rho_lookalike, fold.fold_snr, det))


def tone_check_on(det: DetectorConfig) -> bool:
    """Whether tone tracks need an exact fit's confirmation (`tone_fit_confirms`): a
    ``tones.min_fit_gain`` (not None) with the period sweep and the exact fit on."""
    return det.tones.min_fit_gain is not None and det.sweep is not None and det.fit is not None


def tone_fit_confirms(entries: list[SweepResult], det: DetectorConfig) -> bool:
    """Whether one spec's period-sweep entries on one axis confirm its tone tracks: one of them
    has an exact-model fit passing `tone_rule`."""
    return any(e.fit is not None and bool(tone_rule(e.fit.rho, e.fit.gain, e.fit.coherence_t,
                                                    det))
               for e in entries)
