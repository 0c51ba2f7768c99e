"""benchmarks/evaluate.py groups positives by emitter (issue 21) from the manifest alone."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from synth.dataset import MIXES, item_seed, sample_item

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "evaluate.py"


@pytest.fixture(scope="module")
def evaluate():
    spec = importlib.util.spec_from_file_location("evaluate_bench", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_groups_cover_bands_phases_orders_and_nominal(evaluate):
    items = [sample_item(1, seed=item_seed(7, i), mix=MIXES["default"], size=(1080, 1920))
             for i in range(120)]
    groups = [set(evaluate.kinds(it)) for it in items]
    seen = set().union(*groups)
    for band in ("200", "between", "f1", "beyond"):
        assert f"f_B:{band}" in seen
    assert {"phase:restart", "phase:continuous", "order:0,1,2", "order:2,1,0",
            "order-kind:other", "nominal:mono", "nominal:RGB"} <= seen
    for it, g in zip(items, groups, strict=True):
        assert sum(k.startswith("f_B:") for k in g) == 1
        assert ("nominal" in g) == it["nominal"]
        em = evaluate.emitter(it)
        assert em["f_b_band"] == it["f_b_band"] and em["slot_order"] == it["slot_order"]


def test_old_manifests_get_emitter_fields(evaluate):
    old = {"label": 1, "kind": "barcode", "channels": ["W"], "preset": "table1-seq1",
           "tones_hz": {"W": [400.0, 600.0, 800.0]}, "switching_hz": 300.0, "attack": False,
           "coverage": {"fraction": 1.0}, "ambient_ratio": 0.5, "exposure_s": 0.001}
    em = evaluate.emitter(old)
    assert em == {"f_b_band": "between", "phase_mode": "restart", "slot_order": [0, 1, 2],
                  "slot_order_kind": "ascending", "nominal": True, "legacy": True,
                  "within_flicker_rule": True}
    assert evaluate.emitter({**old, "switching_hz": 400.0})["f_b_band"] == "f1"
    assert evaluate.emitter({**old, "exposure_s": 0.002})["nominal"] is False
    assert evaluate.emitter({"label": 0, "kind": "steady"}) is None
    assert evaluate.kinds({"label": 0, "kind": "pwm", "scene_kind": "photo"}) == [
        "pwm", "scene:photo:neg"]


def test_capture_conditions_count_barcodes_and_look_alikes_apart(evaluate):
    """"ambient>1" and the other capture conditions are TPR groups: look-alikes under the
    same condition are counted as "ambient>1:neg", not in the same denominator."""
    cond = {"scene_kind": "real-photo", "ambient_ratio": 2.0, "rotation_deg": 90,
            "downscale": 2.0, "coverage": {"fraction": 0.5}}
    neg = set(evaluate.kinds({"label": 0, "kind": "steady", **cond}))
    assert {"ambient>1:neg", "rotated:neg", "downscaled:neg", "partial-coverage:neg"} <= neg
    assert not {"ambient>1", "rotated", "downscaled", "partial-coverage"} & neg
    pos = set(evaluate.kinds({"label": 1, "kind": "barcode", "channels": ["W"],
                              "preset": "table1-seq1", "tones_hz": {"W": [400.0, 600.0, 800.0]},
                              "switching_hz": 300.0, "exposure_s": 0.001, **cond}))
    assert {"ambient>1", "rotated", "downscaled", "partial-coverage"} <= pos
