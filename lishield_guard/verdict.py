"""The detector's result: a frozen Verdict with typed evidence, skipped work and timings.

A verdict has one of three statuses (`Verdict.status`):

- ``"protected"``: a configured policy's barcode was found;
- ``"clean"``: the detector analysed the image and found none;
- ``"undetermined"``: the detector could not look (``undetermined`` holds the reason), e.g. an
  image with no analysable axis (at least 64 lines, each at least 64 pixels long: a 64x48
  thumbnail is undetermined), or smaller than the paper profile's block grid. An undetermined
  verdict is never "clean": callers that must fail closed check ``status``. Every path builds
  it with `undetermined`, the one constructor, with the reason and what was looked at.

``Verdict.evidence`` is the deciding profile's typed evidence (a subclass of `Evidence`: the
record the decision used, the spec it names, its reason, figure and caption); it reads as the
JSON mapping of ``Verdict.to_dict()["evidence"]`` too, for code that only reads keys.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from lishield_guard.profiles import DEFAULT as DEFAULT_PROFILE

__all__ = ["NO_POLICY", "STATUSES", "Evidence", "GivenEvidence", "Looked", "Timer",
           "UndeterminedEvidence", "Verdict",
           "looked_at_image", "nothing_to_look_for", "undetermined", "verdict_title"]

#: Every value of `Verdict.status`.
STATUSES = ("protected", "clean", "undetermined")
#: Why a config without any barcode spec is undetermined, whatever the profile.
NO_POLICY = "no policy configured: nothing to look for"


class Timer:
    """Wall time per stage, in milliseconds (``ms``), accumulated over ``with timer(name):``."""

    def __init__(self, ms: dict | None = None) -> None:
        self.ms: dict[str, float] = {} if ms is None else ms

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.ms[stage] = self.ms.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3


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


class Evidence(Mapping):
    """The typed evidence of one verdict: a frozen dataclass per profile and media kind.

    Subclasses keep what the deciding stage measured (the record the decision used) and
    define `to_dict`, the JSON of ``Verdict.to_dict()["evidence"]``; the mapping interface
    reads that JSON (``evidence["reason"]``), for callers that only read keys. The reason,
    the spec the verdict names, the figure and its caption all read the typed fields, so none
    of them decodes, measures or applies a rule a second time.
    """

    reason: str

    def to_dict(self) -> dict:
        """JSON-ready evidence (subclasses define it)."""
        raise NotImplementedError

    @cached_property
    def _json(self) -> dict:
        return _clean(self.to_dict())

    def __getitem__(self, key: str) -> Any:
        return self._json[key]

    def __iter__(self):
        return iter(self._json)

    def __len__(self) -> int:
        return len(self._json)

    @property
    def spec(self) -> str | None:
        """The barcode spec the verdict names (None: none); the title, the reason and the
        figure all name this one."""
        return None

    def counts(self, verdict: Verdict) -> str:
        """The decision's numbers in a few words (``detect``'s ``matches:`` line)."""
        return f"{verdict.matches}/{verdict.required} tones required"

    def caption(self, verdict: Verdict) -> str:
        """What `figure` shows, in words."""
        raise NotImplementedError

    def figure(self, verdict: Verdict, config):
        """The figure of what decided ``verdict`` (a matplotlib ``Figure``)."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class UndeterminedEvidence(Evidence):
    """Why the detector could not look, and what it looked at.

    Attributes
    ----------
    reason : str
        Why (``Verdict.undetermined``).
    looked_at : str
        What was looked at, in words (``"40 x 40 pixels, grey"``, ``"640 x 360 clip, 3 frames
        screened of 48"``).
    preview : ndarray or None
        The image as decoded, shrunk to at most `PREVIEW_LINES` lines and columns (for the
        figure; not serialised).
    extra : dict
        Further JSON-ready fields of the kind that looked (a clip's per-frame scores).
    """

    reason: str
    looked_at: str
    preview: Any = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """``reason``, ``looked_at`` and the extra fields."""
        return {"reason": self.reason, "looked_at": self.looked_at, **self.extra}

    def counts(self, verdict: Verdict) -> str:
        """Nothing was measured, so there is nothing to count."""
        return "none (the detector could not look)"

    def caption(self, verdict: Verdict) -> str:
        """The undetermined figure's caption."""
        return ("Left: the image as the detector decoded it. Right: why it could not look at "
                "it; the image is not clean, and nothing was fitted.")

    def figure(self, verdict: Verdict, config):
        """The image as decoded (its preview) and the reason
        (`figure_text.undetermined_figure`)."""
        from lishield_guard.figure_text import undetermined_figure

        return undetermined_figure(verdict_title(verdict), self.preview, self.looked_at,
                                   self.reason, verdict.skipped)


@dataclass(frozen=True, eq=False)
class GivenEvidence(Evidence):
    """Evidence given as a dict (a verdict built by hand, not by a profile): kept as given;
    it names no spec, and its figure states its reason only (there is no record to draw).

    Attributes
    ----------
    given : dict
        The JSON-ready evidence, as given.
    """

    given: dict

    @property
    def reason(self) -> str:
        """The ``"reason"`` given, or an empty string."""
        return str(self.given.get("reason") or "")

    def to_dict(self) -> dict:
        """The dict as given."""
        return self.given

    def caption(self, verdict: Verdict) -> str:
        """The text figure's caption."""
        return "The verdict and its reason (evidence given by hand: no record to draw)."

    def figure(self, verdict: Verdict, config):
        """Its reason and the verdict's numbers (`figure_text.text_figure`)."""
        from lishield_guard.figure_text import text_figure

        return text_figure(verdict_title(verdict), verdict.status,
                           self.reason or "(no reason given)", verdict.numbers)


PREVIEW_LINES = 256  # an undetermined verdict keeps its image shrunk to this many lines


def undetermined(reason: str, *, looked_at: str, profile: str, required: int,
                 preview: Any = None, skipped=(),
                 timings_ms: dict | None = None, extra: dict | None = None) -> Verdict:
    """The one constructor of a verdict the detector could not look at: never clean.

    Parameters
    ----------
    reason : str
        Why it could not look.
    looked_at : str
        What it looked at, in words.
    profile : str
        The profile that tried (`lishield_guard.profiles`).
    required : int
        Evidence units the profile needs for a verdict of protected (``Verdict.required``).
    preview : ndarray, optional
        The decoded image (shrunk here to at most `PREVIEW_LINES` per side) for the figure.
    skipped, timings_ms, extra
        Work not done, timings, further evidence fields (JSON-ready).

    Returns
    -------
    Verdict
        ``status == "undetermined"``, ``protected is None``, ``matches == 0``.
    """
    if preview is not None:
        step = max(1, -(-max(preview.shape[:2]) // PREVIEW_LINES))
        preview = preview[::step, ::step]
    return Verdict(None, None, 0, int(required),
                   evidence=UndeterminedEvidence(reason, looked_at, preview, extra or {}),
                   skipped=tuple(skipped), timings_ms={} if timings_ms is None else timings_ms,
                   profile=profile, undetermined=reason)


@dataclass(frozen=True)
class Looked:
    """What a profile looked at in one decoded image, and why it cannot decide (the part of
    every profile's record that an undetermined verdict needs).

    Attributes
    ----------
    looked_at : str
        The decoded image, in words (`looked_at_image`).
    skipped : tuple of str
        Work not done and why.
    why : str or None
        Why the image cannot be decided (None: it can).
    luma : ndarray
        The decoded luma (the undetermined figure's preview).
    """

    looked_at: str
    skipped: tuple[str, ...]
    why: str | None
    luma: Any

    def undetermined(self, *, profile: str, required: int, timings_ms: dict) -> Verdict:
        """The verdict when `why` is set (`undetermined`)."""
        return undetermined(self.why, looked_at=self.looked_at, profile=profile,
                            required=required, preview=self.luma, skipped=self.skipped,
                            timings_ms=timings_ms)


def looked_at_image(decoded) -> str:
    """What the detector looked at in a decoded image, in words (``"1080 x 1920 pixels,
    colour"``)."""
    n_rows, n_cols = decoded.luma.shape[:2]
    scale = "" if decoded.row_scale == 1 else f", decoded at 1/{decoded.row_scale:g} scale"
    return (f"{n_rows} x {n_cols} pixels, {'colour' if decoded.is_color else 'grey'}"
            f"{scale}")


def nothing_to_look_for(config) -> str | None:
    """`NO_POLICY` when ``config`` holds no barcode spec (None otherwise): every profile and
    media kind is undetermined then."""
    return None if any(p.specs for p in config.policies) else NO_POLICY


def verdict_title(verdict: Verdict) -> str:
    """The verdict in words, e.g. ``"PROTECTED: carries a barcode of policy 'p' (table2-rgb)"``
    (the spec is the one the evidence names, `Evidence.spec`)."""
    status = verdict.status
    if status == "protected":
        spec = verdict.evidence.spec
        return (f"PROTECTED: carries a barcode of policy {verdict.policy!r}"
                + (f" ({spec})" if spec else ""))
    if status == "undetermined":
        return "UNDETERMINED: the detector could not look at this image"
    return "CLEAN: no policy barcode found"


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
    evidence : Evidence
        The deciding profile's typed evidence (`Evidence`: reason, named spec, the record the
        decision used); ``to_dict`` serialises it. A dict given here is kept as it is
        (`GivenEvidence`).
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
    evidence: Evidence = field(default_factory=dict)
    skipped: tuple[str, ...] = ()
    timings_ms: dict = field(default_factory=dict)
    profile: str = DEFAULT_PROFILE
    score: float = 0.0
    undetermined: str | None = None

    def __post_init__(self) -> None:
        if isinstance(self.evidence, dict):  # built by hand: typed as given
            object.__setattr__(self, "evidence", GivenEvidence(self.evidence))
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
    def numbers(self) -> str:
        """The profile, score and evidence counts in one line (the figures' footer)."""
        return (f"profile {self.profile}, score {self.score:.3f}, matches "
                f"{self.matches}/{self.required}")

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
            d["evidence"] = self.evidence.to_dict()
        return _clean(d)
