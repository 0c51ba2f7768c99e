"""Sequence compiler: exact timing, achieved frequencies, refusal, intensity randomization."""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from firmware.sequence import Sequence, achieved_report, compile_spec
from lishield_guard.errors import FirmwareError, SpecError
from lishield_guard.spec import PRESETS, BarcodeSpec, SpecWarning

RANDOMIZED = dataclasses.replace(PRESETS["table2-rgb"], name="rgb-k4", intensity_levels=4)
SEED = b"venue-secret-7f3a"


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_compile_exactly_at_1mhz(name):
    spec = PRESETS[name]
    seq = compile_spec(spec)
    # M / f_B is a whole number of microseconds for every preset: exact period.
    period = Fraction(spec.n_tones) / Fraction(spec.f_b_hz) * 1_000_000
    assert period.denominator == 1
    assert seq.period_ticks == int(period)
    assert seq.period_s == pytest.approx(spec.pattern_period_s, rel=1e-12)
    assert seq.durations_ticks.dtype == np.uint32 and seq.levels.dtype == np.uint16
    assert seq.durations_ticks.min() >= 1
    assert seq.levels.shape == (seq.n_steps, len(spec.channels))
    assert seq.channels == spec.channel_names and seq.max_level == 1
    assert set(np.unique(seq.levels)) <= {0, 1}
    # consecutive steps differ (run-length encoded)
    assert np.all(np.any(seq.levels[1:] != seq.levels[:-1], axis=1))
    starts = seq.step_starts_s()
    assert starts.shape == (seq.n_steps + 1,) and starts[0] == 0.0
    assert starts[-1] == seq.period_s
    assert np.array_equal(seq.levels_unit(), seq.levels.astype(float))

    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] <= 1e-3
    assert rep["slot_rate_hz"] == pytest.approx(spec.f_b_hz, rel=1e-12)
    for tone in rep["tones"]:
        assert tone["achieved_hz"] == pytest.approx(tone["spec_hz"], rel=1e-3)
    assert len(rep["tones"]) == len(spec.channels) * spec.n_tones
    assert len(rep["ratios"]) == sum(len(r.pairs) for r in spec.ratios())


def test_table1_seq1_edges_hand_computed():
    seq = compile_spec(PRESETS["table1-seq1"])
    # slot 0: 400 Hz (period 2500 ticks) ON 0-1250; slot 1 at 2500: 600 Hz (1666.67 ticks) ON,
    # OFF at 3333.33 -> 3333, ON at 4166.67 -> 4167, truncated ON into slot 2 at 5000 (800 Hz):
    # OFF 5625, ON 6250, OFF 6875; loop at 7500.
    assert seq.edges() == [(0, 0, 1), (1250, 0, 0), (2500, 0, 1), (3333, 0, 0), (4167, 0, 1),
                           (5625, 0, 0), (6250, 0, 1), (6875, 0, 0)]
    assert seq.durations_ticks.tolist() == [1250, 1250, 833, 834, 1458, 625, 625, 625]
    rep = achieved_report(seq)
    assert [round(t["achieved_hz"], 2) for t in rep["tones"]] == [400.0, 599.88, 800.0]
    assert rep["worst_ratio_error"] == pytest.approx(1 - 599.88 / 600, rel=1e-9)


def test_coarse_clock_is_refused_with_a_clear_message():
    with pytest.raises(FirmwareError, match=r"clock_hz=10000.*ratio W:1800 Hz / W:1600 Hz"):
        compile_spec(PRESETS["table1-seq3"], clock_hz=10_000)
    # A looser bound accepts the same clock, and the report shows the error it tolerated.
    seq = compile_spec(PRESETS["table1-seq1"], clock_hz=10_000, max_ratio_error=0.05)
    assert 1e-3 < achieved_report(seq)["worst_ratio_error"] <= 0.05
    with pytest.raises(FirmwareError, match="max_ratio_error"):
        compile_spec(PRESETS["table1-seq1"], clock_hz=10_000)


def test_tones_that_lose_their_edges_are_refused():
    with pytest.raises(FirmwareError, match="loses its edges|ratio"):
        compile_spec(PRESETS["table1-seq3"], clock_hz=2_000, max_ratio_error=10.0)


@pytest.mark.parametrize(("kw", "match"), [
    ({"clock_hz": 0}, "clock_hz"), ({"clock_hz": 1.5}, "clock_hz"),
    ({"n_patterns": 0}, "n_patterns"), ({"max_ratio_error": 0.0}, "max_ratio_error"),
])
def test_bad_arguments(kw, match):
    with pytest.raises(FirmwareError, match=match):
        compile_spec(PRESETS["table1-seq1"], **kw)


def test_invalid_spec_is_rejected_before_compiling():
    with pytest.raises(SpecError, match="switching"):
        compile_spec(BarcodeSpec.mono("s", [400, 600, 800], switching_hz=500))


def test_n_patterns_repeats_the_pattern_exactly():
    one = compile_spec(PRESETS["table2-rgb"])
    three = compile_spec(PRESETS["table2-rgb"], n_patterns=3)
    assert three.period_ticks == 3 * one.period_ticks
    sample = np.arange(0, three.period_ticks, 7)
    lv3 = three.levels[np.searchsorted(three.step_starts_ticks(), sample, side="right") - 1]
    lv1 = one.levels[np.searchsorted(one.step_starts_ticks(), sample % one.period_ticks,
                                     side="right") - 1]
    assert np.array_equal(lv3, lv1)


def test_intensity_randomization():
    with pytest.raises(FirmwareError, match="seed is required"):
        compile_spec(RANDOMIZED)
    seq = compile_spec(RANDOMIZED, seed=SEED)
    assert seq.max_level == 4 and seq.n_patterns == 8
    assert seq.period_ticks == 8 * 7500
    assert set(np.unique(seq.levels)) == {0, 1, 2, 3, 4}
    assert seq.levels_unit().max() == 1.0
    # deterministic for one seed, different for another; timing does not depend on the seed
    again = compile_spec(RANDOMIZED, seed=SEED.decode())
    assert again.same_steps(seq)
    other = compile_spec(RANDOMIZED, seed=b"another-secret")
    assert not np.array_equal(other.levels, seq.levels)
    on = compile_spec(dataclasses.replace(RANDOMIZED, intensity_levels=1), n_patterns=8)
    assert np.array_equal(seq.levels > 0, on.levels[
        np.searchsorted(on.step_starts_ticks(), seq.step_starts_ticks()[:-1], side="right") - 1
    ] > 0)
    # the loop is not one pattern repeated
    grid = np.arange(0, 7500, 5)
    idx = np.searchsorted(seq.step_starts_ticks(), grid[None, :] + 7500 * np.arange(8)[:, None],
                          side="right") - 1
    per_pattern = seq.levels[idx]  # (8 patterns, n_samples, n_channels)
    assert not all(np.array_equal(per_pattern[0], per_pattern[i]) for i in range(1, 8))
    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] <= 1e-3
    # the secret appears nowhere
    for text in (repr(seq), str(rep), repr(seq.spec)):
        assert "venue-secret" not in text


def test_randomized_levels_are_roughly_uniform():
    spec = BarcodeSpec.mono("k8", [400, 600, 800], intensity_levels=8)
    seq = compile_spec(spec, seed=b"k", n_patterns=200)
    on_levels = seq.levels[seq.levels > 0]
    counts = np.bincount(on_levels, minlength=9)[1:]
    assert counts.sum() > 900
    assert counts.min() > 0.7 * counts.mean() and counts.max() < 1.3 * counts.mean()


@settings(max_examples=30, deadline=None)
@given(
    f1=st.integers(200, 800),
    steps=st.lists(st.floats(1.05, 3.0), min_size=1, max_size=3),
    duty=st.floats(0.2, 0.8),
    clock_hz=st.sampled_from([1_000_000, 2_000_000, 48_000_000 // 7]),
)
def test_sequence_matches_the_ideal_waveform_within_one_tick(f1, steps, duty, clock_hz):
    freqs = [float(f1)]
    for s in steps:
        freqs.append(freqs[-1] * s)
    spec = BarcodeSpec.mono("h", freqs, duty=duty)
    assume(spec.lowest_side_lobe_hz > 80 and freqs[-1] <= 15_000)
    seq: Sequence = compile_spec(spec, clock_hz=clock_hz, max_ratio_error=1.0)
    # sample at tick centres; away from ideal edges the level must match the ideal square wave
    t_ticks = np.arange(seq.period_ticks) + 0.5
    t_s = t_ticks / clock_hz
    slot = np.floor(t_s * spec.f_b_hz).astype(int).clip(0, spec.n_tones - 1)
    f = np.asarray(spec.channels[0][1])[slot]
    phase = (t_s - slot / spec.f_b_hz) * f
    ideal = (phase % 1.0) < duty
    starts = seq.step_starts_ticks()
    got = seq.levels[np.searchsorted(starts, t_ticks, side="right") - 1, 0] > 0
    # distance (in ticks) from the nearest ideal edge
    frac = phase % 1.0
    dist_on = np.minimum(frac, 1 - frac) / f * clock_hz
    dist_off = np.abs(frac - duty) / f * clock_hz
    dist_slot = np.abs(t_s * spec.f_b_hz - np.round(t_s * spec.f_b_hz)) / spec.f_b_hz * clock_hz
    near = np.minimum(np.minimum(dist_on, dist_off), dist_slot) <= 1.0
    assert np.array_equal(got[~near], ideal[~near])


# ---------------------------------------------------------------------- emitters built by others
ALLOW = ("flicker", "switching")


def _ideal_levels(spec: BarcodeSpec, t_s: np.ndarray, channel: int = 0) -> np.ndarray:
    """The ideal ON/OFF of a channel at times t_s (seconds from the loop start)."""
    g = np.floor(t_s * spec.f_b_hz).astype(int)
    tones = np.asarray(spec.channels[channel][1])[list(spec.slot_order())]
    f = tones[g % spec.n_tones]
    if spec.phase == "continuous":
        phase = t_s * f
    else:
        phase = (t_s - g / spec.f_b_hz) * f
    return (phase % 1.0) < spec.duty


def test_continuous_phase_edges_hand_computed():
    # table1-seq1 at f_B = 300 Hz (slots of 3333.33 us), continuous: 400 Hz runs 0-3333.33
    # (ON 0-1250, 2500-3333.33); 600 Hz from 3333.33 (phase 2 -> ON) OFF at 4166.67, ON 5000,
    # OFF 5833.33; 800 Hz from 6666.67 (phase 5.333 -> ON), OFF 6875, ON 7500, OFF 8125,
    # ON 8750, OFF 9375; loop at 10000. Restart would start 800 Hz ON for 625 us.
    spec = BarcodeSpec.mono("c", [400, 600, 800], switching_hz=300, phase="continuous")
    seq = compile_spec(spec)
    assert seq.edges() == [(0, 0, 1), (1250, 0, 0), (2500, 0, 1), (4167, 0, 0), (5000, 0, 1),
                           (5833, 0, 0), (6667, 0, 1), (6875, 0, 0), (7500, 0, 1), (8125, 0, 0),
                           (8750, 0, 1), (9375, 0, 0)]
    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] <= 1e-3
    for tone in rep["tones"]:
        assert tone["achieved_hz"] == pytest.approx(tone["spec_hz"], rel=1e-3)
    restart = compile_spec(dataclasses.replace(spec, phase="restart"))
    assert (6667, 0, 1) in restart.edges() and (7292, 0, 0) in restart.edges()


@pytest.mark.parametrize("order", [(2, 1, 0), (0, 2, 1), (1, 0, 2)])
def test_explicit_order_plays_the_slots_in_that_order(order):
    spec = dataclasses.replace(PRESETS["table1-seq1"], order=order)
    seq = compile_spec(spec)
    # each slot's number of rising edges (slot start included) names its tone: 1, 2 or 2 (600
    # Hz fits 1.5 cycles in 2.5 ms -> 2 ON periods), so compare with the ideal wave instead
    t_ticks = np.arange(seq.period_ticks) + 0.5
    got = seq.levels[np.searchsorted(seq.step_starts_ticks(), t_ticks, side="right") - 1, 0] > 0
    ideal = _ideal_levels(spec, t_ticks / seq.clock_hz)
    assert np.mean(got != ideal) < 1e-3
    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] <= 1e-3


def test_paper_200hz_compiles_with_a_warning():
    spec = dataclasses.replace(PRESETS["table1-seq3"], switching_hz=200.0)
    with pytest.raises(SpecError, match="flicker"):
        compile_spec(spec)
    with pytest.warns(SpecWarning, match="flicker"):
        seq = compile_spec(spec, allow=ALLOW)
    assert seq.period_ticks == 15_000  # 3 / 200 Hz at 1 MHz
    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] == 0.0  # 200 Hz slots hold whole cycles of 1600-2000 Hz
    assert rep["slot_rate_hz"] == pytest.approx(200.0)


@pytest.mark.parametrize("phase", ["restart", "continuous"])
@pytest.mark.parametrize("f_b", [170.0, 231.7, 480.0])
def test_rates_beyond_our_rules_compile_and_report(phase, f_b):
    spec = dataclasses.replace(PRESETS["table2-rgb"], switching_hz=f_b, phase=phase,
                               order=(2, 0, 1))
    with pytest.warns(SpecWarning):
        seq = compile_spec(spec, clock_hz=16_000_000, allow=ALLOW)
    rep = achieved_report(seq)
    assert rep["worst_ratio_error"] <= 1e-3
    assert all(np.isfinite(t["achieved_hz"]) for t in rep["tones"])


@settings(max_examples=30, deadline=None)
@given(
    f1=st.integers(200, 800),
    steps=st.lists(st.floats(1.05, 3.0), min_size=1, max_size=3),
    duty=st.floats(0.2, 0.8),
    f_b_frac=st.floats(0.4, 1.2),
    clock_hz=st.sampled_from([1_000_000, 48_000_000 // 7]),
    perm_seed=st.integers(0, 100),
)
def test_continuous_sequence_matches_the_ideal_waveform_within_one_tick(
        f1, steps, duty, f_b_frac, clock_hz, perm_seed):
    freqs = [float(f1)]
    for s in steps:
        freqs.append(freqs[-1] * s)
    assume(freqs[-1] <= 15_000)
    order = tuple(int(i) for i in np.random.default_rng(perm_seed).permutation(len(freqs)))
    spec = BarcodeSpec.mono("h", freqs, duty=duty, switching_hz=round(f1 * f_b_frac, 3),
                            phase="continuous", order=order)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SpecWarning)
        seq = compile_spec(spec, clock_hz=clock_hz, max_ratio_error=1.0, allow=ALLOW)
    t_ticks = np.arange(seq.period_ticks) + 0.5
    t_s = t_ticks / clock_hz
    got = seq.levels[np.searchsorted(seq.step_starts_ticks(), t_ticks, side="right") - 1, 0] > 0
    ideal = _ideal_levels(spec, t_s)
    # distance (in ticks) from the nearest ideal edge or slot bound
    g = np.floor(t_s * spec.f_b_hz).astype(int)
    f = np.asarray(spec.channels[0][1])[list(order)][g % len(freqs)]
    frac = (t_s * f) % 1.0
    dist_on = np.minimum(frac, 1 - frac) / f * clock_hz
    dist_off = np.abs(frac - duty) / f * clock_hz
    dist_slot = np.abs(t_s * spec.f_b_hz - np.round(t_s * spec.f_b_hz)) / spec.f_b_hz * clock_hz
    near = np.minimum(np.minimum(dist_on, dist_off), dist_slot) <= 1.0
    assert np.array_equal(got[~near], ideal[~near])


def test_a_continuous_tone_slower_than_its_slot_is_measured_across_slots_or_reported_unmeasured():
    # f_B = 225 Hz > f_1 = 200 Hz: each 200 Hz slot holds under one cycle
    spec = BarcodeSpec.mono("slow", [200.0, 400.0, 800.0], duty=0.75, switching_hz=225.0,
                            phase="continuous", order=(1, 2, 0))
    with pytest.warns(SpecWarning):
        one = achieved_report(compile_spec(spec, clock_hz=1_000_000, allow=ALLOW))
    slow = next(t for t in one["tones"] if t["spec_hz"] == 200.0)
    assert not slow["measured"] and math.isnan(slow["rel_error"])  # one edge in the sequence
    assert math.isfinite(one["worst_ratio_error"])
    with pytest.warns(SpecWarning):
        many = achieved_report(compile_spec(spec, clock_hz=1_000_000, n_patterns=8,
                                            allow=ALLOW))
    slow = next(t for t in many["tones"] if t["spec_hz"] == 200.0)
    assert slow["measured"] and slow["rel_error"] < 1e-3
