"""Pattern folding: period recovery, template fit, and look-alikes losing to the stationary fit."""

from __future__ import annotations

import numpy as np
import pytest
from core_led_model import row_waveform

from lishield_guard import PRESETS
from lishield_guard.detector.fold import candidate_periods, fold, fold_match, refine_period


def _profile(spec, *, row_rate_hz, switching_hz, n_rows=1200, rng=None, depth=0.05):
    w = row_waveform(spec, row_time_s=1 / row_rate_hz, n_rows=n_rows, exposure_s=1 / 8000,
                     switching_hz=switching_hz)["W"]
    x = np.log1p(depth * (w - w.mean()))
    if rng is not None:
        x = x + rng.normal(0, depth * 0.1, n_rows)
    return x


@pytest.mark.parametrize("name, f_b, rate", [("table1-seq1", 400, 60_000),
                                             ("table1-seq2", 1000, 60_000),
                                             ("table1-seq2", 500, 45_000)])
def test_period_and_template_recovered(rng, name, f_b, rate):
    spec = PRESETS[name]
    x = _profile(spec, row_rate_hz=rate, switching_hz=f_b, rng=rng)
    true_period = spec.n_tones / f_b * rate
    periods = candidate_periods(x, min_rows=8, max_rows=600)
    assert any(abs(p / true_period - 1) < 0.02 for p in periods)
    m = fold_match(x, spec, "W", period_range_rows=(8, 600), periods=periods)
    assert abs(m.period_rows / true_period - 1) < 0.005
    assert m.rho > 0.9
    assert m.rho - m.rho_lookalike > 0.1
    assert abs(m.cycles_f1 - spec.f1_hz / f_b) < 0.1


def test_pwm_fold_prefers_the_stationary_model(rng):
    rows = np.arange(1200)
    x = 0.05 * (((rows / 37.3) % 1.0) < 0.4) + rng.normal(0, 0.002, rows.size)
    m = fold_match(x, PRESETS["table1-seq2"], "W", period_range_rows=(8, 600))
    assert m is None or m.rho - m.rho_lookalike < 0.1


def test_fold_of_exact_repeat_has_no_within_scatter():
    t = np.linspace(0, 1, 50, endpoint=False)  # content at 3 and 5 cycles per period, like a
    x = np.tile(np.sin(6 * np.pi * t) + 0.5 * np.sin(10 * np.pi * t), 8)  # barcode's slots
    means, counts, within = fold(x, 50.0, n_bins=50)
    assert within < 0.05 * x.var()  # rows on a bin edge may land one bin over
    assert counts.sum() == x.size
    assert abs(refine_period(x, 50.4) - 50.0) < 0.2
