"""Light sources: exact cumulative integrals checked against dense numerical integration."""

from __future__ import annotations

import numpy as np
import pytest

from firmware.sequence import compile_spec
from lishield_guard.errors import ConfigError
from lishield_guard.spec import PRESETS
from synth.light import (
    MainsFlicker,
    PwmLight,
    SequenceLight,
    SteadyLight,
    coverage_map,
    light_to_rgb,
    row_means,
)


def _numeric_integral(intensity, t0: float, t1: float, n: int = 2_000_001) -> np.ndarray:
    t = np.linspace(t0, t1, n)
    v = intensity(t)
    return np.trapezoid(v, t, axis=0)


def _pwm_intensity(light: PwmLight):
    def f(t):
        r = np.mod(t - light.phase_s, 1 / light.freq_hz) * light.freq_hz
        on = r < light.duty
        return np.where(on, light.on_level, light.off_level)[:, None]
    return f


def _mains_intensity(light: MainsFlicker):
    def f(t):
        s = np.abs(np.sin(2 * np.pi * light.supply_hz * (t - light.phase_s)))
        return (light.mean * ((1 - light.depth) + light.depth * np.pi / 2 * s))[:, None]
    return f


@pytest.mark.parametrize("light", [
    PwmLight(freq_hz=437.0, duty=0.3, depth=0.8, mean=2.0, phase_s=1e-4),
    PwmLight(freq_hz=90.0, duty=0.9, depth=1.0),
    MainsFlicker(supply_hz=50.0, depth=0.6, mean=1.5, phase_s=3e-3),
    MainsFlicker(supply_hz=60.0, depth=1.0),
])
def test_cumulative_matches_numeric_integral(light):
    intensity = _pwm_intensity(light) if isinstance(light, PwmLight) else _mains_intensity(light)
    t0, t1 = 0.0123, 0.0517
    exact = light.cumulative(np.array(t1)) - light.cumulative(np.array(t0))
    num = _numeric_integral(intensity, t0, t1)
    np.testing.assert_allclose(exact, num, rtol=2e-5)


@pytest.mark.parametrize("name", ["table1-seq1", "table2-rgb", "table3-m4"])
def test_sequence_light_is_exact_and_periodic(name):
    seq = compile_spec(PRESETS[name])
    light = SequenceLight(seq)
    starts = seq.step_starts_s()
    lev = seq.levels_unit()
    # At step boundaries the integral is the cumulative sum of level x duration.
    expect = np.concatenate([np.zeros((1, lev.shape[1])),
                             np.cumsum(lev * np.diff(starts)[:, None], axis=0)])
    np.testing.assert_allclose(light.cumulative(starts), expect, atol=1e-15)
    # One period later it has added exactly one period's energy.
    t = np.linspace(0.0, 3 * seq.period_s, 101)
    np.testing.assert_allclose(light.cumulative(t + seq.period_s) - light.cumulative(t),
                               np.broadcast_to(expect[-1], (t.size, lev.shape[1])), atol=1e-13)
    np.testing.assert_allclose(light.mean_level(), expect[-1] / seq.period_s)
    # Inside a step it is linear with the step's level.
    mid = 0.5 * (starts[:-1] + starts[1:])
    d = light.cumulative(mid) - light.cumulative(starts[:-1])
    np.testing.assert_allclose(d, lev * (mid - starts[:-1])[:, None], atol=1e-15)
    assert light.channels == seq.channels


def test_steady_light_and_row_means():
    light = SteadyLight(level=(0.5, 1.0, 2.0), channels=("R", "G", "B"))
    vals = row_means(light, np.arange(5) * 1e-4, 1e-3)
    np.testing.assert_allclose(vals, np.tile([0.5, 1.0, 2.0], (5, 1)))


def test_means_are_the_time_average():
    for light in (PwmLight(freq_hz=300.0, duty=0.25, depth=0.5, mean=3.0),
                  MainsFlicker(supply_hz=60.0, depth=0.7, mean=3.0)):
        period = 1 / (light.freq_hz if isinstance(light, PwmLight) else light.flicker_hz)
        t = np.array([0.01, 0.01 + 7 * period])
        f = light.cumulative(t)
        assert (f[1] - f[0])[0] == pytest.approx(3.0 * 7 * period, rel=1e-12)


def test_light_to_rgb_maps_channels():
    np.testing.assert_array_equal(light_to_rgb(np.array([[2.0]]), ("W",)), [[2.0, 2.0, 2.0]])
    np.testing.assert_array_equal(light_to_rgb(np.array([[1.0, 2.0, 3.0]]), ("B", "R", "G")),
                                  [[2.0, 3.0, 1.0]])
    with pytest.raises(ConfigError, match="channel"):
        light_to_rgb(np.array([[1.0]]), ("X",))


@pytest.mark.parametrize("fraction,centre", [(0.3, (0.5, 0.5)), (0.6, (0.1, 0.9)),
                                             (0.8, (1.2, 0.3))])
def test_coverage_map_fraction_and_smoothness(fraction, centre):
    m = coverage_map(240, 320, fraction=fraction, centre_rc=centre, softness=0.2)
    assert m.shape == (240, 320) and m.dtype == np.float32
    assert 0.0 <= m.min() and m.max() <= 1.0
    assert m.mean() == pytest.approx(fraction, abs=0.02)
    assert np.abs(np.diff(m, axis=0)).max() < 0.05  # smooth falloff, no hard edge
    assert np.all(coverage_map(10, 12, fraction=1.0) == 1.0)


@pytest.mark.parametrize("kw,match", [
    ({"freq_hz": 0.0}, "freq_hz"), ({"freq_hz": 100.0, "duty": 0.0}, "duty"),
    ({"freq_hz": 100.0, "depth": 1.5}, "depth"),
])
def test_bad_pwm_parameters(kw, match):
    with pytest.raises(ConfigError, match=match):
        PwmLight(**kw)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="supply_hz"):
        MainsFlicker(supply_hz=-50.0)
    with pytest.raises(ConfigError, match="fraction"):
        coverage_map(10, 10, fraction=0.0)
    with pytest.raises(ConfigError, match="exposure_s"):
        row_means(SteadyLight(), np.zeros(3), 0.0)


# ---------------------------------------------------------------------- finite rise and fall
def _ramped_sequence(rise_frac: float = 0.05):
    import dataclasses
    import warnings

    spec = dataclasses.replace(PRESETS["table2-rgb"], switching_hz=200.0, phase="continuous",
                               order=(2, 0, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = compile_spec(spec, clock_hz=16_000_000, allow=("flicker",))
    rise_s = rise_frac * 0.5 / spec.all_freqs_hz[-1]  # of the shortest half-period
    return seq, rise_s


@pytest.mark.parametrize("rise_frac", [0.01, 0.05])
def test_rise_time_row_means_match_brute_force(rise_frac):
    seq, rise_s = _ramped_sequence(rise_frac)
    ideal = SequenceLight(seq, phase_s=0.0123)
    ramped = SequenceLight(seq, phase_s=0.0123, rise_s=rise_s)
    exposure_s = 1 / 20_000
    starts = np.random.default_rng(3).uniform(0.0, 2.0, 6)
    got = row_means(ramped, starts, exposure_s)
    for i, t0 in enumerate(starts):
        # brute force: output = driven wave averaged over the preceding rise_s, then a dense
        # trapezoid over the exposure (the output is piecewise linear, so this converges fast)
        t = np.linspace(t0, t0 + exposure_s, 40_001)
        out = (ideal.cumulative(t) - ideal.cumulative(t - rise_s)) / rise_s
        want = np.trapezoid(out, t, axis=0) / exposure_s
        np.testing.assert_allclose(got[i], want, atol=1e-7)
    # the ramp visibly changes short exposures, and never the time average
    assert np.abs(got - row_means(ideal, starts, exposure_s)).max() > 1e-3
    np.testing.assert_allclose(ramped.mean_level(), ideal.mean_level(), rtol=1e-12)
    period = ramped.period_s
    np.testing.assert_allclose(ramped.cumulative(np.array([1000 * period]))[0],
                               1000 * period * ideal.mean_level(), rtol=1e-9)


def test_rise_time_intensity_is_a_linear_ramp():
    seq, rise_s = _ramped_sequence(0.05)
    ramped = SequenceLight(seq, rise_s=rise_s)
    edge = seq.step_starts_s()[1]  # a change of some channel
    t = edge + np.array([-0.1, 0.25, 0.5, 0.75, 1.1]) * rise_s
    lv = ramped.intensity(t)
    before, after = SequenceLight(seq).intensity(t[[0, -1]])
    changed = before != after
    assert changed.any()
    frac = (lv[1:4] - before) / np.where(changed, after - before, 1.0)
    np.testing.assert_allclose(frac[:, changed], np.array([[0.25], [0.5], [0.75]])
                               * np.ones((1, int(changed.sum()))), atol=1e-6)
    np.testing.assert_allclose(lv[[0, -1]], np.stack([before, after]), atol=1e-9)
    assert SequenceLight(seq, rise_s=0.0).rise_s == 0.0


@pytest.mark.parametrize("rise_s", [-1e-6, float("nan"), 1.0])
def test_bad_rise_time(rise_s):
    seq, _ = _ramped_sequence()
    with pytest.raises(ConfigError, match="rise_s"):
        SequenceLight(seq, rise_s=rise_s)
