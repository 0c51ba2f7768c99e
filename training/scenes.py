"""Scene bank for training: the real-photo corpus resized to a bounded size, reserved packages out.

``out/photos`` (``scripts/fetch_photos.py``) holds full-size photos; training renders frames of
at most 1600 rows and crops scenes, so each photo is stored once at a long side of at most
`LONG_SIDE_PX` as a high-quality JPEG (``out/scenebank/NNNN.jpg``). Reserved packages and the
packages held out for fresh evaluation sets (`synth.dataset.EVAL_PHOTO_PACKAGES`) are left
out. The bank is small enough to travel with the working tree to a machine that generates
training data.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from PIL import Image

LONG_SIDE_PX = 1024


def build_bank(photo_dir: str | Path = "out/photos", out_dir: str | Path = "out/scenebank", *,
               long_side_px: int = LONG_SIDE_PX, quality: int = 92) -> int:
    """Write the bank; return the number of photos written (reserved packages are skipped)."""
    from synth.dataset import EVAL_PHOTO_PACKAGES, _reserved_photo
    from synth.scene import corpus_manifest

    rows = corpus_manifest(photo_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    kept = []
    for i, row in enumerate(rows):
        if _reserved_photo(row) or row.get("package") in EVAL_PHOTO_PACKAGES:
            continue  # reserved, or held out for the fresh evaluation sets
        src = Path(photo_dir) / row["file"]
        with Image.open(src) as im:
            im = im.convert("RGB")
            scale = long_side_px / max(im.size)
            if scale < 1:
                im = im.resize((round(im.size[0] * scale), round(im.size[1] * scale)),
                               Image.Resampling.LANCZOS)
            name = f"{i:04d}.jpg"
            im.save(out / name, quality=quality)
        kept.append({"bank": name, **{k: row.get(k) for k in ("package", "version", "path",
                                                              "sha256")}})
    (out / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in kept))
    return len(kept)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photos", default="out/photos")
    ap.add_argument("--out", default="out/scenebank")
    a = ap.parse_args()
    print(f"{build_bank(a.photos, a.out)} photos -> {a.out}")
