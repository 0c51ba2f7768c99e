"""A clairvoyant reference: one statistic's TPR at a false-alarm rate when the template is known.

A clairvoyant detector knows each barcode capture's true template (the light its emitter
played: f_B, slot order, restart or continuous phase, rise time; row rate, exposure, frame
start) and correlates it with the rows the default profile fits (the quiet-weighted
linear column sub-blocks, `fit.linear_common`, high-passed as in the exact fit). For its
false alarms each positive is rendered a second time with the same scene, camera, noise and
JPEG settings under steady light (its *twin*) and the same template is correlated with the
twin's rows.

This bounds *this statistic* (the normalised correlation of the quiet-weighted block mean with
the true template), not the physics: it is not a ceiling for detectors. A detector that whitens
the rows against the scene's own spectrum and weights column blocks and frequencies by their
noise (as the default profile's spectra do), or learns to, can beat it, since natural scenes put
most of their row energy at low frequencies where this correlation takes it in unweighted.
The name of the script is historical.

Monochrome and RGB positives alike (RGB: the luma-weighted sum of the channel templates);
captures whose rotation is baked into the pixels are skipped (their LED runs along columns).

Usage::

    .venv/bin/python benchmarks/clairvoyant_bound.py DATASET_DIR [--limit N] [--jobs 2]
        [--detected EVAL.jsonl] [--json OUT.json]

``--detected`` takes `benchmarks/evaluate.py --per-image` output for the same set and adds
the shipped detector's TPR on the same captures.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from lishield_guard import load_config
from lishield_guard.decode import decode
from lishield_guard.detector.numerics import _highpass, linear_common, linearise
from lishield_guard.detector.search import analyse_plane
from lishield_guard.spec import get_preset
from lishield_guard.stats import clopper_pearson
from lishield_guard.threads import one_thread_per_worker

LUMA = {"W": 1.0, "R": 0.299, "G": 0.587, "B": 0.114}
FARS = (0.001, 0.005, 0.01, 0.05)


def _rows_variants(blocks_log: np.ndarray, fine_log: np.ndarray, t: np.ndarray, hp
                   ) -> dict[str, float]:
    """Correlation of the high-passed template ``t`` with rows built several ways."""
    def corr(x):
        y = hp(x)
        return float(t @ y / math.sqrt((t @ t) * (y @ y) + 1e-300))

    x, _, lin = linear_common(fine_log)
    out = {"quiet": corr(x), "plain": corr(linearise(blocks_log).mean(axis=0))}
    yb = np.array([hp(b) for b in lin])  # the detector's matched re-weighting, true template
    amp = yb @ t / float(t @ t)
    resid = np.mean((yb - amp[:, None] * t[None, :]) ** 2, axis=1)
    w = np.maximum(amp, 0.0) / np.maximum(resid, 1e-6 * max(float(resid.max()), 1e-300))
    out["matched"] = max(out["quiet"], corr((w / w.sum()) @ lin)) if w.sum() > 0 else out["quiet"]
    return out


def _true_rows(item: dict, n: int) -> dict[str, np.ndarray]:
    """The light each of the ``n`` analysed rows integrated, per LED channel, in linear light:
    the item's own emitter (f_B, slot order, phase mode, rise time, as the synth rendered it)
    through its exposure window, averaged over the sensor rows each analysed row resamples."""
    from synth.dataset import _make_light
    from synth.light import row_means

    light = _make_light(item)
    n_sensor = int(item["sensor_rows"])
    t = item["frame_start_s"] + np.arange(n_sensor, dtype=np.float64) / item["row_rate_hz"]
    vals = row_means(light, t, item["exposure_s"])  # (n_sensor, n_channels)
    edges = np.linspace(0, n_sensor, n + 1)  # stored and decoded rows resample the sensor's
    cum = np.concatenate([np.zeros((1, vals.shape[1])), np.cumsum(vals, axis=0)])
    lo, hi = np.floor(edges[:-1]).astype(int), np.ceil(edges[1:]).astype(int)
    binned = (cum[hi] - cum[lo]) / np.maximum(hi - lo, 1)[:, None]
    return {ch: binned[:, i] for i, ch in enumerate(light.channels)}


def _template_corr(jpeg, item: dict, cfg) -> dict[str, float]:
    """Correlations of the item's true template with ``jpeg``'s rows, per row construction
    (see `VARIANTS`); empty when the image has too few rows to analyse."""
    det = cfg.detector
    dec = decode(jpeg, limits=cfg.limits, fast=det.profiles.fast_decode,
                 max_rows=det.profiles.max_decode_rows)
    pa = analyse_plane(dec.luma, 0, cfg, dec.row_scale)
    if pa.blocks is None:
        return {}
    n = pa.blocks.shape[1]
    spec = get_preset(item["preset"])
    period = spec.n_tones / item["switching_hz"] * item["row_rate_hz"] * n / item["sensor_rows"]
    hp = _highpass(n, period / (2 * math.pi * 1.5))
    chan = {ch: hp(rows) for ch, rows in _true_rows(item, n).items()}
    out = _rows_variants(pa.blocks, pa.fit_blocks, sum(LUMA[c] * t for c, t in chan.items()), hp)
    if spec.is_rgb:  # each channel's template on its own colour plane, the best of the three
        rgb = dec.rgb()
        best = -1.0
        for i, ch in enumerate("RGB"):
            pc = analyse_plane(np.ascontiguousarray(rgb[..., i]), 0, cfg, dec.row_scale)
            if pc.blocks is not None and pc.blocks.shape[1] == n:
                best = max(best, _rows_variants(pc.blocks, pc.fit_blocks, chan[ch], hp)["matched"])
        out["planes"] = max(best, out["matched"])
    else:
        out["planes"] = out["matched"]
    out["best"] = max(out.values())
    return out


VARIANTS = {
    "quiet": "quiet-weighted linear sub-blocks (the rows the default profile fits)",
    "plain": "plain mean of the 8 linearised column blocks",
    "matched": "quiet or matched-filter re-weighted sub-blocks, the larger (as the exact fit)",
    "planes": "RGB: matched on luma or each channel's template on its own plane, the largest",
    "best": "the largest of the above",
}


def _one(args: tuple) -> dict:
    dataset, item = args
    from synth.dataset import render_item

    cfg = load_config(None)
    twin = dict(item, light={"kind": "steady"})
    twin_jpeg, _ = render_item(twin)
    return {"file": item["file"], "preset": item["preset"],
            "barcode": _template_corr(Path(dataset) / item["file"], item, cfg),
            "twin": _template_corr(twin_jpeg, item, cfg)}


def main() -> int:
    """Print the clairvoyant ROC points (and the shipped detector's TPR on the same items)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--limit", type=int, default=0, help="at most this many positives (0: all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--detected", type=Path, help="evaluate.py --per-image JSONL of this set")
    ap.add_argument("--json", type=Path, help="write per-item results here")
    args = ap.parse_args()
    items = [json.loads(ln) for ln in (args.dataset / "manifest.jsonl").read_text().splitlines()
             if ln.strip()]
    items = [it for it in items if it["label"] == 1 and it["rotation_mode"] != "bake"]
    if args.limit:
        items = items[: args.limit]
    with ProcessPoolExecutor(args.jobs, initializer=one_thread_per_worker) as ex:
        res = []
        for i, r in enumerate(ex.map(_one, [(str(args.dataset), it) for it in items])):
            res.append(r)
            if (i + 1) % 25 == 0:
                print(f"{i + 1}/{len(items)}", file=sys.stderr, flush=True)
    res = [r for r in res if r["barcode"] and r["twin"]]
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    shipped = {}
    if args.detected:
        shipped = {r["file"]: r["protected"] for r in map(json.loads, args.detected.open())}
    groups = {"all": res, "mono": [r for r in res if r["preset"] != "table2-rgb"],
              "rgb": [r for r in res if r["preset"] == "table2-rgb"]}
    print(f"{len(res)} positives and as many steady-light twins")
    for var, what in VARIANTS.items():
        null = np.sort([r["twin"][var] for r in res])
        print(f"\n{var}: {what}\n  twin rho: median {np.median(null):.3f}, 99th percentile "
              f"{np.quantile(null, 0.99):.3f}, max {null[-1]:.3f}")
        for far in FARS:
            if far * null.size < 2:  # the quantile would rest on fewer than two twins
                continue
            thr = float(np.quantile(null, 1 - far))
            line = [f"  FAR {far:.3f} (rho > {thr:.3f})"]
            for name, g in groups.items():
                k = sum(r["barcode"][var] > thr for r in g)
                lo, hi = clopper_pearson(k, len(g))
                line.append(f"{name} {k}/{len(g)} = {k / max(len(g), 1):.3f} [{lo:.3f}, {hi:.3f}]")
            print("  ".join(line))
    if shipped:
        for name, g in groups.items():
            k = sum(bool(shipped.get(r["file"])) for r in g)
            print(f"shipped detector on the same {name} captures: {k}/{len(g)} = "
                  f"{k / max(len(g), 1):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
