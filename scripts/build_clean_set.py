"""Rebuild the calibration clean set: bundled scikit-image photos, varied, plus synth look-alikes.

Usage (deterministic for a seed; ~3000 images in about 2-3 minutes on 2 cores)::

    .venv/bin/python scripts/build_clean_set.py --out out/calib/clean --seed 0 \
        --n-photo 2300 --n-synth 700 --jobs 2

Part 1, ``photos/``: every scikit-image sample photo that ships with the package (functions of
``skimage.data`` that need no download; the others are skipped, never downloaded). Each output
image takes one photo and applies, drawn from ``numpy.random.default_rng(seed)``: a random crop
(30-100 % of each side), a resize so the long side is 640-1280 px (up- or downscaling), a
rotation by 0/90/180/270 degrees, an optional extra downscale (x1, x1.5, x2, x3, never below
256 px), and JPEG re-encoding at quality 60-95 (a few PNG). None of these photos was taken under
a LiShield LED, so every one is a true negative.

Part 2, ``synth/``: ``lishield-guard synth dataset --mix negatives-only`` (steady, mains, PWM and
texture look-alikes) at 960x720, seed ``seed + 1``.

A ``manifest.jsonl`` in each part records the source photo and every transform.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from lishield_guard.threads import one_thread_per_worker

PHOTO_FUNCS = ("astronaut", "brick", "camera", "cat", "chelsea", "clock", "coffee", "coins",
               "colorwheel", "grass", "gravel", "horse", "hubble_deep_field",
               "immunohistochemistry", "logo", "moon", "page", "rocket", "text", "retina",
               "stereo_motorcycle", "cell", "microaneurysms")
QUALITIES = (60, 70, 75, 85, 90, 95)
EXTRA_DOWNSCALES = (1.0, 1.0, 1.5, 2.0, 3.0)


def bundled_photos() -> dict[str, np.ndarray]:
    """Bundled skimage photos as uint8 (n_rows, n_cols[, 3]); ones needing a download skipped."""
    import skimage.data as sd

    out = {}
    for name in PHOTO_FUNCS:
        fn = getattr(sd, name, None)
        if fn is None:
            continue
        try:
            img = fn()
        except Exception:  # noqa: BLE001 - needs pooch/download: skip, never fetch
            continue
        if name == "stereo_motorcycle":
            out["stereo_motorcycle_left"], out["stereo_motorcycle_right"] = img[0], img[1]
            continue
        img = np.asarray(img)
        if img.dtype == bool:
            img = img.astype(np.uint8) * 255
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        out[name] = img.astype(np.uint8)
    return out


def _one(args: tuple[int, int]) -> dict:
    index, seed = args
    from PIL import Image

    photos = _one.photos  # type: ignore[attr-defined]
    names = sorted(photos)
    rng = np.random.default_rng([seed, index])
    name = names[int(rng.integers(len(names)))]
    img = photos[name]
    n_rows, n_cols = img.shape[:2]
    ch = max(16, int(n_rows * rng.uniform(0.3, 1.0)))
    cw = max(16, int(n_cols * rng.uniform(0.3, 1.0)))
    r0 = int(rng.integers(0, n_rows - ch + 1))
    c0 = int(rng.integers(0, n_cols - cw + 1))
    crop = img[r0:r0 + ch, c0:c0 + cw]
    long_px = int(rng.integers(640, 1281))
    scale = long_px / max(ch, cw)
    pil = Image.fromarray(crop)
    pil = pil.resize((max(1, round(cw * scale)), max(1, round(ch * scale))), Image.BICUBIC)
    rot = int(rng.choice([0, 90, 180, 270]))
    if rot:
        pil = pil.rotate(-rot, expand=True)  # clockwise
    down = float(rng.choice(EXTRA_DOWNSCALES))
    if down > 1 and min(pil.size) / down >= 256:
        pil = pil.resize((round(pil.size[0] / down), round(pil.size[1] / down)), Image.LANCZOS)
    else:
        down = 1.0
    png = rng.random() < 0.05
    quality = None if png else int(rng.choice(QUALITIES))
    buf = io.BytesIO()
    if png:
        pil.save(buf, format="PNG")
    else:
        pil.save(buf, format="JPEG", quality=quality)
    fname = f"{index:06d}.{'png' if png else 'jpg'}"
    (_one.out / fname).write_bytes(buf.getvalue())  # type: ignore[attr-defined]
    return {"file": fname, "label": 0, "kind": "photo", "source": name, "crop": [r0, c0, ch, cw],
            "long_side_px": long_px, "rotation_deg": rot, "downscale": down,
            "jpeg_quality": quality, "size": list(pil.size[::-1])}


def _init(out: str) -> None:
    one_thread_per_worker()
    _one.photos = bundled_photos()  # type: ignore[attr-defined]
    _one.out = Path(out)  # type: ignore[attr-defined]


def build_photos(out: Path, *, n: int, seed: int, jobs: int) -> int:
    """Write ``n`` varied photo negatives and their manifest into ``out``; returns the count."""
    out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(jobs, initializer=_init, initargs=(str(out),)) as pool:
        rows = list(pool.map(_one, [(i, seed) for i in range(n)], chunksize=32))
    with open(out / "manifest.jsonl", "w", encoding="utf-8") as fh:
        for row in rows:
            fh.write(json.dumps(row) + "\n")
    return len(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-photo", type=int, default=2300)
    ap.add_argument("--n-synth", type=int, default=700)
    ap.add_argument("--synth-size", default="960x720")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    print(f"{len(bundled_photos())} bundled photos", file=sys.stderr)
    n_photo = build_photos(a.out / "photos", n=a.n_photo, seed=a.seed, jobs=a.jobs)
    print(f"photos: {n_photo} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if a.n_synth:
        exe = Path(sys.executable).with_name("lishield-guard")
        subprocess.run([str(exe), "synth", "dataset", "--out", str(a.out / "synth"),
                        "--n-neg", str(a.n_synth), "--mix", "negatives-only",
                        "--seed", str(a.seed + 1), "--size", a.synth_size,
                        "--jobs", str(a.jobs), "--no-progress"], check=True)
    print(f"clean set: {n_photo} photos + {a.n_synth} synth negatives in {a.out} "
          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
