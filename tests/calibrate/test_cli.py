"""`lishield-guard calibrate` end to end; its config works for scan and the service."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lishield_guard.commands.calibrate import EVIDENCE_PREFIX
from lishield_guard.config import load_config

EXE = str(Path(sys.executable).with_name("lishield-guard"))


@pytest.fixture(scope="module")
def calibrated(tiny_sets):
    root = tiny_sets["root"]
    out, rep = root / "cal.toml", root / "report"
    args = [EXE, "calibrate", "--clean", str(tiny_sets["neg"]), "--clean",
            str(tiny_sets["noise"]), "--positives", str(tiny_sets["pos"]), "--target-far",
            "0.5", "--out", str(out), "--report", str(rep), "--jobs", "2", "--quiet"]
    first = subprocess.run(args, capture_output=True, text=True, timeout=600)
    second = subprocess.run(args, capture_output=True, text=True, timeout=600)  # from cache
    return first, second, out, rep


def test_command_writes_config_and_report(calibrated):
    first, second, out, rep = calibrated
    assert first.returncode == 0, first.stderr
    assert second.returncode == 0, second.stderr
    cfg = load_config(out)
    assert "FAR 95% one-sided upper bound" in cfg.header
    assert "6 images" in cfg.header and "3 images" in cfg.header
    for name in ("summary.md", "roc.png", "heatmaps.png", "detection_by_kind.png",
                 "settings.jsonl"):
        assert (rep / name).stat().st_size > 0, name
    assert list((rep / "cache").glob(f"{EVIDENCE_PREFIX}*.pkl"))
    assert "9 images from cache" in (rep / "summary.md").read_text()  # second run
    summary = (rep / "summary.md").read_text()
    assert "Chosen setting" in summary and "Null model" in summary


def test_unmet_target_exits_3(tiny_sets, calibrated):
    root = tiny_sets["root"]
    r = subprocess.run([EXE, "calibrate", "--clean", str(tiny_sets["noise"]), "--positives",
                        str(tiny_sets["pos"]), "--target-far", "0.001", "--out",
                        str(root / "unmet.toml"), "--report", str(root / "report"), "-q"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 3, r.stderr
    assert "2995 clean images" in r.stderr
    assert "NOT MET" in load_config(root / "unmet.toml").header


def test_scan_accepts_config(calibrated, tiny_sets):
    out = calibrated[2]
    img = sorted(tiny_sets["noise"].glob("*.jpg"))[0]
    r = subprocess.run([EXE, "scan", str(img), "--config", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode in (0, 1), r.stderr
    rec = json.loads(r.stdout.splitlines()[0])
    assert rec["error"] is None and rec["protected"] in (True, False)


def test_service_accepts_config(calibrated):
    pytest.importorskip("fastapi")
    from service.app import effective_config
    from service.settings import ServiceSettings

    cfg = effective_config(ServiceSettings(config_path=calibrated[2], warmup=False))
    assert cfg.detector == load_config(calibrated[2]).detector
