"""The bench library and `lishield-guard bench` on a tiny dataset (no 12 MP targets)."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from lishield_guard import bench
from lishield_guard.cli import app
from lishield_guard.config import load_config


def _sane_rate(r: dict) -> None:
    """A rate of k in n images (n > 0): k/n with a confidence interval around it."""
    assert r["n"] > 0
    k = r["rate"] * r["n"]
    assert k == pytest.approx(round(k), abs=1e-9), r
    assert 0.0 <= r["ci"][0] <= r["rate"] <= r["ci"][1] <= 1.0


def test_cli_writes_json_csv_png(tiny_dataset, clean_dir, tmp_path):
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["bench", "--dataset", str(tiny_dataset), "--clean",
                                   str(clean_dir), "--out", str(out), "--no-targets",
                                   "--no-progress", "--profiles", "paper,default",
                                   "--profiles", "default-ref,fast", "--repeat", "2"])
    assert res.exit_code == 0, res.output
    assert "default-ref" in res.output and "targets:" in res.output
    report = json.loads((out / "bench.json").read_text())
    assert [r["setting"] for r in report["rows"]] == ["paper", "default", "default-ref", "fast"]
    for r in report["rows"]:
        assert r["n_images"] == 8 and r["n_errors"] == 0
        assert r["median_ms"] > 0 and r["p95_ms"] >= r["median_ms"]
        assert r["median_ratio"] > 0 and r["p95_ratio"] >= r["median_ratio"]
        assert r["tpr"]["n"] == 3 and r["fpr"]["n"] == 5
        _sane_rate(r["tpr"])
        _sane_rate(r["fpr"])
        assert 0.0 <= r["error"] <= 2.0
        assert set(r["fpr_by_group"]) == {"synth", f"clean:{clean_dir.name}"}
        assert r["floor_median_ms"] > 0
    assert any(r["pareto"] for r in report["rows"])
    c = {t["id"]: t for t in report["targets"]}
    assert c["c"]["measured"] is not None and c["c"]["measured"] >= 0
    assert c["a"]["met"] is None and c["d"]["met"] is None  # --no-targets: not measured
    with open(out / "bench.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["setting"] for r in rows] == ["paper", "default", "default-ref", "fast"]
    assert all(float(r["median_ratio"]) > 0 and 0 <= float(r["tpr"]) <= 1 for r in rows)
    png = (out / "bench.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


def test_cli_rejects_unknown_setting(tiny_dataset, tmp_path):
    res = CliRunner().invoke(app, ["bench", "--dataset", str(tiny_dataset), "--out",
                                   str(tmp_path), "--profiles", "turbo", "--no-targets"])
    assert res.exit_code == 2
    assert "unknown setting 'turbo'" in res.output


def test_settings_apply_changes():
    by = {s.name: s for s in bench.make_settings(bench.SETTINGS, load_config())}
    assert by["paper"].config.detector.profile == "paper"
    assert by["default-ref"].config.detector.profiles.fast_decode is False
    assert by["default"].config.detector.profiles.fast_decode is True
    assert by["fast"].config.detector.profiles.orientations == "rows"
    assert by["default"].config.policies  # the shipped policies are kept


def test_time_target_and_memory(tiny_dataset):
    path = tiny_dataset / "000000.jpg"
    settings = bench.make_settings(["default"], load_config())
    t = bench.time_target(path, settings, repeat=2)
    d = t["settings"]["default"]
    assert t["shape"] == [240, 320] and t["floor_median_ms"] > 0
    assert d["median_ratio"] > 0 and "decode" in d["stages_median_ms"]
    mem = bench.measure_memory(path, ["default"], jobs=2)
    assert mem["rgb_bytes"] == 240 * 320 * 3
    for name in (bench.FLOOR, "default"):
        m = mem["settings"][name]
        assert "error" not in m, m
        assert m["rss_delta_bytes"] >= 0 and m["tracemalloc_peak_bytes"] > 0
        assert m["x_rgb"] == pytest.approx(m["rss_delta_bytes"] / mem["rgb_bytes"])
    rows = [{"setting": "default", "tpr": {"rate": 0.5, "n": 2}, "fpr": {"rate": 0.0, "n": 2}},
            {"setting": "default-ref", "tpr": {"rate": 0.5, "n": 2},
             "fpr": {"rate": 0.5, "n": 2}}]
    res = {x["id"]: x for x in bench.evaluate_targets(rows, {"12mp": t, "1080p": t}, mem)}
    assert res["a"]["measured"] == pytest.approx(d["median_ratio"])
    assert res["c"]["measured"] == pytest.approx(50.0) and res["c"]["met"] is False
    x = mem["settings"]["default"]["x_rgb"]
    assert res["d"]["measured"] == x
    assert res["d"]["met"] is (x <= bench.TARGETS["d_peak_memory_max_x_rgb"])


def test_pillow_floor_is_rgb(tiny_dataset):
    rgb = bench.pillow_rgb_floor(tiny_dataset / "000001.jpg")
    assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8


def test_time_budget_keeps_a_prefix(tiny_dataset):
    items = bench.synth_items(tiny_dataset)
    settings = bench.make_settings(["fast"], load_config())
    run = bench.run_bench(items, settings, time_budget_s=0.0)
    assert run["n_skipped"] == len(items) - len(run["records"]) and len(run["records"]) <= 1
    rows = bench.summarize(run)
    assert rows[0]["n_images"] == len(run["records"])
    assert math.isnan(rows[0]["median_ratio"]) == (not run["records"])


def test_parallel_matches_sequential_verdicts(tiny_dataset):
    items = bench.synth_items(tiny_dataset)
    names = ["paper", "fast"]
    seq = bench.run_bench(items, bench.make_settings(names, load_config()))
    par = bench.run_bench_parallel(items, names, jobs=2, chunk=2)
    assert par["n_skipped"] == 0
    assert [r["path"] for r in par["records"]] == [r["path"] for r in seq["records"]]
    for a, b in zip(seq["records"], par["records"], strict=True):
        for n in names:
            assert a["settings"][n]["protected"] == b["settings"][n]["protected"]
            assert b["settings"][n]["ratio"] > 0


def test_a_rate_change_with_no_timed_positive_is_reported_not_measured():
    """A --quick run whose time budget ran out before any positive leaves the TPR change
    undefined: the target reads "not measured" for it instead of failing the whole report."""
    rows = [{"setting": "default", "tpr": {"rate": None, "n": 0}, "fpr": {"rate": 0.0, "n": 3}},
            {"setting": "default-ref", "tpr": {"rate": None, "n": 0},
             "fpr": {"rate": 0.0, "n": 3}}]
    (c,) = [x for x in bench.evaluate_targets(rows, None, None) if x["id"] == "c"]
    assert c["measured"] == 0.0 and c["met"] is True
    assert "TPR not measured" in c["detail"] and "FPR +0.00 pp" in c["detail"]
