"""Does the first stage ever clear a capture the full cascade flags? Checked on positives.

For the first N positives of a `lishield-guard synth dataset` folder, the detector runs once with
the first stage off (every plane goes to the pattern search) and, for each capture that run
flags, once more with the shipped config. A capture flagged without the first stage and clean
with it is a first-stage miss; the script lists them and exits 1 when there is one.

    python benchmarks/screen_misses.py out/fresh22 --n 100
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lishield_guard import detect, load_config
from lishield_guard.config import AppConfig


def main(argv: list[str] | None = None) -> int:
    """Run the check; print one line per miss and a summary; exit 1 on any miss."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, help="folder with manifest.jsonl and the images")
    ap.add_argument("--n", type=int, default=100, help="first N positives (manifest order)")
    ap.add_argument("--config", type=Path, default=None, help="config TOML (default: shipped)")
    ap.add_argument("--json", type=Path, default=None, help="write per-image rows here")
    args = ap.parse_args(argv)

    shipped = load_config(args.config)
    no_screen = AppConfig(detector=shipped.detector.replace(screen=None),
                          limits=shipped.limits, policies=shipped.policies)
    rows = [json.loads(line) for line in (args.dataset / "manifest.jsonl").open()]
    positives = [r for r in rows if r.get("label") == 1][: args.n]
    out, flagged, missed = [], 0, []
    t0 = time.process_time()
    for r in positives:
        path = args.dataset / r["file"]
        full = detect(path, no_screen)
        rec = {"file": r["file"], "flagged_without_screen": full.protected,
               "stage_without_screen": full.evidence.get("stage")}
        if full.protected:
            flagged += 1
            v = detect(path, shipped)
            rec.update(flagged_with_screen=v.protected, stage_with_screen=v.evidence.get("stage"))
            if not v.protected:
                missed.append(r["file"])
                print(f"MISS {r['file']}: {v.evidence['reason'][:160]}", flush=True)
        out.append(rec)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    print(f"{len(positives)} positives: the full cascade flags {flagged}; the first stage clears "
          f"{len(missed)} of them ({time.process_time() - t0:.0f} s CPU)")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
