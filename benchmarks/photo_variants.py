"""Speed-target photos: 12 MP and 1080p JPEG variants of the real-photo corpus's largest photos.

The speed targets are stated on ordinary camera photos of 12 MP and 1080p. The corpus
(`scripts/fetch_photos.py`) holds few that large, so each photo at least as large as a class
is cut to the class's size (scaled down, never up, then centre-cropped), flipped four ways and
saved at JPEG qualities 80, 90 and 95: every variant is still a real photograph's content.

    python benchmarks/photo_variants.py out/photos/images --out out/speed-photos
    python benchmarks/first_stage.py out/speed-photos/12mp
    python benchmarks/first_stage.py out/speed-photos/1080p
"""

from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image, ImageOps

SIZES = {"12mp": (4000, 3000), "1080p": (1920, 1080)}  # width, height (landscape)
QUALITIES = (80, 90, 95)
SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".ppm", ".pgm"}


def fit(img: Image.Image, size: tuple[int, int]) -> Image.Image | None:
    """``img`` scaled down to cover ``size`` and centre-cropped to it (None when too small)."""
    w, h = size
    if img.height > img.width:
        w, h = h, w
    scale = max(w / img.width, h / img.height)
    if scale > 1.0:
        return None
    if scale < 1.0:
        img = img.resize((round(img.width * scale), round(img.height * scale)),
                         Image.Resampling.LANCZOS)
    left, top = (img.width - w) // 2, (img.height - h) // 2
    return img.crop((left, top, left + w, top + h))


def main() -> int:
    """Write the variants; print how many per class."""
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photos", type=Path, help="folder of real photos (searched recursively)")
    ap.add_argument("--out", type=Path, default=Path("out/speed-photos"))
    args = ap.parse_args()
    files = sorted(p for p in args.photos.rglob("*") if p.suffix.lower() in SUFFIXES)
    for key, size in SIZES.items():
        folder = args.out / key
        folder.mkdir(parents=True, exist_ok=True)
        n = 0
        for path in files:
            with Image.open(path) as src:
                if src.width * src.height < size[0] * size[1]:
                    continue
                img = fit(ImageOps.exif_transpose(src).convert("RGB"), size)
            if img is None:
                continue
            for flip in range(4):
                out = ImageOps.mirror(img) if flip & 1 else img
                out = ImageOps.flip(out) if flip & 2 else out
                for q in QUALITIES:
                    out.save(folder / f"{path.stem[-40:]}-f{flip}-q{q}.jpg", quality=q)
                    n += 1
        print(f"{key}: {n} JPEGs in {folder}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
