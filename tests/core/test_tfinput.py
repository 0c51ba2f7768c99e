"""The time-frequency decision input: levels, peaks, and what the turn channels say."""

from __future__ import annotations

import numpy as np
import pytest

from lishield_guard.detector.tfinput import (
    CHANNELS,
    FRAME_LINES,
    MAX_LEVELS,
    N_FREQ,
    TURN_OFFSETS,
    freq_grid_cpr,
    profiles_input,
)

COH = CHANNELS.index("coh_mean")
PEAK = CHANNELS.index("coh_max")


def _profiles(light: np.ndarray, *, n_blocks: int = 32, seed: int = 0, scene_std: float = 0.02
              ) -> dict:
    """Block line means (3, n_blocks, n) of a scene lit by ``light`` (n,) on every block."""
    rng = np.random.default_rng(seed)
    n = len(light)
    scene = 100 * np.exp(scene_std * rng.standard_normal((3, n_blocks, n)).cumsum(-1) / 8)
    return {0: (scene * light[None, None, :]).astype(np.float32)}


def _tone(n: int, cpr: float, depth: float = 0.05) -> np.ndarray:
    return 1 + depth * np.sin(2 * np.pi * cpr * np.arange(n))


def test_levels_cover_the_lines_up_to_the_top_of_the_pyramid():
    for n, want in ((64, 1), (127, 1), (128, 2), (1000, 4), (1535, 5), (9000, MAX_LEVELS)):
        inp = profiles_input(_profiles(np.ones(n)), full_scale=255.0)
        assert inp.levels == tuple(range(want)), n
        assert inp.x.shape == (want, len(CHANNELS), N_FREQ)
        assert np.isfinite(inp.x).all()


def test_too_short_an_axis_has_no_instance():
    inp = profiles_input(_profiles(np.ones(FRAME_LINES - 1)), full_scale=255.0)
    assert inp.x.shape == (0, len(CHANNELS), N_FREQ)


@pytest.mark.parametrize("cpr", [0.06, 0.11, 0.23])
def test_a_stripe_peaks_on_its_bin_and_twice_the_scale_is_the_next_level(cpr):
    grid = freq_grid_cpr()
    slow = profiles_input(_profiles(_tone(2048, cpr / 2)), full_scale=255.0)
    fast = profiles_input(_profiles(_tone(2048, cpr)), full_scale=255.0)
    want = int(np.argmin(np.abs(np.log(grid / cpr))))
    assert abs(int(np.argmax(fast.x[0, COH])) - want) <= 1
    # the stripe at half the frequency, read one level up, sits on the same bin
    assert abs(int(np.argmax(slow.x[1, COH])) - want) <= 1


def test_stripes_common_to_every_block_stand_far_above_the_floor():
    inp = profiles_input(_profiles(_tone(1024, 0.1, depth=0.01)), full_scale=255.0)
    clean = profiles_input(_profiles(np.ones(1024)), full_scale=255.0)
    assert inp.x[0, PEAK].max() > clean.x[0, PEAK].max() + 3.0  # ln units: 20x


def _turn(x: np.ndarray, cpr: float, d: int) -> float:
    grid = freq_grid_cpr()
    b = int(np.argmin(np.abs(np.log(grid / cpr))))
    return float(x[CHANNELS.index(f"turn_{d}"), b - 1:b + 2].mean())


def test_tones_that_take_turns_are_anti_correlated_in_time_and_a_steady_comb_is_not():
    n, f1, d = 2048, 0.08, 14  # ratio 2^(14/24) = 1.5: tones f1 and 1.5 f1
    f2 = f1 * 2 ** (d / 24)
    t = np.arange(n)
    slot = (t // 128) % 2  # one tone per slot of two frames
    turns = 1 + 0.05 * np.where(slot == 0, np.sin(2 * np.pi * f1 * t), np.sin(2 * np.pi * f2 * t))
    comb = 1 + 0.035 * (np.sin(2 * np.pi * f1 * t) + np.sin(2 * np.pi * f2 * t))
    together = 1 + (t < n // 2) * 0.05 * (np.sin(2 * np.pi * f1 * t) + np.sin(2 * np.pi * f2 * t))
    x_turns = profiles_input(_profiles(turns), full_scale=255.0).x[0]
    x_comb = profiles_input(_profiles(comb), full_scale=255.0).x[0]
    x_together = profiles_input(_profiles(together), full_scale=255.0).x[0]
    assert _turn(x_turns, f1, d) < -0.5
    assert abs(_turn(x_comb, f1, d)) < 0.3
    assert _turn(x_together, f1, d) > 0.3


def test_offsets_cover_the_shipped_presets_ratios():
    from lishield_guard.spec import PRESETS

    for name in ("table1-seq1", "table1-seq2", "table1-seq3"):
        tones = PRESETS[name].channels[0][1]
        for a in tones:
            for b in tones:
                if b > a:
                    d = np.log2(b / a) * 24
                    assert min(abs(d - o) for o in TURN_OFFSETS) <= 0.5, (name, a, b)


def test_black_blocks_are_left_out_of_the_combination():
    prof = _profiles(_tone(1024, 0.1, depth=0.01))
    keep = np.ones(32, bool)
    prof[0][:, 20:] = 0.0  # a black band across the lines
    keep[20:] = False
    with_keep = profiles_input(prof, full_scale=255.0, keep={0: keep})
    assert np.isfinite(with_keep.x).all()
    assert with_keep.x[0, PEAK].max() > 3.0
