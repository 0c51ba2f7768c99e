"""The detector's result: a frozen Verdict with evidence, skipped work and timings.

A verdict has one of three statuses (`Verdict.status`):

- ``"protected"``: a configured policy's barcode was found;
- ``"clean"``: the detector analysed the image and found none;
- ``"undetermined"``: the detector could not look (``undetermined`` holds the reason), e.g. an
  image with no analysable axis (default profile: at least 64 lines, each at least 64 pixels
  long, `lishield_guard.detector.pipeline.MIN_ROWS` and `MIN_ACROSS`: a 64x48 thumbnail is
  undetermined), or smaller than the paper profile's block grid. An
  undetermined verdict is never "clean": callers that must fail closed check ``status``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

__all__ = ["STATUSES", "Verdict"]

#: Every value of `Verdict.status`.
STATUSES = ("protected", "clean", "undetermined")


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
    protected : bool or None
        True when a policy's barcode was found, False when the image was analysed and none
        was; None whenever the status is neither (undetermined), whatever the constructor was
        given.
    policy : str or None
        Id of the matched policy (None when not protected).
    matches : int
        Evidence of the stage that decided: matching ratios (paper profile); matched tones
        (default profile, tone tracks); 1 when folding, the sweep or the exact fit flagged the
        image (``evidence["stage"]`` names the stage).
    required : int
        How many were required for a verdict of protected (M_b, tones needed, or 1 pattern
        fit).
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
    undetermined : str or None
        Why the detector could not look at this image (None when it did). An undetermined
        verdict has ``protected=None`` and is not clean: see `status`.
    """

    protected: bool | None
    policy: str | None
    matches: int
    required: int
    evidence: dict = field(default_factory=dict)
    skipped: tuple[str, ...] = ()
    timings_ms: dict = field(default_factory=dict)
    profile: str = "default"
    score: float = 0.0
    undetermined: str | None = None

    def __post_init__(self) -> None:
        # derived, so that no constructor can make an undetermined verdict read "not protected"
        if self.undetermined is not None:
            object.__setattr__(self, "protected", None)
        elif self.protected is not None:
            object.__setattr__(self, "protected", bool(self.protected))

    @property
    def status(self) -> str:
        """``"undetermined"``, ``"protected"`` or ``"clean"`` (one of `STATUSES`)."""
        if self.undetermined is not None:
            return "undetermined"
        return "protected" if self.protected else "clean"

    @property
    def protected_or_none(self) -> bool | None:
        """`protected` as every interface reports it: None unless the status is clean or
        protected (also for a verdict whose ``undetermined`` was set after construction)."""
        status = self.status
        return None if status not in ("clean", "protected") else status == "protected"

    def to_dict(self, *, explain: bool = True) -> dict:
        """JSON-ready dict; ``explain=False`` leaves out the bulky evidence."""
        d = {
            "status": self.status,
            "protected": self.protected_or_none,
            "policy": self.policy,
            "matches": int(self.matches),
            "required": int(self.required),
            "score": float(self.score),
            "profile": self.profile,
            "skipped": list(self.skipped),
            "timings_ms": {k: round(float(v), 3) for k, v in self.timings_ms.items()},
            "undetermined_reason": self.undetermined,
        }
        if explain:
            d["evidence"] = self.evidence
        return _clean(d)
