"""The learned decision beside its ceiling, on a synth dataset, by kind and contrast bucket.

Every image is scored twice: by a decision model's image logit (the detector's own decode,
block profiles and `tfinput` instances of both axes; no threshold of the config involved) and
by the matched filter told the true light (`matched_filter.py`). Each score gets its own
threshold: the largest look-alike score of the set (``--fpr 0``) or the score that lets a given
share of look-alikes through, and the model's configured threshold when ``--config-threshold``
is given. The table lists the true-positive rate of each, with exact 95 % intervals, for
white-LED (Table 1) and RGB (Table 2) barcodes by LED row contrast, partly lit captures, and
the false-positive rate per look-alike kind.

    python benchmarks/ceiling.py out/eval/paper40 --model out/train/model/decision_model.npz \
        --jobs 2 --per-image out/eval/paper40-ceiling.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from evaluate import contrast_bucket  # noqa: E402
from matched_filter import score_item  # noqa: E402

from lishield_guard.stats import clopper_pearson  # noqa: E402

_MODEL = {}


def learned_logit(path: Path, model_path: str | None) -> float | None:
    """The image logit of a decision model as detection computes it (`decision.measure` on
    the detector's own decode); None when the image is undetermined."""
    from lishield_guard.config import default_config
    from lishield_guard.decode import decode
    from lishield_guard.detector.decision import measure
    from lishield_guard.detector.learned import load_model, shipped_model

    if model_path not in _MODEL:
        _MODEL[model_path] = shipped_model() if model_path is None else load_model(model_path)
    det = default_config().detector
    decoded = decode(path.read_bytes(), want_rgb=True, max_rows=det.profiles.max_decode_rows)
    rec = measure(decoded.rgb(), det, model=_MODEL[model_path])
    return None if rec.undetermined is not None else rec.logit


def _score(args: tuple) -> dict:
    folder, item, model_path, with_mf = args
    row = score_item((folder, item)) if with_mf else {
        "file": item["file"], "label": item["label"], "kind": item["kind"],
        "preset": item.get("preset"), "score": None}
    row["mf"] = row.pop("score")
    row["logit"] = learned_logit(Path(folder) / item["file"], model_path)
    return row


def groups(item: dict) -> list[str]:
    """Table rows an image counts in."""
    if item["label"] == 0:
        return ["look-alikes", f"look-alike:{item['kind']}"]
    kind = "white" if item.get("channels") == ["W"] else "RGB"
    out = ["barcodes", kind, f"{kind} {contrast_bucket(item).split(':')[1]}"]
    if (item.get("coverage") or {}).get("fraction", 1.0) < 1.0:
        out.append("partly lit")
    return out


def threshold(neg: list[float], fpr: float) -> float:
    """The smallest threshold that flags at most ``fpr`` of the look-alike scores ``neg``
    (strictly above; undetermined images excluded)."""
    vals = np.sort(np.asarray([v for v in neg if v is not None and np.isfinite(v)]))
    if not len(vals):
        return float("inf")
    k = int(np.floor(fpr * len(vals)))
    return float(vals[len(vals) - 1 - k])


def table(rows: list[dict], items: dict, thresholds: dict) -> list[str]:
    """Lines of the report: per group, each score's rate above its threshold."""
    by = defaultdict(list)
    for r in rows:
        for g in groups(items[r["file"]]):
            by[g].append(r)
    order = sorted(by, key=lambda g: (not g.startswith("barcodes"), g.startswith("look"), g))
    names = list(thresholds)
    lines = [f"{'group':24s} " + " ".join(f"{n:>26s}" for n in names)]
    for g in order:
        cells = []
        for n in names:
            key, thr = thresholds[n]
            hits = sum(1 for r in by[g] if r[key] is not None and r[key] > thr)
            lo, hi = clopper_pearson(hits, len(by[g]))
            cells.append(f"{hits:4d}/{len(by[g]):<4d}{hits / max(len(by[g]), 1):6.3f} "
                         f"[{lo:.2f},{hi:.2f}]")
        lines.append(f"{g:24s} " + " ".join(f"{c:>26s}" for c in cells))
    return lines


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--model", help="decision_model.npz (default: the shipped one)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--fpr", type=float, default=0.0,
                    help="share of look-alikes each threshold may let through (default 0)")
    ap.add_argument("--config-threshold", type=float,
                    help="also report the model at this (calibrated) logit threshold")
    ap.add_argument("--no-mf", action="store_true", help="skip the matched filter")
    ap.add_argument("--per-image", help="JSON lines of every image's scores")
    ap.add_argument("--reuse", help="read the per-image scores from this file instead")
    ap.add_argument("--mf-from", help="take the matched filter's scores from this --per-image "
                    "file of the same set (the model is scored afresh)")
    a = ap.parse_args(argv)
    from lishield_guard.threads import one_thread_per_worker

    folder = Path(a.dataset)
    items = {it["file"]: it for it in map(json.loads, (folder / "manifest.jsonl")
                                          .read_text().splitlines())}
    if a.reuse:
        rows = [json.loads(line) for line in Path(a.reuse).read_text().splitlines()]
    else:
        args = [(str(folder), it, a.model, not (a.no_mf or a.mf_from))
                for it in items.values()]
        with ProcessPoolExecutor(a.jobs, initializer=one_thread_per_worker) as pool:
            rows = list(pool.map(_score, args, chunksize=4))
        if a.mf_from:
            lines = Path(a.mf_from).read_text().splitlines()
            mf = {r["file"]: r.get("mf", r.get("score")) for r in map(json.loads, lines)}
            rows = [{**r, "mf": mf[r["file"]]} for r in rows]
    if a.per_image:
        Path(a.per_image).write_text("".join(json.dumps(r) + "\n" for r in rows))
    thresholds = {f"model @FPR<={a.fpr:g}": ("logit", threshold(
        [r["logit"] for r in rows if r["label"] == 0], a.fpr))}
    if a.config_threshold is not None:
        thresholds["model @config"] = ("logit", a.config_threshold - 1e-9)
    if not a.no_mf:
        thresholds[f"matched filter @FPR<={a.fpr:g}"] = ("mf", threshold(
            [r["mf"] for r in rows if r["label"] == 0], a.fpr))
    for name, (_key, thr) in thresholds.items():
        print(f"{name}: threshold {thr:.3f}")
    und = sum(r["logit"] is None for r in rows)
    print(f"undetermined for the model: {und}")
    print("\n".join(table(rows, items, thresholds)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
