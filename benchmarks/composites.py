"""Composites of a labelled set: each image inside a border, in a 2x2 collage, shrunk in a frame.

What upload apps do to photos: a uniform border of any colour (the image then covers 1/3 to
1/1.2 of the result), a 2x2 collage with three clean photos, or the image shrunk to half its size
inside a frame (a uniform colour or a clean photo). The clean photos come from the set's own
negatives of kind ``steady`` (ordinary photos under steady light), so a composite of a clean
image stays clean. Every output keeps its source's manifest row (label, preset, conditions) and
adds ``composite`` and ``source_file``; ``benchmarks/evaluate.py`` reads the result as it reads
the source set, and groups it by ``kind`` as usual.

    python benchmarks/composites.py out/paper32 out/paper32-comp --seed 5
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

KINDS = ("border", "collage", "frame")


def _load(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        from PIL import ImageOps

        return np.asarray(ImageOps.exif_transpose(im).convert("RGB"))


def _fit(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return np.asarray(Image.fromarray(img).resize((shape[1], shape[0]), Image.BILINEAR))


def compose(img: np.ndarray, kind: str, rng: np.random.Generator, clean: list[np.ndarray]
            ) -> tuple[np.ndarray, dict]:
    """One composite of ``img`` and its description."""
    h, w = img.shape[:2]
    colour = rng.integers(0, 256, 3).astype(np.uint8) if rng.random() < 0.5 else \
        np.full(3, 255, np.uint8)
    if kind == "border":
        area = float(rng.uniform(1.2, 3.0))
        if rng.random() < 0.5:  # border on every side
            s = np.sqrt(area)
            hh, ww = int(h * s), int(w * s)
        else:  # a wide border on one axis only
            hh, ww = (int(h * area), w) if rng.random() < 0.5 else (h, int(w * area))
        out = np.empty((hh, ww, 3), np.uint8)
        out[:] = colour
        r0, c0 = int(rng.integers(0, hh - h + 1)), int(rng.integers(0, ww - w + 1))
        out[r0:r0 + h, c0:c0 + w] = img
        return out, {"kind": kind, "area": area, "colour": colour.tolist()}
    if kind == "collage":
        tiles = [img] + [_fit(clean[int(rng.integers(len(clean)))], (h, w)) for _ in range(3)]
        k = int(rng.integers(4))
        tiles[0], tiles[k] = tiles[k], tiles[0]
        return np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])]), {"kind": kind,
                                                                        "position": k}
    small = np.asarray(Image.fromarray(img).resize((w // 2, h // 2), Image.LANCZOS))
    photo = rng.random() < 0.5 and bool(clean)
    out = _fit(clean[int(rng.integers(len(clean)))], (h, w)).copy() if photo else \
        np.full((h, w, 3), colour, np.uint8)
    r0, c0 = int(rng.integers(0, h - h // 2 + 1)), int(rng.integers(0, w - w // 2 + 1))
    out[r0:r0 + h // 2, c0:c0 + w // 2] = small
    return out, {"kind": kind, "background": "photo" if photo else colour.tolist()}


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--quality", type=int, default=90, help="JPEG quality of the composites")
    a = ap.parse_args(argv)
    items = [json.loads(x) for x in (a.dataset / "manifest.jsonl").read_text().splitlines()
             if x.strip()]
    clean = [_load(a.dataset / it["file"]) for it in items if it.get("kind") == "steady"][:40]
    if not clean:
        print("the set has no steady-light negatives to compose with", file=sys.stderr)
        return 2
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, it in enumerate(items):
        rng = np.random.default_rng([a.seed, i])
        kind = KINDS[i % len(KINDS)]
        img, desc = compose(_load(a.dataset / it["file"]), kind, rng, clean)
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="JPEG", quality=a.quality)
        name = f"{i:06d}.jpg"
        (a.out / name).write_bytes(buf.getvalue())
        row = {k: v for k, v in it.items() if k not in ("file", "rotation_deg",
                                                         "rotation_mode", "exif_orientation")}
        rows.append({**row, "file": name, "source_file": it["file"], "composite": desc,
                     "rotation_deg": 0, "source_rotation_deg": it.get("rotation_deg", 0)})
    (a.out / "manifest.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    print(f"{len(rows)} composites -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
