"""`spec show` on an emitter our firmware would refuse: the rule fails, and the output says
that the rule is about our LEDs, not about what the detector searches."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from lishield_guard.cli import app

SPEC_200_HZ = """name = "paper200"
switching_hz = 200.0
phase = "continuous"
[channels]
W = [400.0, 600.0, 800.0]
"""


def test_spec_show_names_the_phase_and_marks_the_flicker_rule_as_an_emitter_rule(tmp_path):
    path = tmp_path / "paper200.toml"
    path.write_text(SPEC_200_HZ)
    res = CliRunner().invoke(app, ["spec", "show", str(path)])
    assert res.exit_code == 2  # a hard rule of our firmware fails
    assert "phase continuous" in res.output
    assert "FAIL    flicker" in res.output
    assert "firmware --allow flicker" in res.output
    assert "the detector searches such emitters" in res.output
    out = CliRunner().invoke(app, ["spec", "show", str(path), "--json"]).output
    js, _ = json.JSONDecoder().raw_decode(out)  # the JSON, then the error line
    assert js["phase"] == "continuous"


def test_spec_show_adds_no_note_when_every_emitter_rule_passes():
    res = CliRunner().invoke(app, ["spec", "show", "table1-seq1"])
    assert res.exit_code == 0
    assert "phase restart" in res.output
    assert "note:" not in res.output
