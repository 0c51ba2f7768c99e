"""Video screening on real encoded clips: decode limits, the frame plan, the stopping rule and
verdicts of barcode and clean clips."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from lishield_guard.config import default_config
from lishield_guard.errors import (
    CorruptVideoError,
    EmptyImageError,
    ImageTooLargeError,
    UnsupportedImageError,
    VideoTooLongError,
)
from lishield_guard.video.calibrate import ClipScores, flag_threshold, markov_far
from lishield_guard.video.decode import is_video_bytes, open_video
from lishield_guard.video.screen import (
    clip_logit,
    combine_frames,
    detect_video,
    plan_runs,
)
from lishield_guard.settings import VideoConfig, VideoLimits

av = pytest.importorskip("av")
synth_video = pytest.importorskip("synth.video")


def _clip(**kw) -> bytes:
    args = dict(size="360p", duration_s=2.0, fps=30, motion=False, bitrate=1_500_000)
    args.update(kw)
    data, _ = synth_video.render_video_item(synth_video.clip_params(**args))
    return data


@pytest.fixture(scope="module")
def barcode_clip() -> bytes:
    """A strong RGB barcode (f_B = 200 Hz) under dim ambient light."""
    return _clip(seed=3, preset="table2-rgb", switching_hz=200.0, ambient_ratio=0.2,
                 exposure_s=1 / 4000)


@pytest.fixture(scope="module")
def clean_clip() -> bytes:
    """A steady light over a photo, camera panning."""
    return _clip(seed=2, negative="steady", motion=True)


def _remux(data: bytes, path, **options) -> bytes:
    """The same packets in a new MP4 (e.g. ``movflags=faststart``: index before the data)."""
    src = av.open(io.BytesIO(data))
    with av.open(str(path), "w", format="mp4", options=options) as out:
        st = out.add_stream_from_template(src.streams.video[0])
        for pkt in src.demux(src.streams.video[0]):
            if pkt.dts is None:
                continue
            pkt.stream = st
            out.mux(pkt)
    src.close()
    return path.read_bytes()


def test_barcode_clip_is_flagged_and_names_its_frames(barcode_clip):
    v = detect_video(barcode_clip, default_config())
    assert v.status == "protected", v.evidence["reason"]
    vid = v.evidence["video"]
    assert vid["info"]["codec"] == "h264" and vid["info"]["n_frames"] == 60
    assert v.evidence["deciding_frames"] and v.policy == "no-distribution"
    assert vid["stop"] == "flagged" and len(vid["frames"]) <= VideoConfig().max_frames


def test_clean_clip_is_cleared_early(clean_clip):
    v = detect_video(clean_clip, default_config())
    assert v.status == "clean", v.evidence["reason"]
    assert len(v.evidence["video"]["frames"]) < VideoConfig().max_frames  # stopped early


def test_rotated_clip_reports_its_rotation_and_is_still_flagged():
    data = _clip(seed=3, preset="table2-rgb", switching_hz=200.0, ambient_ratio=0.2,
                 exposure_s=1 / 4000, rotation_deg=90)
    with open_video(data) as r:
        assert r.info.rotation_deg == 90
    v = detect_video(data, default_config())
    assert v.status == "protected"
    assert v.evidence["video"]["info"]["rotation_deg"] == 90


def test_truncated_clip_is_refused(barcode_clip, tmp_path):
    with pytest.raises(CorruptVideoError) as e:  # index (moov) at the end: cut off
        open_video(barcode_clip[: len(barcode_clip) * 2 // 3])
    assert e.value.code == "undecodable_video"
    fast = _remux(barcode_clip, tmp_path / "fast.mp4", movflags="faststart")
    assert fast[:64].find(b"moov") > 0
    with pytest.raises(CorruptVideoError, match="truncated"):  # index first: data cut off
        open_video(fast[: len(fast) * 2 // 3])


def test_limits_refuse_long_and_large_clips(barcode_clip):
    with pytest.raises(VideoTooLongError) as e:
        open_video(barcode_clip, VideoLimits(max_duration_s=1.5))
    assert e.value.code == "video_too_long"
    with pytest.raises(VideoTooLongError):
        open_video(barcode_clip, VideoLimits(max_frames=59))
    with pytest.raises(ImageTooLargeError):
        open_video(barcode_clip, VideoLimits(max_frame_pixels=640 * 360 - 1))


def test_not_a_video_and_empty_input():
    with pytest.raises(EmptyImageError):
        open_video(b"")
    with pytest.raises(UnsupportedImageError):
        open_video(b"\x89PNG\r\n\x1a\n" + b"\0" * 100)
    assert not is_video_bytes(b"\xff\xd8\xff\xe0")


def test_decode_budget_leaves_the_clip_undetermined(barcode_clip):
    vcfg = VideoConfig(limits=VideoLimits(max_decoded_frames=1), min_frames=2, first_frames=2)
    v = detect_video(barcode_clip, default_config(), vcfg)
    assert v.status == "undetermined" and "decode_budget" in v.undetermined


def test_webm_vp9_clip_is_read():
    data = _clip(seed=2, negative="steady", codec="vp9")
    assert data[:4] == b"\x1a\x45\xdf\xa3"
    with open_video(data) as r:
        assert r.info.codec == "vp9"
        frames = list(r.frames([0.0, 0.5]))
    assert [f.index for f in frames] == [0, 15]


def test_frames_are_decoded_where_asked_and_scaled(barcode_clip):
    with open_video(barcode_clip) as r:
        assert r.row_scale(180) == 2 and r.row_scale(181) == 1 and r.row_scale(0) == 1
        frames = list(r.frames([1.0, 0.0, 1 / 30], max_rows=180))
    assert [f.index for f in frames] == [0, 1, 30]
    assert frames[0].rgb.shape == (180, 320, 3) and frames[0].keyframe


def test_plan_visits_keyframes_first_and_stays_in_budget(barcode_clip):
    with open_video(barcode_clip) as r:
        info = r.info
    vcfg = VideoConfig()
    runs = plan_runs(info, vcfg)
    times = [t for run in runs for t in run]
    assert len(times) == len(set(times)) <= vcfg.max_frames
    assert all(0 <= t < info.duration_s for t in times)
    assert runs[0][0] == 0.0 and all(len(run) <= vcfg.first_frames for run in runs)


def test_clip_logit_lies_between_mean_and_max():
    rng = np.random.default_rng(0)
    for _ in range(50):
        x = rng.normal(0, 3, rng.integers(1, 20))
        s = clip_logit(x)
        assert x.mean() - 1e-9 <= s <= x.max() + 1e-9
    assert clip_logit([]) == -math.inf


def test_stopping_rule_flags_clears_and_waits():
    assert combine_frames([5.0, 5.0], [2], 3.0, 0.0)[0] == "flagged"
    assert combine_frames([-2.0, -3.0], [2], 3.0, 0.0)[0] == "cleared"
    assert combine_frames([-1.0, 2.0], [2], 3.0, 0.0)[0] == "open"
    stop, n, _ = combine_frames([1.0, 1.0, 4.0, 4.0], [2, 2], 3.0, 0.0)
    assert (stop, n) == ("flagged", 4)  # the second run added up
    assert combine_frames([1.0, 1.0], [2], 3.0, 0.0)[0] == "open"


def test_flag_threshold_is_the_lowest_flagging_threshold():
    c = ClipScores("x", (1.0, 2.0, -5.0, 3.0), (2, 2), 1.0)
    vcfg = VideoConfig(clear_logit=0.0, min_frames=1, first_frames=2)
    t = flag_threshold(c, vcfg)
    for thr in (t - 0.01, t + 0.01):
        stop = combine_frames(c.logits, c.run_sizes, thr, 0.0, 1)[0]
        assert (stop == "flagged") == (thr <= t)


def test_markov_bound_holds_on_dependent_frames():
    rng = np.random.default_rng(1)
    frames = rng.normal(-3, 1.5, 20_000)
    clips = np.repeat(rng.normal(-3, 1.5, 4000)[:, None], 8, axis=1)  # fully dependent
    clips = clips + rng.normal(0, 0.3, clips.shape)
    s = np.array([clip_logit(c) for c in clips])
    for thr in (0.0, 1.0, 2.0):
        assert np.mean(s >= thr) <= markov_far(frames, thr, 1) + 0.01


def test_a_clip_is_flagged_where_its_first_frame_alone_is_clean():
    """A faint barcode (ambient light 5x the LED): the clip's first frame, screened as a
    photo, is clean; other frames of the clip (the light at other phases) show the stripes,
    and the clip is flagged. The scene is pinned, so the clip does not depend on the photo
    corpus being present."""
    from lishield_guard import detect

    data = _clip(seed=2, preset="table2-rgb", switching_hz=200.0, ambient_ratio=5.0,
                 exposure_s=1 / 4000, scene="skimage:astronaut")
    cfg = default_config()
    v = detect_video(data, cfg)
    vid = v.evidence["video"]
    assert v.status == "protected" and vid["stop"] == "flagged"
    first = vid["frames"][0]
    assert first["index"] == 0 and first["logit"] < cfg.detector.learned.threshold_logit
    with open_video(data) as r:  # the same frame as a photo: clean
        frame = next(r.frames([0.0])).rgb
    assert detect(frame, cfg).status == "clean"
