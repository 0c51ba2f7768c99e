"""Cost of screening clips, one thread, decode included, against decoding every frame.

For each clip of a folder, interleaved and repeated: the screen as it runs (`detect_video`,
wall time from the file on disk to the verdict) and a baseline, PyAV decoding every frame of
the same clip to RGB (what any screen that looks at every frame pays before it computes
anything). The first call of the process (imports, the model's load) is made on the first clip
before timing starts. Reports median and maximum per clip kind and the ratio screen/baseline.

    python benchmarks/video_cost.py out/video-cost --repeats 3 --json out/video-cost.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path


def _decode_all(path: str) -> int:
    import av

    n = 0
    with av.open(path) as c:
        st = c.streams.video[0]
        st.codec_context.thread_count = 1
        for frame in c.decode(st):
            frame.to_ndarray(format="rgb24")
            n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    """Command line entry (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    from lishield_guard.config import default_config
    from lishield_guard.threads import one_thread_per_worker
    from lishield_guard.video.screen import detect_video

    one_thread_per_worker()
    cfg = default_config()
    man = {}
    mpath = a.folder / "manifest.jsonl"
    if mpath.exists():
        man = {json.loads(ln)["file"]: json.loads(ln) for ln in mpath.read_text().splitlines()}
    clips = sorted(str(p) for p in a.folder.glob("*.mp4"))
    detect_video(clips[0], cfg)  # the process's first call: imports and the model's load
    rows = []
    for rep in range(a.repeats):
        for path in clips:
            t0 = time.perf_counter()
            v = detect_video(path, cfg)
            t_screen = time.perf_counter() - t0
            t0 = time.perf_counter()
            n = _decode_all(path)
            t_base = time.perf_counter() - t0
            label = man.get(Path(path).name, {}).get("label")
            rows.append({"file": Path(path).name, "repeat": rep, "label": label,
                         "status": v.status, "screen_s": t_screen, "decode_all_s": t_base,
                         "frames": n, "screened": v.evidence.get("video", {}).get(
                             "frames_screened")})
    out = {}
    for label, name in ((0, "clean"), (1, "barcode"), (None, "unlabelled")):
        rs = [r for r in rows if r["label"] == label]
        if not rs:
            continue
        ratio = [r["screen_s"] / r["decode_all_s"] for r in rs]
        out[name] = {"n": len(rs), "screen_median_s": statistics.median(r["screen_s"] for r in rs),
                     "screen_max_s": max(r["screen_s"] for r in rs),
                     "decode_all_median_s": statistics.median(r["decode_all_s"] for r in rs),
                     "ratio_median": statistics.median(ratio),
                     "frames_screened_median": statistics.median(r["screened"] or 0 for r in rs),
                     "statuses": {s: sum(r["status"] == s for r in rs)
                                  for s in ("protected", "clean", "undetermined")}}
        o = out[name]
        print(f"{name:10s} n={o['n']:3d} screen median {o['screen_median_s']:.3f} s max "
              f"{o['screen_max_s']:.3f} s | decode every frame median "
              f"{o['decode_all_median_s']:.3f} s | ratio {o['ratio_median']:.3f} | frames "
              f"screened median {o['frames_screened_median']} | {o['statuses']}")
    if a.json:
        a.json.write_text(json.dumps({"summary": out, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
