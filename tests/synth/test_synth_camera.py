"""Camera pipeline: metering, saturation, noise, post-processing, JPEG/EXIF; scenes."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageOps

from lishield_guard.camera import CameraModel
from lishield_guard.errors import ConfigError, InvalidImageError
from synth.camera import (
    EXIF_ORIENTATION,
    auto_exposure_s,
    encode_jpeg,
    linear_to_srgb8,
    postprocess,
    render_linear,
    simulate_frame,
    simulate_video,
)
from synth.light import PwmLight, SteadyLight, coverage_map
from synth.scene import PHOTO_NAMES, load_scene, srgb_to_linear, texture_scene

CAM = CameraModel(row_time_s=1 / 60_000, n_rows=96, exposure_s=1 / 1000)


def _scene(n_rows=96, n_cols=128, value=0.4):
    return np.full((n_rows, n_cols, 3), value, dtype=np.float32)


def test_auto_gain_meters_to_target():
    out = simulate_frame(SteadyLight(), _scene(), CAM, rng=np.random.default_rng(0),
                         noise=False, output="linear", target_mean=0.25)
    assert out.dtype == np.float32
    assert out.mean() == pytest.approx(0.25, rel=1e-5)


def test_manual_gain_scales_with_exposure_and_saturates():
    kw = {"rng": np.random.default_rng(0), "noise": False, "output": "linear", "gain": 1.0}
    a = simulate_frame(SteadyLight(), _scene(), CAM, **kw)
    cam2 = CameraModel(row_time_s=CAM.row_time_s, n_rows=CAM.n_rows, exposure_s=2e-3)
    b = simulate_frame(SteadyLight(), _scene(), cam2, **kw)
    np.testing.assert_allclose(b, 2 * a, rtol=1e-6)
    hot = simulate_frame(SteadyLight(), _scene(), CAM, rng=np.random.default_rng(0), gain=64.0)
    assert np.all(hot == 255)


def test_noise_statistics_follow_shot_noise():
    cam = CameraModel(row_time_s=1 / 60_000, n_rows=256, exposure_s=1 / 1000)
    out = simulate_frame(SteadyLight(), _scene(256, 256), cam, rng=np.random.default_rng(3),
                         output="linear", gain=4.0)
    # electrons = 0.4 * 1.5e6 * 1e-3 = 600; DN = e * 4 / 6000; var = e * (4/6000)^2 + read
    mean_dn = 600 * 4 / 6000
    var = (600 + 2.5**2) * (4 / 6000) ** 2
    assert out.mean() == pytest.approx(mean_dn, rel=2e-3)
    assert out.var() == pytest.approx(var, rel=0.02)


def test_ambient_and_coverage_compose_linearly():
    light = PwmLight(freq_hz=700.0, duty=0.5)
    cov = coverage_map(96, 128, fraction=0.5, centre_rc=(0.5, 0.2))
    full = render_linear(light, _scene(), CAM, start_s=0.01)
    mixed = render_linear(light, _scene(), CAM, start_s=0.01, ambient_ratio=2.0, coverage=cov)
    np.testing.assert_allclose(mixed, 0.4 * 2.0 + cov[:, :, None] * full, rtol=1e-6)


def test_srgb_round_trip_and_lut():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    enc = linear_to_srgb8(x.copy())
    assert enc[0] == 0 and enc[-1] == 255
    back = srgb_to_linear(enc)
    assert np.abs(back - x).max() < 0.01
    assert np.all(np.diff(enc.astype(int)) >= 0)


def test_postprocess_downscale_and_rotation():
    img = np.random.default_rng(0).integers(0, 256, (90, 120, 3), dtype=np.uint8)
    small, o = postprocess(img, downscale=2.0)
    assert small.shape == (45, 60, 3) and o == 1
    for deg in (90, 180, 270):
        baked, o = postprocess(img, rotation_deg=deg, rotation_mode="bake")
        assert o == 1
        _, tag = postprocess(img, rotation_deg=deg, rotation_mode="exif")
        assert tag == EXIF_ORIENTATION[deg]
        # A viewer applying the EXIF tag shows exactly the baked pixels.
        im = Image.open(io.BytesIO(encode_jpeg(img, quality=100, subsampling="4:4:4",
                                               exif_orientation=tag)))
        assert im.getexif()[0x0112] == tag
        shown = np.asarray(ImageOps.exif_transpose(im), dtype=int)
        assert shown.shape == baked.shape
        ref = np.asarray(Image.open(io.BytesIO(encode_jpeg(baked, quality=100,
                                                           subsampling="4:4:4"))), dtype=int)
        assert np.abs(shown - ref).mean() < 3
    with pytest.raises(ConfigError, match="rotation_deg"):
        postprocess(img, rotation_deg=45)
    with pytest.raises(ConfigError, match="downscale"):
        postprocess(img, downscale=0.5)


def test_jpeg_quality_and_subsampling():
    img = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    lo = encode_jpeg(img, quality=60, subsampling="4:2:0")
    hi = encode_jpeg(img, quality=95, subsampling="4:4:4")
    assert len(lo) < len(hi)
    assert Image.open(io.BytesIO(lo)).format == "JPEG"
    with pytest.raises(ConfigError, match="subsampling"):
        encode_jpeg(img, subsampling="4:1:1")
    with pytest.raises(ConfigError, match="quality"):
        encode_jpeg(img, quality=0)


def test_video_frames_advance_in_time():
    light = PwmLight(freq_hz=333.0)
    frames = list(simulate_video(light, _scene(), CAM, rng=np.random.default_rng(0), n_frames=3,
                                 frame_rate_hz=30.0, start_s=0.0, noise=False, output="linear"))
    assert len(frames) == 3
    single = simulate_frame(light, _scene(), CAM, rng=np.random.default_rng(0),
                            start_s=2 / 30.0, noise=False, output="linear")
    np.testing.assert_allclose(frames[2], single, rtol=1e-6)
    assert not np.allclose(frames[0], frames[1])
    with pytest.raises(ConfigError, match="frame_rate_hz"):
        list(simulate_video(light, _scene(), CameraModel(1e-4, 96, 1e-3),
                            rng=np.random.default_rng(0), n_frames=2, frame_rate_hz=200.0))


def test_auto_exposure_picks_longer_exposure_for_darker_scene():
    t_bright = auto_exposure_s(_scene(value=0.8))
    t_dark = auto_exposure_s(_scene(value=0.1))
    assert t_dark > t_bright
    assert 1 / 8000 <= t_bright <= 1 / 30


def test_bad_scene_shape():
    with pytest.raises(InvalidImageError, match="n_rows"):
        simulate_frame(SteadyLight(), _scene(50, 50), CAM, rng=np.random.default_rng(0))


@pytest.mark.parametrize("name", PHOTO_NAMES[:4])
def test_skimage_scenes(name):
    s = load_scene(f"skimage:{name}", 72, 128)
    assert s.shape == (72, 128, 3) and s.dtype == np.float32
    assert 0.0 <= s.min() and s.max() <= 1.0 and s.std() > 0.01


def test_scene_from_file_and_array(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (50, 80), dtype=np.uint8)
    path = tmp_path / "s.png"
    Image.fromarray(img).save(path)
    a = load_scene(path, 30, 40)
    b = load_scene(img, 30, 40)
    np.testing.assert_allclose(a, b)
    assert a.shape == (30, 40, 3)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    from lishield_guard.errors import ImageDecodeError

    with pytest.raises(ImageDecodeError):
        load_scene(tmp_path / "bad.png", 30, 40)
    with pytest.raises(ConfigError, match="unknown skimage"):
        load_scene("skimage:nope", 30, 40)


@pytest.mark.parametrize("kind", ["blinds", "bricks", "fabric"])
def test_texture_scenes_are_periodic(kind):
    rng = np.random.default_rng(0)
    s, p = texture_scene(kind, 256, 256, rng=rng, period_px=16.0, angle_deg=0.0)
    assert s.shape == (256, 256, 3) and p["kind"] == kind
    prof = s.mean(axis=(1, 2))
    spec = np.abs(np.fft.rfft(prof - prof.mean()))
    assert np.argmax(spec[2:]) + 2 == 256 // 16  # strongest row frequency: one per period
    with pytest.raises(ConfigError, match="texture"):
        texture_scene("plaid", 8, 8, rng=rng)
