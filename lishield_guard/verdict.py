"""The detector's result: a frozen Verdict with evidence, skipped work and timings."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Verdict"]


def _clean(obj: Any) -> Any:
    """JSON-ready copy: numpy scalars to Python, tuples to lists, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return _clean(obj.tolist())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


@dataclass(frozen=True)
class Verdict:
    """Whether an image carries a known policy barcode, and why.

    Attributes
    ----------
    protected : bool
        True when a policy's barcode was found.
    policy : str or None
        Id of the matched policy (None when not protected).
    matches : int
        Matching ratios (paper profile) or matched tones (default profile) of the best policy.
    required : int
        How many were required for a verdict of protected (M_b, or tones needed).
    evidence : dict
        JSON-ready detail: detected tones (cycles/row), ratios, blocks, best candidate, reason.
    skipped : tuple of str
        Work not done and why (e.g. ``"chroma: luma verdict certain"``).
    timings_ms : dict
        Wall time per stage, in milliseconds.
    profile : str
        Detector profile that produced the verdict.
    score : float
        Evidence strength in [0, 1]; compared against the configured threshold.
    """

    protected: bool
    policy: str | None
    matches: int
    required: int
    evidence: dict = field(default_factory=dict)
    skipped: tuple[str, ...] = ()
    timings_ms: dict = field(default_factory=dict)
    profile: str = "default"
    score: float = 0.0

    def to_dict(self, *, explain: bool = True) -> dict:
        """JSON-ready dict; ``explain=False`` leaves out the bulky evidence."""
        d = {
            "protected": bool(self.protected),
            "policy": self.policy,
            "matches": int(self.matches),
            "required": int(self.required),
            "score": float(self.score),
            "profile": self.profile,
            "skipped": list(self.skipped),
            "timings_ms": {k: round(float(v), 3) for k, v in self.timings_ms.items()},
        }
        if explain:
            d["evidence"] = self.evidence
        return _clean(d)
