"""The package's data files (decision weights, their card, the shipped config) and their digests.

A threshold is calibrated for one set of weights: the digest of the weights file ties the two
together (the card carries it, a calibrated config records it beside each threshold, caches
key on it). `file_digest` is the one definition of that digest.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["CARD_FILE", "CONFIG_FILE", "DATA_DIR", "MODEL_FILE", "data_digest", "file_digest",
           "weights_path"]

DATA_DIR = Path(__file__).resolve().parent / "data"
MODEL_FILE = "decision_model.npz"  # the shipped decision weights ...
CARD_FILE = "decision_model.json"  # ... and their card
CONFIG_FILE = "default.toml"  # the shipped, calibrated config


def file_digest(path: str | Path) -> str:
    """``"sha256:<hex>"`` of a file's bytes.

    Raises
    ------
    OSError
        When the file cannot be read.
    """
    return "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()


def weights_path(model: str | None) -> Path:
    """The decision weights a config uses: ``learned.model``, or the shipped ones (None)."""
    return DATA_DIR / MODEL_FILE if model is None else Path(model)


def data_digest() -> str:
    """One digest of every shipped data file (names and bytes): whatever changes a score or a
    threshold changes it."""
    h = hashlib.sha256()
    for f in sorted(p for p in DATA_DIR.rglob("*") if p.is_file() and p.suffix != ".py"
                    and "__pycache__" not in p.parts):
        h.update(f.relative_to(DATA_DIR).as_posix().encode())
        h.update(f.read_bytes())
    return "sha256:" + h.hexdigest()
