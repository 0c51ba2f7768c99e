"""The verdict's counts describe the stage that decided (issue 21): tone tracks report tones
found / needed, the pattern stages (folding, the sweep, the exact fit) one fit of one needed,
and ``evidence["stage"]`` names the stage."""

from __future__ import annotations

import pytest
from cascade import detect_cascade

from lishield_guard import PRESETS

PATTERN_STAGES = ("fold", "sweep", "exact fit")


@pytest.mark.parametrize("name, switching_hz, exposure_s, want", [
    ("table1-seq1", 200.0, 1 / 4000, "tones"),       # several cycles of each tone per slot
    ("table1-seq2", 1000.0, 1 / 2000, "exact fit")])  # one cycle per slot: only the pattern
def test_protected_verdict_counts_belong_to_the_deciding_stage(make_led_image, name,
                                                                switching_hz, exposure_s, want):
    v = detect_cascade(make_led_image(PRESETS[name], switching_hz=switching_hz,
                                      exposure_s=exposure_s))
    assert v.protected, v.evidence["reason"]
    stage = v.evidence["stage"]
    assert stage == want
    best = v.evidence["best"]
    assert best["stage"] == stage
    if stage == "tones":
        assert v.matches == best["n_matched"] >= v.required == best["required"]
    else:
        assert stage in PATTERN_STAGES
        assert (v.matches, v.required) == (1, 1)
        assert best["fold" if stage == "fold" else "sweep"] is not None


def test_clean_verdict_names_the_last_stage_that_looked(make_led_image):
    v = detect_cascade(make_led_image(None))  # steady light: the first stage clears it
    assert not v.protected
    assert v.evidence["stage"] == "first stage"
    assert v.matches < v.required
