"""Training report: learning curves, ROC on a fresh seed, detection by condition (docs/training.md).

    python -m training.report --model out/train/model/decision_model.npz

The fresh set is examples 0..n-1 of ``--seed`` (default 41, never used for training or
tuning) of the training mix (`training.data`), generated and cached like the training set.
The network is scored with the numpy inference that ships (`lishield_guard.detector.learned`)
and flagged by the one rule (`decision.rule_at`), so the figures are those of the product, not
of the training framework. Output: ``training_curves_roc.png`` and ``training_report.json`` in
``--out``, and a markdown summary on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

CONTRAST_BUCKETS = ((0.0, 0.01, "< 1 %"), (0.01, 0.03, "1-3 %"), (0.03, 0.1, "3-10 %"),
                    (0.1, np.inf, ">= 10 %"))


def _rate(mask: np.ndarray, flagged: np.ndarray) -> str:
    n = int(mask.sum())
    return f"{int(flagged[mask].sum())}/{n} = {flagged[mask].mean():.3f}" if n else "-"


def conditions(recs: list[dict], y: np.ndarray, flagged: np.ndarray) -> list[tuple[str, str]]:
    """(condition, detection or flag rate) rows: positives by contrast, preset, composite,
    attack, ambient and coverage; negatives by kind."""
    c = np.array([r["led_contrast"] for r in recs])
    pos = y == 1
    rows = [(f"positives, LED row contrast {name}", _rate(pos & (c >= lo) & (c < hi), flagged))
            for lo, hi, name in CONTRAST_BUCKETS]
    for key in ("preset", "composite", "attack"):
        vals = np.array([str(r[key]) for r in recs])
        rows += [(f"positives (contrast >= 3 %), {key} {v}",
                  _rate(pos & (vals == v) & (c >= 0.03), flagged))
                 for v in sorted(set(vals[pos]))]
    amb = np.array([r["ambient"] for r in recs])
    cov = np.array([r["coverage"] for r in recs])
    rows += [("positives (contrast >= 3 %), ambient > 2x", _rate(pos & (amb > 2) & (c >= .03),
                                                                 flagged)),
             ("positives (contrast >= 3 %), LED on < 50 % of the frame",
              _rate(pos & (cov < 0.5) & (c >= 0.03), flagged))]
    kinds = np.array([r["kind"] for r in recs])
    rows += [(f"negatives, {k} (flagged)", _rate(~pos & (kinds == k), flagged))
             for k in sorted(set(kinds[~pos]))]
    return rows


def threshold_at_fpr(negatives: np.ndarray, fpr: float) -> float:
    """The smallest logit threshold that flags (`decision.rule_at`: logit >= threshold) at
    most ``fpr`` of ``negatives``."""
    neg = np.sort(np.asarray(negatives, np.float64))
    k = int(np.floor(fpr * len(neg)))  # negatives allowed at or above the threshold
    return float(np.nextafter(neg[len(neg) - 1 - k], np.inf)) if len(neg) else float("inf")


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True, help="decision_model.npz (card beside it)")
    ap.add_argument("--seed", type=int, default=41, help="fresh data seed (default 41)")
    ap.add_argument("--n", type=int, default=4000)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--fpr", type=float, default=0.01, help="false-alarm rate of the table's "
                    "operating point on the fresh negatives (default 0.01)")
    ap.add_argument("--cache", default="out/train/eval")
    ap.add_argument("--bank", default="out/scenebank")
    ap.add_argument("--out", default="docs/figures")
    a = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lishield_guard.detector.decision import rule_at
    from lishield_guard.detector.learned import load_model, score_windows
    from training.train import _trainable, auc, dequantise, generate

    model = load_model(a.model)
    x, meta, mask, recs = generate(a.n, a.seed, jobs=a.jobs, cache=Path(a.cache), bank=a.bank)
    keep = _trainable(recs) | np.array([r["label"] == 1 and r["usable"] for r in recs])
    recs = [r for r, k in zip(recs, keep, strict=True) if k]
    x, meta, mask = x[keep], meta[keep], mask[keep]
    y = np.array([r["label"] for r in recs])
    logit = np.array([score_windows(dequantise(xi[m], mi[m]), model).max()
                      for xi, mi, m in zip(x, meta, mask, strict=True)])
    thr = threshold_at_fpr(logit[y == 0], a.fpr)
    flagged = rule_at(logit, thr)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    curves = model.card.get("curves") or []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    if curves:
        seen = [c["seen"] for c in curves]
        axes[0].plot(seen, [c["train_loss"] for c in curves], label="training loss")
        axes[0].plot(seen, [c["val_loss"] for c in curves], label="held-out loss")
        sizes = model.card.get("size_curve") or []
        if sizes:
            axes[0].plot([s["seen"] for s in sizes], [s["val_loss"] for s in sizes], "ko",
                         label="held-out loss, trained on " + ", ".join(
                             f"{s['train_examples'] // 1000}k" for s in sizes))
        axes[0].set_xlabel("training examples seen")
        axes[0].legend(loc="upper right", fontsize=8)
        axes[0].set_title("learning curves (held-out: the training seed's last examples)",
                          fontsize=9)
    order = np.argsort(-logit)
    tp = np.cumsum(y[order] == 1) / max(1, int((y == 1).sum()))
    fp = np.cumsum(y[order] == 0) / max(1, int((y == 0).sum()))
    axes[1].plot(fp, tp, label=f"seed {a.seed}, AUC {auc(logit, y):.3f}")
    c = np.array([r["led_contrast"] for r in recs])
    for lo, hi, name in CONTRAST_BUCKETS[1:]:
        keep = (y == 0) | ((c >= lo) & (c < hi))
        o = np.argsort(-logit[keep])
        yy = y[keep][o]
        axes[1].plot(np.cumsum(yy == 0) / max(1, (yy == 0).sum()),
                     np.cumsum(yy == 1) / max(1, (yy == 1).sum()), lw=1,
                     label=f"positives of contrast {name}")
    axes[1].set_xscale("log")
    axes[1].set_xlim(1e-3, 1)
    axes[1].set_xlabel("false-alarm rate (fresh negatives)")
    axes[1].set_ylabel("detection rate")
    axes[1].legend(fontsize=8)
    axes[1].set_title("ROC on the fresh seed")
    fig.tight_layout()
    fig.savefig(out / "training_curves_roc.png", dpi=100)
    plt.close(fig)

    rows = conditions(recs, y, flagged)
    report = {"model": a.model, "card": {k: v for k, v in model.card.items() if k != "curves"},
              "fresh_seed": a.seed, "n": len(y), "auc": auc(logit, y),
              "tpr_at_fpr": {str(f): float(rule_at(logit[y == 1], threshold_at_fpr(
                  logit[y == 0], f)).mean()) for f in (0.001, 0.01, 0.05)},
              "threshold_logit_at_fpr": thr, "conditions": rows}
    (out / "training_report.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"fresh seed {a.seed}: {len(y)} examples, AUC {report['auc']:.3f}; detection at "
          f"false-alarm rate 0.1 % / 1 % / 5 %: "
          + " / ".join(f"{v:.3f}" for v in report["tpr_at_fpr"].values()))
    print(f"\n| condition (operating point: {a.fpr:.0%} of fresh negatives flagged) | rate |")
    print("|---|---|")
    for name, val in rows:
        print(f"| {name} | {val} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
