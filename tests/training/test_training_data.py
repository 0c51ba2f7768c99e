"""Training data and the decision input: deterministic per seed, physics on the grid."""

from __future__ import annotations

import numpy as np
import pytest

from lishield_guard.detector.spectra import (
    BINS_PER_OCTAVE,
    CHANNELS,
    N_FREQ,
    freq_grid_cpr,
    image_input,
)


def _striped(freq_cpr: float, n_rows: int = 1024, n_cols: int = 768, seed: int = 0):
    rng = np.random.default_rng(seed)
    r = np.arange(n_rows)[:, None, None]
    img = 110 * (1 + 0.03 * np.sign(np.sin(2 * np.pi * freq_cpr * r)))
    return np.clip(img + rng.normal(0, 4, (n_rows, n_cols, 3)), 0, 255).astype(np.uint8)


def test_examples_are_deterministic_per_seed_and_index():
    pytest.importorskip("synth")
    from lishield_guard.detector import tfinput
    from training.data import example, sample_example
    from training.train import example_arrays

    assert sample_example(3, 5) == sample_example(3, 5)
    assert sample_example(3, 5) != sample_example(4, 5)
    x1, r1 = example(1, 5, bank_dir="/nonexistent")  # procedural scenes: no corpus needed
    x2, r2 = example(1, 5, bank_dir="/nonexistent")
    assert np.array_equal(x1.x, x2.x) and r1 == r2
    assert x1.x.shape[1:] == (len(tfinput.CHANNELS), tfinput.N_FREQ)
    q, meta, mask, rec = example_arrays(1, 5, "/nonexistent")
    assert mask.sum() == len(x1.x) == rec["n_instances"]


def test_the_mix_holds_every_kind_of_look_alike_and_both_barcode_kinds():
    from training.data import NEG_KINDS, sample_example

    draws = [sample_example(i, 9) for i in range(600)]
    kinds = {p["kind"] for p in draws}
    assert set(NEG_KINDS) <= kinds and "barcode" in kinds
    presets = {p["preset"] for p in draws if p["label"] == 1}
    assert {"table1-seq1", "table1-seq2", "table1-seq3", "table2-rgb"} <= presets
    rates = {p["lights"][0]["switching_hz"] for p in draws if p["label"] == 1}
    assert 200.0 in rates and len(rates) > 100
    assert any(p["coverage"] for p in draws if p["label"] == 1)
    assert any(p["composite"] for p in draws) and any(p["rotate"] for p in draws)
    # look-alikes at the barcodes' own frequencies, and lights that change mid-frame
    tones = [p for p in draws if p["kind"] == "pwm-tones"]
    assert tones and all(p["lights"][0]["kind"] == "pwm" for p in tones)
    assert all(p["lights"][0]["kind"] == "switched" for p in draws if p["kind"] == "dimmer")
    assert any(len(p["lights"]) >= 3 for p in draws if p["kind"] == "multi-pwm")


@pytest.mark.parametrize("freq_cpr", [0.01, 0.03, 0.09])
def test_a_stripe_peaks_at_its_frequency_and_a_resize_is_a_shift(freq_cpr):
    """Coherent luma power peaks within the resolution of the stripe's frequency (a log bin,
    or 1.5 FFT bins of the 1024 rows where those are coarser); doubling the frequency (a camera
    reading rows half as fast, or a 2x downscale) moves the peak by one octave,
    BINS_PER_OCTAVE bins: the network sees ratios as fixed distances."""
    grid = freq_grid_cpr()
    coh = CHANNELS.index("coh_L")
    peaks = []
    for f in (freq_cpr, 2 * freq_cpr):
        x = image_input(_striped(f)).x
        k = int(np.argmax(x[0, coh]))  # full window of the rows axis
        tol = max(f * (2 ** (1.5 / BINS_PER_OCTAVE) - 1), 1.5 / 1024)
        assert abs(grid[k] - f) <= tol, (grid[k], f)
        peaks.append(k)
    assert abs(peaks[1] - peaks[0] - BINS_PER_OCTAVE) <= (1 if freq_cpr > 0.02 else 4)


def test_stripes_common_to_every_block_are_coherent_and_noise_is_not():
    coh, inc = CHANNELS.index("coh_L"), CHANNELS.index("inc_L")
    x = image_input(_striped(0.03)).x[0]
    k = int(np.argmax(x[coh]))
    assert x[coh, k] - x[inc, k] > np.log(8)  # 32 blocks agree: coherent >> incoherent
    rng = np.random.default_rng(2)
    noise = image_input(rng.integers(90, 130, (1024, 768, 3)).astype(np.uint8)).x[0]
    assert noise[coh].max() < x[coh, k] - 5
