"""The pass rules against fixed expected verdicts and a literal restatement of each.

Detection (`rules.sweep_passes`, `fold_passes`, `tone_fit_confirms`) and calibration's table
form (`calibrate.sweep_protected`, `fold_protected`, `tone_confirmed`) both call the rule
functions of detector/rules.py (`grid_rule`, `fit_rule`, `fold_rule`, `tone_rule`), so comparing
the two forms with each other cannot catch a rule changed in that one place. Each form is checked
here against (a) hand-computed verdicts at and around every threshold and (b) the rules
written out below in plain Python (`_grid`, `_fit`, `_tone`, `_fold`), not imported.

Catches: the look-alike margin dropped from `grid_rule` or `fold_rule`, a gain term dropped
from a `fit_rule` path or from `tone_rule`, a ``>=`` turned into ``>``, a coherence or SNR
term lost, and the two forms drifting apart.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from lishield_guard.calibration import fold_protected, sweep_protected, sweep_row, tone_confirmed
from lishield_guard.config import (
    FIT_RHO_FLOOR,
    PERIODIC_MIN_PERIODS,
    DetectorConfig,
    FitConfig,
    FoldConfig,
    SweepConfig,
    ToneConfig,
)
from lishield_guard.detector.results import FoldMatch, FoldResult, SweepMatch, SweepResult
from lishield_guard.detector.rules import fold_passes, sweep_passes, tone_fit_confirms

# The two constants the rules use, restated: the literal rules below use these numbers.
TONE_RHO_FLOOR = 0.8  # config.FIT_RHO_FLOOR
PERIODIC_PERIODS = 2.0  # config.PERIODIC_MIN_PERIODS


def test_rule_constants_are_the_restated_ones():
    """The literal rules below are written for these constants; a change must be deliberate."""
    assert (FIT_RHO_FLOOR, PERIODIC_MIN_PERIODS) == (TONE_RHO_FLOOR, PERIODIC_PERIODS)


# ------------------------------------------------------------------ the rules, written out

def _grid(s: dict, det: DetectorConfig) -> bool:
    return (det.sweep is not None and s["rho"] >= det.sweep.min_rho
            and s["rho"] - s["rho_lookalike"] >= det.sweep.min_margin
            and s["coherence_t"] >= det.sweep.min_coherence)


def _fit(fit: dict | None, det: DetectorConfig) -> bool:
    if (fit is None or det.fit is None or det.sweep is None
            or fit["coherence_t"] < det.sweep.min_coherence):
        return False
    rho, gain, leak = fit["rho"], fit["gain"], fit["chroma_leak"]
    if rho >= det.fit.min_rho and gain >= det.fit.min_gain:
        return True
    if (fit["n_periods"] >= PERIODIC_PERIODS and det.fit.min_gain_periodic is not None
            and rho >= det.fit.min_rho_periodic and gain >= det.fit.min_gain_periodic):
        return True
    # an unmeasured leak (None: a mono plane) never takes the colour-verified path, nor any
    # fit when the path is off (max_leak_rgb None)
    return (leak is not None and det.fit.max_leak_rgb is not None
            and leak <= det.fit.max_leak_rgb and rho >= det.fit.min_rho_rgb
            and gain >= det.fit.min_gain_rgb)


def _sweep(s: dict, det: DetectorConfig) -> bool:
    return _grid(s, det) or _fit(s.get("fit"), det)


def _tone(fit: dict | None, det: DetectorConfig) -> bool:
    return (fit is not None and fit["rho"] >= TONE_RHO_FLOOR
            and fit["coherence_t"] >= det.sweep.min_coherence
            and fit["gain"] >= det.tones.min_fit_gain)


def _fold(rho: float, rho_lookalike: float, snr: float, det: DetectorConfig) -> bool:
    return (rho >= det.fold.min_rho and snr >= det.fold.min_snr
            and rho - rho_lookalike >= det.fold.min_margin)


# ------------------------------------------------------------- hand-computed verdicts

# Thresholds are dyadic fractions, so each tie below is exact in binary floating point
# (0.875 - 0.625 == 0.25 exactly; 0.9 - 0.6 is not 0.3).
DET = DetectorConfig(
    sweep=SweepConfig(min_rho=0.75, min_margin=0.25, min_coherence=4.0),
    fit=FitConfig(min_rho=0.875, min_gain=8.0, min_rho_periodic=0.9375, min_gain_periodic=1.0,
                  min_rho_rgb=0.8125, min_gain_rgb=2.0, max_leak_rgb=0.25),
    tones=ToneConfig(min_fit_gain=0.5),
    fold=FoldConfig(min_rho=0.875, min_snr=32.0, min_margin=0.0625))


def _ids(cases) -> list[str]:
    return [re.sub(r"[^a-z0-9_.]+", "-", c[0].lower()).strip("-") for c in cases]


def _info(rho=0.0, la=0.0, t=0.0, fit=None) -> dict:
    return {"rho": rho, "rho_lookalike": la, "coherence_t": t, "fit": fit}


def _fold_result(rho: float, rho_lookalike: float, snr: float) -> FoldResult:
    """The typed fold result detection judges, with these numbers."""
    match = FoldMatch("x", rho, period_rows=100.0, cycles_f1=1.0, fold_snr=snr, n_periods=3.0,
                      rho_lookalike=rho_lookalike)
    return FoldResult(match, rho, rho_lookalike, snr, 1, "")


def _entry(info: dict) -> SweepResult:
    """The typed sweep entry detection judges, carrying ``info``'s numbers. Its fit is a
    stand-in with the attributes the rules read: a `ModelFit` derives its gain from rho and
    the look-alike's rho, and these tables set the gain on its own."""
    match = SweepMatch("x", info["rho"], info["rho_lookalike"], period_rows=100.0,
                       cycles_f1=1.0, exposure_slots=0.0, coherence_t=info["coherence_t"],
                       n_periods=1.0)
    fit = None if info["fit"] is None else SimpleNamespace(**info["fit"])
    return SweepResult(match, "W", "", fit=fit)


def _f(rho=0.0, gain=0.0, t=0.0, periods=1.0, leak=None) -> dict:
    return {"rho": rho, "gain": gain, "coherence_t": t, "n_periods": periods,
            "chroma_leak": leak}


# (name, sweep entry, expected verdict of sweep_passes with DET)
SWEEP_CASES = [
    ("grid: every term at its tie", _info(0.75, 0.5, 4.0), True),
    ("grid: rho just below sweep_min_rho", _info(0.74, 0.0, 40.0), False),
    ("grid: look-alike 0.625 leaves margin 0.25 (tie)", _info(0.875, 0.625, 10.0), True),
    # the look-alike defence: a high grid rho that a steady square wave fits nearly as well
    ("grid: look-alike eats the margin (PWM-like rows)", _info(0.875, 0.75, 40.0), False),
    ("grid: look-alike above the fit", _info(0.8125, 0.9375, 40.0), False),
    ("grid: coherence just below", _info(0.875, 0.0, 3.99), False),
    ("fit: rho and gain at fit_min_rho / fit_min_gain (tie)", _info(fit=_f(0.875, 8.0, 4.0)),
     True),
    ("fit: gain just below fit_min_gain", _info(fit=_f(0.96875, 7.99, 40.0)), False),
    ("fit: rho just below fit_min_rho", _info(fit=_f(0.87, 100.0, 40.0)), False),
    ("fit: coherence just below", _info(fit=_f(0.96875, 100.0, 3.99)), False),
    # the look-alike defence of the exact fit: a negative gain (the steady square wave fits
    # better than the barcode) fails every path, however high the fit's own rho
    ("fit: negative gain, every path open but gain", _info(fit=_f(0.96875, -0.5, 40.0, 4.0,
                                                                  0.0)), False),
    ("periodic: two periods, tie on rho and gain", _info(fit=_f(0.9375, 1.0, 4.0, 2.0)), True),
    ("periodic: 1.99 periods", _info(fit=_f(0.9375, 1.0, 40.0, 1.99)), False),
    ("periodic: gain just below", _info(fit=_f(0.9375, 0.99, 40.0, 4.0)), False),
    ("periodic: rho just below", _info(fit=_f(0.93, 7.0, 40.0, 4.0)), False),
    ("rgb: leak, rho and gain at their ties", _info(fit=_f(0.8125, 2.0, 4.0, 1.0, 0.25)), True),
    ("rgb: leak just over", _info(fit=_f(0.8125, 2.0, 40.0, 1.0, 0.26)), False),
    ("rgb: unmeasured leak never takes the path", _info(fit=_f(0.8125, 7.0, 40.0, 1.0, None)),
     False),
    ("rgb: gain just below", _info(fit=_f(0.85, 1.99, 40.0, 1.0, 0.0)), False),
    ("rgb: rho just below", _info(fit=_f(0.81, 7.0, 40.0, 1.0, 0.0)), False),
    ("grid fails, fit passes: either suffices",
     _info(0.875, 0.75, 40.0, _f(0.875, 8.0, 40.0)), True),
]


@pytest.mark.parametrize("info, expected", [c[1:] for c in SWEEP_CASES],
                         ids=_ids(SWEEP_CASES))
def test_sweep_rule_fixed_verdicts(info, expected):
    """Detection's and calibration's form of the sweep rule give the hand-computed verdict."""
    assert _sweep(info, DET) is expected  # the restatement itself is right
    assert sweep_passes(_entry(info), DET) is expected
    assert bool(sweep_protected([np.array([sweep_row(_entry(info), 0)])], DET)[0]) is expected


def test_sweep_rule_without_exact_fit():
    """The fit off (``fit = false``): no exact-model fit decides, however good (grid fits
    still do)."""
    det = DET.replace(fit=None)
    fit_only = _entry(_info(fit=_f(0.96875, 100.0, 40.0, 4.0, 0.0)))
    assert not sweep_passes(fit_only, det)
    assert not sweep_protected([np.array([sweep_row(fit_only, 0)])], det)[0]
    grid = _entry(_info(0.875, 0.0, 40.0))
    assert sweep_passes(grid, det) and sweep_protected([np.array([sweep_row(grid, 0)])], det)[0]


# (name, fit, expected verdict of tone_fit_confirms with DET)
TONE_CASES = [
    ("floor, coherence and gain at their ties", _f(0.8, 0.5, 4.0), True),
    ("rho just below the 0.8 floor", _f(0.79, 50.0, 40.0), False),
    ("coherence just below", _f(0.96875, 50.0, 3.99), False),
    # the look-alike defence of tone tracks: a PWM tone that jitters reads as two tones, and
    # no fit of the barcode explains the rows better than a steady square wave
    ("gain just below tone_min_fit_gain", _f(0.96875, 0.49, 40.0), False),
    ("negative gain: the look-alike fits better", _f(0.96875, -0.9, 40.0), False),
    ("no exact fit", None, False),
]


@pytest.mark.parametrize("fit, expected", [c[1:] for c in TONE_CASES],
                         ids=_ids(TONE_CASES))
def test_tone_rule_fixed_verdicts(fit, expected):
    """`tone_fit_confirms` and `tone_confirmed` give the hand-computed verdict."""
    entry = _entry(_info(fit=fit))
    assert _tone(fit, DET) is expected
    assert tone_fit_confirms([entry], DET) is expected
    assert bool(tone_confirmed([np.array([sweep_row(entry, 0)])], 1, DET)[0, 0]) is expected


# (name, (rho, rho_lookalike, fold_snr), expected verdict of fold_passes with DET)
FOLD_CASES = [
    ("every term at its tie", (0.875, 0.8125, 32.0), True),
    ("rho just below", (0.87, 0.0, 100.0), False),
    ("snr just below", (0.96875, 0.0, 31.9), False),
    # the look-alike defence of folding
    ("look-alike leaves less than the margin", (0.96875, 0.9375, 100.0), False),
    ("look-alike above the fit", (0.9375, 0.96875, 100.0), False),
]


@pytest.mark.parametrize("fold, expected", [c[1:] for c in FOLD_CASES],
                         ids=_ids(FOLD_CASES))
def test_fold_rule_fixed_verdicts(fold, expected):
    """`fold_passes` and `fold_protected` give the hand-computed verdict."""
    rho, la, snr = fold
    assert _fold(rho, la, snr, DET) is expected
    assert fold_passes(_fold_result(rho, la, snr), DET) is expected
    assert bool(fold_protected([np.array([fold], dtype=float)], DET)[0]) is expected


# ------------------------------------------------- the literal rules over random settings

# Values on and around the thresholds, so that ties (>=) and both sides of each are drawn.
RHO = st.sampled_from([0.0, 0.5, 0.8, 0.85, 0.9, 0.95, 1.0])
FIT_MIN_RHO = st.sampled_from(sorted({FIT_RHO_FLOOR, 0.85, 0.9, 0.95, 1.0}))
GAIN = st.sampled_from([-1.0, 0.0, 1.0, 3.0, 5.0, 8.0, 20.0, math.inf])
COHERENCE = st.sampled_from([0.0, 2.9, 3.0, 10.0])
PERIODS = st.sampled_from([0.5, PERIODIC_MIN_PERIODS - 0.01, PERIODIC_MIN_PERIODS, 4.0])
LEAK = st.sampled_from([None, 0.0, 0.15, 0.3, 0.31, 2.0])

FIT = st.none() | st.fixed_dictionaries({
    "rho": RHO, "gain": GAIN, "coherence_t": COHERENCE, "n_periods": PERIODS,
    "chroma_leak": LEAK})
SWEEP = st.fixed_dictionaries({"rho": RHO, "rho_lookalike": RHO, "coherence_t": COHERENCE,
                               "fit": FIT})
SWEEPS = st.builds(SweepConfig, min_rho=RHO, min_margin=st.sampled_from([0.0, 0.05, 0.2]),
                   min_coherence=st.sampled_from([0.0, 3.0]))
FITS = st.none() | st.builds(
    FitConfig, min_rho=FIT_MIN_RHO, min_gain=GAIN,
    min_rho_periodic=FIT_MIN_RHO, min_gain_periodic=st.none() | GAIN,
    min_rho_rgb=FIT_MIN_RHO, min_gain_rgb=GAIN,
    # inf included: an unmeasured leak must not pass even with no leak limit
    max_leak_rgb=st.sampled_from([None, 0.0, 0.3, math.inf]))
DETS = st.builds(
    DetectorConfig, sweep=SWEEPS, fit=FITS,
    tones=st.builds(ToneConfig, min_fit_gain=st.sampled_from([None, 0.0, 0.5, 3.0])),
)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(sweeps=st.lists(SWEEP, min_size=1, max_size=3), det=DETS)
@example(sweeps=[_info(0.9, 0.8, 10.0)], det=DetectorConfig(sweep=SweepConfig(min_margin=0.2)))
def test_sweep_forms_equal_the_literal_rule(sweeps, det):
    """Protected exactly when the literal rule passes one of the fits, in both forms; tone
    tracks confirmed exactly when the literal tone rule passes one."""
    expected = any(_sweep(s, det) for s in sweeps)
    entries = [_entry(s) for s in sweeps]
    assert any(sweep_passes(e, det) for e in entries) is expected
    table = np.array([sweep_row(e, candidate=0) for e in entries], dtype=float)
    assert bool(sweep_protected([table], det)[0]) is expected
    det_on = det.replace(fit=det.fit or FitConfig())
    if det_on.tones.min_fit_gain is not None:
        confirmed = any(_tone(s["fit"], det_on) for s in sweeps)
        assert tone_fit_confirms(entries, det_on) is confirmed
        assert bool(tone_confirmed([table], 1, det_on)[0, 0]) is confirmed


@settings(max_examples=100, deadline=None, derandomize=True)
@given(folds=st.lists(st.tuples(RHO, RHO, st.sampled_from([0.0, 3.0, 6.0, 12.0])),
                      min_size=1, max_size=3),
       min_rho=RHO, min_snr=st.sampled_from([0.0, 6.0]), margin=st.sampled_from([0.0, 0.1]))
def test_fold_forms_equal_the_literal_rule(folds, min_rho, min_snr, margin):
    """`fold_passes` and `fold_protected` agree with the literal fold rule on every fit."""
    det = DetectorConfig(fold=FoldConfig(min_rho=min_rho, min_snr=min_snr, min_margin=margin))
    expected = any(_fold(r, a, s, det) for r, a, s in folds)
    assert any(fold_passes(_fold_result(r, a, s), det)
               for r, a, s in folds) is expected
    assert bool(fold_protected([np.array(folds, dtype=float)], det)[0]) is expected


def test_unmeasured_leak_never_takes_the_rgb_path():
    """The corner where the two copies once differed: a fit with no measured chroma leak
    (a mono plane) fails the RGB path even when the leak limit is off."""
    det = DetectorConfig(fit=FitConfig(min_rho=1.0, min_gain=math.inf, min_rho_rgb=0.8,
                                       min_gain_rgb=3.0, max_leak_rgb=math.inf),
                         sweep=SweepConfig(min_rho=1.0))
    fit = {"rho": 0.9, "gain": 5.0, "coherence_t": 10.0, "n_periods": 1.0, "chroma_leak": None}
    info = {"rho": 0.0, "rho_lookalike": 0.0, "coherence_t": 10.0, "fit": fit}
    assert not sweep_passes(_entry(info), det)
    assert not sweep_protected([np.array([sweep_row(_entry(info))])], det)[0]
    measured = {**info, "fit": {**fit, "chroma_leak": 0.5}}
    assert sweep_passes(_entry(measured), det)
    assert sweep_protected([np.array([sweep_row(_entry(measured))])], det)[0]
