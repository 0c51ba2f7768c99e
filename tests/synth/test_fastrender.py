"""The profile-domain renderer against the real thing: JPEG, rotation, compositing, whole captures.

The whole-capture comparison renders 100 examples of the training mix twice, in full (frame,
Pillow JPEG, the detector's decode) and in the profile domain, with procedural scenes (no
photo corpus needed), and checks the block profiles' level, the whitened coherent power at the
LED's tones and, with the shipped weights, the decision logit.
"""

from __future__ import annotations

import numpy as np
import pytest

from lishield_guard.decode import decode
from lishield_guard.detector.spectra import block_profiles_rgb
from synth import fastrender as fr
from synth.camera import encode_jpeg


def _striped(h: int = 1024, w: int = 1024, depth: float = 0.01, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r = np.arange(h)[:, None, None]
    base = 100 + 60 * np.sin(np.arange(w) / 70.0)[None, :, None] * np.array([1, 0.8, 0.6])
    img = base * (1 + depth * np.sin(2 * np.pi * r / 37.0)) + rng.normal(0, 2, (h, w, 3))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _detrended(x: np.ndarray) -> np.ndarray:
    return x - x.mean(axis=-1, keepdims=True)


@pytest.mark.parametrize("quality, subsampling", [(30, "4:2:0"), (50, "4:2:0"), (50, "4:4:4")])
def test_jpeg_emulation_reproduces_most_of_what_jpeg_does_to_faint_stripes(quality,
                                                                           subsampling):
    img = _striped()
    orig = block_profiles_rgb(img)[0].mean(axis=0)
    real = block_profiles_rgb(decode(encode_jpeg(img, quality=quality, subsampling=subsampling),
                                     want_rgb=True).rgb())[0].mean(axis=0)
    emu = fr.block_profiles(fr.jpeg_roundtrip(fr.grids_of_pixels(img), quality=quality,
                                              subsampling=subsampling))[0].mean(axis=0)
    ignored = _detrended(real - orig).std()  # what JPEG did to the stripes
    missed = _detrended(real - emu).std()  # what the emulation misses of it
    assert missed < 0.5 * ignored, (missed, ignored)


def test_a_scaled_decode_is_emulated_at_its_line_count():
    img = _striped(h=1600, w=1200)
    data = encode_jpeg(img, quality=70, subsampling="4:2:0")
    real = block_profiles_rgb(decode(data, want_rgb=True, max_rows=768).rgb())
    emu = fr.block_profiles(fr.jpeg_roundtrip(fr.grids_of_pixels(img), quality=70,
                                              subsampling="4:2:0", scale=2))
    for axis in (0, 1):
        assert emu[axis].shape == real[axis].shape
        assert np.abs(emu[axis] - real[axis]).mean() < 1.0


@pytest.mark.parametrize("degrees, k", [(90, -1), (270, 1)])
def test_rotated_grids_are_the_grids_of_the_rotated_pixels(degrees, k):
    img = np.random.default_rng(1).integers(0, 256, (72, 48, 3)).astype(np.float32)
    got = fr.rotate_grids(fr.grids_of_pixels(img), degrees)
    want = fr.grids_of_pixels(np.rot90(img, k=k))
    assert (got.height, got.width) == (want.height, want.width)
    np.testing.assert_allclose(got.rows, want.rows, atol=1e-4)
    np.testing.assert_allclose(got.cols, want.cols, atol=1e-4)


@pytest.mark.parametrize("r0, c0", [(16, 24), (13, 37)])
def test_a_border_composed_cell_by_cell_has_the_pixels_block_means(r0, c0):
    """Exact where the image and the blocks lie on the 8-pixel grid (a 256 x 512 canvas has
    blocks of 8 and 16 pixels); resampled cells otherwise."""
    img = np.random.default_rng(2).integers(0, 256, (96, 80, 3)).astype(np.float32)
    canvas = np.full((256, 512, 3), (10.0, 200.0, 30.0), np.float32)
    canvas[r0:r0 + 96, c0:c0 + 80] = img
    got = fr.block_profiles(fr.compose_border(fr.grids_of_pixels(img), height=256, width=512,
                                              r0=r0, c0=c0, colour=(10, 200, 30)))
    want = block_profiles_rgb(canvas)
    for axis in (0, 1):
        tol = 1e-3 if (r0 % 8, c0 % 8) == (0, 0) else 6.0  # off-grid cells are resampled
        assert np.abs(got[axis] - want[axis]).mean() < tol


@pytest.fixture(scope="module")
def agreement():
    """Both renders of 100 training examples with procedural scenes, and the shipped model's
    logits of both when it reads this input."""
    from lishield_guard.detector import tfinput
    from lishield_guard.detector.learned import shipped_model
    from training.agreement import compare

    model = shipped_model()
    use = model if model.card["input_version"] == tfinput.INPUT_VERSION else None
    return [compare(i, 2026, (), (), use) for i in range(100)]


def test_the_profile_renderer_agrees_with_the_full_render(agreement):
    from training.agreement import summary

    s = summary(agreement)
    assert sum(r["partial"] for r in agreement) >= 10  # partly lit captures are in
    assert sum(r["clipped"] for r in agreement) >= 3  # and mostly clipped ones
    assert s["level_rel_median"] < 0.01 and s["level_rel_p90"] < 0.03, s
    assert s["tone_ln_median"] < 0.25 and s["tone_ln_p90"] < 1.0, s
    if "logit_median" in s:
        assert s["logit_median"] < 0.5 and s["logit_p90"] < 1.5, s
