"""`calibrate-videos` on real encoded clean clips: a threshold above every tuning clip, the
per-clip bound on the held-out clips, the written config read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from lishield_guard.cli import app
from lishield_guard.config import load_config
from lishield_guard.video.calibrate import ClipScores, calibrate_video, flag_threshold
from lishield_guard.settings import VideoConfig

synth_video = pytest.importorskip("synth.video")


@pytest.fixture(scope="module")
def clean_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("clean")
    for i, kind in enumerate(["steady", "mains", "pwm", "texture"] * 3):
        p = synth_video.clip_params(size="360p", duration_s=1.0, fps=25, seed=100 + i,
                                    negative=kind, bitrate=800_000)
        (d / f"{i:03d}.mp4").write_bytes(synth_video.render_video_item(p)[0])
    return d


def test_cli_writes_a_certified_video_threshold(clean_dir, tmp_path):
    out, rep = tmp_path / "v.toml", tmp_path / "rep"
    r = CliRunner().invoke(app, ["calibrate-videos", "--clean", str(clean_dir), "--out",
                                 str(out), "--report", str(rep), "--certify-fraction", "0.25",
                                 "--target-far", "0.5", "-j", "1", "--no-progress"])
    assert r.exit_code in (0, 3), r.output
    cfg = load_config(out)
    summary = json.loads((rep / "summary.json").read_text())
    assert cfg.video.threshold_logit == summary["threshold_logit"]
    clips = [ClipScores(**{**d, "logits": tuple(d["logits"]), "run_sizes": tuple(d["run_sizes"])})
             for d in map(json.loads, (rep / "clips.jsonl").read_text().splitlines())]
    assert len(clips) == 12 and summary["n_tune"] + summary["n_cert"] == 12
    assert summary["flagged_tune"] == 0  # the threshold sits above every tuning clip
    assert "per-clip FAR" in out.read_text().split("[detector]")[0]


def test_threshold_and_bound_follow_the_clips():
    rng = np.random.default_rng(0)
    vcfg = VideoConfig(clear_logit=-99.0)
    clean = [ClipScores(f"c{i}", tuple(rng.normal(-1, 1, 8)), (4, 4), 0.0) for i in range(200)]
    cal = calibrate_video(clean, vcfg, target_far=0.05)
    tune_max = max(flag_threshold(c, vcfg) for c in clean)
    assert cal.threshold_logit <= tune_max + 0.01 and cal.flagged_tune == 0
    assert cal.n_tune + cal.n_cert == 200 and cal.far_bound < 0.05 and cal.met
    held = [ClipScores(f"h{i}", (9.0,) * 8, (4, 4), 9.0) for i in range(3)]
    both = calibrate_video(clean, vcfg, target_far=0.05, certify=held)
    assert both.threshold_logit == cal.threshold_logit  # held-out clips never tune
    assert both.n_cert == cal.n_cert + 3 and both.flagged_cert == cal.flagged_cert + 3
    with pytest.raises(ValueError):
        calibrate_video(clean[:5], vcfg)
