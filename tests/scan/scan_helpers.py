"""Helpers of the scan tests: small real images and JSON Lines (a module of its own, so test
files import it by a name no other test folder uses; ``from conftest import`` picks whichever
folder's conftest was imported first when several folders run together)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

__all__ = ["jpeg_bytes", "read_jsonl", "write_images"]


def jpeg_bytes(seed: int, *, shape: tuple[int, int] = (240, 320)) -> bytes:
    """A small noisy colour JPEG."""
    rng = np.random.default_rng(seed)
    img = (rng.random((*shape, 3)) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    return buf.tobytes()


def write_images(folder: Path, names: list[str], seed: int = 0) -> list[Path]:
    """Write a JPEG at every relative name under folder."""
    out = []
    for i, name in enumerate(names):
        p = folder / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(jpeg_bytes(seed + i))
        out.append(p)
    return out


def read_jsonl(path: Path) -> list[dict]:
    """Every line of a JSON Lines file, parsed (fails on a corrupt line)."""
    return [json.loads(line) for line in path.read_text().splitlines()]
