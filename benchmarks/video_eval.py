"""Evaluate video screening on a labelled video set (`synth dataset --videos`).

Per clip, in worker processes of one thread each: the screen as it runs (`detect_video`, timed,
decode included) and, with ``--exhaustive``, every planned frame's logit (`clip_scores`, for
replaying other thresholds and combinations). Reports TPR and FPR per clip with exact 95%
intervals, TPR by condition (ambient > 1, exposure >= one slot, partial coverage, motion,
resolution) beside the single-frame TPR of the same clips (the first screened frame judged
alone by the photo rule), and the cost per clip (median and maximum wall time).

    python benchmarks/video_eval.py out/video-fresh --jobs 2 --json out/video-fresh-eval.json
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

from lishield_guard import load_config
from lishield_guard.stats import clopper_pearson
from lishield_guard.threads import one_thread_per_worker

_CFG = None


def _init(config_path: str | None, overrides: dict) -> None:
    global _CFG
    one_thread_per_worker()
    import dataclasses

    from lishield_guard.settings import VideoConfig

    cfg = load_config(config_path) if config_path else load_config()
    vcfg = dataclasses.replace(getattr(cfg, "video", None) or VideoConfig(), **overrides)
    _CFG = (cfg, vcfg)


def _one(args: tuple) -> dict:
    path, exhaustive = args
    from lishield_guard.errors import LishieldError
    from lishield_guard.video.calibrate import clip_scores
    from lishield_guard.video.screen import detect_video

    cfg, vcfg = _CFG
    out: dict = {"file": Path(path).name}
    t0 = time.perf_counter()
    try:
        v = detect_video(path, cfg, vcfg)
        out["status"] = v.status
        vid = v.evidence.get("video", {})
        out["clip_logit"] = vid.get("clip_logit")
        out["frames"] = [f["logit"] for f in vid.get("frames", [])]
        out["stop"] = vid.get("stop")
        out["decoded"] = vid.get("frames_decoded")
    except LishieldError as exc:
        out["status"] = "error"
        out["error"] = f"{exc.code}: {exc}"
    out["seconds"] = time.perf_counter() - t0
    if exhaustive:
        c = clip_scores(path, out["file"], cfg, vcfg)
        out["all_logits"], out["run_sizes"] = list(c.logits), list(c.run_sizes)
    return out


def conditions(rec: dict) -> list[str]:
    """The condition groups a clip belongs to."""
    out = ["all", f"size:{rec.get('size')}", f"motion:{bool(rec['motion'].get('enabled'))}"]
    if rec["label"]:
        out.append("rgb" if len(rec.get("channels") or ()) > 1 else "mono")
        if rec["ambient_ratio"] > 1:
            out.append("ambient>1")
        if rec["exposure_s"] >= 1.0 / rec["switching_hz"]:
            out.append("exposure>=slot")
        if rec["coverage"]["fraction"] < 1.0:
            out.append("partial")
        if rec.get("nominal"):
            out.append("nominal")
    else:
        out.append(f"kind:{rec['kind']}")
    return out


def summarise(rows: list[dict], manifest: dict[str, dict], image_threshold: float) -> dict:
    """Rates with intervals per label and condition, and the cost per clip."""
    groups: dict[tuple[int, str], list[dict]] = defaultdict(list)
    for r in rows:
        rec = manifest[r["file"]]
        for c in conditions(rec):
            groups[(rec["label"], c)].append(r)
    out: dict = {"rates": {}, "cost_s": {}}
    for (label, cond), rs in sorted(groups.items()):
        k = sum(r["status"] == "protected" for r in rs)
        lo, hi = clopper_pearson(k, len(rs))
        first = sum(bool(r.get("frames")) and r["frames"][0] is not None
                    and r["frames"][0] >= image_threshold for r in rs)
        out["rates"][f"{'pos' if label else 'neg'}:{cond}"] = {
            "n": len(rs), "flagged": k, "rate": k / len(rs), "ci95": [lo, hi],
            "single_frame": first / len(rs),
            "undetermined": sum(r["status"] == "undetermined" for r in rs),
            "errors": sum(r["status"] == "error" for r in rs)}
    for label in (0, 1):
        secs = [r["seconds"] for r in rows if manifest[r["file"]]["label"] == label]
        if secs:
            out["cost_s"]["pos" if label else "neg"] = {
                "median": statistics.median(secs), "max": max(secs), "n": len(secs)}
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line entry (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--limit", type=int, default=0)
    ap.add_argument("--config", default=None)
    ap.add_argument("--exhaustive", action="store_true", help="also score every planned frame")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a [video] setting (e.g. threshold_logit=2.5)")
    ap.add_argument("--json", type=Path, default=None, help="write the summary here")
    ap.add_argument("--per-clip", type=Path, default=None, help="write per-clip JSON lines")
    a = ap.parse_args(argv)
    manifest = {}
    with open(a.folder / "manifest.jsonl", encoding="utf-8") as fh:
        for line in fh:
            rec = json.loads(line)
            manifest[rec["file"]] = rec
    files = sorted(manifest)[: a.limit or None]
    overrides = {k: float(v) if "." in v or "e" in v else int(v)
                 for k, v in (s.split("=", 1) for s in a.set)}
    t0 = time.time()
    with ProcessPoolExecutor(a.jobs, initializer=_init, initargs=(a.config, overrides)) as ex:
        rows = list(ex.map(_one, [(str(a.folder / f), a.exhaustive) for f in files]))
    cfg = load_config(a.config) if a.config else load_config()
    summary = summarise(rows, manifest, cfg.detector.learned.threshold_logit)
    summary.update(folder=str(a.folder), n=len(rows), wall_s=time.time() - t0, overrides=overrides)
    for key, v in summary["rates"].items():
        print(f"{key:28s} {v['flagged']:4d}/{v['n']:<4d} = {v['rate']:.3f} "
              f"[{v['ci95'][0]:.3f}, {v['ci95'][1]:.3f}]  single-frame {v['single_frame']:.3f}"
              f"  undetermined {v['undetermined']}  errors {v['errors']}")
    for key, v in summary["cost_s"].items():
        print(f"cost {key}: median {v['median']:.3f} s  max {v['max']:.3f} s  (n={v['n']})")
    if a.json:
        a.json.write_text(json.dumps(summary, indent=1))
    if a.per_clip:
        with open(a.per_clip, "w", encoding="utf-8") as fh:
            for r in rows:
                fh.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
