"""How well the profile-domain renderer stands in for the full render, example by example.

For examples of the training mix, both renderers (`training.data.render` then the detector's
decode, and `training.data.render_profiles`) produce the stripe axis' block profiles; both go
through `tfinput.profiles_input`. Compared per example:

- ``level_db``: the profiles' mean level, relative difference;
- ``tone_ln``: for a barcode, the whitened coherent luma power at the LED's tones (the
  `tfinput` bin each tone falls in, at every level where it is on the grid; ln units);
- ``logit``: the image logit of a decision model (``None`` without one).

    python -m training.agreement --n 200 --seed 77 --model out/train/model/decision_model.npz
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from lishield_guard.detector.tfinput import FRAME_LINES, freq_grid_cpr


def _tone_bins(p: dict, level: int) -> list[int]:
    """`tfinput` bins of the LED's tones at ``level`` for example ``p`` (`sample_example`)."""
    from lishield_guard.spec import get_preset
    from training.data import stripe_lines_per_row

    led = next((d for d in p["lights"] if d["kind"] == "led"), None)
    if led is None:
        return []
    per_row = stripe_lines_per_row(p)
    grid = freq_grid_cpr()
    out = []
    for _, tones in get_preset(led["preset"]).channels:
        for f in tones:
            cpr = f / p["row_rate_hz"] / per_row * (1 << level)
            if grid[0] <= cpr <= grid[-1] and cpr * FRAME_LINES >= 2:
                out.append(int(np.argmin(np.abs(np.log(grid / cpr)))))
    return out


def compare(index: int, seed: int, bank: tuple[str, ...], weights: tuple, model=None) -> dict:
    """Both renders of one example, compared (see the module docstring)."""
    from lishield_guard.detector.learned import score_windows
    from lishield_guard.detector.spectra import USABLE_TILES
    from lishield_guard.detector.tfinput import POWER_CHANNELS, profiles_input
    from lishield_guard.detector.usable import usable_blocks
    from training.data import profiles_of_jpeg, render, render_profiles, sample_example

    p = sample_example(index, seed, weights)
    axis = 1 if p["rotate"] else 0
    fast, _ = render_profiles(p, bank)
    data, meas = render(p, bank)
    full = profiles_of_jpeg(data)["profiles"]
    row = {"index": index, "label": p["label"], "kind": p["kind"],
           "partial": p["coverage"] is not None, "led_contrast": meas["led_contrast"]}
    inputs = []
    for prof in (fast[axis], full[axis]):
        keep, _ = usable_blocks(prof.mean(axis=0), full_scale=255.0, tiles=USABLE_TILES)
        inputs.append(profiles_input({axis: prof}, full_scale=255.0, keep={axis: keep}))
    row["clipped"] = bool((full[axis].mean(axis=(0, 2)) > 0.98 * 255).mean() > 0.25)
    row["level_rel"] = float(abs(fast[axis].mean() / max(full[axis].mean(), 1e-6) - 1))
    coh = POWER_CHANNELS.index("coh_mean")
    diffs = []
    for k, (xf, xr) in enumerate(zip(inputs[0].x, inputs[1].x, strict=False)):
        for b in _tone_bins(p, k):
            diffs.append(float(xf[coh, b] - xr[coh, b]))
    row["tone_ln"] = diffs
    if model is not None:
        z = [float(score_windows(i.x, model).max()) if len(i.x) else None for i in inputs]
        row["logit_fast"], row["logit_full"] = z
    return row


def summary(rows: list[dict]) -> dict:
    """Medians and 90th percentiles of the differences."""
    out = {"n": len(rows)}
    lv = np.array([r["level_rel"] for r in rows])
    out["level_rel_median"], out["level_rel_p90"] = float(np.median(lv)), float(
        np.quantile(lv, 0.9))
    tones = np.abs([d for r in rows for d in r["tone_ln"]])
    if len(tones):
        out["tone_ln_median"], out["tone_ln_p90"] = float(np.median(tones)), float(
            np.quantile(tones, 0.9))
    z = [(r["logit_fast"], r["logit_full"]) for r in rows
         if r.get("logit_fast") is not None and r.get("logit_full") is not None]
    if z:
        dz = np.abs([a - b for a, b in z])
        out["logit_median"], out["logit_p90"] = float(np.median(dz)), float(
            np.quantile(dz, 0.9))
        out["logit_corr"] = float(np.corrcoef(np.array(z).T)[0, 1])
    return {k: (round(v, 4) if isinstance(v, float) and math.isfinite(v) else v)
            for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--bank", default="out/scenebank")
    ap.add_argument("--model", help="decision_model.npz to compare logits with")
    ap.add_argument("--per-example", help="write every example's comparison (JSON lines)")
    a = ap.parse_args(argv)
    from lishield_guard.detector.learned import load_model
    from training.data import bank_weights, scene_bank

    model = load_model(a.model) if a.model else None
    bank = scene_bank(a.bank)
    rows = [compare(i, a.seed, bank, bank_weights(a.bank), model) for i in range(a.n)]
    if a.per_example:
        with open(a.per_example, "w") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)
    print(json.dumps(summary(rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
