"""The fast sweep path agrees with detect.decide, and the null model behaves."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from lishield_guard import calibrate as cal
from lishield_guard.config import AppConfig, default_config
from lishield_guard.detect import decide


@pytest.fixture(scope="module")
def records(tiny_sets):
    cfg = default_config()
    files = sorted(tiny_sets["pos"].glob("*.jpg")) + sorted(tiny_sets["neg"].glob("*.jpg"))
    return cfg, [cal.image_record(p, cfg, paper_grid=cal.PaperGrid(n_b=(4,), max_peaks=(2,)))
                 for p in files]


def _orthogonal_subset(settings, grid_levels: dict[str, tuple]) -> list[int]:
    """Indices of the settings forming a strength-2 orthogonal array over five two-level
    factors (a 2^(5-2) fraction: d = a xor b, e = a xor c): every pair of factors meets in all
    four level combinations, in 8 of the 32 settings."""
    names = list(grid_levels)
    keep = []
    for i, s in enumerate(settings):
        p = s.as_dict
        a, b, c, d, e = (int(p[n] == grid_levels[n][1]) for n in names)
        if d == a ^ b and e == a ^ c:
            keep.append(i)
    return keep


@pytest.mark.timeout(1200)
def test_candidate_table_agrees_with_decide(records):
    """Calibration's vectorised decision (candidate tables, fold and sweep tables) equals
    `detect.decide` on every image, for every setting of a strength-2 orthogonal array of the
    thresholds below (each `decide` call refits, so all 32 settings took 131 s on 2 cores;
    `test_rule_agreement` covers the pass rules themselves over random thresholds). Since the
    emitter-variant search the 8 take about 5-10 minutes on a shared machine."""
    cfg, recs = records
    grid = cal.DefaultGrid(peak_false_prob=(1e-2, 1e-4), tone_rel_tol=(0.05,),
                           min_occupancy=(0.04,), max_occupancy=(0.8,), min_purity=(0.3, 0.6),
                           min_tones=(2,), sweep_min_rho=(0.6, 0.9), sweep_min_margin=(0.0,),
                           sweep_min_coherence=(3.0,), fit_min_rho=(0.9,),
                           fit_min_gain=(1.0, math.inf),
                           fit_rgb=((0.8, 0.5, 0.3),),
                           fit_periodic=((0.85, 1.0), (1.0, math.inf)))
    tables = np.stack([cal.candidate_table(r["evidence"], cfg, grid)[0] for r in recs])
    settings, prot, _, _ = cal.default_scores(tables, grid, [r["folds"] for r in recs],
                                              cfg.detector, fold_min_rho=(0.9,),
                                              sweeps=[r["sweeps"] for r in recs])
    assert len(settings) == 32
    subset = _orthogonal_subset(settings, {
        "peak_false_prob": (1e-2, 1e-4), "min_purity": (0.3, 0.6),
        "sweep_min_rho": (0.6, 0.9), "fit_min_gain": (1.0, math.inf),
        "fit_min_gain_periodic": (1.0, math.inf)})
    assert len(subset) == 8
    n_pos = 0
    for i in subset:
        det = settings[i].apply(cfg.detector)
        app = AppConfig(detector=det, limits=cfg.limits, policies=cfg.policies)
        want = [decide(r["evidence"].with_false_prob(det.peak_false_prob), app).protected
                for r in recs]
        assert prot[i].tolist() == want, settings[i].label()
        n_pos += sum(want)
    assert n_pos > 0  # the easy positives are found by some settings


def test_paper_peaks_match_run_paper(records, tiny_sets):
    from lishield_guard import detect

    cfg, recs = records
    det = cfg.detector.replace(profile="paper", n_block_rows=4, n_block_cols=4, max_peaks=2)
    f = sorted(tiny_sets["pos"].glob("*.jpg"))[0]
    v = detect(f, det)
    assert np.allclose(recs[0]["paper_peaks"][(4, 2)], v.evidence["frequencies_hz"], atol=1e-2)


def test_null_model_monotone_and_zero(records):
    cfg, recs = records
    ev = recs[0]["evidence"]
    vals = [cal.null_model_far(ev, cfg, q=q)["far"] for q in (0.0, 1e-3, 1e-2, 1e-1)]
    assert vals[0] == 0.0
    assert all(a <= b for a, b in itertools.pairwise(vals))
    loose = AppConfig(detector=cfg.detector.replace(min_purity=0.0, tone_rel_tol=0.08),
                      limits=cfg.limits, policies=cfg.policies)
    assert cal.null_model_far(ev, loose, q=0.05)["far"] >= cal.null_model_far(ev, cfg,
                                                                             q=0.05)["far"]
