"""Cost of ordinary photos: detection time against Pillow's full decode, and where each exits.

For every image (a folder of real photographs, or a synth dataset's negatives), one process
and one thread, interleaved per image: Pillow's full RGB decode of the file, then
`lishield_guard.detect` on the same file, each timed in process CPU time (robust to other
work on a shared machine) and wall time. Reports per size class (>= 8 MP, 1-8 MP, < 1 MP)
the median and p95 of detect / decode, and which stage decided the verdict (first stage,
tone tracks, pattern search) with the share of images at each.

    python benchmarks/first_stage.py out/photos/images --limit 300 --json out/first_stage.json
"""

from __future__ import annotations

import argparse
import collections
import json
import time
from pathlib import Path

import numpy as np
from PIL import Image

import lishield_guard as lg
from lishield_guard.threads import one_thread_per_worker

SUFFIXES = {".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff"}


def _stage(verdict) -> str:
    reason = (verdict.evidence or {}).get("reason", "")
    if verdict.status == "undetermined":
        return "undetermined"
    if (verdict.evidence or {}).get("stage") == "learned":  # the default profile: one stage
        return "learned: protected" if verdict.protected else "learned: clean"
    if reason.startswith("first stage"):
        return "first stage"
    if verdict.protected:
        return "protected"
    return "pattern search"


def _size_class(n_pixels: int) -> str:
    return ">=8MP" if n_pixels >= 8e6 else ("1-8MP" if n_pixels >= 1e6 else "<1MP")


def main() -> None:
    """Run the benchmark (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--limit", type=int, default=0, help="first N images (sorted by path)")
    ap.add_argument("--json", type=Path, help="write the summary and per-image rows here")
    args = ap.parse_args()
    one_thread_per_worker()
    paths = sorted(p for p in args.folder.rglob("*") if p.suffix.lower() in SUFFIXES)
    if args.limit:
        paths = paths[: args.limit]
    rows = []
    for p in paths:
        t = time.process_time()
        with Image.open(p) as im:
            rgb = im.convert("RGB")
            rgb.load()
        pil_s = time.process_time() - t
        n_px = rgb.width * rgb.height
        t, w = time.process_time(), time.perf_counter()
        try:
            v = lg.detect(p)
        except lg.LishieldError as exc:
            rows.append({"path": str(p), "error": type(exc).__name__})
            continue
        det_s, det_wall = time.process_time() - t, time.perf_counter() - w
        rows.append({"path": str(p), "pixels": n_px, "pil_cpu_s": pil_s, "detect_cpu_s": det_s,
                     "detect_wall_s": det_wall, "ratio": det_s / max(pil_s, 1e-6),
                     "stage": _stage(v), "protected": v.protected})
    ok = [r for r in rows if "error" not in r]
    summary = {}
    print(f"{len(ok)} images ({len(rows) - len(ok)} errors)")
    print(f"{'class':8s} {'n':>4s} {'ratio med':>9s} {'p95':>6s} {'det ms med':>10s} "
          f"{'pil ms med':>10s}  stages")
    for cls in (">=8MP", "1-8MP", "<1MP", "all"):
        sel = [r for r in ok if cls == "all" or _size_class(r["pixels"]) == cls]
        if not sel:
            continue
        ratio = np.array([r["ratio"] for r in sel])
        stages = collections.Counter(r["stage"] for r in sel)
        summary[cls] = {"n": len(sel), "ratio_median": float(np.median(ratio)),
                        "ratio_p95": float(np.quantile(ratio, 0.95)),
                        "detect_ms_median": 1e3 * float(np.median([r["detect_cpu_s"]
                                                                   for r in sel])),
                        "pil_ms_median": 1e3 * float(np.median([r["pil_cpu_s"] for r in sel])),
                        "stages": {k: v / len(sel) for k, v in stages.items()}}
        s = summary[cls]
        print(f"{cls:8s} {len(sel):4d} {s['ratio_median']:9.2f} {s['ratio_p95']:6.2f} "
              f"{s['detect_ms_median']:10.1f} {s['pil_ms_median']:10.1f}  "
              + ", ".join(f"{k} {v:.0%}" for k, v in sorted(s["stages"].items())))
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
