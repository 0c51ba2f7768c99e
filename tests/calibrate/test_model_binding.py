"""Issue 42 item 3: a threshold is bound to the decision weights it was calibrated for.

The two bugs: after new weights (``make train`` overwrites the weights file in place), a
calibration reused the old weights' cached logits; and photo calibration wrote its config with
the ``[video]`` group reset to the defaults. Both fail on the code before issue 42.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

import lishield_guard

EXE = str(Path(sys.executable).with_name("lishield-guard"))
DATA_DIR = Path(lishield_guard.__file__).parent / "data"  # (the two bug tests run on old code
MODEL_FILE, CARD_FILE = "decision_model.npz", "decision_model.json"  # too: no newer import)


def _digest(path: Path) -> str:
    return "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()

pytestmark = pytest.mark.timeout(900)  # two calibrate runs on a loaded machine


def _shift_last_bias(weights: Path, by: float, *, card: bool = True) -> None:
    """Retrain in place, cheaply: the same file with the network's output bias moved by
    ``by`` (every logit moves by it), and (``card``) its card's digest of the weights, as
    training writes it."""
    import json

    with np.load(weights) as z:
        arrays = {k: z[k] for k in z.files}
    last = max((k for k in arrays if k.startswith("dense") and k.endswith("_b")),
               key=lambda k: int(re.sub(r"\D", "", k)))
    arrays[last] = arrays[last] + np.float32(by)
    with open(weights, "wb") as fh:
        np.savez(fh, **arrays)
    if card:
        path = weights.with_suffix(".json")
        meta = json.loads(path.read_text(encoding="utf-8"))
        path.write_text(json.dumps({**meta, "weights_digest": _digest(weights)}),
                        encoding="utf-8")


def _written(path: Path) -> dict:
    """The TOML a calibration wrote, as written."""
    return tomllib.loads(path.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def two_runs(tiny_sets, tmp_path_factory):
    """Calibrate the learned threshold twice into one report folder (one evidence cache): with
    weights A, then with weights B written over A's file. The base config sets its own clip
    thresholds."""
    root = tmp_path_factory.mktemp("binding")
    weights = root / "model.npz"
    shutil.copy(DATA_DIR / MODEL_FILE, weights)
    shutil.copy(DATA_DIR / CARD_FILE, weights.with_suffix(".json"))
    base = root / "base.toml"
    # model_digest = false: the base's thresholds are not claimed for any weights (the shipped
    # config's are the shipped weights', which B no longer is)
    base.write_text(f'[detector.learned]\nmodel = "{weights}"\nmodel_digest = false\n\n'
                    f"[video]\nthreshold_logit = 5.5\nclear_logit = 1.5\nmodel_digest = false\n",
                    encoding="utf-8")
    rep = root / "report"
    runs = []
    for name in ("a", "b"):
        if name == "b":
            _shift_last_bias(weights, 5.0)
        out = root / f"{name}.toml"
        res = subprocess.run(
            [EXE, "calibrate", "--clean", str(tiny_sets["neg"]), "--certify",
             str(tiny_sets["noise"]), "--positives", str(tiny_sets["pos"]), "--target-far",
             "0.7", "--out", str(out), "--report", str(rep), "--jobs", "1", "--no-progress",
             "--profiles", "default", "--config", str(base)],
            capture_output=True, text=True, timeout=600)
        assert res.returncode in (0, 3), res.stderr
        runs.append((out, (rep / "summary.md").read_text(encoding="utf-8"),
                     _digest(weights)))
    return runs


def test_new_weights_do_not_reuse_the_old_weights_logits(two_runs):
    """The second run measures every image again: its cache keys carry the weights' digest
    (before, it reused all 9 entries and chose the old threshold)."""
    (out_a, _, digest_a), (out_b, summary_b, digest_b) = two_runs
    assert digest_a != digest_b
    assert "; 0 images from cache)" in summary_b
    thresholds = [_written(out)["detector"]["learned"]["threshold_logit"]
                  for out in (out_a, out_b)]
    assert thresholds[1] != pytest.approx(thresholds[0])


def test_photo_calibration_keeps_the_video_group(two_runs):
    """The written config keeps the base config's ``[video]`` thresholds (they were reset to
    the dataclass defaults)."""
    video = _written(two_runs[0][0])["video"]
    assert (video["threshold_logit"], video["clear_logit"]) == (5.5, 1.5)


def test_a_calibrated_config_records_and_checks_its_weights(two_runs):
    """The threshold's weights digest is written beside it; loading the config once the
    weights changed is an error that says how to recalibrate, or, asked for, a warning."""
    from lishield_guard.config import load_config
    from lishield_guard.errors import ConfigError

    (out_a, _, digest_a), (out_b, _, digest_b) = two_runs
    assert load_config(out_a, model_mismatch="warn").detector.learned.model_digest == digest_a
    assert load_config(out_b).detector.learned.model_digest == digest_b
    with pytest.raises(ConfigError, match="calibrated for decision weights .* calibrate"):
        load_config(out_a)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_config(out_a, model_mismatch="warn")
    assert any("loaded anyway" in str(w.message) for w in caught)


def test_a_card_that_does_not_describe_its_weights_is_refused(tmp_path):
    import json

    from lishield_guard.detector.learned import load_model
    from lishield_guard.errors import ConfigError

    weights = tmp_path / "m.npz"
    shutil.copy(DATA_DIR / MODEL_FILE, weights)
    card = json.loads((DATA_DIR / CARD_FILE).read_text())
    card["weights_digest"] = _digest(weights)
    weights.with_suffix(".json").write_text(json.dumps(card))
    assert load_model(weights).digest == card["weights_digest"]
    _shift_last_bias(weights, 1.0, card=False)
    with pytest.raises(ConfigError, match="do not belong together"):
        load_model(weights)


def test_video_calibration_records_the_digest(tmp_path, monkeypatch):
    """``calibrate-videos`` writes the weights' digest beside the clip threshold."""
    import lishield_guard.batch as batch
    import lishield_guard.video.calibrate as vcal
    from lishield_guard.config import default_config, load_config

    clips = [tmp_path / f"c{i}.mp4" for i in range(20)]
    monkeypatch.setattr(batch, "list_files", lambda folder, kinds=None: clips)
    monkeypatch.setattr(vcal, "score_clips", lambda paths, *a, **k: [
        vcal.ClipScores(Path(p).name, (0.1 * i, 0.2), (2,), 0.1 * i, 0)
        for i, p in enumerate(paths)])
    out = tmp_path / "v.toml"
    vcal.run_video_calibration([tmp_path], base=default_config(), out=out)
    video = load_config(out).video
    assert video.model_digest == _digest(DATA_DIR / MODEL_FILE)


def test_calibrate_with_weights_its_card_does_not_describe_is_a_usage_error(tiny_sets,
                                                                            tmp_path):
    """A clear error and exit status 2, not a traceback."""
    weights = tmp_path / "m.npz"
    shutil.copy(DATA_DIR / MODEL_FILE, weights)
    shutil.copy(DATA_DIR / CARD_FILE, weights.with_suffix(".json"))
    _shift_last_bias(weights, 1.0, card=False)
    base = tmp_path / "base.toml"
    base.write_text(f'[detector.learned]\nmodel = "{weights}"\nmodel_digest = false\n\n'
                    "[video]\nmodel_digest = false\n", encoding="utf-8")
    res = subprocess.run(
        [EXE, "calibrate", "--clean", str(tiny_sets["neg"]), "--positives",
         str(tiny_sets["pos"]), "--out", str(tmp_path / "o.toml"), "--report",
         str(tmp_path / "r"), "--jobs", "1", "--no-progress", "--config", str(base)],
        capture_output=True, text=True, timeout=600)
    assert res.returncode == 2, res.stderr
    assert "do not belong together" in res.stderr and "Traceback" not in res.stderr
