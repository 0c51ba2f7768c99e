"""The detect command: words, JSON, exit codes and the spectrum plot."""

from __future__ import annotations

import json

from scan_helpers import write_images

import lishield_guard.detector as detect_mod  # the CLI imports `detect` from here when it runs
from lishield_guard.verdict import Verdict


def test_clean_image_exits_0(tmp_path, run_cli):
    (img,) = write_images(tmp_path, ["a.jpg"])
    res = run_cli("detect", img)
    assert res.exit_code == 0
    assert "clean, not protected" in res.output and "timings" in res.output
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


def test_bad_input_exits_2_or_3(tmp_path, run_cli):
    txt = tmp_path / "x.txt"
    txt.write_text("not an image")
    res = run_cli("detect", txt)  # an unreadable image: an input error, never clean
    assert res.exit_code == 3 and "unsupported_media_type" in res.output
    assert "Traceback" not in res.output
    assert run_cli("detect", tmp_path / "missing.jpg").exit_code == 3  # an input error (#33 item 4)
    (img,) = write_images(tmp_path, ["a.jpg"])
    assert run_cli("detect", img, "--profile", "bogus").exit_code == 2
    assert run_cli("detect", img, "--config", tmp_path / "nope.toml").exit_code == 2


def test_plot_real_verdict(tmp_path, run_cli):
    (img,) = write_images(tmp_path, ["a.jpg"])
    # a noise JPEG: clean by default; the paper's Algorithm 1 finds ratio matches among its
    # noise peaks (its known false alarm, see test_default_profile_beats_paper_on_clean_photos)
    for profile, code in (("default", 0), ("paper", 1)):
        png = tmp_path / f"{profile}.png"
        res = run_cli("detect", img, "--plot", png, "--profile", profile)
        assert res.exit_code == code, res.output
        assert png.stat().st_size > 1000


def test_several_images_give_one_json_line_each(tmp_path, run_cli):
    imgs = write_images(tmp_path, ["a.jpg", "b.jpg"])
    res = run_cli("detect", *imgs, "--json")
    lines = [json.loads(ln) for ln in res.output.splitlines() if ln.startswith("{")]
    assert [d["path"] for d in lines] == [str(p) for p in imgs]
    assert res.exit_code == (1 if any(d["protected"] for d in lines) else 0)


def test_several_images_plot_into_a_folder(tmp_path, run_cli, monkeypatch):
    imgs = write_images(tmp_path, ["a.jpg", "b.jpg"])
    v = Verdict(False, None, 0, 2, evidence={"reason": "0 tone(s) found, 2 needed"})
    monkeypatch.setattr(detect_mod, "detect", lambda source, config=None: v)
    res = run_cli("detect", *imgs, "--plot", tmp_path / "figs")
    assert res.exit_code == 0
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == ["a.png", "b.png"]


def test_folder_points_to_scan(tmp_path, run_cli):
    res = run_cli("detect", tmp_path)
    assert res.exit_code == 2 and "lishield-guard scan" in res.output


def test_undetermined_is_not_clean(tmp_path, run_cli, monkeypatch):
    (img,) = write_images(tmp_path, ["a.jpg"])
    v = Verdict(False, None, 0, 2, evidence={"reason": "image too small"})
    object.__setattr__(v, "undetermined", "image too small")  # older Verdicts lack the field
    if getattr(v, "status", None) != "undetermined":
        import pytest

        pytest.skip("Verdict has no undetermined status in this tree")
    monkeypatch.setattr(detect_mod, "detect", lambda source, config=None: v)
    res = run_cli("detect", img)
    assert res.exit_code not in (0, 1) and "UNDETERMINED" in res.output


def test_version_and_help_teach(run_cli):
    res = run_cli("--version")
    assert res.exit_code == 0 and res.output.startswith("lishield-guard ")
    for cmd in (["detect"], ["serve"], ["bench"], ["firmware"], ["spec", "show"],
                ["spec", "list"], ["synth", "capture"], ["synth", "dataset"]):
        out = run_cli(*cmd, "--help").output
        assert "<bool>" not in out, cmd
        assert "Examples:" in out, cmd
    out = run_cli("detect", "--help").output
    assert "<default|cascade|paper>" in out and "(use this)" in out


def test_plot_draws_verdicts_built_by_hand(tmp_path):
    """A verdict whose evidence is a dict (built by hand, not by a profile) gets a figure of
    its reason, whatever keys the dict holds; the title states the status."""
    from lishield_guard.config import load_config
    from lishield_guard.plot import verdict_png, verdict_title

    (img,) = write_images(tmp_path, ["a.jpg"])
    cfg = load_config(None)
    fit = {"spec": "table1-seq1", "channel": "W", "rho": 0.95, "rho_lookalike": 0.5,
           "gain": 8.8, "period_rows": 100.0, "cycles_per_slot_f1": 1.0, "phase_slots": 0.3,
           "exposure_slots": 0.5, "coherence_t": 9.0, "n_periods": 2.4, "chroma_leak": None,
           "domain": "linear", "phase_mode": "continuous", "slot_order": [2, 1, 0],
           "switching": {"hz": 400.0, "band": "f_1"}, "emitter": "order 0-2-1, continuous",
           "lookalike": {"freq_cpr": 0.02, "duty": 0.6, "phase_cycles": 0.1,
                         "exposure_cycles": 0.2}}
    evidences = [
        {"reason": "fits", "axis": "rows", "best": {"spec": "table1-seq1", "sweep": {
            "spec": "table1-seq1", "rho": 0.8, "period_rows": 100.0, "fit": fit}}},
        {"reason": "folded", "axis": "columns", "best": {"spec": "table1-seq2", "fold": {
            "spec": "table1-seq2", "rho": 0.93, "period_rows": 80.0,
            "cycles_per_slot_f1": 1.1, "fold_snr": 40.0, "n_periods": 3.0}}},
        {"reason": "nothing analysable"},
        {},
    ]
    for i, ev in enumerate(evidences):
        v = Verdict(i == 0, "no-distribution" if i == 0 else None, 0, 2, evidence=ev)
        png = verdict_png(str(img), v, cfg)
        assert png[:8] == b"\x89PNG\r\n\x1a\n", i
    assert verdict_title(Verdict(True, "p", 0, 2, evidence=evidences[0])).startswith(
        "PROTECTED")
    und = Verdict(False, None, 0, 2, evidence={"reason": "too small"})
    object.__setattr__(und, "undetermined", "too small")
    if getattr(und, "status", None) == "undetermined":
        assert verdict_title(und).startswith("UNDETERMINED")


def test_the_figure_states_the_thresholds_of_each_path():
    """The lines under the figure hold each number against the thresholds of every way to pass
    that is open to the fit (`rules.fit_paths`, the rule itself: a path that is off or does
    not apply is not listed; the colour path's limit is stated)."""
    from lishield_guard.config import default_config
    from lishield_guard.detector.results import ModelFit, SweepMatch, SweepResult
    from lishield_guard.plot import _threshold_lines

    det = default_config().detector
    fit = ModelFit("table2-rgb", "R", 0.883, 0.718, 100.0, 1.0, 0.3, 0.5, 20.9, 0.87, 0.28)
    text = "\n".join(_threshold_lines("exact capture-model fit", fit, det))
    assert "[pass] colour-verified path: rho 0.883 (needs >= 0.85), gain over the look-alike " \
           "1.20 (needs >= 1); look-alike rho 0.718" in text
    assert "[FAIL] general path: rho 0.883 (needs >= 0.9)" in text
    assert "periods path" not in text  # 0.87 periods: the periodic path is not open
    assert "t = 20.9   (needs >= 3)" in text and "colour path needs <= 0.3" in text
    off = det.with_values({"fit.max_leak_rgb": None, "fit.min_gain_periodic": None})
    text = "\n".join(_threshold_lines("exact capture-model fit", fit, off))
    assert "colour-verified" not in text and "colour path off" in text
    grid = SweepResult(SweepMatch("table1-seq1", 0.75, 0.4, 100.0, 1.0, 0.5, 12.0, 2.0), "W", "")
    assert "grid rho 0.750  (needs >= 0.7)" in _threshold_lines("period-sweep grid fit", grid,
                                                                 det)[0]


# ------------------------------------------------------------------ issue 41: traps and contradictions

def _help_words(text: str) -> str:
    """Help text as words: Rich's box and line breaks removed."""
    return " ".join(text.replace("│", " ").split())


def test_same_stems_plot_to_distinct_files(tmp_path, run_cli, monkeypatch):
    """``detect a/x.jpg b/x.jpg --plot DIR`` wrote one x.png over the other."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = write_images(tmp_path / "a", ["x.jpg"])[0]
    b = write_images(tmp_path / "b", ["x.jpg"], seed=1)[0]
    v = Verdict(False, None, 0, 2, evidence={"reason": "0 tone(s) found, 2 needed"})
    monkeypatch.setattr(detect_mod, "detect", lambda source, config=None: v)
    res = run_cli("detect", a, b, "--plot", tmp_path / "figs")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == ["a_x.png", "b_x.png"]


def test_undetermined_prints_no_tone_count(tmp_path, run_cli):
    """The default profile has no tones to require: an undetermined verdict printed
    "matches: 0/1 tones required"."""
    from PIL import Image

    tiny = tmp_path / "tiny.png"
    Image.new("L", (64, 48), 128).save(tiny)
    res = run_cli("detect", tiny)
    assert res.exit_code == 3 and "UNDETERMINED" in res.output
    assert "tones required" not in res.output
    assert "matches: none (the detector could not look)" in res.output


def test_explain_states_one_row_rate(tmp_path, run_cli, monkeypatch):
    """`--explain` printed the tones' row rate (1 / scale) as the best spec's while the sweep
    that decided reported another ("85,412 Hz" and "row_rate_hz_if_not_resized 61408")."""
    import re

    from lishield_guard.detector.results import SpecMatch, Stage, SweepMatch, SweepResult

    sweep = SweepResult(SweepMatch("table2-rgb", 0.79, 0.43, 902.3, 1.96, 0.1, 83.7, 1.2,
                                   switching_hz=204.2, row_rate_hz=61408.3), "R", "0-1-2")
    best = SpecMatch("table2-rgb", 1.1708e-05, {"R": [0.0, 0.4]}, {"R": [600.0], "G": [1400.0]},
                     2, 2, 0.5, 0, True, "pattern fits", sweep=sweep, stage=Stage.SWEEP)
    assert best.to_dict()["row_rate_hz_if_not_resized"] == 61408.3
    v = Verdict(True, "no-distribution", 1, 1, evidence={
        "reason": "pattern fits", "stage": "sweep", "best": best.to_dict(), "candidates": []},
        profile="cascade", score=0.79)
    monkeypatch.setattr(detect_mod, "detect", lambda source, config=None: v)
    (img,) = write_images(tmp_path, ["a.jpg"])
    res = run_cli("detect", img, "--explain", "--profile", "cascade")
    rates = {float(r.replace(",", "")) for r in re.findall(
        r"row rate ([\d,.]+) Hz|row_rate_hz_if_not_resized ([\d.]+)", res.output) for r in r if r}
    assert rates == {61408.0}, res.output
    assert "from the sweep's fitted period" in res.output


def test_an_archive_given_to_detect_points_to_scan(tmp_path, run_cli):
    import zipfile

    import pytest

    import lishield_guard

    (img,) = write_images(tmp_path, ["a.jpg"])
    archive = tmp_path / "photos.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.write(img, "a.jpg")
    res = run_cli("detect", archive)
    assert res.exit_code == 3 and "[unsupported_media_type]" in res.output
    assert "`lishield-guard scan` reads" in res.output and "ZIP archive" in res.output
    with pytest.raises(lishield_guard.UnsupportedImageError, match="lishield-guard scan"):
        detect_mod.detect(archive.read_bytes())  # the Python API (not patched here)


def test_plot_help_describes_the_figure_drawn_now(run_cli):
    """`detect --plot`'s help described the cascade's old figure (fitted rows, template,
    look-alike) as what every verdict gets."""
    from lishield_guard.figure_learned import learned_caption

    words = _help_words(run_cli("detect", "--help").output)
    assert "the network's logit for every axis and pyramid level" in words
    assert "take turns" in words and "take turns" in learned_caption(False)
