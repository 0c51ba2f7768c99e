"""First stage: ordinary photos are cleared before the pattern search; barcodes never are."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from cascade import cascade_config, detect_cascade
from fit_once import RefineOnce
from skimage import data

from lishield_guard import PRESETS
from lishield_guard.detector.screen import screen_plane
from lishield_guard.detector.tracks import PlaneAnalysis, Track

FIRST_STAGE = "first stage"


@pytest.mark.parametrize("photo", ["astronaut", "chelsea", "coffee", "rocket"])
def test_steady_light_photo_is_cleared_by_the_first_stage(make_led_image, photo):
    scene = cv2.resize(getattr(data, photo)(), (1440, 1080))
    v = detect_cascade(make_led_image(None, scene=scene))
    assert not v.protected
    assert v.evidence["reason"].startswith(FIRST_STAGE), v.evidence["reason"]
    for cand in v.evidence["candidates"]:
        assert cand["reason"].startswith(FIRST_STAGE)


@pytest.mark.parametrize("pwm_hz, duty", [(400.0, 0.3), (1000.0, 0.5), (2400.0, 0.7)])
def test_pwm_light_on_a_photo_is_cleared_by_the_first_stage(make_led_image, pwm_hz, duty):
    """A PWM-dimmed light (deep, column-coherent stripes on scikit-image's moon photo at 1080p)
    passes the track screen; its stripes are one steady square wave, so the first stage clears
    every spec before any pattern search (the steady test removed, the search would run).
    On strongly textured photos the texture keeps the look-alike below the 0.99 the test
    needs and the PWM goes on to the pattern search, which rejects it later."""
    t = np.arange(1080) / 30_000.0
    flicker = 0.25 + 0.5 * (((t * pwm_hz) % 1.0) < duty)
    moon = np.repeat(data.moon()[..., None], 3, axis=2)
    v = detect_cascade(make_led_image(None, flicker=flicker, scene=cv2.resize(moon, (1440, 1080))))
    assert not v.protected
    reasons = [c["reason"] for c in v.evidence["candidates"] if c["axis"] == "rows"]
    assert reasons and all(r.startswith(f"{FIRST_STAGE}: the stripes are a steady square wave")
                           for r in reasons), reasons
    assert v.evidence["candidates"][0]["sweep"] is None


def test_a_12_mp_jpegs_own_block_grid_is_not_stripes():
    """A 12 MP JPEG decoded at 3/8 scale shows its 8x8 block grid as a column-coherent
    3-row period; the first stage must not take it for LED stripes (it did: every such
    photo paid the whole pattern search, about 1 s)."""
    from lishield_guard.decode import decode
    from lishield_guard.detector.screen import jpeg_grid_cpr
    from lishield_guard.detector.search import analyse_plane

    rng = np.random.default_rng(12)
    big = cv2.resize(data.astronaut(), (4032, 3024), interpolation=cv2.INTER_CUBIC)
    big = np.clip(big + rng.normal(0, 2.0, big.shape), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", big[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    v = detect_cascade(buf.tobytes())
    assert v.status == "clean"
    assert all(c["stage"] == FIRST_STAGE for c in v.evidence["candidates"]), \
        [(c["axis"], c["reason"]) for c in v.evidence["candidates"]]
    # the grid is what the screen would otherwise count
    cfg = cascade_config()
    dec = decode(buf.tobytes(), limits=cfg.limits, max_rows=cfg.detector.profiles.max_decode_rows)
    grid = jpeg_grid_cpr(dec.format, dec.row_scale)
    assert dec.row_scale == pytest.approx(8 / 3) and min(abs(g - 1 / 3) for g in grid) < 1e-6
    planes = [analyse_plane(np.ascontiguousarray(dec.rgb()[:, :, i]), axis, cfg, dec.row_scale)
              for i in range(3) for axis in (0, 1)]
    det = cfg.detector
    assert any(screen_plane(pa, false_prob=det.screen.false_prob,
                            min_frames=det.screen.min_frames).passed for pa in planes)
    assert not any(screen_plane(pa, false_prob=det.screen.false_prob,
                                min_frames=det.screen.min_frames, grid_cpr=grid).passed
                   for pa in planes)


def test_screen_counts_frames_above_its_own_threshold():
    snr = np.array([0.0, 50.0, 60.0, 1.0])
    track = Track(64, 0.01, 0.4, np.full(4, 0.1), snr, 1e9, n_bins=20.0, n_blocks=8)
    pa = PlaneAnalysis(512, 8, (track,), ())
    # threshold at p = 0.01 over 20 bins and 7 degrees of freedom pairs: 7 ((5e-4)^(-1/7) - 1)
    thr = 7 * ((0.01 / 20) ** (-1 / 7) - 1)
    assert 1.0 < thr < 50.0
    r = screen_plane(pa, false_prob=0.01, min_frames=2)
    assert (r.passed, r.frames, r.window_rows) == (True, 2, 64)
    assert not screen_plane(pa, false_prob=0.01, min_frames=3).passed
    assert screen_plane(pa, false_prob=None, min_frames=99).passed  # screen off


def test_two_windows_agreeing_on_one_frequency_pass():
    """One frame above the threshold in each of two window lengths is enough when both peaks
    sit at one frequency (two looks at one stripe); at unrelated frequencies it is noise."""
    def track(w, freq):
        snr = np.array([0.0, 1e3, 0.0])
        return Track(w, 0.01, 0.4, np.array([0.2, freq, 0.3]), snr, 1e9, n_bins=20.0,
                     n_blocks=8)

    agree = PlaneAnalysis(512, 8, (track(128, 0.1), track(256, 0.1 + 0.5 / 256)), ())
    r = screen_plane(agree, false_prob=0.01, min_frames=2)
    assert (r.passed, r.frames, r.via) == (True, 1, "two windows")
    apart = PlaneAnalysis(512, 8, (track(128, 0.1), track(256, 0.1 + 2 / 256)), ())
    r = screen_plane(apart, false_prob=0.01, min_frames=2)
    assert (r.passed, r.via) == (False, None)


def test_a_light_covering_half_the_frame_passes_the_first_stage(make_led_image):
    """A barcode LED lighting the right half of the scene: the unlit blocks raise the residual
    the peaks are tested against, so no frame passes on all blocks together; the right half of
    the columns passes on its own, and the capture the full cascade flags stays flagged (two
    such development captures were cleared before the halves were tested)."""
    from lishield_guard.decode import decode
    from lishield_guard.detector.search import analyse_plane

    cfg = cascade_config()
    det = cfg.detector
    img = make_led_image(PRESETS["table1-seq1"], switching_hz=300.0, lit_fraction=0.5,
                         ambient=0.5)
    pa = analyse_plane(decode(img, limits=cfg.limits).luma, 0, cfg)
    on_all = screen_plane(pa, false_prob=det.screen.false_prob, min_frames=det.screen.min_frames)
    assert not on_all.passed
    halves = screen_plane(pa, false_prob=det.screen.false_prob, min_frames=det.screen.min_frames,
                          partial_false_prob=det.screen.partial_false_prob,
                          partial_min_frames=det.screen.partial_min_frames)
    assert halves.passed and halves.via == "right half", halves
    assert detect_cascade(img, det.replace(screen=None)).protected
    assert detect_cascade(img).protected
    assert not detect_cascade(img, det.with_values({"screen.partial_false_prob": None})).protected


def test_screen_never_clears_what_the_full_cascade_flags(make_led_image, rng, monkeypatch):
    """Barcodes of random presets, rates, exposures and ambient: each one the full cascade
    flags (screen off) is flagged with the screen on. What the screen passes is searched
    again, but its exact fits, made with the screen off, are not made again
    (`fit_once.RefineOnce`: 38 s of CPU before, 26 s)."""
    RefineOnce().install(monkeypatch)
    base = cascade_config()
    full = base.detector.replace(screen=None)
    flagged = 0
    for _ in range(6):
        name = str(rng.choice(["table1-seq1", "table1-seq2", "table1-seq3", "table2-rgb"]))
        spec = PRESETS[name]
        img = make_led_image(spec, switching_hz=float(rng.uniform(200.0, spec.f1_hz)),
                             exposure_s=float(rng.choice([1 / 8000, 1 / 2000, 1 / 1000])),
                             ambient=float(rng.choice([0.5, 2.0, 4.0])),
                             row_rate_hz=float(rng.uniform(30e3, 120e3)))
        v_full = detect_cascade(img, full)
        if v_full.protected:
            flagged += 1
            v = detect_cascade(img, base)
            assert v.protected, v.evidence["reason"]
    assert flagged >= 3


def test_a_cleared_photo_pays_neither_tone_tracks_nor_sub_block_detrending(make_led_image,
                                                                          monkeypatch):
    """What the first stage clears costs only the screen: no spec's tones are matched, and
    sub-blocks are detrended only for the luma halves test, not for the 8 planes analysed
    (both ran for every plane of every photo before)."""
    import lishield_guard.detector.search as search
    import lishield_guard.detector.tracks as tracks

    def forbidden(*args, **kwargs):
        raise AssertionError("called for a photo the first stage clears")

    scene = cv2.resize(data.coffee(), (1440, 1080))
    image = make_led_image(None, scene=scene)
    monkeypatch.setattr(search, "match_spec", forbidden)
    real_detrend = tracks.detrend_profiles
    sizes = []
    monkeypatch.setattr(tracks, "detrend_profiles",
                        lambda p, **kw: sizes.append(p.shape[0]) or real_detrend(p, **kw))
    v = detect_cascade(image)
    assert v.status == "clean"
    assert all(c["stage"] == FIRST_STAGE and c["n_matched"] == 0
               for c in v.evidence["candidates"])
    n_blocks = cascade_config().detector.profiles.n_col_blocks
    assert sizes.count(n_blocks) == 8  # L, R, G, B along rows and columns
    assert sum(s > n_blocks for s in sizes) <= 2  # the halves test, luma only


def test_sub_blocks_detrended_on_first_use_equal_the_eager_result(rng):
    """`PlaneAnalysis.fit_blocks` from sub-block row means, detrended on first use, is the
    eager detrend of the usable sub-blocks, and judged at another false-pass probability the
    copy shares it."""
    from lishield_guard.detector.profiles import detrend_profiles
    from lishield_guard.detector.tracks import analyse_profiles

    rows = np.arange(1024)
    fine = 120 + 30 * rng.random((32, 1)) + 5 * np.sin(rows / 40.0) + rng.normal(0, 1, (32, 1024))
    fine[3] = 0.0  # a black sub-block is not usable
    coarse = fine.reshape(8, 4, -1).mean(axis=1)
    pa = analyse_profiles(coarse, full_scale=255.0, band_cpr=(0.01, 0.4), trend_sigma_rows=50.0,
                          false_prob=1e-3, fine_profiles=fine)
    usable = np.delete(fine, 3, axis=0)
    want = detrend_profiles(usable, sigma_rows=50.0)[0].astype(np.float32)
    np.testing.assert_array_equal(pa.fit_blocks, want)
    other = pa.with_false_prob(1e-2)
    assert other.fit_blocks is pa.fit_blocks


def test_every_usable_sub_block_takes_part_in_the_halves_test(rng):
    """With 24 usable sub-blocks (some black or saturated), stripes in the right-most 8 are
    found by the right half; only the first 16 took part before, and they were missed."""
    n_rows, n_sub = 1024, 24
    rows = np.arange(n_rows)
    fine = rng.normal(0.0, 0.01, (n_sub, n_rows))
    fine[16:] += 0.05 * np.sin(2 * np.pi * 0.06 * rows)
    pa = PlaneAnalysis(n_rows, 8, (), (), fine.mean(axis=0).astype(np.float32),
                       fine.reshape(8, 3, -1).mean(axis=1).astype(np.float32),
                       fine.astype(np.float32), (0.01, 0.45))
    r = screen_plane(pa, false_prob=0.01, min_frames=2, partial_false_prob=1e-3,
                     partial_min_frames=3)
    assert r.via == "right half" and r.part_frames >= 3, r


def test_the_evidence_lists_searched_candidates_before_cleared_ones():
    """With more (axis, spec) candidates than the evidence lists, the ones the pattern search
    looked at are kept ahead of those the first stage cleared (same tone count): what
    evaluate.py's "stage reached" reads from the verdict."""
    from lishield_guard.detector.results import SpecMatch
    from lishield_guard.profiles.cascade import MAX_CANDIDATES, _verdict

    def cand(axis, name, stage):
        return (axis, "p", SpecMatch(name, 0.0, {}, {}, 0, 2, 0.0, 0, False, "r", stage=stage))

    cands = [cand("rows", f"s{i}", "first stage") for i in range(MAX_CANDIDATES)]
    cands += [cand("columns", "s0", "exact fit"), cand("columns", "s1", "sweep")]
    v = _verdict(cands, {"rows": {}, "columns": {}}, cascade_config(), [], {}, 1, "jpeg", "",
                 1.0)
    listed = v.evidence["candidates"]
    assert len(listed) == MAX_CANDIDATES
    assert [c["stage"] for c in listed[:2]] == ["exact fit", "sweep"]
