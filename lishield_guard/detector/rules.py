"""Pass rules of the pattern stages, written once over numbers or arrays, shared with calibration.

The rules (`grid_rule`, `fit_rule`, `tone_rule`, `fold_rule`) are written over numbers or
same-shape arrays (``&`` and ``|`` rather than ``and`` and ``or``): detection applies them to
one fit (`grid_passes`, `fit_passes`, `sweep_passes`, `fold_passes`, `tone_fit_confirms`),
calibration (`calibrate.sweep_protected` and friends) to whole tables of cached fits.
"""

from __future__ import annotations

import math

import numpy as np

from lishield_guard.config import FIT_RHO_FLOOR, PERIODIC_MIN_PERIODS, DetectorConfig

__all__ = ["fit_passes", "fit_rule", "fold_passes", "fold_rule", "grid_passes", "grid_rule",
           "sweep_passes", "tone_check_on", "tone_fit_confirms", "tone_rule"]


def grid_rule(rho, rho_lookalike, coherence_t, det: DetectorConfig):
    """Period-sweep grid fit: rho >= ``sweep_min_rho``, rho beats the stationary look-alike
    by ``sweep_min_margin`` and the column blocks agree (coherence t >= ``sweep_min_coherence``).
    """
    return ((rho >= det.sweep_min_rho) & (rho - rho_lookalike >= det.sweep_min_margin)
            & (coherence_t >= det.sweep_min_coherence))


def fit_rule(rho, gain, coherence_t, n_periods, chroma_leak, det: DetectorConfig):
    """Exact-model fit, with the exact fit enabled and coherence t >= ``sweep_min_coherence``:
    rho and gain reach ``fit_min_rho`` and ``fit_min_gain``; or the frame holds at least
    `config.PERIODIC_MIN_PERIODS` pattern periods and rho and gain reach the ``_periodic``
    thresholds; or (an RGB channel whose colour was measured: ``chroma_leak`` finite, inf
    when not measured) the leak is at most ``fit_max_leak_rgb`` and rho and gain reach the
    ``_rgb`` thresholds."""
    return (det.model_fit & (coherence_t >= det.sweep_min_coherence)
            & (((rho >= det.fit_min_rho) & (gain >= det.fit_min_gain))
               | ((n_periods >= PERIODIC_MIN_PERIODS) & (rho >= det.fit_min_rho_periodic)
                  & (gain >= det.fit_min_gain_periodic))
               | (np.isfinite(chroma_leak) & (chroma_leak <= det.fit_max_leak_rgb)
                  & (rho >= det.fit_min_rho_rgb) & (gain >= det.fit_min_gain_rgb))))


def tone_rule(rho, gain, coherence_t, det: DetectorConfig):
    """Exact-model fit confirming tone tracks: rho >= `config.FIT_RHO_FLOOR`, coherence t >=
    ``sweep_min_coherence`` and gain >= ``tone_min_fit_gain`` (the barcode explains the rows
    better than the best steady square wave)."""
    return ((rho >= FIT_RHO_FLOOR) & (coherence_t >= det.sweep_min_coherence)
            & (gain >= det.tone_min_fit_gain))


def fold_rule(rho, rho_lookalike, fold_snr, det: DetectorConfig):
    """Fold fit: rho >= ``fold_min_rho``, SNR >= ``fold_min_snr`` and rho beats the stationary
    look-alike by ``fold_min_margin``."""
    return ((rho >= det.fold_min_rho) & (fold_snr >= det.fold_min_snr)
            & (rho - rho_lookalike >= det.fold_min_margin))


def grid_passes(info: dict, det: DetectorConfig) -> bool:
    """Whether the sweep's own (binned-grid) fit passes `grid_rule`."""
    return bool(grid_rule(info["rho"], info["rho_lookalike"], info["coherence_t"], det))


def fit_passes(fit: dict | None, det: DetectorConfig) -> bool:
    """Whether an exact-model fit (`fit.ModelFit.to_dict`, or None) passes `fit_rule`."""
    if fit is None:
        return False
    leak = fit.get("chroma_leak")
    return bool(fit_rule(fit["rho"], fit["gain"], fit["coherence_t"], fit["n_periods"],
                         math.inf if leak is None else leak, det))


def sweep_passes(info: dict, det: DetectorConfig) -> bool:
    """Whether a period-sweep fit (`sweep_fits` entry) is evidence enough for protected:
    the grid fit passes `grid_rule`, or its exact-model refinement passes `fit_passes`."""
    return grid_passes(info, det) or fit_passes(info.get("fit"), det)


def fold_passes(info: dict, det: DetectorConfig) -> bool:
    """Whether a fold fit (`fold_fits` entry) passes `fold_rule` (evidence enough for a
    verdict of protected)."""
    return bool(fold_rule(info["rho"], info["rho_lookalike"], info["fold_snr"], det))


def tone_check_on(det: DetectorConfig) -> bool:
    """Whether tone tracks need an exact fit's confirmation (`tone_fit_confirms`): a finite
    ``tone_min_fit_gain`` with the period sweep and the exact fit enabled."""
    return det.tone_min_fit_gain > -math.inf and det.period_sweep and det.model_fit


def tone_fit_confirms(fits: list[dict], det: DetectorConfig) -> bool:
    """Whether one spec's period-sweep entries on one axis confirm its tone tracks: one of them
    has an exact-model fit passing `tone_rule`."""
    return any(f.get("fit") is not None
               and bool(tone_rule(f["fit"]["rho"], f["fit"]["gain"], f["fit"]["coherence_t"], det))
               for f in fits)
