"""Evaluate detector profiles on a labelled synth dataset: TPR/FPR per kind with 95% intervals.

Besides the negative kinds and the positives' capture conditions, positives are grouped by the
emitter that played them (issue 21): ``f_B:200`` / ``f_B:between`` / ``f_B:f1`` /
``f_B:beyond`` (switching-rate band), ``phase:restart`` / ``phase:continuous``,
``order:0,1,2`` ... (slot order) and ``order-kind:ascending`` / ``descending`` / ``other``, and
the ``nominal`` sub-mix (no attack, full coverage, ambient <= 1, exposure < half a slot) per
mono/RGB and per band. ``legacy-emitter`` holds the emitters the firmware-only mix drew before
(f_B / M > 80 Hz, f_B <= f_1, restart phase, ascending order) and ``f_B/M>80Hz`` every
positive inside our firmware's flicker rule (for paired comparisons with detectors that only
knew those). Every rate comes with its exact
(Clopper-Pearson) 95% interval.

    python benchmarks/evaluate.py out/dev21 --profiles default --limit 100 \
        --per-image out/dev21-eval.jsonl --json out/dev21-eval.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from lishield_guard import AppConfig, detect, load_config
from lishield_guard.stats import clopper_pearson
from lishield_guard.threads import one_thread_per_worker

# clopper_pearson re-exported for old imports
__all__ = ["clopper_pearson", "contrast_bucket", "decided_by", "emitter", "kinds",
           "led_contrast", "main"]

LOW_BAND_HZ = 200.0  # paper Sec. 7.3
FLICKER_RULE_HZ = 80.0  # our firmware's rule, f_B / M > 80 Hz (paper Sec. 3.3.1)


def emitter(item: dict) -> dict | None:
    """The emitter fields of a positive (computed for manifests that predate them), else None.

    Returns ``{"f_b_band", "phase_mode", "slot_order", "slot_order_kind", "nominal",
    "legacy"}``; a manifest without ``phase_mode`` / ``slot_order`` was drawn with restart
    phase and ascending order.
    """
    if item.get("label") != 1:
        return None
    tones = [f for fs in (item.get("tones_hz") or {}).values() for f in fs]
    f1 = min(tones) if tones else float("nan")
    m = len(next(iter((item.get("tones_hz") or {"W": [0, 0, 0]}).values())))
    f_b = float(item.get("switching_hz") or f1)
    band = item.get("f_b_band")
    if band is None:
        if abs(f_b - LOW_BAND_HZ) <= 1e-6 * LOW_BAND_HZ:
            band = "200"
        elif abs(f_b - f1) <= 1e-6 * f1:
            band = "f1"
        else:
            band = "between" if LOW_BAND_HZ < f_b < f1 else "beyond"
    phase = item.get("phase_mode") or "restart"
    order = [int(i) for i in (item.get("slot_order") or range(m))]
    kind = item.get("slot_order_kind") or (
        "ascending" if order == sorted(order) else
        "descending" if order == sorted(order, reverse=True) else "other")
    nominal = item.get("nominal")
    if nominal is None:
        nominal = bool(not item.get("attack")
                       and (item.get("coverage") or {}).get("fraction", 1.0) >= 1.0
                       and (item.get("ambient_ratio") or 0.0) <= 1.0
                       and item.get("exposure_s", 1.0) < 0.5 / f_b)
    legacy = bool(f_b / m > FLICKER_RULE_HZ and f_b <= f1 * (1 + 1e-9)
                  and phase == "restart" and kind == "ascending")
    return {"f_b_band": band, "phase_mode": phase, "slot_order": order,
            "slot_order_kind": kind, "nominal": bool(nominal), "legacy": legacy,
            "within_flicker_rule": bool(f_b / m > FLICKER_RULE_HZ)}


def kinds(item: dict) -> list[str]:
    """Groups an item belongs to, for the per-kind table."""
    out = [item.get("kind", "?")]
    if item.get("label") == 1:
        colour = "RGB" if item.get("channels") != ["W"] else "mono"
        out.append(colour)
        out.append(str(item.get("preset")))
        em = emitter(item)
        out += [f"f_B:{em['f_b_band']}", f"phase:{em['phase_mode']}",
                f"order:{','.join(map(str, em['slot_order']))}",
                f"order-kind:{em['slot_order_kind']}"]
        if em["nominal"]:
            out += ["nominal", f"nominal:{colour}", f"nominal:f_B:{em['f_b_band']}",
                    f"nominal:{colour}:f_B:{em['f_b_band']}"]
        if em["legacy"]:
            out.append("legacy-emitter")
        if em["within_flicker_rule"]:
            out.append("f_B/M>80Hz")
        if item.get("exposure_s", 0.0) >= 1.0 / float(item.get("switching_hz") or 1e9):
            out.append("exposure>=slot")
    if item.get("scene_kind"):
        out.append(f"scene:{item['scene_kind']}:{'pos' if item.get('label') == 1 else 'neg'}")
        # capture conditions: the plain name counts barcodes (a TPR), ":neg" look-alikes
        side = "" if item.get("label") == 1 else ":neg"
        for key, name in (("attack", "exposure-attack"),):
            if item.get(key):
                out.append(name + side)
        if (item.get("ambient_ratio") or 0) > 1:
            out.append("ambient>1" + side)
        if (item.get("coverage") or {}).get("fraction", 1) not in (1, 1.0, None):
            out.append("partial-coverage" + side)
        if (item.get("downscale") or 1) > 1:
            out.append("downscaled" + side)
        if item.get("rotation_deg"):
            out.append("rotated" + side)
    return out


CONTRAST_BUCKETS = ((0.0, 0.01, "<1%"), (0.01, 0.03, "1-3%"), (0.03, 0.1, "3-10%"),
                    (0.1, float("inf"), ">=10%"))


def led_contrast(item: dict) -> float | None:
    """The LED's row contrast in a positive's capture (`synth.camera.led_row_contrast`:
    std over mean of the row light, ambient included, diluted by the lit fraction),
    recomputed from its manifest row; None for negatives."""
    if item.get("label") != 1:
        return None
    from lishield_guard.camera import CameraModel
    from synth.camera import led_row_contrast
    from synth.dataset import _make_light

    camera = CameraModel(row_time_s=1.0 / item["row_rate_hz"], n_rows=item["sensor_rows"],
                         exposure_s=item["exposure_s"])
    return led_row_contrast(_make_light(item), camera, start_s=item["frame_start_s"],
                            ambient_ratio=item.get("ambient_ratio") or 0.0,
                            lit_fraction=(item.get("coverage") or {}).get("fraction", 1.0))


def contrast_bucket(item: dict) -> str | None:
    """``contrast:<1%`` ... ``contrast:>=10%`` for a positive (`CONTRAST_BUCKETS`)."""
    c = led_contrast(item)
    if c is None:
        return None
    return "contrast:" + next(name for lo, hi, name in CONTRAST_BUCKETS if lo <= c < hi)


def decided_by(verdict) -> str:
    """Which stage flagged an image: the learned score (default profile), or for the cascade
    tone tracks, folding, the period sweep's grid fit or its exact-model refinement."""
    stage = verdict.evidence.get("stage")
    if verdict.profile == "default":
        return "learned"
    if stage in ("tones", "fold", "sweep", "exact fit"):
        return stage.replace(" ", "-")
    best = verdict.evidence.get("best") or {}
    if best.get("sweep") and "exact capture model" in str(verdict.evidence.get("reason")):
        return "exact-fit"
    if best.get("sweep") and "tiled every" in str(verdict.evidence.get("reason")):
        return "sweep"
    if best.get("fold") and "repeat every" in str(verdict.evidence.get("reason")):
        return "fold"
    return "tones"


def _judge(path: Path, cfg: AppConfig) -> tuple[bool, str | None, float, str | None, int]:
    """One image's verdict: (protected, deciding default-profile stage or None, ms, how far it
    went: ``"first stage"`` when the first stage cleared every candidate the verdict lists,
    ``"search"`` otherwise, None for the paper profile; the verdict's ``matches``, which for
    the paper profile is its ratio-match count m_b)."""
    t0 = time.perf_counter()
    v = detect(path, cfg)
    ms = (time.perf_counter() - t0) * 1e3
    stage = decided_by(v) if v.protected and v.profile in ("default", "cascade") else None
    cands = v.evidence.get("candidates") or []
    reached = None
    if v.profile == "cascade" and cands:
        cleared = all(c.get("stage") == "first stage" for c in cands)
        reached = "first stage" if cleared else "search"
    return bool(v.protected), stage, ms, reached, int(v.matches)


def main() -> int:
    """Run every profile over DIR/manifest.jsonl and print the table (and --json)."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--profiles", default="default,cascade",
                    help="comma-separated: default (learned), cascade, paper")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--config", type=Path, default=None,
                    help="TOML config (default: the shipped lishield_guard/data/default.toml)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--per-image", type=Path, default=None,
                    help="write one JSON line per image and profile here")
    ap.add_argument("--limit", type=int, default=None,
                    help="evaluate only the first N manifest items (labels are shuffled in a "
                         "manifest, so this is a random subset)")
    ap.add_argument("--label", choices=("pos", "neg"), default=None,
                    help="evaluate only positives or only negatives")
    args = ap.parse_args()
    per_image: list[dict] = []
    items = [json.loads(ln) for ln in (args.dataset / "manifest.jsonl").read_text().splitlines()
             if ln.strip()]
    if args.label is not None:
        items = [it for it in items if it["label"] == (1 if args.label == "pos" else 0)]
    if args.limit is not None:
        items = items[:max(args.limit, 0)]
    if not items:
        print("no images to evaluate", file=sys.stderr)
        return 2
    base = load_config(args.config)
    contrasts = {it["file"]: contrast_bucket(it) for it in items}
    report = {}
    for profile in args.profiles.split(","):
        cfg = AppConfig(detector=base.detector.replace(profile=profile), limits=base.limits,
                        policies=base.policies)
        stats: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        t0 = time.perf_counter()
        paths = [args.dataset / it["file"] for it in items]
        with ProcessPoolExecutor(args.jobs, initializer=one_thread_per_worker) as pool:
            outcomes = list(pool.map(_judge, paths, [cfg] * len(paths), chunksize=4))
        for it, (protected, stage, ms, reached, matches) in zip(items, outcomes, strict=True):
            extra = ["ALL-pos"] if it["label"] == 1 else ["ALL-neg"]
            if protected and profile == "cascade":
                extra.append(f"decided-by:{stage}:{'pos' if it['label'] else 'neg'}")
            if (bucket := contrasts.get(it["file"])) is not None:
                extra.append(bucket)
            for k in kinds(it) + extra:
                stats[k][0] += int(protected)
                stats[k][1] += 1
            if args.per_image:
                em = emitter(it) or {}
                per_image.append({"file": it["file"], "profile": profile,
                                  "label": it["label"], "kind": it.get("kind"),
                                  "protected": protected, "decided_by": stage,
                                  "stage_reached": reached, "matches": matches,
                                  "ms": round(ms, 1), "preset": it.get("preset"),
                                  "switching_hz": it.get("switching_hz"), **em})
        dt = time.perf_counter() - t0
        med = statistics.median(o[2] for o in outcomes) if outcomes else 0.0
        print(f"\nprofile={profile}  ({len(items)} images, {args.jobs} processes, "
              f"{dt / len(items) * 1e3:.1f} ms/image wall, median {med:.1f} ms per image "
              f"in a process)")
        print(f"{'kind':28s} {'flagged':>8s} {'n':>5s} {'rate':>7s}  95% CI")
        rows = {}
        for k in sorted(stats):
            hit, n = stats[k]
            lo, hi = clopper_pearson(hit, n)
            rows[k] = {"flagged": hit, "n": n, "rate": hit / n, "ci95": [lo, hi]}
            print(f"{k:28s} {hit:8d} {n:5d} {hit / n:7.3f}  [{lo:.3f}, {hi:.3f}]")
        report[profile] = rows
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    if args.per_image:
        args.per_image.write_text("".join(json.dumps(r) + "\n" for r in per_image))
    return 0


if __name__ == "__main__":
    sys.exit(main())
