"""Re-measure a config on the certification part of a calibration split, without re-tuning.

`lishield-guard calibrate --certify-fraction F --split-seed S` chooses thresholds on one part
of the clean images and measures them once on the other. After a detector change that keeps
the thresholds, the certification part is still held out from their choice: scanning it with
the new code and the same config measures the false-alarm rate again at a fraction of the
calibration's cost (one `detect` per image instead of every setting's evidence).

    python benchmarks/certification_part.py list --clean out/calib/clean/realphotos \
        --clean out/calib/clean/photos --clean out/calib/clean/synth > cert.txt
    lishield-guard scan --from-list cert.txt -o cert.jsonl -j 2
    python benchmarks/certification_part.py count cert.jsonl --target-far 0.001

The split is the calibrate command's own (same folders in the same order, same fraction and
seed give the same images).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lishield_guard.commands.calibrate import _list_images, _origin_names, _split
from lishield_guard.stats import upper_bound


def certification_paths(clean: list[Path], fraction: float, seed: int) -> list[Path]:
    """The images of ``clean`` (folders, in calibrate's order) in the certification part."""
    items = [(p, m, o) for d, o in zip(clean, _origin_names(clean), strict=True)
             for p, m in _list_images(d)]
    mask, _ = _split(items, fraction, seed)
    return [p for (p, _, _), cert in zip(items, mask, strict=True) if cert]


def main() -> int:
    """``list``: print the certification part; ``count``: its false alarms and FAR bound."""
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    ls = sub.add_parser("list", help="print the certification part's paths, one per line")
    ls.add_argument("--clean", type=Path, action="append", required=True)
    ls.add_argument("--fraction", type=float, default=0.5)
    ls.add_argument("--seed", type=int, default=0)
    ct = sub.add_parser("count", help="false alarms of a scan's JSONL output, with the bound")
    ct.add_argument("scan_jsonl", type=Path)
    ct.add_argument("--target-far", type=float, default=0.001)
    args = ap.parse_args()
    if args.cmd == "list":
        paths = certification_paths(args.clean, args.fraction, args.seed)
        sys.stdout.write("".join(f"{p}\n" for p in paths))
        print(f"{len(paths)} images in the certification part", file=sys.stderr)
        return 0
    recs = [json.loads(ln) for ln in args.scan_jsonl.read_text().splitlines() if ln.strip()]
    errors = [r for r in recs if r.get("error")]
    judged = [r for r in recs if not r.get("error")]
    flagged = [r for r in judged if r.get("protected")]
    undetermined = [r for r in judged if r.get("status") == "undetermined"]
    k, n = len(flagged), len(judged)
    bound = upper_bound(k, n) if n else 1.0
    print(f"{k}/{n} false alarms ({len(errors)} errors, {len(undetermined)} undetermined): "
          f"FAR <= {bound:.6f} at 95% (one-sided); target {args.target_far:g} "
          f"{'met' if bound <= args.target_far else 'NOT met'}")
    for r in flagged:
        print(f"  flagged: {r.get('path')}")
    return 0 if bound <= args.target_far else 1


if __name__ == "__main__":
    raise SystemExit(main())
