"""Issue #33 item 5: `spec show`, `firmware` and the config loader agree on which specs are
valid: every shipped preset is; a spec that is no barcode (a repeated tone, a tone above
max_freq) is refused by all three; one that breaks only an emitter rule is refused by our
firmware and `spec show` unless allowed, and accepted as a policy."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from lishield_guard.cli import app
from lishield_guard.config import load_config
from lishield_guard.errors import ConfigError, SpecError
from lishield_guard.spec import PRESETS, BarcodeSpec, check_spec

runner = CliRunner()


def _policy_toml(path, spec_table: str) -> None:
    path.write_text('[[policies]]\nid = "p"\ndescription = "x"\n'
                    f'specs = [{spec_table}]\n')


def _spec_toml(path, tones: str, switching: str = "") -> None:
    path.write_text(f'name = "s"\n{switching}[channels]\nW = [{tones}]\n')


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_is_valid_everywhere(name, tmp_path):
    show = runner.invoke(app, ["spec", "show", name])
    assert show.exit_code == 0, show.output
    fw = runner.invoke(app, ["firmware", name, "-o", str(tmp_path / "x.h")])
    assert fw.exit_code == 0, fw.output
    cfg = tmp_path / "c.toml"
    _policy_toml(cfg, f'"{name}"')
    assert [s.name for s in load_config(cfg).policies[0].specs] == [name]
    assert check_spec(PRESETS[name]).ok_as_policy


def test_default_policy_specs_pass_spec_show():
    from lishield_guard.config import default_config

    for policy in default_config().policies:
        for spec in policy.specs:
            assert runner.invoke(app, ["spec", "show", spec.name]).exit_code == 0


@pytest.mark.parametrize("tones", ["400, 400, 800", "400, 600, 20000"],
                         ids=["distinct_freqs", "max_freq"])
def test_no_barcode_is_refused_by_all_three(tones, tmp_path):
    spec = tmp_path / "s.toml"
    _spec_toml(spec, tones)
    assert runner.invoke(app, ["spec", "show", str(spec)]).exit_code == 2
    assert runner.invoke(app, ["firmware", str(spec), "-o", str(tmp_path / "x.h")]
                         ).exit_code == 2
    cfg = tmp_path / "c.toml"
    _policy_toml(cfg, f'{{name = "s", channels = {{W = [{tones}]}}}}')
    with pytest.raises(ConfigError):
        load_config(cfg)
    with pytest.raises(SpecError):
        BarcodeSpec.from_dict({"name": "s", "channels": {"W": [float(t) for t in
                                                               tones.split(",")]}})


def test_emitter_rule_needs_allow_in_show_and_firmware_alike(tmp_path):
    """The paper's 200 Hz switching (flicker): our firmware refuses it without --allow, and
    `spec show` answers the same; as a policy it is accepted (others' LEDs)."""
    spec = tmp_path / "s.toml"
    _spec_toml(spec, "400, 600, 800", 'switching_hz = 200\n')
    out = str(tmp_path / "x.h")
    for allow in ([], ["--allow", "flicker"]):
        show = runner.invoke(app, ["spec", "show", str(spec), *allow]).exit_code
        fw = runner.invoke(app, ["firmware", str(spec), "-o", out, *allow]).exit_code
        assert show == fw == (2 if not allow else 0), (allow, show, fw)
    cfg = tmp_path / "c.toml"
    _policy_toml(cfg, '{name = "s", switching_hz = 200, channels = {W = [400, 600, 800]}}')
    assert load_config(cfg).policies[0].specs[0].switching_hz == 200
