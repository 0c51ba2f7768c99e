"""Period sweep: barcodes with under two periods in the frame, look-alikes, block coherence."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from core_led_model import row_waveform

from lishield_guard import PRESETS
from lishield_guard.detector.fold import fold_match
from lishield_guard.detector.sweep import sweep_match

SCALE = (1 / 120_000, 4 / 30_000)  # cycles per row per Hz: the shipped row-rate range
N_ROWS = 1080
N_BLOCKS = 8


def _blocks(common: np.ndarray, rng, *, texture: float = 0.0, noise: float = 0.002):
    """Column blocks = the common LED log signal + each block's own scene and noise."""
    out = np.empty((N_BLOCKS, common.size))
    rows = np.arange(common.size)
    for b in range(N_BLOCKS):
        scene = texture * np.sin(2 * np.pi * rows / rng.uniform(150, 600) + rng.uniform(0, 6))
        out[b] = common + scene + rng.normal(0, noise, common.size)
    return out


def _led(spec, *, rate_hz, f_b, exposure_s=1 / 8000, depth=0.05, t0_s=0.0):
    w = row_waveform(spec, row_time_s=1 / rate_hz, n_rows=N_ROWS, exposure_s=exposure_s,
                     switching_hz=f_b, t0_s=t0_s)
    return {c: np.log1p(depth * (v - v.mean())) for c, v in w.items()}


def _sweep(blocks, spec, channel="W"):
    return sweep_match(blocks, [(spec, channel)], period_range_rows=[(8.0, 2000.0)],
                       scale_range_cpr_per_hz=SCALE)[0]


@pytest.mark.parametrize("name, f_b, rate, t0", [("table1-seq1", 300.0, 100_000, 0.0),
                                                 ("table1-seq1", 260.0, 70_000, 3e-3),
                                                 ("table1-seq2", 330.0, 110_000, 1e-3),
                                                 ("table1-seq3", 600.0, 120_000, 2e-3)])
def test_barcode_under_two_periods_is_found(rng, name, f_b, rate, t0):
    spec = PRESETS[name]
    x = _led(spec, rate_hz=rate, f_b=f_b, t0_s=t0)["W"]
    period = spec.n_tones / f_b * rate
    assert N_ROWS / period < 2.0  # nothing to fold on
    fm = fold_match(x, spec, "W", period_range_rows=(8, 2000))
    assert fm is None or abs(fm.period_rows / period - 1) > 0.05  # folding cannot see it
    m = _sweep(_blocks(x, rng, texture=0.01), spec)
    assert abs(m.period_rows / period - 1) < 0.02, m
    assert abs(m.cycles_f1 - spec.f1_hz / f_b) < 0.12, m
    assert m.rho > 0.9 and m.rho - m.rho_lookalike > 0.2, m
    assert m.coherence_t > 10, m
    assert abs(m.switching_hz / f_b - 1) < 0.1 and abs(m.row_rate_hz / rate - 1) < 0.1, m


def test_long_exposure_still_fits(rng):
    spec = PRESETS["table1-seq1"]
    f_b, rate = 300.0, 90_000
    x = _led(spec, rate_hz=rate, f_b=f_b, exposure_s=0.6 / f_b)["W"]  # 0.6 slot per row
    m = _sweep(_blocks(x, rng), spec)
    assert abs(m.period_rows / (3 / f_b * rate) - 1) < 0.02, m
    assert m.rho > 0.9, m


def test_stationary_pwm_is_explained_by_the_lookalike(rng):
    rows = np.arange(N_ROWS)
    x = 0.05 * (((rows / 187.3) % 1.0) < 0.4)
    m = _sweep(_blocks(x - x.mean(), rng), PRESETS["table1-seq1"])
    assert m.rho - m.rho_lookalike < 0.1, m


def test_scene_content_is_not_coherent_across_blocks(rng):
    """Structure that differs between column blocks is scene, whatever it fits."""
    blocks = _blocks(np.zeros(N_ROWS), rng, texture=0.03)
    m = _sweep(blocks, PRESETS["table1-seq1"])
    assert m.coherence_t < 3, m


def test_a_target_does_not_depend_on_its_neighbours(rng):
    spec, other = PRESETS["table1-seq1"], PRESETS["table1-seq3"]
    blocks = _blocks(_led(spec, rate_hz=90_000, f_b=280.0)["W"], rng, texture=0.01)
    alone = _sweep(blocks, spec)
    shared = sweep_match(blocks, [(other, "W"), (spec, "W")],
                         period_range_rows=[(8.0, 2000.0), (8.0, 2000.0)],
                         scale_range_cpr_per_hz=SCALE)[1]
    assert alone == shared


def test_rgb_channel_fits_on_its_own_plane(rng):
    spec = PRESETS["table2-rgb"]
    planes = _led(spec, rate_hz=80_000, f_b=250.0)
    m = _sweep(_blocks(planes["R"], rng), spec, "R")
    assert m.rho > 0.9 and abs(m.period_rows / (3 / 250 * 80_000) - 1) < 0.02, m


@pytest.mark.parametrize("shape", [(8, 4), (1, 1080), (8, 1080)])
def test_degenerate_inputs(shape):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = sweep_match(np.zeros(shape), [(PRESETS["table1-seq1"], "W")],
                          period_range_rows=[(8.0, 2000.0)], scale_range_cpr_per_hz=SCALE)
    assert out == [None]


def test_impossible_period_range_gives_none(rng):
    blocks = _blocks(np.zeros(N_ROWS), rng, texture=0.01)
    out = sweep_match(blocks, [(PRESETS["table1-seq1"], "W")], period_range_rows=[(8.0, 100.0)],
                      scale_range_cpr_per_hz=SCALE)
    assert out == [None]  # periods under n_rows / 4 are folding's job


@pytest.mark.parametrize("n_rows", [64, 128, 300])
def test_small_frames_give_bounded_correlations(rng, n_rows):
    """Sparse phase bins once made float32 variances cancel to ~0 and rho explode."""
    for name in ("table1-seq1", "table1-seq3"):
        m = sweep_match(rng.normal(size=(8, n_rows)), [(PRESETS[name], "W")],
                        period_range_rows=[(4.0, 1500.0)], scale_range_cpr_per_hz=SCALE)[0]
        assert m is not None and -1 <= m.rho_lookalike <= 1 and -1 <= m.rho <= 1, m


def test_refinement_stays_inside_the_period_range(rng):
    """Periods far above the frame once refined to negative periods (a crash in detect)."""
    from lishield_guard import DetectorConfig, detect

    img = rng.integers(0, 256, (64, 200), dtype=np.uint8)
    det = DetectorConfig().with_values({"profiles.max_row_rate_hz": 200_000.0})
    assert not detect(img, det).protected


def test_fit_periods_leave_two_slots_in_the_frame():
    """A small crop holds a fraction of a pattern: a smooth curve anything fits. Sweep and
    exact fit only try periods that leave two slots (two tones) in the frame."""
    from lishield_guard import default_config
    from lishield_guard.detector.search import (
        MIN_SLOTS_IN_FRAME,
        _frame_period_range,
        _period_range_rows,
    )

    det = default_config().detector
    spec = PRESETS["table1-seq1"]
    lo, hi = _period_range_rows(spec, det)
    assert _frame_period_range(spec, det, 100_000) == (lo, hi)  # tall frames: physics only
    n_rows = 278
    f_lo, f_hi = _frame_period_range(spec, det, n_rows)
    assert f_lo == lo and f_hi == pytest.approx(n_rows * spec.n_tones / MIN_SLOTS_IN_FRAME)
    assert n_rows / f_hi * spec.n_tones == pytest.approx(2.0)
