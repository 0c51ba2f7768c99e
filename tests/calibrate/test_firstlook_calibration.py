"""`calibrate` derives the first look's threshold (`calibration.firstlook`) with the model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lishield_guard.calibration.firstlook import (
    MARGIN_LN,
    calibrate_first_look,
    first_look_threshold,
)


def test_the_threshold_sits_a_margin_below_the_smallest_flagged_peak():
    assert first_look_threshold([6.0, 4.5, 9.0]) == pytest.approx(4.5 - math.log(2))
    assert MARGIN_LN == pytest.approx(math.log(2))
    assert first_look_threshold([4.5, np.nan], margin_ln=0.5) == pytest.approx(4.0)


@pytest.mark.parametrize("peaks", [[], [np.nan], [5.0, -np.inf]])
def test_without_a_flagged_peak_to_bound_it_the_first_look_is_off(peaks):
    assert first_look_threshold(peaks) is None


def test_a_bad_margin_is_refused():
    with pytest.raises(ValueError, match="margin_ln"):
        first_look_threshold([5.0], margin_ln=-1.0)


def test_calibration_counts_what_goes_on_and_never_clears_a_flagged_image():
    # clean: peaks 1..6, the one at 6 flagged; positives: 3 flagged (5, 7, 2 but unusable)
    fc = calibrate_first_look(
        [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [True] * 6, [False] * 5 + [True],
        [5.0, 7.0, 2.0, 8.0], [True, True, False, True], [True, True, True, False],
        margin_ln=0.5)
    assert fc.min_flagged_peak == 5.0 and fc.first_look_ln == pytest.approx(4.5)
    assert fc.n_flagged == 4 and fc.n_flagged_cleared == 0
    assert (fc.clean_on, fc.n_clean) == (2, 6)  # 5 and 6 go on
    assert (fc.pos_on, fc.n_pos) == (4, 4)  # the unusable one always goes on
    assert "learned.first_look_ln=4.5000" in fc.line() and fc.to_dict()["clean_on"] == [2, 6]


def test_a_first_look_that_clears_too_few_clean_images_stays_off():
    """Peaks 1..10 of clean images, the smallest flagged at 3.5: a threshold of 3 would clear
    2 of 10, under the half where the first look pays; it stays off and says why."""
    fc = calibrate_first_look(list(map(float, range(1, 11))), [True] * 10, [False] * 10,
                              [3.5], [True], [True], margin_ln=0.5)
    assert fc.first_look_ln is None and fc.unpaid_ln == pytest.approx(3.0)
    assert (fc.clean_on, fc.pos_on, fc.n_flagged_cleared) == (10, 1, 0)
    assert "off (at 3.0000" in fc.line() and "20.0 %" in fc.line()
    assert fc.to_dict()["unpaid_ln"] == pytest.approx(3.0)


def test_nothing_flagged_leaves_it_off_and_everything_goes_on():
    fc = calibrate_first_look([1.0, 2.0], [True, True], [False, False], [3.0], [True], [False])
    assert fc.first_look_ln is None and fc.clean_on == 2 and fc.pos_on == 1
    assert "off" in fc.line()


def test_calibrate_writes_the_first_look_for_its_weights(tiny_sets, tmp_path):
    from lishield_guard.calibration import run
    from lishield_guard.config import default_config, load_config

    out = tmp_path / "cal.toml"
    res = run([tiny_sets["neg"], tiny_sets["noise"]], tiny_sets["pos"], out=out,
              report=tmp_path / "rep", base=default_config(), target_far=0.2,
              certify_fraction=0.5, on_warning=lambda _: None)
    fl = res.info["first_look"]
    cfg = load_config(out)
    assert cfg.detector.learned.first_look_ln == fl["first_look_ln"]
    assert fl["n_flagged_cleared"] == 0
    assert "first look:" in out.read_text() and "First look" in res.report_paths[
        "summary"].read_text()
    if fl["first_look_ln"] is not None:
        assert fl["first_look_ln"] == pytest.approx(fl["min_flagged_peak"] - fl["margin_ln"])
