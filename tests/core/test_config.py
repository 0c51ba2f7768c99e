"""Config file: load/dump round trip and typed errors for bad files."""

from __future__ import annotations

import pytest

from lishield_guard.config import (
    AppConfig,
    DetectorConfig,
    Limits,
    PaperConfig,
    Policy,
    default_config,
    dump_config,
    load_config,
)
from lishield_guard.errors import ConfigError
from lishield_guard.spec import PRESETS, BarcodeSpec


def _write(tmp_path, text: str):
    p = tmp_path / "cfg.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_default_config_loads():
    cfg = default_config()
    assert cfg is default_config()  # cached
    # the shipped thresholds come from `lishield-guard calibrate` (README), not the dataclass
    assert cfg.detector.profile == "default"
    assert "written by `lishield-guard calibrate`" in cfg.header
    # measured on held-out clean images (issue 24), not on the images it was chosen on; the
    # header states the outcome either way (2026-11-26: 1/3101, NOT MET; README known limits)
    assert "certification: false alarms " in cfg.header
    assert "target FAR 0.001 on the certification part: " in cfg.header
    assert [p.id for p in cfg.policies] == ["no-distribution"]
    assert cfg.policies[0].specs == tuple(PRESETS[n] for n in
                                          ("table1-seq1", "table1-seq2", "table1-seq3",
                                           "table2-rgb"))


def test_dump_load_round_trip(tmp_path):
    custom = BarcodeSpec.mono("venue", [500, 750, 1000], duty=0.4, intensity_levels=3)
    cfg = AppConfig(
        detector=DetectorConfig(profile="paper",
                                paper=PaperConfig(ratio_tol=0.04, band_hz=(300.0, 12_000.0))),
        limits=Limits(max_pixels=1_000_000, max_bytes=2_000_000),
        policies=(Policy("no-distribution", (PRESETS["table1-seq1"], custom), "desc"),
                  Policy("blur", (PRESETS["table2-rgb"],))),
    )
    text = dump_config(cfg, header="written by a test\nsecond line")
    assert text.startswith("# written by a test\n# second line\n")
    back = load_config(_write(tmp_path, text))
    assert back == cfg
    assert back.policies[0].specs[1] == custom
    assert "# written by a test" in back.header
    # dump(load(dump(x))) is a fixed point
    assert dump_config(back) == dump_config(cfg)


def test_round_trip_of_shipped_default(tmp_path):
    cfg = default_config()
    assert load_config(_write(tmp_path, dump_config(cfg))) == cfg


def test_policy_ratio_values_are_union():
    pol = Policy("p", (PRESETS["table1-seq1"], PRESETS["table3-m2"]))
    assert pol.ratio_values().tolist() == pytest.approx([1.25, 4 / 3, 1.5, 2.0])
    assert pol.to_dict()["ratios"] == [1.25, 1.333333, 1.5, 2.0]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("colour = 1\n", "unknown top-level keys"),
        ("[detector]\nmax_peakz = 3\n", r"unknown \[detector\] keys"),
        ("[detector.fit]\nmax_gainz = 3\n", r"unknown \[detector.fit\] keys"),
        ("[detector.tones]\nmin_tones = 2\n[detector]\nsweep = 3\n", "must be a table or false"),
        ("[detector]\ntones = false\n", "must be a table"),
        ("[limits]\nmax_megabytes = 3\n", r"unknown \[limits\] keys"),
        ("[detector]\nprofile = \"fast\"\n", "profile"),
        ("[detector.paper]\nn_block_rows = 0\n", "n_block_rows"),
        ("[detector.paper]\nmax_peaks = 1.5\n", "max_peaks"),
        ("[detector.paper]\nband_hz = [15000, 400]\n", "band_hz"),
        ("[detector.profiles]\nmin_row_rate_hz = 200000\n", "min_row_rate_hz"),
        ("[detector.profiles]\nmax_downscale = 0.5\n", "max_downscale"),
        ("[detector.tones]\npeak_false_prob = 1.0\n", "peak_false_prob"),
        ("[detector.paper]\nratio_tol = -0.1\n", "ratio_tol"),
        ("[detector.paper]\nm_att = -1\n", "m_att"),
        ("[detector.profiles]\norientations = \"diagonal\"\n", "orientations"),
        ("[detector.fit]\nmin_rho_rgb = 0.5\n", "fit.min_rho_rgb"),
        ("[detector.fit]\nmin_gain_rgb = nan\n", "fit.min_gain_rgb"),
        ("[detector.fit]\nmin_rho_periodic = 0.5\n", "fit.min_rho_periodic"),
        ("[detector.fit]\nmin_gain_periodic = nan\n", "fit.min_gain_periodic"),
        ("[detector.fit]\nmax_leak_rgb = -0.1\n", "fit.max_leak_rgb"),
        ("[limits]\nmax_bytes = 0\n", "max_bytes"),
        ("[detector.paper]\nratio_tol = \"a\"\n", "real number"),
        ("[[policies]]\nid = \"p\"\npresets = [\"table9\"]\n", "unknown preset 'table9'"),
        ("[[policies]]\nid = \"p\"\n", "needs at least one barcode spec"),
        ("[[policies]]\ndescription = \"no id\"\n", "needs an 'id'"),
        ("[[policies]]\nid = \"p\"\npresets = [\"table1-seq1\"]\n"
         "[[policies]]\nid = \"p\"\npresets = [\"table1-seq2\"]\n", "duplicate policy ids"),
        ("[[policies]]\nid = \"p\"\nspecs = [{name = \"x\", channels = {W = [400, 600]}, "
         "duty = 2.0}]\n", "duty"),
        ("[[policies]]\nid = \"p\"\nspecs = [{name = \"x\"}]\n", "needs 'name' and 'channels'"),
        ("[[policies]]\nid = \"p\"\nspecs = [3]\n", "preset name or a table"),
        ("[detector\n", "not valid TOML"),
    ],
)
def test_bad_config_raises_config_error(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_write(tmp_path, text))


@pytest.mark.parametrize("text", [
    "[detector.paper]\nn_block_rows = \"a\"\n",
    "[detector.paper]\nband_hz = \"x\"\n",
    "[detector.paper]\nband_hz = [400]\n",
    "policies = 3\n",
])
def test_wrong_value_types_raise_config_error(tmp_path, text):
    with pytest.raises(ConfigError):
        load_config(_write(tmp_path, text))


def test_missing_file_raises_config_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config file") as info:
        load_config(tmp_path / "nope.toml")
    assert "nope.toml" in str(info.value)


def test_dataclass_validation_messages_name_the_field():
    with pytest.raises(ConfigError, match="max_pixels"):
        Limits(max_pixels=0)
    with pytest.raises(ConfigError, match="n_col_blocks"):
        DetectorConfig().with_values({"profiles.n_col_blocks": 0})
    with pytest.raises(ConfigError, match="policy id"):
        Policy("", (PRESETS["table1-seq1"],))


# --- #22 item 1: a partial config merges over the shipped one; no policy is an error


def test_partial_config_keeps_shipped_policies_and_calibrated_values(tmp_path):
    cfg = load_config(_write(tmp_path, "[detector.fit]\nmin_rho = 0.85\n"))
    shipped = default_config()
    assert cfg.detector.fit.min_rho == 0.85
    assert cfg.policies == shipped.policies and cfg.policies
    # keys left out keep the shipped calibrated values
    assert cfg.detector.with_values({"fit.min_rho": shipped.detector.fit.min_rho}) \
        == shipped.detector
    assert cfg.limits == shipped.limits


def test_one_source_of_defaults():
    """`DetectorConfig()` is the shipped detector: a recalibrated default.toml must update the
    dataclass defaults too (issue 21: they disagreed on 17 settings)."""
    assert DetectorConfig() == default_config().detector


def test_partial_limits_merge_key_by_key(tmp_path):
    cfg = load_config(_write(tmp_path, "[limits]\nmax_bytes = 1000\n"))
    assert cfg.limits.max_bytes == 1000
    assert cfg.limits.max_pixels == default_config().limits.max_pixels


def test_policies_given_replace_the_shipped_ones(tmp_path):
    cfg = load_config(_write(tmp_path, "[[policies]]\nid = \"blur\"\npresets = [\"table2-rgb\"]\n"))
    assert [p.id for p in cfg.policies] == ["blur"]
    assert cfg.detector == default_config().detector


@pytest.mark.parametrize("text", ["policies = []\n", "policies = []\n[detector]\nm_att = 1\n"])
def test_config_without_any_policy_is_refused(tmp_path, text):
    with pytest.raises(ConfigError, match="no policy"):
        load_config(_write(tmp_path, text))


def test_merge_false_reads_the_file_alone(tmp_path):
    cfg_text = dump_config(default_config())
    assert load_config(_write(tmp_path, cfg_text), merge=False) == default_config()


def test_limits_memory_budget_is_validated():
    with pytest.raises(ConfigError, match="max_decode_bytes"):
        Limits(max_decode_bytes=0)


# --- #21 item 5: settings grouped per stage; None (``false`` in TOML) is off


def test_a_flat_config_of_an_earlier_version_reads_as_its_groups(tmp_path):
    flat = ("[detector]\nfit_min_gain = 5.0\ntone_rel_tol = 0.04\nscreen_min_frames = 3\n"
            "n_block_rows = 2\nmodel_fit = true\nperiod_sweep = false\n"
            "tone_min_fit_gain = -inf\nfit_max_leak_rgb = 0.0\nfit_min_gain_periodic = inf\n")
    det = load_config(_write(tmp_path, flat)).detector
    shipped = default_config().detector
    assert det.fit.min_gain == 5.0 and det.tones.rel_tol == 0.04
    assert det.screen.min_frames == 3 and det.paper.n_block_rows == 2
    assert det.sweep is None  # period_sweep = false
    # the old "off" values are None now
    assert (det.tones.min_fit_gain, det.fit.max_leak_rgb, det.fit.min_gain_periodic) == (
        None, None, None)
    assert det.fit.min_rho == shipped.fit.min_rho  # keys left out keep the shipped values


def test_false_turns_a_stage_or_an_optional_path_off_and_survives_dump(tmp_path):
    text = ("[detector]\nfold = false\n[detector.screen]\npartial_false_prob = false\n"
            "[detector.fit]\nmin_gain_periodic = false\n")
    cfg = load_config(_write(tmp_path, text))
    assert cfg.detector.fold is None
    assert cfg.detector.screen.partial_false_prob is None
    assert cfg.detector.fit.min_gain_periodic is None
    assert cfg.detector.sweep == default_config().detector.sweep
    again = tmp_path / "again.toml"
    again.write_text(dump_config(cfg))
    assert load_config(again, merge=False).detector == cfg.detector
    assert "fold = false" in again.read_text()


def test_settings_by_dotted_name():
    det = DetectorConfig()
    changed = det.with_values({"fit.min_gain": 3.0, "tones.min_tones": 3})
    assert (changed.fit.min_gain, changed.tones.min_tones) == (3.0, 3)
    assert changed.values()["fit.min_gain"] == 3.0 and det.values()["fit.min_gain"] == 8.0
    assert det.replace(fit=None).values()["fit"] is None
    with pytest.raises(ConfigError, match="unknown detector setting"):
        det.with_values({"fitt.min_gain": 3.0})
    with pytest.raises(ConfigError, match="the stage is off"):
        det.replace(fit=None).with_values({"fit.min_gain": 3.0})
    with pytest.raises(ConfigError, match="cannot be off"):
        DetectorConfig(tones=None)
