"""Column sub-blocks and their quiet weighting: nested profiles, weights, weighted coherence t."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lishield_guard import PRESETS
from lishield_guard.detector.fit import pattern_knots, refine, render_rows
from lishield_guard.detector.numerics import block_coherence_t, quiet_weights
from lishield_guard.detector.profiles import block_row_profiles, merge_blocks


@pytest.mark.parametrize("n_cols, blocks, sub", [(640, 8, 4), (1001, 8, 4), (37, 8, 4),
                                                 (5, 8, 4), (12, 3, 5), (1, 8, 4)])
def test_merged_sub_blocks_equal_direct_blocks(rng, n_cols, blocks, sub):
    plane = rng.integers(0, 256, size=(50, n_cols)).astype(np.uint8)
    fine = block_row_profiles(plane, n_col_blocks=blocks, sub_blocks=sub)
    direct = block_row_profiles(plane, n_col_blocks=blocks)
    assert fine.shape[0] <= min(blocks * sub, n_cols)
    merged = merge_blocks(fine, n_cols, blocks, sub)
    np.testing.assert_allclose(merged, direct, rtol=1e-5, atol=1e-4)
    # the transposed axis splits the same way
    fine_t = block_row_profiles(plane.T.copy(), n_col_blocks=blocks, sub_blocks=sub, axis=1)
    np.testing.assert_allclose(fine_t, fine, rtol=1e-6, atol=1e-4)


def test_quiet_weights_favour_quiet_blocks(rng):
    n = 2000
    common = np.sin(np.arange(n) / 7.0)
    noise_sd = np.array([0.05, 0.05, 0.05, 0.05, 1.0, 1.0, 2.0, 4.0])
    blocks = common + rng.normal(0, 1, (noise_sd.size, n)) * noise_sd[:, None]
    w = quiet_weights(blocks)
    assert w.sum() == pytest.approx(1.0)
    assert w[:4].sum() > 0.99
    # close to inverse-variance weights
    ideal = 1 / noise_sd ** 2
    np.testing.assert_allclose(w, ideal / ideal.sum(), atol=0.02)
    err_w = np.std(w @ blocks - common)
    err_mean = np.std(blocks.mean(axis=0) - common)
    assert err_w < 0.2 * err_mean


def test_equal_noise_gives_equal_weights(rng):
    blocks = rng.normal(0, 1, (32, 4000))
    w = quiet_weights(blocks)
    assert np.all(np.abs(w * 32 - 1) < 0.15)
    assert np.all(np.isfinite(w))


@pytest.mark.parametrize("k", [1, 2])
def test_too_few_blocks_keep_equal_weights(rng, k):
    w = quiet_weights(rng.normal(0, 1, (k, 100)))
    np.testing.assert_allclose(w, np.full(k, 1 / k))


def test_identical_blocks_do_not_divide_by_zero():
    blocks = np.tile(np.sin(np.arange(300) / 5.0), (6, 1))
    w = quiet_weights(blocks)
    assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0)


def test_weighted_t_reduces_to_ordinary_t(rng):
    tmpl = np.sin(np.arange(500) / 4.0)
    blocks = 0.3 * tmpl + rng.normal(0, 1, (8, 500))
    assert block_coherence_t(blocks, tmpl, np.ones(8)) == pytest.approx(
        block_coherence_t(blocks, tmpl), rel=1e-9)
    amp = blocks @ tmpl / (tmpl @ tmpl)
    t = amp.mean() / (amp.std(ddof=1) / np.sqrt(8))
    assert block_coherence_t(blocks, tmpl) == pytest.approx(t, rel=1e-9)


def test_weighted_t_ignores_a_loud_block(rng):
    tmpl = np.sin(np.arange(800) / 6.0)
    blocks = 0.05 * tmpl + rng.normal(0, 0.01, (8, 800))
    blocks[0] += 5.0 * np.sin(np.arange(800) / 6.0 + 0.3)  # one block of strong scene
    w = quiet_weights(blocks - blocks.mean(axis=1, keepdims=True))
    assert block_coherence_t(blocks, tmpl, w) > 5 * block_coherence_t(blocks, tmpl)


def test_refine_finds_led_behind_textured_columns(rng):
    """Half the columns hold strong scene texture; the weighted fit still sees the barcode."""
    spec = PRESETS["table1-seq1"]
    n, period, c1, phi, e = 1080, 600.0, 1.2, 0.4, 0.3
    m = spec.n_tones
    rows = np.arange(n, dtype=np.float64)
    led = render_rows(*pattern_knots(spec, "W", c1), m * rows / period + phi, e)
    log_led = np.log1p(0.2 * (led - led.mean())) / 2.2
    blocks = np.empty((32, n))
    for b in range(32):
        loud = b % 2 == 0
        scene = (0.15 if loud else 0.0) * np.sin(2 * np.pi * rows / rng.uniform(40, 300)
                                                 + rng.uniform(0, 6))
        blocks[b] = log_led + scene + rng.normal(0, 0.03 if loud else 0.002, n)
    start = [(0.8, period * 1.01, c1, phi, e)]
    fit = refine(blocks, spec, "W", start, period_range_rows=(50.0, 3000.0),
                 scale_range_cpr_per_hz=(1e-6, 1.0))
    assert fit is not None
    assert fit.rho > 0.97, fit
    assert abs(fit.period_rows / period - 1) < 0.01, fit
    assert fit.coherence_t > 20, fit


# --- colour verification of RGB channel fits -------------------------------------------------


def test_chroma_leak_geometry():
    from lishield_guard.detector.fit import chroma_leak

    assert chroma_leak(np.array([1.0, 0.0, 0.0]), "R") == pytest.approx(0.0)
    assert chroma_leak(np.array([1.0, 1.0, 1.0]), "R") == pytest.approx(math.sqrt(2))
    assert chroma_leak(np.array([2.0, 2.0, 2.0]), "W") == pytest.approx(0.0)
    assert chroma_leak(np.array([0.1, 0.0, 0.1]), "G") == 1e6  # nothing along G
    assert chroma_leak(np.array([-1.0, 0.0, 0.0]), "R") == 1e6  # negative amplitude
    assert chroma_leak(np.array([1.0, 0.3, 0.0]), "R") == pytest.approx(0.3)


def _rgb_led_planes(rng, spec, *, grey_scene: bool):
    """Log-contrast sub-blocks of the R, G, B planes: each plane carries its own channel's
    stripes, or (grey_scene) the red channel's pattern shows in every plane as scene
    structure would."""
    n, period, c1, phi, e = 900, 700.0, 1.15, 0.3, 0.4
    rows = np.arange(n, dtype=np.float64)
    out = {}
    for c in "RGB":
        src = "R" if grey_scene else c
        led = render_rows(*pattern_knots(spec, src, c1), spec.n_tones * rows / period + phi, e)
        log_led = np.log1p(0.15 * (led - led.mean())) / 2.2
        out[c] = log_led + rng.normal(0, 0.003, (32, n))
    return out, (0.8, period * 0.99, c1, phi, e)


@pytest.mark.parametrize("grey", [False, True])
def test_refine_measures_chroma_leak(rng, grey):
    spec = PRESETS["table2-rgb"]
    planes, start = _rgb_led_planes(rng, spec, grey_scene=grey)
    fit = refine(planes["R"], spec, "R", [start], period_range_rows=(50.0, 3000.0),
                 scale_range_cpr_per_hz=(1e-6, 1.0), colour_blocks=planes)
    assert fit is not None and fit.rho > 0.95, fit
    if grey:
        assert fit.chroma_leak == pytest.approx(math.sqrt(2), rel=0.1), fit
    else:
        assert fit.chroma_leak < 0.15, fit
    assert fit.to_dict()["chroma_leak"] == pytest.approx(fit.chroma_leak, abs=1e-4)


def test_without_colour_planes_no_leak_is_claimed(rng):
    spec = PRESETS["table2-rgb"]
    planes, start = _rgb_led_planes(rng, spec, grey_scene=False)
    fit = refine(planes["R"], spec, "R", [start], period_range_rows=(50.0, 3000.0),
                 scale_range_cpr_per_hz=(1e-6, 1.0))
    assert fit is not None and fit.chroma_leak is None


def _passes_with(fit_passes):
    """`rules.fit_passes` over a dict of the numbers it reads (a `ModelFit` derives its gain
    from the two rhos; these cases set it on its own)."""
    from types import SimpleNamespace

    return lambda fit, det: fit_passes(SimpleNamespace(**fit), det)


def test_colour_verified_path_of_fit_passes():
    from lishield_guard.config import DetectorConfig
    from lishield_guard.detector.rules import fit_passes

    det = DetectorConfig().with_values({
        "fit.min_rho": 0.95, "fit.min_gain": 8.0, "fit.min_rho_rgb": 0.85,
        "fit.min_gain_rgb": 1.0, "fit.max_leak_rgb": 0.3, "sweep.min_coherence": 3.0})
    fit = {"rho": 0.88, "gain": 2.0, "coherence_t": 10.0, "chroma_leak": 0.1, "n_periods": 1.5}
    fit_passes = _passes_with(fit_passes)
    assert fit_passes(fit, det)
    assert not fit_passes({**fit, "chroma_leak": 0.5}, det)  # colour says grey scene
    assert not fit_passes({**fit, "chroma_leak": None}, det)  # colour not measured
    assert not fit_passes({**fit, "coherence_t": 2.0}, det)
    assert not fit_passes(fit, det.with_values({"fit.max_leak_rgb": None}))  # path off
    assert not fit_passes(fit, det.replace(fit=None))  # the fit off
    assert fit_passes({**fit, "rho": 0.96, "gain": 9.0, "chroma_leak": None}, det)


def test_periodic_path_of_fit_passes():
    """A fit whose frame holds two or more pattern periods passes at the lower _periodic
    thresholds; one of fewer periods needs the full gain; gain None turns the path off."""
    from lishield_guard.config import PERIODIC_MIN_PERIODS, DetectorConfig
    from lishield_guard.detector.rules import fit_passes

    det = DetectorConfig().with_values({
        "fit.min_rho": 0.9, "fit.min_gain": 8.0, "fit.min_rho_periodic": 0.85,
        "fit.min_gain_periodic": 2.0, "sweep.min_coherence": 3.0})
    fit = {"rho": 0.9, "gain": 3.0, "coherence_t": 10.0, "chroma_leak": None,
           "n_periods": PERIODIC_MIN_PERIODS}
    fit_passes = _passes_with(fit_passes)
    assert fit_passes(fit, det)
    assert not fit_passes({**fit, "n_periods": PERIODIC_MIN_PERIODS - 0.01}, det)
    assert not fit_passes({**fit, "gain": 1.9}, det)
    assert not fit_passes({**fit, "rho": 0.84}, det)
    assert not fit_passes({**fit, "coherence_t": 2.9}, det)
    assert not fit_passes(fit, det.with_values({"fit.min_gain_periodic": None}))
    assert fit_passes(fit, DetectorConfig())  # on in the shipped (default) thresholds
    assert fit_passes({**fit, "n_periods": 1.0, "gain": 8.0}, det)
