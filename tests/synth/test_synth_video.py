"""Synthetic clips: decodable files, per-frame physics, deterministic sets, rotation, CLI."""

from __future__ import annotations

import hashlib
import io
import json
from collections import Counter

import numpy as np
import pytest
from typer.testing import CliRunner

from lishield_guard.errors import ConfigError
from synth.video import (
    clip_params,
    render_frames,
    render_video_item,
    sample_video_item,
)

av = pytest.importorskip("av")

SIZE = "96x64"  # W x H: tiny and even (yuv420p)


def _decode(data: bytes) -> tuple[object, list]:
    with av.open(io.BytesIO(data)) as c:
        st = c.streams.video[0]
        frames = [f for f in c.decode(st)]
        info = {"codec": st.codec_context.name, "fps": float(st.average_rate),
                "width": st.width, "height": st.height, "format": c.format.name}
    return info, frames


@pytest.mark.parametrize("codec,fmt", [("h264", "mp4"), ("vp9", "webm")])
def test_clip_decodes_with_its_rate_size_and_codec(codec, fmt):
    p = clip_params(seed=1, size=SIZE, fps=25, duration_s=0.4, codec=codec)
    data, rec = render_video_item(p)
    info, frames = _decode(data)
    assert info["codec"] == codec and fmt in info["format"]
    assert info["fps"] == 25.0 and len(frames) == rec["n_frames"] == 10
    assert (info["width"], info["height"]) == (rec["width"], rec["height"]) == (96, 64)
    assert rec["duration_s"] == pytest.approx(0.4)
    assert len(rec["exposures_s"]) == 10 and max(rec["exposures_s"]) <= 1 / 25
    if rec["label"]:
        assert len(rec["led_contrast"]) == 10


def test_sampled_clips_respect_the_frame_interval_and_cover_every_kind():
    items = [sample_video_item(i % 2, seed=100 + i, size="mixed") for i in range(120)]
    for p in items:
        assert p["fps"] in (24.0, 25.0, 30.0, 50.0, 60.0)
        assert p["sensor_rows"] / p["row_rate_hz"] < 1 / p["fps"]  # readout fits a frame
        assert p["exposure_s"] <= 1 / p["fps"]
        assert 2.0 - 1 / p["fps"] <= p["duration_s"] <= 10.0 + 1 / p["fps"]
        assert "jpeg_quality" not in p and p["bitrate"] > 0
    kinds = Counter(p["kind"] for p in items)
    assert set(kinds) == {"barcode", "steady", "mains", "pwm", "texture"}
    moving = sum(p["motion"]["enabled"] for p in items)
    assert 35 <= moving <= 85
    assert {p["size"] for p in items} >= {"540p", "720p"}


def _profiles(p: dict) -> np.ndarray:
    return np.array([f.astype(np.float64).mean(axis=(1, 2)) for f in render_frames(p)])


@pytest.mark.parametrize("negative", [None, "steady"])
def test_led_phase_moves_between_frames_only_under_a_flickering_light(negative):
    p = clip_params(seed=4, size="128x96", preset="table1-seq1", switching_hz=200.0, fps=30,
                    duration_s=0.1, negative=negative, ambient_ratio=0.0, coverage=1.0,
                    exposure_s=1 / 4000, motion=False, scene="skimage:camera")
    p["noise"] = False
    prof = _profiles(p)
    change = np.abs(prof[1:] - prof[:-1]).mean(axis=1) / prof.mean()
    if negative is None:
        assert change.min() > 0.02  # the stripes move: frame k starts k / fps later
    else:
        assert change.max() < 1e-3  # same scene, same light: the same frame


def test_camera_motion_moves_the_scene():
    p = clip_params(seed=5, size=SIZE, fps=30, duration_s=0.3, negative="texture",
                    motion=True, exposure_s=1 / 1000)
    p["noise"] = False
    p["motion"] = dict(p["motion"], pan_start_rc=[0.0, 0.0], pan_end_rc=[1.0, 1.0], margin=0.3)
    prof = _profiles(p)
    assert np.abs(prof[-1] - prof[0]).mean() > 0.5


@pytest.mark.parametrize("mode,rotation,shape", [("tag", -90, (96, 64)),
                                                 ("bake", 0, (64, 96))])
def test_rotation_tag_round_trips(mode, rotation, shape):
    p = clip_params(seed=2, size=SIZE, fps=24, duration_s=0.25, rotation_deg=90,
                    rotation_mode=mode)
    data, rec = render_video_item(p)
    info, frames = _decode(data)
    assert rec["rotation_mode"] == mode
    assert frames[0].rotation == rotation  # PyAV: counter-clockwise degrees
    assert (info["width"], info["height"]) == shape


_WRITE_SET = """
import dataclasses, sys
from synth.dataset import resolve_mix
from synth.video import VIDEO_MIXES, write_video_dataset
if __name__ == "__main__":
    write_video_dataset(sys.argv[1], n_pos=2, n_neg=2, seed=9, size=(64, 96),
                        mix=dataclasses.replace(resolve_mix("default"), real_photo_prob=0.0),
                        video_mix=dataclasses.replace(VIDEO_MIXES["default"],
                                                      duration_range_s=(0.15, 0.25)),
                        jobs=int(sys.argv[2]), progress=False)
"""


@pytest.mark.xfail(strict=False, reason="known issue (docs/synth_video.md): one clip of this "
                   "set is sometimes encoded differently from run to run; cause not found")
def test_video_dataset_is_identical_for_any_jobs(tmp_path):
    """Each set is written by a fresh process, as the CLI does."""
    import subprocess
    import sys

    script = tmp_path / "write_set.py"
    script.write_text(_WRITE_SET)
    digests = []
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        subprocess.run([sys.executable, str(script), str(out), str(jobs)], check=True,
                       timeout=120)
        manifest = out / "manifest.jsonl"
        rows = [json.loads(line) for line in manifest.read_text().splitlines()]
        assert [r["file"] for r in rows] == [f"{i:06d}.mp4" for i in range(4)]
        assert sorted(r["label"] for r in rows) == [0, 0, 1, 1]
        for r in rows:
            assert {"fps", "duration_s", "n_frames", "bitrate", "codec", "container",
                    "motion", "rotation_deg", "kind", "light", "scene"} <= set(r)
        digests.append([hashlib.sha256((out / r["file"]).read_bytes()).hexdigest()
                        for r in rows] + [hashlib.sha256(manifest.read_bytes()).hexdigest()])
    assert digests[0] == digests[1]


def test_bad_parameters_are_config_errors():
    with pytest.raises(ConfigError, match="even"):
        clip_params(size="95x64")
    with pytest.raises(ConfigError, match="negative"):
        clip_params(size=SIZE, negative="neon")
    with pytest.raises(ConfigError, match="exposure_s"):
        clip_params(size=SIZE, fps=60, exposure_s=1 / 30)


def test_cli_writes_a_clip(tmp_path):
    from lishield_guard.cli import app

    out = tmp_path / "clip.mp4"
    res = CliRunner().invoke(app, ["synth", "video", "-o", str(out), "--size", SIZE,
                                   "--fps", "24", "--duration", "0.5", "--negative", "mains",
                                   "--json"])
    assert res.exit_code == 0, res.output
    rec = json.loads(res.stdout.splitlines()[-1])
    assert rec["kind"] == "mains" and rec["n_frames"] == 12
    info, frames = _decode(out.read_bytes())
    assert info["codec"] == "h264" and len(frames) == 12


def test_cli_plays_the_presets_own_f_b_and_prints_one_line(tmp_path):
    """Issue 41: ``--preset table1-seq1`` without ``--f-b`` ran at the mix's 200 Hz, not at
    the preset's 400 Hz, and the command printed the whole record (per-frame arrays)."""
    from lishield_guard.cli import app
    from lishield_guard.spec import get_preset

    out = tmp_path / "clip.mp4"
    res = CliRunner().invoke(app, ["synth", "video", "-o", str(out), "--size", SIZE,
                                   "--fps", "24", "--duration", "0.25", "--preset",
                                   "table1-seq1"])
    assert res.exit_code == 0, res.output
    (line,) = res.stdout.splitlines()
    assert line.startswith(f"{out} preset=table1-seq1 f_B=400Hz frames=6 ") and len(line) < 200
    assert get_preset("table1-seq1").f_b_hz == 400.0


def test_an_interrupted_video_set_resumes_from_its_finished_clips(tmp_path):
    """A clip whose record is in ``.parts`` is not rendered again; the parts go once the
    manifest is written."""
    import dataclasses

    from synth.dataset import resolve_mix
    from synth.video import PARTS_DIR, VIDEO_MIXES, write_video_dataset

    kw = dict(n_pos=1, n_neg=1, seed=9, size=(64, 96), progress=False,
              mix=dataclasses.replace(resolve_mix("default"), real_photo_prob=0.0),
              video_mix=dataclasses.replace(VIDEO_MIXES["default"],
                                            duration_range_s=(0.15, 0.2)))
    parts = tmp_path / PARTS_DIR
    parts.mkdir()
    (parts / "000000.json").write_text(json.dumps({"file": "000000.mp4", "index": 0,
                                                   "label": 1, "resumed": True}))
    manifest = write_video_dataset(tmp_path, **kw)
    rows = [json.loads(line) for line in manifest.read_text().splitlines()]
    assert rows[0]["resumed"] and not (tmp_path / "000000.mp4").exists()
    assert (tmp_path / rows[1]["file"]).exists() and "resumed" not in rows[1]
    assert not parts.exists()
