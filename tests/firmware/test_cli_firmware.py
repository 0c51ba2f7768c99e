"""`lishield-guard firmware`: files written, report printed, secrets kept out of every output."""

from __future__ import annotations

import json
import subprocess
import sys

from typer.testing import CliRunner

from firmware.emit import read_binary, read_json
from firmware.sequence import compile_spec
from lishield_guard.cli import app
from lishield_guard.spec import PRESETS, BarcodeSpec

runner = CliRunner()
SECRET = "s3cr3t-venue-seed-do-not-leak"


def test_firmware_writes_each_format(tmp_path):
    seq = compile_spec(PRESETS["table2-rgb"])
    for fmt in ("bin", "json", "c"):
        out = tmp_path / f"seq.{fmt}"
        res = runner.invoke(app, ["firmware", "table2-rgb", "--format", fmt, "-o", str(out)])
        assert res.exit_code == 0, res.output
        assert "worst ratio error" in res.stdout and "599.8800" in res.stdout
        if fmt == "bin":
            assert read_binary(out.read_bytes()).same_steps(seq)
        elif fmt == "json":
            assert read_json(out.read_text()).same_steps(seq)
        else:
            assert "lsp_seq_durations_ticks" in out.read_text()


def test_firmware_json_report_and_clock(tmp_path):
    out = tmp_path / "s.bin"
    res = runner.invoke(app, ["firmware", "table1-seq1", "-f", "bin", "-o", str(out),
                              "--clock-hz", "2000000", "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    assert rep["clock_hz"] == 2_000_000 and rep["period_ticks"] == 15_000
    assert read_binary(out.read_bytes()).clock_hz == 2_000_000


def test_firmware_refuses_coarse_clock(tmp_path):
    out = tmp_path / "s.bin"
    res = runner.invoke(app, ["firmware", "table1-seq3", "-f", "bin", "-o", str(out),
                              "--clock-hz", "10000"])
    assert res.exit_code == 2
    assert "relative error" in res.stderr and "Traceback" not in res.output
    assert not out.exists()


def test_firmware_seed_from_env_or_file_never_printed(tmp_path, monkeypatch):
    spec = BarcodeSpec.mono("venue-k3", [400, 600, 800], intensity_levels=3)
    toml = tmp_path / "venue.toml"
    toml.write_text('name = "venue-k3"\nintensity_levels = 3\n[channels]\nW = [400, 600, 800]\n')
    expected = compile_spec(spec, seed=SECRET)

    res = runner.invoke(app, ["firmware", str(toml), "-f", "bin", "-o", str(tmp_path / "a")])
    assert res.exit_code == 2 and "seed is required" in res.stderr

    monkeypatch.setenv("VENUE_SEED", SECRET)
    res = runner.invoke(app, ["firmware", str(toml), "-f", "json", "-o", str(tmp_path / "a.json"),
                              "--seed-env", "VENUE_SEED"])
    assert res.exit_code == 0, res.output
    assert read_json((tmp_path / "a.json").read_text()).same_steps(expected)

    seed_file = tmp_path / "seed.txt"
    seed_file.write_text(SECRET + "\n")
    for fmt in ("c", "bin"):
        out = tmp_path / f"b.{fmt}"
        res = runner.invoke(app, ["firmware", str(toml), "-f", fmt, "-o", str(out),
                                  "--seed-file", str(seed_file)])
        assert res.exit_code == 0, res.output
        assert SECRET.encode() not in out.read_bytes()
        assert SECRET not in res.output
    assert read_binary((tmp_path / "b.bin").read_bytes()).same_steps(expected)
    assert SECRET not in (tmp_path / "a.json").read_text()

    res = runner.invoke(app, ["firmware", str(toml), "-o", str(tmp_path / "x"),
                              "--seed-env", "UNSET_VAR_XYZ"])
    assert res.exit_code == 2 and "UNSET_VAR_XYZ" in res.stderr


def test_firmware_usage_errors(tmp_path):
    for args, msg in [(["nope", "-o", str(tmp_path / "x")], "neither a preset"),
                      (["table1-seq1", "-o", str(tmp_path / "no" / "dir" / "x")], "cannot write"),
                      (["table1-seq1", "-o", str(tmp_path / "x"), "--symbol", "1x"],
                       "C identifier")]:
        res = runner.invoke(app, ["firmware", *args])
        assert res.exit_code == 2, res.output
        assert msg in res.stderr


def test_core_does_not_import_firmware_at_import_time():
    code = ("import sys, lishield_guard, lishield_guard.cli; "
            "print(any(m == 'firmware' or m.startswith('firmware.') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"


def test_paper_200_hz_spec_needs_allow_flicker(tmp_path):
    spec = tmp_path / "paper200.toml"
    spec.write_text('name = "paper200"\nswitching_hz = 200.0\n'
                    '[channels]\nW = [400.0, 600.0, 800.0]\n')
    out = tmp_path / "seq.json"
    res = runner.invoke(app, ["firmware", str(spec), "-f", "json", "-o", str(out)])
    assert res.exit_code == 2 and "[flicker]" in res.output and not out.exists()
    res = runner.invoke(app, ["firmware", str(spec), "-f", "json", "-o", str(out),
                              "--allow", "flicker"])
    assert res.exit_code == 0, res.output
    assert "warning:" in res.output and "(allowed)" in res.output
    assert read_json(out.read_text()).period_ticks == 15_000  # 3 slots of 5 ms at 1 MHz
