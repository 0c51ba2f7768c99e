"""Fixtures of the bench tests: a tiny labelled dataset and a folder of clean photos."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest


def _jpeg(path: Path, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    path.write_bytes(buf.tobytes())


def _scene(rng: np.random.Generator, n_rows: int, n_cols: int) -> np.ndarray:
    """A smooth colour scene with sensor-like noise, float in [0, 1], (n_rows, n_cols, 3)."""
    r = np.linspace(0, 1, n_rows)[:, None, None]
    c = np.linspace(0, 1, n_cols)[None, :, None]
    base = 0.35 + 0.3 * r * c + 0.1 * np.sin(6 * c + rng.uniform(0, 3, size=3))
    return base + rng.normal(0, 0.01, size=(n_rows, n_cols, 3))


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Three striped (label 1) and three flat-lit (label 0) 240x320 JPEGs with a manifest."""
    root = tmp_path_factory.mktemp("bench-ds")
    rng = np.random.default_rng(7)
    n_rows, n_cols = 240, 320
    rows = np.arange(n_rows)[:, None, None]
    lines = []
    for i in range(6):
        label = i % 2
        img = _scene(rng, n_rows, n_cols)
        if label:  # two stripe frequencies switching half way down the frame (a toy barcode)
            f = np.where(rows < n_rows // 2, 1 / 12, 1 / 8)
            img = img * (1 + 0.2 * np.sign(np.sin(2 * np.pi * f * rows)))
        name = f"{i:06d}.jpg"
        _jpeg(root / name, (np.clip(img, 0, 1) * 255).astype(np.uint8))
        lines.append(json.dumps({"file": name, "label": label,
                                 "kind": "barcode" if label else "steady"}))
    (root / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="session")
def clean_dir(tmp_path_factory) -> Path:
    """Two clean photos (one in a subfolder) and a text file that must be ignored."""
    root = tmp_path_factory.mktemp("bench-clean")
    rng = np.random.default_rng(11)
    (root / "sub").mkdir()
    for rel in ("a.jpg", "sub/b.jpeg"):
        _jpeg(root / rel, (np.clip(_scene(rng, 200, 260), 0, 1) * 255).astype(np.uint8))
    (root / "notes.txt").write_text("not an image")
    return root
