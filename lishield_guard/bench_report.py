"""The benchmark's report: the issue's targets judged, the terminal table, the figure, the files."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lishield_guard.profiles import DEFAULT

__all__ = ["CSV_FIELDS", "MAIN_SETTING", "REFERENCE_OF", "TARGETS", "evaluate_targets",
           "format_table", "plot_report", "write_report"]

MAIN_SETTING = DEFAULT  # the setting of the default profile (the one the targets time)
# Setting -> the same setting decoded on the reference path (target c compares the two).
REFERENCE_OF = {MAIN_SETTING: f"{MAIN_SETTING}-ref"}

# The targets (unitless ratios; rates in percentage points).
TARGETS = {
    "a_12mp_ratio_max": 0.35,
    "b_1080p_ratio_max": 0.6,
    "c_rate_change_max_pp": 0.5,
    "d_peak_memory_max_x_rgb": 1.5,
}


def evaluate_targets(rows: Sequence[dict], targets: dict | None, memory: dict | None) -> list:
    """The issue's four targets as measured: (a) 12 MP ratio, (b) 1080p ratio, (c) fast path
    rate change, (d) 12 MP peak memory.

    Parameters
    ----------
    rows : sequence of dict
        `summarize` output.
    targets : dict or None
        ``{"12mp": time_target(...), "1080p": time_target(...)}``.
    memory : dict or None
        `measure_memory` output on the 12 MP image.

    Returns
    -------
    list of dict
        ``id``, ``what``, ``measured``, ``limit``, ``met`` (bool, or None when not measured),
        ``detail``.
    """
    out = []
    targets = targets or {}
    for tid, key, limit in (("a", "12mp", TARGETS["a_12mp_ratio_max"]),
                            ("b", "1080p", TARGETS["b_1080p_ratio_max"])):
        t = targets.get(key, {}).get("settings", {}).get(MAIN_SETTING, {})
        m = t.get("median_ratio")
        out.append({"id": tid, "what": f"default profile time / Pillow RGB decode, {key} JPEG",
                    "measured": m, "limit": limit, "met": None if m is None else m <= limit,
                    "detail": (f"{t['median_ms']:.1f} ms vs floor "
                               f"{targets[key]['floor_median_ms']:.1f} ms, median of "
                               f"{targets[key]['repeat']} paired runs") if m is not None else
                    "not measured"})
    by = {r["setting"]: r for r in rows}
    for fast, ref in REFERENCE_OF.items():
        if fast in by and ref in by:
            f, r = by[fast], by[ref]
            d_tpr = _pp(f["tpr"]["rate"], r["tpr"]["rate"])
            d_fpr = _pp(f["fpr"]["rate"], r["fpr"]["rate"])
            worst = max(abs(d) for d in (d_tpr, d_fpr) if d is not None) if (
                d_tpr is not None or d_fpr is not None) else None
            lim = TARGETS["c_rate_change_max_pp"]
            res = (f["tpr"]["n"], f["fpr"]["n"])
            out.append({"id": "c", "what": f"{fast} vs {ref}: |change| of TPR and FPR (pp)",
                        "measured": worst, "limit": lim,
                        "met": None if worst is None else worst < lim,
                        "detail": f"TPR {_pp_text(d_tpr)}, FPR {_pp_text(d_fpr)} on {res[0]} "
                                  f"pos / {res[1]} neg (one image = "
                                  f"{100 / max(min(res), 1):.2f} pp)"})
    m = (memory or {}).get("settings", {}).get(MAIN_SETTING, {})
    x = m.get("x_rgb")
    out.append({"id": "d", "what": "default profile peak memory above baseline / 8-bit RGB size, "
                                   "12 MP", "measured": x,
                "limit": TARGETS["d_peak_memory_max_x_rgb"],
                "met": None if x is None else x <= TARGETS["d_peak_memory_max_x_rgb"],
                "detail": (f"RSS +{m['rss_delta_bytes'] / 2**20:.1f} MiB (tracemalloc peak "
                           f"{m['tracemalloc_peak_bytes'] / 2**20:.1f} MiB) vs RGB "
                           f"{memory['rgb_bytes'] / 2**20:.1f} MiB") if x is not None else
                "not measured"})
    return out


def _pp(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else (a - b) * 100.0


def _pp_text(d: float | None) -> str:
    """A change in percentage points, or why there is none (no image of that label timed)."""
    return "not measured (no image)" if d is None else f"{d:+.2f} pp"


def _fmt_rate(r: dict) -> str:
    if r["rate"] is None:
        return "-"
    return f"{r['rate']:.3f} [{r['ci'][0]:.3f},{r['ci'][1]:.3f}]"


def format_table(report: dict) -> str:
    """The terminal table: one line per setting, then the targets."""
    rows = report["rows"]
    mem = (report.get("memory") or {}).get("settings", {})
    tg = report.get("targets_measured") or {}
    head = (f"{'setting':12s} {'n':>4s} {'med ms':>7s} {'p95 ms':>7s} {'x floor':>7s} "
            f"{'p95 x':>6s} {'12MP x':>6s} {'1080p x':>7s} {'TPR [95% CI]':>20s} "
            f"{'FPR [95% CI]':>20s} {'error':>6s} {'mem x':>5s} P")
    lines = [head, "-" * len(head)]
    for r in rows:
        name = r["setting"]
        m = mem.get(name, {}).get("x_rgb")
        t12 = tg.get("12mp", {}).get("settings", {}).get(name, {}).get("median_ratio")
        t10 = tg.get("1080p", {}).get("settings", {}).get(name, {}).get("median_ratio")
        lines.append(
            f"{name:12s} {r['n_images']:4d} {r['median_ms']:7.1f} {r['p95_ms']:7.1f} "
            f"{r['median_ratio']:7.3f} {r['p95_ratio']:6.3f} "
            f"{_num(t12, 6, 3)} {_num(t10, 7, 3)} {_fmt_rate(r['tpr']):>20s} "
            f"{_fmt_rate(r['fpr']):>20s} {_num(r['error'], 6, 3)} {_num(m, 5, 2)} "
            f"{'*' if r['pareto'] else ' '}")
    floor = rows[0]["floor_median_ms"] if rows else float("nan")
    lines.append(f"floor = Pillow Image.open().convert('RGB') + np.asarray, median "
                 f"{floor:.1f} ms/image on the dataset; x = paired per-image ratio; "
                 f"P = Pareto front (x floor, error); mem x = 12 MP peak RSS above baseline / "
                 f"RGB array size")
    for g in rows[0]["fpr_by_group"] if rows else {}:
        lines.append(f"FPR {g}: " + ", ".join(f"{r['setting']} {_fmt_rate(r['fpr_by_group'][g])}"
                                              for r in rows if g in r["fpr_by_group"]))
    lines.append("targets:")
    for t in report.get("targets", []):
        state = {True: "MET", False: "NOT MET", None: "n/a"}[t["met"]]
        meas = "-" if t["measured"] is None else f"{t['measured']:.3f}"
        lines.append(f"  ({t['id']}) {t['what']}: {meas} (limit {t['limit']}) {state} -- "
                     f"{t['detail']}")
    return "\n".join(lines)


def _num(x: float | None, width: int, prec: int) -> str:
    return f"{'-':>{width}s}" if x is None or not math.isfinite(x) else f"{x:{width}.{prec}f}"


def plot_report(report: dict, out_png: Path) -> Path:
    """Median time ratio against error per setting, with the Pareto front, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in report["rows"] if r["error"] is not None]
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for i, r in enumerate(rows):
        x = r["median_ratio"]
        ax.scatter([x], [r["error"]], s=60, color="C0" if not r["pareto"] else "C3", zorder=3)
        ax.annotate(r["setting"], (x, r["error"]), textcoords="offset points",
                    xytext=(6, 4 + 11 * (i % 3)), fontsize=9)
        fnr = 1 - r["tpr"]["rate"] if r["tpr"]["rate"] is not None else None
        if fnr is not None:
            ax.scatter([x], [fnr], marker="v", color="0.5", s=25, zorder=2)
        if r["fpr"]["rate"] is not None:
            ax.scatter([x], [r["fpr"]["rate"]], marker="^", color="0.5", s=25, zorder=2)
    front = sorted((r for r in rows if r["pareto"]), key=lambda r: r["median_ratio"])
    if front:
        xs, ys = [front[0]["median_ratio"]], [front[0]["error"]]
        for r in front[1:]:
            xs += [r["median_ratio"], r["median_ratio"]]
            ys += [ys[-1], r["error"]]
        ax.plot(xs, ys, color="C3", lw=1.5, label="Pareto front", zorder=1)
    ax.scatter([], [], color="C0", label="error = 1 - TPR + FPR")
    ax.scatter([], [], color="C3", label="on the Pareto front")
    ax.scatter([], [], marker="v", color="0.5", label="1 - TPR")
    ax.scatter([], [], marker="^", color="0.5", label="FPR")
    ax.axvline(1.0, color="0.7", ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("median time / Pillow full RGB decode of the same image (unitless)")
    ax.set_ylabel("error rate")
    n = rows[0]["n_images"] if rows else 0
    ax.set_title(f"lishield-guard bench: speed vs error ({n} images)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


CSV_FIELDS = ("setting", "n_images", "n_errors", "median_ms", "p95_ms", "median_ratio",
              "p95_ratio", "ratio_12mp", "ratio_1080p", "tpr", "tpr_lo", "tpr_hi", "fpr",
              "fpr_lo", "fpr_hi", "error", "peak_rss_delta_mib", "peak_tracemalloc_mib",
              "peak_x_rgb", "pareto")


def write_report(report: dict, out_dir: Path) -> dict[str, Path]:
    """Write ``bench.json``, ``bench.csv`` and ``bench.png`` into ``out_dir`` (created)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "bench.json", "csv": out_dir / "bench.csv",
             "png": out_dir / "bench.png"}
    paths["json"].write_text(json.dumps(_jsonable(report), indent=2), encoding="utf-8")
    mem = (report.get("memory") or {}).get("settings", {})
    tg = report.get("targets_measured") or {}
    with open(paths["csv"], "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in report["rows"]:
            m = mem.get(r["setting"], {})
            w.writerow({
                "setting": r["setting"], "n_images": r["n_images"], "n_errors": r["n_errors"],
                "median_ms": r["median_ms"], "p95_ms": r["p95_ms"],
                "median_ratio": r["median_ratio"], "p95_ratio": r["p95_ratio"],
                "ratio_12mp": tg.get("12mp", {}).get("settings", {}).get(
                    r["setting"], {}).get("median_ratio"),
                "ratio_1080p": tg.get("1080p", {}).get("settings", {}).get(
                    r["setting"], {}).get("median_ratio"),
                "tpr": r["tpr"]["rate"], "tpr_lo": r["tpr"]["ci"][0], "tpr_hi": r["tpr"]["ci"][1],
                "fpr": r["fpr"]["rate"], "fpr_lo": r["fpr"]["ci"][0], "fpr_hi": r["fpr"]["ci"][1],
                "error": r["error"],
                "peak_rss_delta_mib": _mib(m.get("rss_delta_bytes")),
                "peak_tracemalloc_mib": _mib(m.get("tracemalloc_peak_bytes")),
                "peak_x_rgb": m.get("x_rgb"), "pareto": r["pareto"]})
    plot_report(report, paths["png"])
    return paths


def _mib(b: int | None) -> float | None:
    return None if b is None else b / 2**20


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    return obj
