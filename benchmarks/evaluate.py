"""Evaluate detector profiles on a labelled synth dataset: TPR/FPR per kind with 95% intervals."""

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
__all__ = ["clopper_pearson", "decided_by", "kinds", "main"]


def kinds(item: dict) -> list[str]:
    """Groups an item belongs to, for the per-kind table."""
    out = [item.get("kind", "?")]
    if item.get("label") == 1:
        out.append("RGB" if item.get("channels") != ["W"] else "mono")
        out.append(str(item.get("preset")))
        for key, name in (("attack", "exposure-attack"),):
            if item.get(key):
                out.append(name)
        if (item.get("ambient_ratio") or 0) > 1:
            out.append("ambient>1")
        if (item.get("coverage") or {}).get("fraction", 1) not in (1, 1.0, None):
            out.append("partial-coverage")
        if (item.get("downscale") or 1) > 1:
            out.append("downscaled")
        if item.get("rotation_deg"):
            out.append("rotated")
    return out


def decided_by(verdict) -> str:
    """Which default-profile stage flagged an image: tone tracks, folding, the period sweep's
    grid fit or its exact-model refinement."""
    best = verdict.evidence.get("best") or {}
    if best.get("sweep") and "exact capture model" in str(verdict.evidence.get("reason")):
        return "exact-fit"
    if best.get("sweep") and "tiled every" in str(verdict.evidence.get("reason")):
        return "sweep"
    if best.get("fold") and "repeat every" in str(verdict.evidence.get("reason")):
        return "fold"
    return "tones"


def _judge(path: Path, cfg: AppConfig) -> tuple[bool, str | None, float]:
    """One image's verdict: (protected, deciding default-profile stage or None, ms)."""
    t0 = time.perf_counter()
    v = detect(path, cfg)
    ms = (time.perf_counter() - t0) * 1e3
    stage = decided_by(v) if v.protected and v.profile == "default" else None
    return bool(v.protected), stage, ms


def main() -> int:
    """Run every profile over DIR/manifest.jsonl and print the table (and --json)."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--profiles", default="default,paper")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--config", type=Path, default=None,
                    help="TOML config (default: the shipped lishield_guard/data/default.toml)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--per-image", type=Path, default=None,
                    help="write one JSON line per image and profile here")
    args = ap.parse_args()
    per_image: list[dict] = []
    items = [json.loads(ln) for ln in (args.dataset / "manifest.jsonl").read_text().splitlines()
             if ln.strip()]
    base = load_config(args.config)
    report = {}
    for profile in args.profiles.split(","):
        cfg = AppConfig(detector=base.detector.replace(profile=profile), limits=base.limits,
                        policies=base.policies)
        stats: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        t0 = time.perf_counter()
        paths = [args.dataset / it["file"] for it in items]
        with ProcessPoolExecutor(args.jobs, initializer=one_thread_per_worker) as pool:
            outcomes = list(pool.map(_judge, paths, [cfg] * len(paths), chunksize=4))
        for it, (protected, stage, ms) in zip(items, outcomes, strict=True):
            extra = ["ALL-pos"] if it["label"] == 1 else ["ALL-neg"]
            if protected and profile == "default":
                extra.append(f"decided-by:{stage}:{'pos' if it['label'] else 'neg'}")
            for k in kinds(it) + extra:
                stats[k][0] += int(protected)
                stats[k][1] += 1
            if args.per_image:
                per_image.append({"file": it["file"], "profile": profile,
                                  "label": it["label"], "protected": protected,
                                  "decided_by": stage, "ms": round(ms, 1)})
        dt = time.perf_counter() - t0
        med = statistics.median(ms for _, _, ms in outcomes) if outcomes else 0.0
        print(f"\nprofile={profile}  ({len(items)} images, {args.jobs} processes, "
              f"{dt / len(items) * 1e3:.1f} ms/image wall, median {med:.1f} ms per image "
              f"in a process)")
        print(f"{'kind':22s} {'flagged':>8s} {'n':>5s} {'rate':>7s}  95% CI")
        rows = {}
        for k in sorted(stats):
            hit, n = stats[k]
            lo, hi = clopper_pearson(hit, n)
            rows[k] = {"flagged": hit, "n": n, "rate": hit / n, "ci95": [lo, hi]}
            print(f"{k:22s} {hit:8d} {n:5d} {hit / n:7.3f}  [{lo:.3f}, {hi:.3f}]")
        report[profile] = rows
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    if args.per_image:
        args.per_image.write_text("".join(json.dumps(r) + "\n" for r in per_image))
    return 0


if __name__ == "__main__":
    sys.exit(main())
