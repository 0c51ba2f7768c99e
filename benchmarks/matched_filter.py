"""The ceiling: a matched filter told the true row light of every capture, on a synth dataset.

For a barcode capture the filter is given what no detector knows: the LED's light in every
sensor row (`synth.camera.led_rows_rgb` of the manifest's emitter, camera and frame start),
mapped through the capture's resize, rotation and the decoder's DCT-domain scale onto the
decoded image's lines. It scores the image's block line profiles (`spectra.analysable`, the
detector's own decode) against that template:

- first differences of ln(profile) per block and of ln(ambient + light) (whitening: a natural
  scene's row spectrum falls like 1/f, its differences are roughly flat);
- each block weighted by the inverse of its own residual variance (what it does not share
  with the mean of the blocks), blocks that are black, saturated or flat left out;
- R, G and B scored against their own light (an RGB barcode's tones sit in separate planes);
- a circular-shift null: the same correlation for the template shifted by 64 offsets spread
  over the lines; the score is (correlation - mean of the null) / its standard deviation, so
  a scene that happens to correlate with any shifted copy scores nothing.

A look-alike is scored against a barcode template of its own geometry (its camera, exposure,
frame start, resize and rotation, with an emitter drawn from the dataset's mix), so the
threshold is set where the filter meets images without a barcode. The TPR at that threshold,
by kind and contrast bucket, is what the learned decision is measured against: the gap is
work left, what even the filter misses is physics.

    python benchmarks/matched_filter.py out/eval/paper40 --jobs 2 --per-image out/mf.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

N_SHIFTS = 64
LUMA = np.array([0.299, 0.587, 0.114])


def _template(item: dict, n_lines: int, light_item: dict) -> np.ndarray:
    """ln(ambient + row light) per colour plane on the decoded image's lines, (3, n_lines)."""
    from lishield_guard.camera import CameraModel
    from synth.camera import led_rows_rgb
    from synth.dataset import _make_light

    camera = CameraModel(row_time_s=1.0 / item["row_rate_hz"], n_rows=item["sensor_rows"],
                         exposure_s=item["exposure_s"])
    rows = led_rows_rgb(_make_light(light_item), camera, start_s=item["frame_start_s"])
    lin = rows + float(item.get("ambient_ratio") or 0.0)  # (sensor_rows, 3)
    if item.get("rotation_mode") == "bake" and item.get("rotation_deg") == 90:
        lin = lin[::-1]  # the stored column j is the sensor row h-1-j
    res = cv2.resize(lin.astype(np.float32)[:, None, :], (1, n_lines),
                     interpolation=cv2.INTER_AREA)[:, 0, :]
    return np.log(np.maximum(res, 1e-6)).T


def _stripe_profiles(path: Path, item: dict) -> np.ndarray | None:
    """ln of the stripe axis' block profiles (3, 32, n) and the usable-block mask."""
    from lishield_guard.decode import decode
    from lishield_guard.detector.spectra import analysable

    decoded = decode(path.read_bytes(), want_rgb=True, max_rows=768)
    axis = 1 if item.get("rotation_mode") == "bake" and item.get("rotation_deg") in (90, 270) \
        else 0
    a = analysable(decoded.rgb(), (axis,))
    if axis not in a["profiles"]:
        return None
    prof = a["profiles"][axis]
    return np.log(np.maximum(prof, a["full_scale"] / 512.0)), a["keep"][axis]


def score(logp: np.ndarray, keep: np.ndarray, template: np.ndarray) -> float:
    """Matched-filter z-score of block profiles against a template (module docstring)."""
    d = np.diff(logp, axis=-1)  # (3, blocks, n-1)
    dt = np.diff(template, axis=-1)  # (3, n-1)
    use = keep if keep.sum() >= 2 else np.ones(len(keep), bool)
    d = d[:, use]
    resid = d - d.mean(axis=1, keepdims=True)
    w = 1.0 / np.maximum(resid.var(axis=-1), 1e-12)  # (3, blocks)
    combined = (d * w[:, :, None]).sum(axis=1) / w.sum(axis=1, keepdims=True)  # (3, n-1)
    active = [c for c in range(3) if dt[c].std() > 1e-9]
    if not active:
        return float("-inf")
    n = dt.shape[-1]
    shifts = np.unique(np.linspace(0, n, N_SHIFTS + 1, dtype=int)[1:-1])
    vals = []
    for s in [0, *shifts]:
        t = np.roll(dt, s, axis=-1)
        vals.append(sum(float(np.dot(combined[c], t[c]) / (np.linalg.norm(t[c]) + 1e-12))
                        for c in active))
    vals = np.asarray(vals)
    null = vals[1:]
    return float((vals[0] - null.mean()) / (null.std() + 1e-12))


def _lookalike_light(item: dict, rng: np.random.Generator) -> dict:
    """A barcode emitter of the paper's presets for a look-alike's template."""
    from synth.dataset import MIXES, sample_emitter
    from lishield_guard.spec import get_preset

    preset = str(rng.choice(["table1-seq1", "table1-seq2", "table1-seq3", "table2-rgb"]))
    spec = get_preset(preset)
    em = sample_emitter(spec, rng=rng, mix=MIXES["default"])
    return {"light": {"kind": "led", "preset": preset, "switching_hz": em["switching_hz"],
                      "phase": em["phase_mode"], "order": em["slot_order"],
                      "rise_s": em["rise_s"], "loop_patterns": em["loop_patterns"]}}


def score_item(args: tuple) -> dict:
    """Score one manifest row (a positive against its own light, a look-alike against a
    drawn emitter of its geometry)."""
    folder, item = args
    got = _stripe_profiles(Path(folder) / item["file"], item)
    out = {"file": item["file"], "label": item["label"], "kind": item["kind"],
           "preset": item.get("preset")}
    if got is None:
        return {**out, "score": None}
    logp, keep = got
    if item["label"] == 1:
        light = item
    else:
        rng = np.random.default_rng(int(item.get("item_seed", 0)) % (2**32))
        light = {**item, **_lookalike_light(item, rng)}
    t = _template(item, logp.shape[-1], light)
    return {**out, "score": score(logp, keep, t)}


def main(argv: list[str] | None = None) -> int:
    """Command line: score every image, write them (``--per-image``), print the threshold."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", help="a `lishield-guard synth dataset` folder")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--per-image", help="write every image's score here (JSON lines)")
    a = ap.parse_args(argv)
    from lishield_guard.threads import one_thread_per_worker

    folder = Path(a.dataset)
    items = [json.loads(line) for line in (folder / "manifest.jsonl").read_text().splitlines()]
    with ProcessPoolExecutor(a.jobs, initializer=one_thread_per_worker) as pool:
        rows = list(pool.map(score_item, [(str(folder), it) for it in items], chunksize=4))
    if a.per_image:
        Path(a.per_image).write_text("".join(json.dumps(r) + "\n" for r in rows))
    neg = [r["score"] for r in rows if r["label"] == 0 and r["score"] is not None]
    pos = [r["score"] for r in rows if r["label"] == 1 and r["score"] is not None]
    thr = max(neg) if neg else float("inf")
    print(f"threshold (largest of {len(neg)} look-alike scores): {thr:.2f}; barcodes above: "
          f"{sum(s > thr for s in pos)}/{len(pos)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
