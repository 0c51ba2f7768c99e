"""Sweep scoring and selection on synthetic score tables."""

from __future__ import annotations

import numpy as np

from lishield_guard import calibration as cal
from lishield_guard.calibration import Setting, select_setting, summarise
from lishield_guard.config import default_config


def _summaries(fa: list[int], det: list[int], n_clean: int = 3000, n_pos: int = 100):
    settings = [Setting("default", (("tones.peak_false_prob", 10.0 ** -(i + 1)),))
                for i in range(len(fa))]
    clean = np.zeros((len(fa), n_clean), bool)
    pos = np.zeros((len(fa), n_pos), bool)
    for i, (k, d) in enumerate(zip(fa, det, strict=True)):
        clean[i, :k] = True
        pos[i, :d] = True
    return summarise(settings, clean, pos, clean_hits=clean.astype(float),
                     clean_cands=np.ones(n_clean), time_ms=np.ones(len(fa)))


def test_selection_honours_target():
    # 0/3000 -> bound 0.000998 (meets 1e-3); 1/3000 -> 0.00158 (does not)
    s = _summaries(fa=[0, 1, 0, 5], det=[40, 90, 60, 99])
    best, met = select_setting(s, 1e-3)
    assert met
    assert best.detected == 60 and best.false_alarms == 0
    assert best.far_upper <= 1e-3


def test_selection_reports_unmet_target():
    s = _summaries(fa=[2, 1, 3], det=[40, 30, 90])
    best, met = select_setting(s, 1e-3)
    assert not met
    assert best.false_alarms == 1  # lowest bound wins when nothing meets the target


def test_selection_tie_prefers_lower_bound():
    s = _summaries(fa=[1, 0], det=[50, 50])
    best, met = select_setting(s, 1e-2)
    assert met and best.false_alarms == 0


def test_cascade_scores_gates():
    grid = cal.CascadeGrid(peak_false_prob=(1e-3,), tone_rel_tol=(0.04,), min_occupancy=(0.04,),
                           max_occupancy=(0.8,), min_purity=(0.3, 0.7), min_tones=(2, 3),
                           min_tones_rgb=(3,))
    # 2 images x 1 combo x 2 candidates (mono, rgb)
    t = np.zeros((2, 1, 2, 6), np.float32)
    t[..., cal.VALID] = 1
    t[:, :, 1, cal.IS_RGB] = 1
    t[0, 0, 0, :4] = (2, 0.5, 3, 1)  # mono: 2 tones, purity .5, switching
    t[1, 0, 1, :4] = (3, 0.9, 2, 1)  # rgb: 3 tones but only one channel hit
    settings, prot, hits, cands = cal.cascade_scores(t, grid)
    got = {(s.as_dict["tones.min_purity"], s.as_dict["tones.min_tones"]): p.tolist()
           for s, p in zip(settings, prot, strict=True)}
    assert got[(0.3, 2)] == [True, False]
    assert got[(0.7, 2)] == [False, False]
    assert got[(0.3, 3)] == [False, False]
    assert cands.tolist() == [2, 2]


def test_paper_scores_counts_ratios():
    cfg = default_config()
    grid = cal.PaperGrid(n_b=(4,), max_peaks=(2,), ratio_tol=(0.01,), gamma=(0.1,))
    spec = cfg.policies[0].specs[0]
    tones = np.array(spec.all_freqs_hz, dtype=float)
    peaks = [{(4, 2): tones}, {(4, 2): np.array([1000.0, 3140.0])}]
    settings, prot, hits, _ = cal.paper_scores(peaks, cfg, grid)
    assert prot.shape == (1, 2)
    assert prot[0].tolist() == [True, False]
    assert hits[0, 0] >= 3


def test_group_labels():
    row = {"channels": ["R", "G", "B"], "preset": "table2-rgb", "attack": True,
           "ambient_ratio": 0.0, "coverage": {"fraction": 0.4}, "downscale": 1.7,
           "rotation_deg": 90, "kind": "barcode"}
    g = cal.group_labels(row)
    assert g["channels"] == "RGB" and g["attack"] == "attack" and g["ambient"] == "0"
    assert g["coverage"] == "[0,0.5)" and g["downscale"] == "(1,2]" and g["rotation"] == "90 deg"
