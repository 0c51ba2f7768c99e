"""Datasets: manifest contents, mix proportions, byte-identical output, CLI and demo."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from lishield_guard.errors import ConfigError
from lishield_guard.spec import get_preset
from synth.dataset import (
    MIXES,
    Mix,
    demo_images,
    item_seed,
    parse_size,
    sample_item,
    write_dataset,
)

SIZE = "96x64"
REQUIRED = {"file", "label", "kind", "preset", "channels", "switching_hz", "row_rate_hz",
            "exposure_s", "attack", "attacked_tone", "ambient_ratio", "coverage", "jpeg_quality",
            "chroma_subsampling", "downscale", "rotation_deg", "rotation_mode",
            "exif_orientation", "scene", "light", "item_seed", "width", "height"}


def _digest(folder) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir())}


def test_manifest_and_files(tmp_path):
    manifest = write_dataset(tmp_path, n_pos=6, n_neg=6, seed=3, size=SIZE, progress=False)
    recs = [json.loads(line) for line in manifest.read_text().splitlines()]
    assert len(recs) == 12
    assert Counter(r["label"] for r in recs) == {1: 6, 0: 6}
    for r in recs:
        assert REQUIRED <= set(r)
        im = Image.open(tmp_path / r["file"])
        assert im.size == (r["width"], r["height"])
        if r["label"]:
            assert r["kind"] == "barcode" and r["preset"] is not None
        else:
            assert r["kind"] in {"steady", "mains", "pwm", "texture"}
            assert r["attack"] is False
        if r["exif_orientation"] != 1:
            assert im.getexif()[0x0112] == r["exif_orientation"]


def test_byte_identical_for_a_seed_whatever_the_jobs(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    write_dataset(a, n_pos=4, n_neg=4, seed=11, size=SIZE, jobs=1, progress=False)
    write_dataset(b, n_pos=4, n_neg=4, seed=11, size=SIZE, jobs=2, progress=False)
    write_dataset(c, n_pos=4, n_neg=4, seed=12, size=SIZE, jobs=1, progress=False)
    assert _digest(a) == _digest(b)
    assert _digest(a) != _digest(c)


def test_default_mix_proportions():
    mix = MIXES["default"]
    pos = [sample_item(1, seed=item_seed(0, i), mix=mix, size=(1080, 1920)) for i in range(3000)]
    neg = [sample_item(0, seed=item_seed(1, i), mix=mix, size=(1080, 1920)) for i in range(2000)]

    def frac(items, pred):
        return sum(bool(pred(p)) for p in items) / len(items)

    assert frac(pos, lambda p: p["preset"] == "table2-rgb") == pytest.approx(0.5, abs=0.04)
    assert frac(pos, lambda p: p["attack"]) == pytest.approx(0.2, abs=0.03)
    assert frac(pos, lambda p: p["ambient_ratio"] == 0) == pytest.approx(0.3, abs=0.03)
    assert frac(pos, lambda p: p["coverage"]["fraction"] < 1) == pytest.approx(0.25, abs=0.03)
    assert frac(pos, lambda p: p["downscale"] > 1) == pytest.approx(0.4, abs=0.03)
    assert frac(pos, lambda p: p["rotation_deg"] in (90, 270)) == pytest.approx(0.2, abs=0.03)
    assert frac(pos, lambda p: p["chroma_subsampling"] == "4:2:0") == pytest.approx(0.8,
                                                                                     abs=0.03)
    kinds = Counter(p["kind"] for p in neg)
    for kind, share in zip(("steady", "mains", "pwm", "texture"), (0.3, 0.25, 0.25, 0.2),
                           strict=True):
        assert kinds[kind] / len(neg) == pytest.approx(share, abs=0.04)
    for p in pos:
        spec = get_preset(p["preset"])
        assert max(200.0, 80.0 * spec.n_tones) <= p["switching_hz"] <= spec.f1_hz
        assert 30_000 <= p["row_rate_hz"] <= 120_000
        assert 60 <= p["jpeg_quality"] <= 95
        if p["attack"]:
            t = p["attacked_tone"]
            assert p["exposure_s"] == pytest.approx(t["k"] / t["hz"])
            assert 1 / 8000 <= p["exposure_s"] <= 1 / 200 and t["k"] in (1, 2, 3)
            assert t["hz"] in dict(spec.channels)[t["channel"]]
        else:
            assert 1 / 8000 <= p["exposure_s"] <= 1 / 500
        if p["ambient_ratio"]:
            assert 0.1 <= p["ambient_ratio"] <= 10
        if p["coverage"]["fraction"] < 1:
            assert 0.3 <= p["coverage"]["fraction"] <= 0.8
        if p["downscale"] > 1:
            assert 1.25 <= p["downscale"] <= 3
    for p in neg:
        lt = p["light"]
        if lt["kind"] == "mains":
            assert lt["supply_hz"] in (50.0, 60.0) and 0.05 <= lt["depth"] <= 1
        if lt["kind"] == "pwm":
            assert 90 <= lt["freq_hz"] <= 20_000 and 0.1 <= lt["duty"] <= 0.9
        if p["kind"] == "texture":
            assert lt["kind"] == "steady" and p["scene_kind"] == "texture"


def test_easy_mono_rgb_mixes():
    easy = [sample_item(1, seed=i, mix=MIXES["easy"], size=(64, 96)) for i in range(300)]
    assert not any(p["attack"] or p["ambient_ratio"] or p["downscale"] > 1 or p["rotation_deg"]
                   or p["coverage"]["fraction"] < 1 for p in easy)
    assert all(sample_item(1, seed=i, mix=MIXES["mono"], size=(64, 96))["channels"] == ["W"]
               for i in range(50))
    assert all(sample_item(1, seed=i, mix=MIXES["rgb"], size=(64, 96))["preset"] == "table2-rgb"
               for i in range(50))


def test_mix_overrides_and_errors(tmp_path):
    m = MIXES["default"].with_overrides({"attack_prob": "1", "jpeg_quality_range": "90,95",
                                         "noise": "false"})
    assert m.attack_prob == 1.0 and m.jpeg_quality_range == (90, 95) and m.noise is False
    with pytest.raises(ConfigError, match="unknown mix field"):
        MIXES["default"].with_overrides({"bogus": "1"})
    with pytest.raises(ConfigError, match="attack_prob"):
        Mix(attack_prob=1.5)
    with pytest.raises(ConfigError, match="negatives only"):
        write_dataset(tmp_path, n_pos=1, n_neg=1, seed=0, mix="negatives-only", size=SIZE,
                      progress=False)
    with pytest.raises(ConfigError, match="size"):
        parse_size("big")
    assert parse_size("12mp") == (3024, 4032) and parse_size("640x480") == (480, 640)


def test_demo_images(tmp_path):
    prot, clean = demo_images(tmp_path, seed=1)
    for p in (prot, clean):
        assert Image.open(p).size == (1920, 1080)
    a = np.asarray(Image.open(prot).convert("L"), dtype=float).mean(axis=1)
    b = np.asarray(Image.open(clean).convert("L"), dtype=float).mean(axis=1)
    # The protected capture carries row stripes the clean one does not.
    assert np.std(np.diff(a)) > 3 * np.std(np.diff(b))


def _cli():
    from lishield_guard.cli import app

    return app


def test_cli_dataset_and_capture(tmp_path):
    runner = CliRunner()
    res = runner.invoke(_cli(), ["synth", "dataset", "--out", str(tmp_path / "ds"), "--n-pos",
                                 "2", "--n-neg", "2", "--seed", "5", "--size", SIZE, "--mix",
                                 "easy", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert len((tmp_path / "ds" / "manifest.jsonl").read_text().splitlines()) == 4
    out = tmp_path / "cap.jpg"
    res = runner.invoke(_cli(), ["synth", "capture", "--preset", "table2-rgb", "--scene",
                                 "skimage:coffee", "--size", "160x120", "--exposure-s", "0.0005",
                                 "--ambient-ratio", "0.5", "--coverage", "0.6",
                                 "--jpeg-quality", "80", "--downscale", "1.5", "--rotate", "90",
                                 "--seed", "2", "-o", str(out), "--plot",
                                 str(tmp_path / "p.png")])
    assert res.exit_code == 0, res.output
    assert Image.open(out).size == (80, 107)
    assert (tmp_path / "p.png").stat().st_size > 1000


@pytest.mark.parametrize("args,match", [
    (["synth", "capture", "--preset", "nope", "-o", "x.jpg"], "unknown preset"),
    (["synth", "capture", "--rotate", "45", "-o", "x.jpg"], "--rotate"),
    (["synth", "capture", "--exposure-s", "0.001", "--auto", "-o", "x.jpg"], "either"),
    (["synth", "capture", "--coverage", "0", "-o", "x.jpg"], "--coverage"),
    (["synth", "capture", "--scene", "/no/such.png", "-o", "x.jpg"], "not found"),
    (["synth", "capture", "--jpeg-quality", "0", "-o", "x.jpg", "--size", "64x48"], "quality"),
    (["synth", "dataset", "--out", "d", "--n-pos", "1", "--mix", "bogus"], "unknown --mix"),
    (["synth", "dataset", "--out", "d", "--n-pos", "1", "--size", "huge"], "size"),
    (["synth", "dataset", "--out", "d"], "n_pos"),
    (["synth", "dataset", "--out", "d", "--n-pos", "1", "--set", "x"], "KEY=VALUE"),
])
def test_cli_bad_arguments(tmp_path, monkeypatch, args, match):
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(_cli(), args)
    assert res.exit_code == 2
    assert match in res.output
    assert "Traceback" not in res.output
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit)


def test_lishield_guard_does_not_import_synth():
    code = ("import sys, lishield_guard, lishield_guard.cli; "
            "assert 'synth' not in sys.modules, sorted(m for m in sys.modules if 'synth' in m)")
    subprocess.run([sys.executable, "-c", code], check=True)
