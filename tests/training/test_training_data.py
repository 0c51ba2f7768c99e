"""Training data: deterministic per seed, every kind of look-alike and barcode in the mix.

The input's physics (a stripe on its bin, a resize one level up, coherence across blocks,
tones taking turns) is tested in tests/core/test_tfinput.py."""

from __future__ import annotations

import numpy as np
import pytest


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
