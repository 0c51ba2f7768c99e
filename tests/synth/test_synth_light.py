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
