"""The detect command: words, JSON, exit codes and the spectrum plot."""

from __future__ import annotations

import json
import sys

from conftest import write_images

import lishield_guard.detect  # noqa: F401 - the module, shadowed by the function of that name
from lishield_guard.verdict import Verdict

detect_mod = sys.modules["lishield_guard.detect"]


def test_clean_image_exits_0(tmp_path, run_cli):
    (img,) = write_images(tmp_path, ["a.jpg"])
    res = run_cli("detect", img)
    assert res.exit_code == 0
    assert "not protected" in res.output and "timings" in res.output
    res = run_cli("detect", img, "--json", "--profile", "paper")
    d = json.loads(res.output)  # Algorithm 1 often flags noise: only check consistency
    assert d["profile"] == "paper" and res.exit_code == (1 if d["protected"] else 0)


def test_protected_exits_1(tmp_path, run_cli, monkeypatch):
    (img,) = write_images(tmp_path, ["a.jpg"])
    v = Verdict(True, "no-distribution", 2, 2, evidence={
        "reason": "2 tones matched",
        "best": {"spec": "table1-seq1", "sigma_cpr_per_hz": 1e-5,
                 "matched_hz": {"W": [1000.0, 1500.0]}},
        "candidates": []}, score=0.9)
    monkeypatch.setattr(detect_mod, "detect", lambda source, config=None: v)
    png = tmp_path / "p.png"
    res = run_cli("detect", img, "--explain", "--plot", png)
    assert res.exit_code == 1
    assert "PROTECTED" in res.output and "no-distribution" in res.output
    assert "1000 Hz" in res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_input_exits_2(tmp_path, run_cli):
    txt = tmp_path / "x.txt"
    txt.write_text("not an image")
    res = run_cli("detect", txt)
    assert res.exit_code == 2 and "unsupported_media_type" in res.output
    assert "Traceback" not in res.output
    assert run_cli("detect", tmp_path / "missing.jpg").exit_code == 2
    (img,) = write_images(tmp_path, ["a.jpg"])
    assert run_cli("detect", img, "--profile", "bogus").exit_code == 2
    assert run_cli("detect", img, "--config", tmp_path / "nope.toml").exit_code == 2


def test_plot_real_verdict(tmp_path, run_cli):
    (img,) = write_images(tmp_path, ["a.jpg"])
    for profile in ("default", "paper"):
        png = tmp_path / f"{profile}.png"
        assert run_cli("detect", img, "--plot", png, "--profile", profile).exit_code in (0, 1)
        assert png.stat().st_size > 1000
