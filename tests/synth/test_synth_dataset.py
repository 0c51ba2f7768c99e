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
from lishield_guard.spec import SpecWarning, get_preset
from synth.dataset import (
    EMITTER_FIELDS,
    MIXES,
    Mix,
    demo_images,
    f_b_band,
    item_seed,
    parse_size,
    render_item,
    sample_emitter,
    sample_item,
    slot_order_kind,
    write_dataset,
)

SIZE = "96x64"
REQUIRED = {"file", "label", "kind", "preset", "channels", "switching_hz", "f_b_band",
            "phase_mode", "slot_order", "slot_order_kind", "rise_s", "nominal", "row_rate_hz",
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
    assert frac(pos, lambda p: p["downscale"] > 1) == pytest.approx(0.5, abs=0.03)
    assert frac(pos, lambda p: p["rotation_deg"] in (90, 270)) == pytest.approx(0.2, abs=0.03)
    assert frac(pos, lambda p: p["chroma_subsampling"] == "4:2:0") == pytest.approx(0.8,
                                                                                     abs=0.03)
    kinds = Counter(p["kind"] for p in neg)
    for kind, share in zip(("steady", "mains", "pwm", "texture"), (0.3, 0.25, 0.25, 0.2),
                           strict=True):
        assert kinds[kind] / len(neg) == pytest.approx(share, abs=0.04)
    bands = Counter(p["f_b_band"] for p in pos)
    for band, share in (("200", 0.31), ("between", 0.31), ("f1", 0.31), ("beyond", 0.07)):
        assert bands[band] / len(pos) == pytest.approx(share, abs=0.03)
    assert frac(pos, lambda p: p["phase_mode"] == "continuous") == pytest.approx(0.5, abs=0.03)
    orders = Counter(p["slot_order_kind"] for p in pos)
    for kind in ("ascending", "descending", "other"):
        assert orders[kind] / len(pos) == pytest.approx(1 / 3, abs=0.03)
    for p in pos:
        spec = get_preset(p["preset"])
        f_b = p["switching_hz"]
        assert p["light"]["switching_hz"] == f_b
        if p["f_b_band"] == "beyond":
            assert 170 <= f_b < 200 or spec.f1_hz < f_b <= 1.2 * spec.f1_hz
        else:
            assert 200.0 <= f_b <= spec.f1_hz
            assert (f_b == 200.0) == (p["f_b_band"] == "200")
            assert (f_b == spec.f1_hz) == (p["f_b_band"] == "f1")
        assert sorted(p["slot_order"]) == [0, 1, 2] == sorted(p["light"]["order"])
        half_period_s = 0.5 / spec.all_freqs_hz[-1]
        assert 0 <= p["rise_s"] == p["light"]["rise_s"] <= 0.05 * half_period_s
        assert p["nominal"] == (not p["attack"] and p["coverage"]["fraction"] == 1
                                and p["ambient_ratio"] <= 1 and p["exposure_s"] < 0.5 / f_b)
        assert 30_000 <= p["row_rate_hz"] <= 120_000
        assert 60 <= p["jpeg_quality"] <= 95
        if p["attack"]:
            t = p["attacked_tone"]
            assert p["exposure_s"] == pytest.approx(t["k"] / t["hz"])
            assert 1 / 8000 <= p["exposure_s"] <= 1 / 200 and t["k"] in (1, 2, 3)
            assert t["hz"] in dict(spec.channels)[t["channel"]]
        else:
            assert 1 / 8000 <= p["exposure_s"] <= 1 / 30
        if p["ambient_ratio"]:
            assert 0.1 <= p["ambient_ratio"] <= 10
        if p["coverage"]["fraction"] < 1:
            assert 0.3 <= p["coverage"]["fraction"] <= 0.8
        if p["downscale"] > 1:
            assert 1080 <= 1920 / p["downscale"] <= 1920
    assert frac(pos, lambda p: p["exposure_s"] > 1 / 200) > 0.2
    for p in neg:
        lt = p["light"]
        if lt["kind"] == "mains":
            assert lt["supply_hz"] in (50.0, 60.0) and 0.05 <= lt["depth"] <= 1
        if lt["kind"] == "pwm":
            assert 90 <= lt["freq_hz"] <= 20_000 and 0.1 <= lt["duty"] <= 0.9
        if p["kind"] == "texture":
            assert lt["kind"] == "steady" and p["scene_kind"] == "texture"


def test_default_mix_covers_every_emitter_cell_in_60_draws():
    pos = [sample_item(1, seed=item_seed(21, i), mix=MIXES["default"], size=(1080, 1920))
           for i in range(60)]
    assert {p["f_b_band"] for p in pos} == {"200", "between", "f1", "beyond"}
    assert {p["phase_mode"] for p in pos} == {"restart", "continuous"}
    assert {p["slot_order_kind"] for p in pos} == {"ascending", "descending", "other"}
    assert {p["channels"] == ["W"] for p in pos} == {True, False}
    for p in pos:
        assert set(EMITTER_FIELDS) <= set(p)
    neg = sample_item(0, seed=1, mix=MIXES["default"], size=(64, 96))
    assert all(neg[k] is None for k in EMITTER_FIELDS) and neg["nominal"] is None


def test_nominal_mix_is_all_nominal():
    pos = [sample_item(1, seed=item_seed(9, i), mix=MIXES["nominal"], size=(1080, 1920))
           for i in range(200)]
    assert all(p["nominal"] for p in pos)
    assert {p["f_b_band"] for p in pos} == {"200", "between", "f1", "beyond"}
    assert min(p["exposure_s"] for p in pos) >= 1 / 8000
    # the default mix's draws do not depend on the new field
    d = sample_item(1, seed=5, mix=MIXES["default"], size=(64, 96))
    assert d == sample_item(1, seed=5, mix=Mix(exposure_max_slot_frac=0.0), size=(64, 96))


def test_emitter_helpers():
    assert f_b_band(200.0, 400.0) == "200" and f_b_band(400.0, 400.0) == "f1"
    assert f_b_band(300.0, 400.0) == "between"
    assert f_b_band(190.0, 400.0) == f_b_band(420.0, 400.0) == "beyond"
    assert slot_order_kind([0, 1, 2]) == "ascending"
    assert slot_order_kind((2, 1, 0)) == "descending"
    assert slot_order_kind([1, 2, 0]) == "other"
    # M = 2 has no "other" order: the draw falls back to descending
    mix = MIXES["default"].with_overrides({"order_probs": "0,0,1"})
    spec2 = get_preset("table3-m2")
    rng = np.random.default_rng(0)
    assert sample_emitter(spec2, rng=rng, mix=mix)["slot_order"] == [1, 0]
    with pytest.raises(ConfigError, match="switching_band_probs"):
        Mix(switching_band_probs=(0.5, 0.5, 0.5, 0.0))


def test_rendered_emitter_is_what_the_manifest_says(monkeypatch):
    from firmware.sequence import compile_spec
    from synth import dataset as ds
    from synth.light import SequenceLight

    p = next(q for i in range(200)
             if (q := sample_item(1, seed=item_seed(4, i), mix=MIXES["default"],
                                  size=(64, 96)))["f_b_band"] == "200"
             and q["phase_mode"] == "continuous" and q["slot_order_kind"] == "other")
    light = ds._make_light(p)
    assert isinstance(light, SequenceLight)
    spec = light.sequence.spec
    assert spec.f_b_hz == 200.0 and spec.phase == "continuous"
    assert list(spec.slot_order()) == p["slot_order"]
    assert light.rise_s == p["rise_s"]
    # the LED sequence is the firmware's (single source of truth)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert light.sequence.same_steps(compile_spec(spec, clock_hz=ds.LED_CLOCK_HZ,
                                                      allow=ds.EMITTER_ALLOW,
                                                      n_patterns=p["loop_patterns"]))
    # the continuous emitter's timers run on over 0.1 s of patterns: 200 Hz / 3 -> 7 patterns
    assert p["loop_patterns"] == 7 and light.period_s == pytest.approx(7 * 3 / 200)
    restart = next(q for i in range(50)
                   if (q := sample_item(1, seed=i, mix=MIXES["default"], size=(64, 96)))[
                       "phase_mode"] == "restart")
    assert restart["loop_patterns"] == 1


def test_real_photo_hook(monkeypatch, tmp_path):
    from synth import dataset as ds
    from synth import scene

    monkeypatch.delattr(scene, "photo_scene_names", raising=False)
    monkeypatch.setattr(scene, "list_photo_scenes", lambda: [], raising=False)
    assert ds.real_photo_scenes() == ()
    photo = tmp_path / "p.png"
    Image.fromarray(np.full((40, 60, 3), 128, np.uint8)).save(photo)
    monkeypatch.setattr(scene, "list_photo_scenes", lambda: [photo], raising=False)
    items = [sample_item(1, seed=i, mix=MIXES["default"], size=(32, 48)) for i in range(40)]
    real = [p for p in items if p["scene_kind"] == "real-photo"]
    assert real and all(p["scene_photo"] == str(photo) for p in real)
    _, rec = render_item(real[0])
    assert rec["scene"] == {"scene": str(photo)}


def test_real_photo_corpus_names_skip_reserved_packages(monkeypatch, tmp_path):
    from synth import dataset as ds
    from synth import scene

    rows = [{"file": "a.png", "package": "hugin-data", "version": "2022.0.0", "sha256": "aa"},
            {"file": "b.png", "package": "lomiri-wallpapers", "version": "20.04.0-2"},
            {"file": "c.png", "package": "palapeli-data", "version": "4:22.12.3-1"},
            {"file": "d.png", "package": "scikit-learn", "version": "1.5"}]
    for r in rows:
        Image.fromarray(np.full((40, 60, 3), 100, np.uint8)).save(tmp_path / r["file"])
    names = [f"photos:{tmp_path}#{i}" for i in range(len(rows))]
    monkeypatch.setattr(scene, "photo_scene_names", lambda: names, raising=False)
    monkeypatch.setattr(scene, "corpus_manifest", lambda folder: rows, raising=False)
    monkeypatch.setattr(scene, "parse_photo_scene",
                        lambda n: (tmp_path, int(n.rpartition("#")[2])), raising=False)
    monkeypatch.setattr(scene, "corpus_photo", lambda folder, i, min_side_px=None: np.asarray(
        Image.open(tmp_path / rows[i]["file"])), raising=False)
    assert ds.real_photo_scenes() == (names[0],)
    p = next(q for i in range(40)
             if (q := sample_item(0, seed=i, mix=MIXES["default"], size=(32, 48)))[
                 "scene_kind"] == "real-photo")
    _, rec = render_item(p)
    assert rec["scene"] == {"scene": names[0], "package": "hugin-data",
                            "version": "2022.0.0", "sha256": "aa"}


def test_real_photos_weighted_by_package_size(monkeypatch, tmp_path):
    from synth import dataset as ds
    from synth import scene

    rows = [{"file": "a.png", "package": "one"}] + [{"file": f"{i}.png", "package": "big"}
                                                    for i in range(4)]
    names = tuple(f"photos:{tmp_path}#{i}" for i in range(len(rows)))
    monkeypatch.setattr(scene, "corpus_manifest", lambda folder: rows, raising=False)
    monkeypatch.setattr(scene, "parse_photo_scene",
                        lambda n: (tmp_path, int(n.rpartition("#")[2])), raising=False)
    # 1/sqrt(1) for the lone photo, 1/sqrt(4) for each of the big package's four
    np.testing.assert_allclose(ds._photo_probs(names), [1 / 3] + [1 / 6] * 4)


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


def test_cli_capture_emitter_options(tmp_path):
    runner = CliRunner()
    out = tmp_path / "c200.jpg"
    with pytest.warns(SpecWarning, match="flicker"):  # our firmware's rule, allowed here
        res = runner.invoke(_cli(), ["synth", "capture", "--preset", "table1-seq1",
                                     "--switching-hz", "200", "--phase", "continuous",
                                     "--order", "2,1,0", "--rise-s", "2e-5",
                                     "--loop-patterns", "3", "--size",
                                     "160x120", "--exposure-s", "0.0005", "--seed", "1", "-o",
                                     str(out)])
    assert res.exit_code == 0, res.output
    assert "f_B=200Hz phase=continuous order=2,1,0" in res.output
    assert Image.open(out).size == (160, 120)
    for args, match in ((["--order", "0,0,1"], "permutation"), (["--order", "x"], "--order"),
                        (["--phase", "running"], "phase"), (["--rise-s", "-1"], "rise_s")):
        res = runner.invoke(_cli(), ["synth", "capture", "--size", "64x48", "-o",
                                     str(tmp_path / "x.jpg"), *args])
        assert res.exit_code == 2 and match in res.output, res.output


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
