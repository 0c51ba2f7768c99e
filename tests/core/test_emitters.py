"""Emitters the policy allows but our firmware would not play: 200 Hz switching, slot orders,
tones that run on across slots (issue 21)."""

from __future__ import annotations

from dataclasses import replace

import pytest
from cascade import detect_cascade

from lishield_guard import PRESETS
from lishield_guard.detector.emitters import MIN_SWITCHING_HZ, cycles_range, emitter_variants


def test_variants_cover_every_cyclic_order_and_both_phases():
    spec = PRESETS["table1-seq1"]
    labels = {(v.slot_order(), v.phase) for v in emitter_variants(spec)}
    assert labels == {((0, 1, 2), "restart"), ((0, 1, 2), "continuous"),
                      ((0, 2, 1), "restart"), ((0, 2, 1), "continuous")}
    assert emitter_variants(spec)[0] is spec


def test_switching_range_reaches_below_the_papers_200_hz():
    lo, hi = cycles_range(400.0)
    assert 400.0 / hi == pytest.approx(MIN_SWITCHING_HZ) and MIN_SWITCHING_HZ < 200.0
    assert 400.0 / lo > 400.0  # a little above f_B = f_1 as well


# The paper's own evaluation (Sec. 7.3) switches three Table 1 tones at 200 Hz: outside our
# firmware's flicker rule (f_B / M >= 80 Hz). The detector before issue 21 modelled only
# compliant LEDs and vetoed these tone tracks.
@pytest.mark.parametrize("name", ["table1-seq1", "table1-seq3"])
def test_200_hz_switching_is_detected(make_led_image, name):
    v = detect_cascade(make_led_image(PRESETS[name], switching_hz=200.0))
    assert v.protected, v.evidence["reason"]
    assert v.policy == "no-distribution"


def test_reversed_slot_order_is_detected(make_led_image):
    spec = replace(PRESETS["table1-seq2"], order=(2, 1, 0))
    v = detect_cascade(make_led_image(spec, switching_hz=300.0))
    assert v.protected, v.evidence["reason"]


def test_tones_running_on_across_slots_are_detected(make_led_image):
    # free-running timers: 600 Hz holds 2.4 cycles per 250 Hz slot, so its phase at each
    # slot start differs and the pattern does not repeat for 5 patterns
    v = detect_cascade(make_led_image(PRESETS["table1-seq1"], switching_hz=250.0, phase="free"))
    assert v.protected, v.evidence["reason"]


# Free-running timers with a pattern that never repeats in the frame: the grid of repeating
# templates ranks a wrong period first, and only the tones' own coherence (detector/freerun.py)
# leads the fit to the right one. Both were missed before it (development set 000035 is the
# first case).
@pytest.mark.parametrize(("name", "switching_hz", "row_rate_hz"),
                         [("table1-seq3", 1526.0, 100_000.0), ("table1-seq1", 320.0, 60_000.0)])
def test_free_running_tones_lead_the_fit_to_their_period(make_led_image, name, switching_hz,
                                                         row_rate_hz):
    v = detect_cascade(make_led_image(PRESETS[name], switching_hz=switching_hz,
                                      row_rate_hz=row_rate_hz, exposure_s=1 / 8000,
                                      phase="free"))
    assert v.protected, v.evidence["reason"]
