"""Rebuild the calibration clean set: real-photo variants, scikit-image photos, synth look-alikes.

Usage (deterministic for a seed; ~3000 images in about 2-3 minutes on 2 cores)::

    .venv/bin/python scripts/build_clean_set.py --out out/calib/clean --seed 0 \
        --n-photo 2300 --n-synth 700 --jobs 2

With the real-photo corpus (``scripts/fetch_photos.py``, default ``out/photos``)::

    .venv/bin/python scripts/build_clean_set.py --out out/calib/clean --seed 0 \
        --photos out/photos --n-real 2000 --n-photo 300 --n-synth 700 --jobs 2

Part 0, ``realphotos/`` (only with ``--photos DIR``): ``--n-real`` variants of the corpus
photos. Each output draws, from ``numpy.random.default_rng([seed, index, 2])``: a photo
(weight 1/sqrt(photos of its package), so no package dominates), a crop of aspect 4:3, 3:2,
16:9 or 1:1 in landscape or portrait (50-100 % of the largest such crop), a resize to a long
side of 1080-2048 px (downscaling; a small photo is enlarged at most ``--max-upscale`` = 2x and
stays smaller), a
rotation by 0/90/180/270 degrees, and JPEG quality 60-95. The manifest records the package,
path and sha256 of the source photo and every transform.

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

REAL_ASPECTS = ((4, 3), (3, 2), (16, 9), (1, 1))   # (long, short) side ratios
REAL_LONG_SIDE_PX = (1080, 2048)                   # drawn uniformly, inclusive
REAL_MAX_UPSCALE = 2.0                             # unitless; small photos stay smaller
REAL_QUALITY = (60, 95)                            # JPEG quality, drawn uniformly, inclusive

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


def real_photo_weights(rows: list[dict] | tuple[dict, ...]) -> np.ndarray:
    """Sampling probability of each corpus photo: 1/sqrt(n photos of its package), normalised."""
    counts: dict[str, int] = {}
    for r in rows:
        counts[r.get("package", "")] = counts.get(r.get("package", ""), 0) + 1
    w = np.array([1.0 / np.sqrt(counts[r.get("package", "")]) for r in rows])
    return w / w.sum()


def real_variant(photo: np.ndarray, rng: np.random.Generator, *,
                 max_upscale: float = REAL_MAX_UPSCALE) -> tuple[np.ndarray, dict]:
    """One calibration variant of a corpus photo (crop, resize, rotation), before encoding.

    Parameters
    ----------
    photo : ndarray of uint8, shape (n_rows, n_cols, 3)
        sRGB photo.
    rng : numpy.random.Generator
        Source of every choice (see the module docstring, part 0).
    max_upscale : float
        Largest enlargement factor, unitless >= 1; a photo whose crop is smaller than
        long_side_px / max_upscale comes out smaller than the target.

    Returns
    -------
    image : ndarray of uint8, shape (out_rows, out_cols, 3)
    params : dict
        JSON-ready transforms: crop [r0, c0, n_rows, n_cols], aspect, orientation,
        long_side_px (target), scale, rotation_deg.
    """
    from PIL import Image

    n_rows, n_cols = photo.shape[:2]
    long_r, short_r = REAL_ASPECTS[int(rng.integers(len(REAL_ASPECTS)))]
    portrait = bool(rng.random() < 0.5)
    aspect = short_r / long_r if portrait else long_r / short_r  # n_cols / n_rows of the crop
    ch, cw = (n_rows, round(n_rows * aspect)) if n_cols / n_rows >= aspect else (
        round(n_cols / aspect), n_cols)
    frac = rng.uniform(0.5, 1.0)
    ch, cw = max(16, min(n_rows, round(ch * frac))), max(16, min(n_cols, round(cw * frac)))
    r0 = int(rng.integers(0, n_rows - ch + 1))
    c0 = int(rng.integers(0, n_cols - cw + 1))
    long_px = int(rng.integers(REAL_LONG_SIDE_PX[0], REAL_LONG_SIDE_PX[1] + 1))
    scale = min(long_px / max(ch, cw), max_upscale)
    pil = Image.fromarray(np.ascontiguousarray(photo[r0:r0 + ch, c0:c0 + cw]))
    size = (max(1, round(cw * scale)), max(1, round(ch * scale)))
    pil = pil.resize(size, Image.LANCZOS if scale < 1 else Image.BICUBIC)
    rot = int(rng.choice([0, 90, 180, 270]))
    if rot:
        pil = pil.rotate(-rot, expand=True)  # clockwise
    return np.asarray(pil), {"crop": [r0, c0, ch, cw],
                             "aspect": f"{long_r}:{short_r}",
                             "orientation": "portrait" if portrait else "landscape",
                             "long_side_px": long_px, "scale": round(scale, 5),
                             "rotation_deg": rot}


def _one_real(args: tuple[int, int]) -> dict:
    index, seed = args
    from PIL import Image

    from synth.scene import corpus_photo

    st = _one_real.state  # type: ignore[attr-defined]
    rows = st["rows"]
    rng = np.random.default_rng([seed, index, 2])
    k = int(rng.choice(len(rows), p=st["probs"]))
    img, params = real_variant(corpus_photo(st["photo_dir"], k), rng,
                               max_upscale=st["max_upscale"])
    quality = int(rng.integers(REAL_QUALITY[0], REAL_QUALITY[1] + 1))
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=quality)
    fname = f"{index:06d}.jpg"
    (st["out"] / fname).write_bytes(buf.getvalue())
    row = rows[k]
    return {"file": fname, "label": 0, "kind": "real_photo", "source": row.get("package"),
            "source_path": row.get("path"), "source_sha256": row.get("sha256"),
            "photo_index": k, **params, "jpeg_quality": quality,
            "size": list(img.shape[:2])}


def _init_real(out: str, photo_dir: str, max_upscale: float) -> None:
    from synth.scene import corpus_manifest

    one_thread_per_worker()
    rows = corpus_manifest(photo_dir)
    _one_real.state = {"rows": rows, "probs": real_photo_weights(rows),  # type: ignore[attr-defined]
                       "photo_dir": photo_dir, "out": Path(out), "max_upscale": max_upscale}


def build_real_photos(out: Path, *, photo_dir: Path, n: int, seed: int, jobs: int,
                      max_upscale: float = REAL_MAX_UPSCALE) -> int:
    """Write ``n`` real-photo variants and their manifest into ``out``; returns the count."""
    if max_upscale < 1.0:
        raise ValueError(f"need max_upscale={max_upscale!r} >= 1")
    out.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(jobs, initializer=_init_real,
                             initargs=(str(out), str(photo_dir), max_upscale)) as pool:
        rows = list(pool.map(_one_real, [(i, seed) for i in range(n)], chunksize=8))
    with open(out / "manifest.jsonl", "w", encoding="utf-8") as fh:
        for row in rows:
            fh.write(json.dumps(row) + "\n")
    return len(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--photos", type=Path, default=None, metavar="DIR",
                    help="real-photo corpus (scripts/fetch_photos.py --cache-dir); adds part 0")
    ap.add_argument("--n-real", type=int, default=2000,
                    help="real-photo variants when --photos is given (default %(default)s)")
    ap.add_argument("--max-upscale", type=float, default=REAL_MAX_UPSCALE,
                    help="largest enlargement of a small corpus photo (default %(default)s); "
                         "most corpus photos are 300-1000 px, so the default leaves many "
                         "variants below the 1080 px target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-photo", type=int, default=2300)
    ap.add_argument("--n-synth", type=int, default=700)
    ap.add_argument("--synth-size", default="960x720")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    n_real = 0
    if a.photos is not None and a.n_real:
        n_real = build_real_photos(a.out / "realphotos", photo_dir=a.photos, n=a.n_real,
                                   seed=a.seed, jobs=a.jobs, max_upscale=a.max_upscale)
        print(f"real photos: {n_real} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    print(f"{len(bundled_photos())} bundled photos", file=sys.stderr)
    n_photo = build_photos(a.out / "photos", n=a.n_photo, seed=a.seed, jobs=a.jobs)
    print(f"photos: {n_photo} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if a.n_synth:
        exe = Path(sys.executable).with_name("lishield-guard")
        subprocess.run([str(exe), "synth", "dataset", "--out", str(a.out / "synth"),
                        "--n-neg", str(a.n_synth), "--mix", "negatives-only",
                        "--seed", str(a.seed + 1), "--size", a.synth_size,
                        "--jobs", str(a.jobs), "--no-progress"], check=True)
    print(f"clean set: {n_real} real-photo variants + {n_photo} photos + {a.n_synth} synth "
          f"negatives in {a.out} "
          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
