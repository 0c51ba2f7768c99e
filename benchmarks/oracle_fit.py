"""Oracle check of the default profile's template models on a labelled synth dataset.

For every monochrome positive (unrotated or EXIF-rotated), knowing the true capture parameters
from the manifest:

- ``grid_ideal``: the period sweep's best binned-grid fit of the *noise-free* LED log signal
  (what the grid can reach at best);
- ``truth_lin`` / ``truth_log``: correlation of the exact template (`fit.render_rows`) at
  the true period, c_1, phase and exposure with the *observed* rows (linearised / log contrast),
  rows being the plain mean of the 8 column blocks;
- ``truth_w``: the same with the rows the detector fits, the quiet-weighted mean of the
  linearised column sub-blocks (`fit.linear_common`);
- whether the shipped detector flags the image.

Usage::

    .venv/bin/python benchmarks/oracle_fit.py DATASET_DIR [--limit 25]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np

from lishield_guard import detect, load_config
from lishield_guard.camera import CameraModel
from lishield_guard.decode import decode
from lishield_guard.detector.fit import pattern_knots, render_rows
from lishield_guard.detector.numerics import _highpass, linear_common, linearise
from lishield_guard.detector.sweep import sweep_match
from lishield_guard.detector.tones import scale_range_cpr_per_hz
from lishield_guard.spec import get_preset


def _stored_log_signal(item: dict) -> np.ndarray:
    """The LED's log contrast per stored row (display gamma 2.2), without scene or noise."""
    from synth.camera import led_rows_rgb
    from synth.dataset import _make_light

    cam = CameraModel(row_time_s=1 / item["row_rate_hz"], n_rows=item["sensor_rows"],
                      exposure_s=item["exposure_s"])
    rgb = led_rows_rgb(_make_light(item), cam, start_s=item["frame_start_s"])
    luma = (rgb + item["ambient_ratio"]) @ np.array([0.299, 0.587, 0.114])
    n_st = max(int(round(item["sensor_rows"] / item["downscale"])), 1)
    edges = np.linspace(0, luma.size, n_st + 1)
    cum = np.concatenate([[0.0], np.cumsum(luma)])
    idx = np.minimum(np.floor(edges).astype(int), luma.size - 1)
    at = cum[idx] + (edges - idx) * (cum[np.minimum(idx + 1, luma.size)] - cum[idx])
    mean = np.diff(at) / np.diff(edges)
    return np.log(np.maximum(mean, 0.02 * mean.mean())) / 2.2


def main() -> int:
    """Print one line per image and the medians per preset."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--limit", type=int, default=25)
    args = ap.parse_args()
    cfg = load_config(None)
    det = cfg.detector
    items = [json.loads(ln) for ln in (args.dataset / "manifest.jsonl").read_text().splitlines()
             if ln.strip()]
    items = [it for it in items if it["label"] == 1 and it["channels"] == ["W"]
             and it["rotation_mode"] != "bake"][: args.limit]
    rows = []
    for it in items:
        spec = get_preset(it["preset"])
        m = spec.n_tones
        dec = decode(args.dataset / it["file"], limits=cfg.limits, fast=det.profiles.fast_decode,
                     max_rows=det.profiles.max_decode_rows)
        from lishield_guard.detector.search import (
            _period_range_rows,
            analyse_plane,
            scaled_detector,
        )

        pa = analyse_plane(dec.luma, 0, cfg, dec.row_scale)
        if pa.blocks is None:
            continue
        n = pa.blocks.shape[1]
        n_stored = round(it["sensor_rows"] / it["downscale"])
        period = (m / it["switching_hz"] * it["row_rate_hz"] / it["downscale"] * n / n_stored)
        c1 = spec.f1_hz / it["switching_hz"]
        e = it["exposure_s"] * it["switching_hz"]
        phi = (it["frame_start_s"] * it["switching_hz"]) % m
        hp = _highpass(n, period / (2 * math.pi * 1.5))
        tmpl = hp(render_rows(*pattern_knots(spec, "W", c1), m * np.arange(n) / period + phi, e))

        def corr(x, tmpl=tmpl, hp=hp):
            y = hp(x)
            return float(tmpl @ y / math.sqrt((tmpl @ tmpl) * (y @ y) + 1e-300))

        ideal = _stored_log_signal(it)
        if ideal.size != n:  # decoded at a reduced scale: resample the ideal signal
            ideal = np.interp(np.linspace(0, ideal.size - 1, n), np.arange(ideal.size), ideal)
        blocks = ideal[None, :] + np.random.default_rng(0).normal(0, 1e-5, (8, n))
        d2 = scaled_detector(det, dec.row_scale)
        sm = sweep_match(blocks, [(spec, "W")], scale_range_cpr_per_hz=scale_range_cpr_per_hz(d2),
                         period_range_rows=[_period_range_rows(spec, d2)])[0]
        row = {"file": it["file"], "preset": it["preset"],
               "grid_ideal": sm.rho if sm else float("nan"),
               "truth_lin": corr(linearise(pa.blocks).mean(axis=0)),
               "truth_log": corr(pa.blocks.mean(axis=0).astype(np.float64)),
               "truth_w": corr(linear_common(pa.fit_blocks)[0]),
               "detected": detect(args.dataset / it["file"], cfg).protected}
        rows.append(row)
        print(f"{row['file']} {row['preset']:12s} grid_ideal {row['grid_ideal']:.3f}  truth_lin "
              f"{row['truth_lin']:.3f}  truth_log {row['truth_log']:.3f}  truth_w "
              f"{row['truth_w']:.3f}  detected "
              f"{row['detected']}", flush=True)
    for p in sorted({r["preset"] for r in rows}):
        sel = [r for r in rows if r["preset"] == p]
        print(f"{p}: n={len(sel)} median grid_ideal "
              f"{statistics.median(r['grid_ideal'] for r in sel):.3f}, truth_lin >= 0.95: "
              f"{sum(r['truth_lin'] >= 0.95 for r in sel)}, truth_lin < 0.9: "
              f"{sum(r['truth_lin'] < 0.9 for r in sel)} (of them detected: "
              f"{sum(r['truth_lin'] < 0.9 and r['detected'] for r in sel)}), truth_w >= 0.9: "
              f"{sum(r['truth_w'] >= 0.9 for r in sel)} (truth_lin: "
              f"{sum(r['truth_lin'] >= 0.9 for r in sel)}), detected "
              f"{sum(r['detected'] for r in sel)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
