"""Calibration's table form of the pass rules gives the same verdict as detection's, fit by fit."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lishield_guard.calibrate import fold_protected, sweep_protected, sweep_row, tone_confirmed
from lishield_guard.config import FIT_RHO_FLOOR, PERIODIC_MIN_PERIODS, DetectorConfig
from lishield_guard.detect import fold_passes, sweep_passes, tone_fit_confirms

# Values on and around the thresholds, so that ties (>=) and both sides of each are drawn.
RHO = st.sampled_from([0.0, 0.5, 0.8, 0.85, 0.9, 0.95, 1.0])
FIT_MIN_RHO = st.sampled_from(sorted({FIT_RHO_FLOOR, 0.85, 0.9, 0.95, 1.0}))
GAIN = st.sampled_from([0.0, 1.0, 3.0, 5.0, 8.0, 20.0, math.inf])
COHERENCE = st.sampled_from([0.0, 2.9, 3.0, 10.0])
PERIODS = st.sampled_from([0.5, PERIODIC_MIN_PERIODS - 0.01, PERIODIC_MIN_PERIODS, 4.0])
LEAK = st.sampled_from([None, 0.0, 0.15, 0.3, 0.31, 2.0])

FIT = st.none() | st.fixed_dictionaries({
    "rho": RHO, "gain": GAIN, "coherence_t": COHERENCE, "n_periods": PERIODS,
    "chroma_leak": LEAK})
SWEEP = st.fixed_dictionaries({"rho": RHO, "rho_lookalike": RHO, "coherence_t": COHERENCE,
                               "fit": FIT})
DET = st.builds(
    DetectorConfig,
    model_fit=st.booleans(),
    sweep_min_rho=RHO, sweep_min_margin=st.sampled_from([0.0, 0.05, 0.2]),
    sweep_min_coherence=st.sampled_from([0.0, 3.0]),
    fit_min_rho=FIT_MIN_RHO, fit_min_gain=GAIN,
    fit_min_rho_periodic=FIT_MIN_RHO, fit_min_gain_periodic=GAIN,
    fit_min_rho_rgb=FIT_MIN_RHO, fit_min_gain_rgb=GAIN,
    # inf included: an unmeasured leak must not pass even with no leak limit
    fit_max_leak_rgb=st.sampled_from([0.0, 0.3, math.inf]),
    tone_min_fit_gain=st.sampled_from([-math.inf, 0.0, 0.5, 3.0]),
)


@settings(max_examples=300, deadline=None)
@given(sweeps=st.lists(SWEEP, min_size=1, max_size=3), det=DET)
def test_sweep_table_rule_agrees_with_detection(sweeps, det):
    """`calibrate.sweep_protected` over cached rows says protected exactly when
    `detect.sweep_passes` passes one of the fits, and `tone_confirmed` exactly when
    `detect.tone_fit_confirms` confirms them."""
    table = np.array([sweep_row(s, candidate=0) for s in sweeps], dtype=float)
    expected = any(sweep_passes(s, det) for s in sweeps)
    assert bool(sweep_protected([table], det)[0]) is expected
    det_on = det.replace(model_fit=True, period_sweep=True)
    if det_on.tone_min_fit_gain > -math.inf:
        assert bool(tone_confirmed([table], 1, det_on)[0, 0]) is tone_fit_confirms(sweeps, det_on)


@settings(max_examples=100, deadline=None)
@given(folds=st.lists(st.tuples(RHO, RHO, st.sampled_from([0.0, 3.0, 6.0, 12.0])),
                      min_size=1, max_size=3),
       min_rho=RHO, min_snr=st.sampled_from([0.0, 6.0]), margin=st.sampled_from([0.0, 0.1]))
def test_fold_table_rule_agrees_with_detection(folds, min_rho, min_snr, margin):
    """`calibrate.fold_protected` agrees with `detect.fold_passes` on every fold fit."""
    det = DetectorConfig(fold_min_rho=min_rho, fold_min_snr=min_snr, fold_min_margin=margin)
    expected = any(fold_passes({"rho": r, "rho_lookalike": a, "fold_snr": s}, det)
                   for r, a, s in folds)
    assert bool(fold_protected([np.array(folds, dtype=float)], det)[0]) is expected


def test_unmeasured_leak_never_takes_the_rgb_path():
    """The corner where the two copies once differed: a fit with no measured chroma leak
    (a mono plane) fails the RGB path even when the leak limit is off."""
    det = DetectorConfig(fit_min_rho=1.0, fit_min_gain=math.inf, fit_min_rho_rgb=0.8,
                         fit_min_gain_rgb=3.0, fit_max_leak_rgb=math.inf, sweep_min_rho=1.0)
    fit = {"rho": 0.9, "gain": 5.0, "coherence_t": 10.0, "n_periods": 1.0, "chroma_leak": None}
    info = {"rho": 0.0, "rho_lookalike": 0.0, "coherence_t": 10.0, "fit": fit}
    assert not sweep_passes(info, det)
    assert not sweep_protected([np.array([sweep_row(info)])], det)[0]
    measured = {**info, "fit": {**fit, "chroma_leak": 0.5}}
    assert sweep_passes(measured, det)
    assert sweep_protected([np.array([sweep_row(measured)])], det)[0]
