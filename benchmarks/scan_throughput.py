"""Scan throughput: images/s for --jobs 1, --jobs 2 and --dask local (2 workers) on 1080p JPEGs.

Usage: ``python benchmarks/scan_throughput.py [--dir DIR] [--n 500] [--source auto|synth|photos]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

N_ROWS, N_COLS = 1080, 1920


def make_photos(folder: Path, n: int, *, seed: int = 0) -> None:
    """n 1080p JPEGs from scikit-image sample photos, randomly cropped, scaled and noised."""
    import cv2
    import numpy as np
    from skimage import data

    rng = np.random.default_rng(seed)
    bases = [data.astronaut(), data.coffee(), data.chelsea(), data.rocket(),
             np.dstack([data.camera()] * 3)]
    for i in range(n):
        img = bases[i % len(bases)][:, :, ::-1]
        img = cv2.resize(img, (N_COLS, N_ROWS), interpolation=cv2.INTER_CUBIC).astype(np.float32)
        img *= rng.uniform(0.6, 1.2)
        img += rng.normal(0.0, rng.uniform(1.0, 6.0), img.shape).astype(np.float32)
        out = np.clip(img, 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{i:06d}.jpg"), out,
                    [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(70, 95))])


def ensure_dataset(folder: Path, n: int, source: str) -> str:
    """Reuse folder when it holds >= n JPEGs, else fill it; returns how it was made."""
    folder.mkdir(parents=True, exist_ok=True)
    have = len(list(folder.glob("*.jpg")))
    if have >= n:
        return f"reused {have} JPEGs"
    if source in ("auto", "synth"):
        try:
            from synth.dataset import write_dataset
        except ImportError:
            if source == "synth":
                raise
        else:
            write_dataset(folder, n_pos=n // 2, n_neg=n - n // 2, seed=0, size="1080p",
                          jobs=os.cpu_count() or 1, progress=sys.stderr.isatty())
            return f"synth.dataset: {n} captures"
    make_photos(folder, n)
    return f"skimage photos + noise: {n} JPEGs"


def run(folder: Path, *extra: str) -> float:
    """Images/s of one `lishield-guard scan` run (wall clock, process start included)."""
    cli = Path(sys.executable).with_name("lishield-guard")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "o.jsonl"
        t0 = time.perf_counter()
        subprocess.run([str(cli), "scan", str(folder), "-o", str(out), "--quiet",
                        "--include", "*.jpg", *extra], check=False)
        elapsed_s = time.perf_counter() - t0
        recs = [json.loads(line) for line in out.read_text().splitlines()]
    n_ok = sum(r["error"] is None for r in recs)
    return n_ok / elapsed_s


def main() -> None:
    """Build or reuse the dataset, time the three modes and print a small report."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "lg_scan_bench")
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--source", choices=("auto", "synth", "photos"), default="auto")
    args = ap.parse_args()
    how = ensure_dataset(args.dir, args.n, args.source)
    print(f"dataset: {args.dir} ({how}), {N_COLS}x{N_ROWS}, cpu_count={os.cpu_count()}")
    r1 = run(args.dir, "--jobs", "1")
    print(f"--jobs 1               : {r1:7.1f} images/s")
    r2 = run(args.dir, "--jobs", "2")
    print(f"--jobs 2               : {r2:7.1f} images/s  (scaling {r2 / r1:.2f}x, target 1.7x)")
    rd = run(args.dir, "--jobs", "2", "--dask", "local")
    print(f"--dask local, 2 workers: {rd:7.1f} images/s  ({rd / r1:.2f}x of --jobs 1; "
          f"includes cluster start-up)")


if __name__ == "__main__":
    main()
