"""Run time against error of the steady square-wave look-alike search (`fit.lookalike_rho`).

The exact fit's gain divides the barcode's misfit by the best steady square wave's, so a
look-alike search that stops short of the true square wave inflates the gain of a PWM or
mains light and can pass it as a barcode. This benchmark renders steady square waves (random
period, duty, phase and exposure, behind the fit's high-pass, over a drifting scene plus
noise) and runs the search with each number of refined starts (`detector.numerics.SQUARE_REFINES`),
in a shuffled order per case so that machine noise falls on all settings alike.

Each case's reference is the *oracle* rho: the correlation of the rows with the true square
wave, high-passed the same way. Reported per setting: cases where the search ended more than
``--tol`` below the oracle (a *miss*: the look-alike was not found), with an exact 95%
interval; the median and worst shortfall against the oracle; the median time per call and the
median per-case time ratio to the shipped setting.

Usage::

    .venv/bin/python benchmarks/lookalike_search.py [--cases 300] [--refines 1,2,4,9]
        [--seed 1] [--tol 0.02] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from lishield_guard.detector import numerics as fit_mod
from lishield_guard.detector.numerics import HIGHPASS_CYCLES, _highpass, lookalike_rho, square_rows
from lishield_guard.stats import clopper_pearson


def make_case(rng: np.random.Generator, n_rows: int):
    """One steady square wave over a drifting scene: (high-passed rows, high-pass, params with
    the oracle rho)."""
    period_rows = float(rng.uniform(30.0, 300.0))
    duty = float(rng.uniform(0.5, 0.95))
    phase = float(rng.uniform(0.0, 1.0))
    exposure_cycles = float(rng.uniform(0.005, 0.3))
    scene_amp = float(rng.uniform(0.02, 0.3))
    rows = np.arange(n_rows, dtype=float)
    hp = _highpass(n_rows, period_rows / (2 * math.pi * HIGHPASS_CYCLES))
    scene = np.cumsum(rng.normal(0.0, 1.0, n_rows))
    light = square_rows(rows / period_rows + phase, duty, exposure_cycles)
    y = hp(0.3 * light + scene_amp * scene / scene.std() + rng.normal(0.0, 0.01, n_rows))
    t = hp(light)
    oracle = float(t @ y / math.sqrt(float(t @ t) * float(y @ y)))
    params = {"period_rows": period_rows, "duty": duty, "phase": phase,
              "exposure_cycles": exposure_cycles, "scene_amp": scene_amp, "oracle_rho": oracle}
    return y, hp, params


def run(cases: int, refines: list[int], seed: int, n_rows: int) -> list[dict]:
    """Rho and seconds of every setting on every case (settings in a shuffled order)."""
    rng = np.random.default_rng(seed)
    shipped = fit_mod.SQUARE_REFINES
    out = []
    try:
        for i in range(cases):
            y, hp, params = make_case(rng, n_rows)
            rec = {"case": i, **params, "rho": {}, "s": {}}
            for r in rng.permutation(refines):
                fit_mod.SQUARE_REFINES = int(r)
                t0 = time.perf_counter()
                rec["rho"][int(r)] = lookalike_rho(y, hp)
                rec["s"][int(r)] = time.perf_counter() - t0
            out.append(rec)
    finally:
        fit_mod.SQUARE_REFINES = shipped
    return out


def summarise(recs: list[dict], refines: list[int], tol: float) -> list[dict]:
    """Per setting: misses (rho more than ``tol`` below the oracle) with a 95% interval,
    median and worst shortfall, median time and median paired time ratio to the shipped
    setting."""
    shipped = fit_mod.SQUARE_REFINES
    oracle = np.array([r["oracle_rho"] for r in recs])
    rows = []
    for k in refines:
        rho = np.array([r["rho"][k] for r in recs])
        s = np.array([r["s"][k] for r in recs])
        short = oracle - rho
        misses = int((short > tol).sum())
        lo, hi = clopper_pearson(misses, len(recs))
        ratio = (np.median(s / np.array([r["s"][shipped] for r in recs]))
                 if shipped in refines else math.nan)
        rows.append({"refines": k, "misses": misses, "n": len(recs), "miss_lo": lo,
                     "miss_hi": hi, "median_shortfall": float(np.median(short)),
                     "worst_shortfall": float(short.max()), "median_ms": 1e3 * float(np.median(s)),
                     "time_ratio_to_shipped": float(ratio)})
    return rows


def main() -> None:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=300)
    ap.add_argument("--refines", default="1,2,4,9",
                    help="numbers of refined starts to compare (9 = every candidate)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rows", type=int, default=720, help="rows per profile (default 720)")
    ap.add_argument("--tol", type=float, default=0.02,
                    help="shortfall against the oracle rho that counts as a miss (default 0.02)")
    ap.add_argument("--json", help="write the per-case records and the summary here")
    args = ap.parse_args()
    refines = sorted({int(v) for v in args.refines.split(",")})
    recs = run(args.cases, refines, args.seed, args.rows)
    summary = summarise(recs, refines, args.tol)
    print(f"{args.cases} steady square waves, {args.rows} rows, seed {args.seed}; "
          f"shipped SQUARE_REFINES = {fit_mod.SQUARE_REFINES}")
    print(f"median oracle rho {np.median([r['oracle_rho'] for r in recs]):.3f}; a miss ends "
          f"more than {args.tol} below the oracle")
    print(f"{'refines':>7}  {'misses':>13}  {'95% CI':>15}  {'med shortfall':>13}  "
          f"{'worst':>7}  {'med ms':>7}  {'time / shipped':>14}")
    for r in summary:
        print(f"{r['refines']:>7}  {r['misses']:>6}/{r['n']:<6}  "
              f"[{r['miss_lo']:.3f}, {r['miss_hi']:.3f}]  {r['median_shortfall']:>13.4f}  "
              f"{r['worst_shortfall']:>7.3f}  {r['median_ms']:>7.1f}  "
              f"{r['time_ratio_to_shipped']:>14.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"summary": summary, "cases": recs}, fh, indent=1)


if __name__ == "__main__":
    main()
