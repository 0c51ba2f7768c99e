"""Fixtures of the calibration tests: a tiny synth dataset (positives and clean) on disk."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXE = str(Path(sys.executable).with_name("lishield-guard"))


@pytest.fixture(scope="session")
def tiny_sets(tmp_path_factory) -> dict[str, Path]:
    """3 barcode captures and 3 look-alike negatives at 640x480, plus a folder of 3 noise JPEGs."""
    root = tmp_path_factory.mktemp("calib")
    pos, neg = root / "pos", root / "neg"
    subprocess.run([EXE, "synth", "dataset", "--out", str(pos), "--n-pos", "3", "--seed", "5",
                    "--mix", "easy", "--size", "640x480", "--no-progress"], check=True)
    subprocess.run([EXE, "synth", "dataset", "--out", str(neg), "--n-neg", "3", "--seed", "6",
                    "--mix", "negatives-only", "--size", "640x480", "--no-progress"],
                   check=True)
    import cv2
    import numpy as np

    noise = root / "noise"
    noise.mkdir()
    for i, name in enumerate(["a.jpg", "b.jpg", "c.jpg"]):
        img = (np.random.default_rng(i).random((240, 320, 3)) * 255).astype(np.uint8)
        cv2.imwrite(str(noise / name), img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return {"pos": pos, "neg": neg, "noise": noise, "root": root}
