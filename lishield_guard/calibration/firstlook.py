"""The first look's threshold, derived from the full decision on the calibration images.

The first look (`detector.firstlook`) clears an image whose peak (the largest whitened coherent
luma power, ln units) stays below ``learned.first_look_ln``; the others go on to the full
decision. It must never clear an image the decision would flag, so the threshold is put below
the smallest peak of every image the decision flags at the calibrated ``threshold_logit``,
positives and clean images alike, by a margin (`MARGIN_LN`, a factor of 2 in power):

    first_look_ln = min(peak of flagged images the first look could clear) - margin_ln

Images whose first look cannot clear them (``usable`` False: the decision might find them
unusable, and goes on to say so) do not bound it. With no flagged image there is nothing to
bound it by, and the first look stays off (None): every image goes on.

The first look only pays when it clears enough: an image that goes on pays it on top of the
full decision (about a third of its cost at 1080p, `benchmarks/first_look.py`). Below
`MIN_CLEARED_SHARE` of the clean calibration images cleared, it would cost more than it saves,
and it stays off; the report still gives the threshold it would have had.

Calibration measures each image's peak in the same pass that measures its logit
(`calibration.evidence.learned_record`, one decode of luma, then colour), so the threshold
costs no second pass; a retrained model gets its own first look from one ``calibrate`` run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MARGIN_LN", "MIN_CLEARED_SHARE", "FirstLookCalibration", "calibrate_first_look",
           "first_look_threshold"]

MARGIN_LN = math.log(2.0)  # below the smallest flagged peak: a factor 2 in power, ln units
MIN_CLEARED_SHARE = 0.5  # of the clean images; below it the first look costs more than it saves


def first_look_threshold(flagged_peaks, *, margin_ln: float = MARGIN_LN) -> float | None:
    """``learned.first_look_ln`` from the peaks of the images the decision flags.

    Parameters
    ----------
    flagged_peaks : array_like of float
        First-look peaks (ln units) of the flagged images the first look could clear
        (``FirstLook.usable``); nan is left out.
    margin_ln : float
        How far below the smallest peak the threshold goes, ln units, >= 0.

    Returns
    -------
    float or None
        ``min(flagged_peaks) - margin_ln``; None (first look off) when no peak is given, or
        when one is -inf (a flagged image that nothing could be measured on: no threshold
        keeps it).

    Examples
    --------
    >>> round(first_look_threshold([5.0, 7.5], margin_ln=0.5), 3)
    4.5
    >>> first_look_threshold([]) is None
    True
    """
    if not margin_ln >= 0 or not math.isfinite(margin_ln):
        raise ValueError(f"need a finite margin_ln >= 0, got {margin_ln!r}")
    x = np.asarray(flagged_peaks, dtype=float).ravel()
    x = x[~np.isnan(x)]
    return None if not len(x) or not np.isfinite(x.min()) else float(x.min() - margin_ln)


@dataclass(frozen=True)
class FirstLookCalibration:
    """The first look's threshold and what it does on the calibration images.

    Attributes
    ----------
    first_look_ln : float or None
        The threshold (None: off, no flagged image to bound it).
    margin_ln : float
        Margin below the smallest flagged peak, ln units.
    min_flagged_peak : float or None
        The smallest peak among the flagged images the first look could clear.
    n_flagged : int
        Images the decision flags (positives and clean).
    n_flagged_cleared : int
        Of them, those the first look clears: 0 by construction.
    clean_on, n_clean, pos_on, n_pos : int
        Clean images and positives that go on to the full decision, of how many.
    unpaid_ln : float or None
        The threshold the flagged peaks allowed when it was left off because it clears
        fewer than `MIN_CLEARED_SHARE` of the clean images (None otherwise).
    unpaid_cleared : int
        Clean images that threshold would have cleared (0 when it is on or absent).
    """

    first_look_ln: float | None
    margin_ln: float
    min_flagged_peak: float | None
    n_flagged: int
    n_flagged_cleared: int
    clean_on: int
    n_clean: int
    pos_on: int
    n_pos: int
    unpaid_ln: float | None = None
    unpaid_cleared: int = 0

    @property
    def clean_on_share(self) -> float:
        """Share of clean images that go on to the full decision (unitless)."""
        return self.clean_on / self.n_clean if self.n_clean else float("nan")

    @property
    def pos_on_share(self) -> float:
        """Share of positives that go on to the full decision (unitless)."""
        return self.pos_on / self.n_pos if self.n_pos else float("nan")

    def to_dict(self) -> dict:
        """JSON of the figures (the report's ``first_look``)."""
        return {"first_look_ln": self.first_look_ln, "margin_ln": self.margin_ln,
                "min_flagged_peak": self.min_flagged_peak, "n_flagged": self.n_flagged,
                "n_flagged_cleared": self.n_flagged_cleared,
                "clean_on": [self.clean_on, self.n_clean],
                "positives_on": [self.pos_on, self.n_pos], "unpaid_ln": self.unpaid_ln}

    def line(self) -> str:
        """One line for the config header and the console."""
        if self.first_look_ln is None and self.unpaid_ln is not None:
            share = 100 * self.unpaid_cleared / self.n_clean
            return (f"first look: off (at {self.unpaid_ln:.4f}, below the smallest flagged "
                    f"peak {self.min_flagged_peak:.4f} by {self.margin_ln:.4f}, it would clear "
                    f"only {share:.1f} % of the clean images, under the "
                    f"{100 * MIN_CLEARED_SHARE:.0f} % where it pays): every image goes on to "
                    "the full decision")
        if self.first_look_ln is None:
            return ("first look: off (no image flagged by the decision to bound it): every "
                    "image goes on to the full decision")
        return (f"first look: learned.first_look_ln={self.first_look_ln:.4f} = smallest "
                f"flagged peak {self.min_flagged_peak:.4f} - margin {self.margin_ln:.4f} "
                f"(ln); {self.n_flagged_cleared}/{self.n_flagged} flagged images cleared; "
                f"to the full decision: {self.clean_on}/{self.n_clean} clean images "
                f"({100 * self.clean_on_share:.1f} %), {self.pos_on}/{self.n_pos} positives")


def _goes_on(peaks: np.ndarray, usable: np.ndarray, thr: float | None) -> np.ndarray:
    """Per image: does it go on to the full decision (`FirstLook.clears`, negated)?"""
    if thr is None:
        return np.ones(len(peaks), dtype=bool)
    return ~(usable & (np.nan_to_num(peaks, nan=np.inf) < thr))


def calibrate_first_look(peaks_clean, usable_clean, flagged_clean, peaks_pos, usable_pos,
                         flagged_pos, *, margin_ln: float = MARGIN_LN,
                         min_cleared_share: float = MIN_CLEARED_SHARE) -> FirstLookCalibration:
    """The first look's threshold (`first_look_threshold`) and its figures.

    Parameters
    ----------
    peaks_clean, peaks_pos : array_like of float
        First-look peaks (ln units; -inf or nan where nothing was measured).
    usable_clean, usable_pos : array_like of bool
        ``FirstLook.usable`` of each image.
    flagged_clean, flagged_pos : array_like of bool
        Whether the full decision flags each image (at the chosen ``threshold_logit``).
    margin_ln : float
        Margin below the smallest flagged peak, ln units.
    min_cleared_share : float
        Share of the clean images the threshold must clear for the first look to be on.

    Returns
    -------
    FirstLookCalibration
        With the first look off (``first_look_ln`` None, ``unpaid_ln`` the threshold) when
        it clears fewer than ``min_cleared_share`` of the clean images; the figures are then
        those of no first look (every image goes on).
    """
    pc, pp = (np.asarray(p, float) for p in (peaks_clean, peaks_pos))
    uc, up = (np.asarray(u, bool) for u in (usable_clean, usable_pos))
    fc, fp = (np.asarray(f, bool) for f in (flagged_clean, flagged_pos))
    peaks, usable, flagged = (np.concatenate(a) for a in ((pc, pp), (uc, up), (fc, fp)))
    bound = peaks[flagged & usable]
    thr = first_look_threshold(bound, margin_ln=margin_ln)
    on_c, on_p = _goes_on(pc, uc, thr), _goes_on(pp, up, thr)
    unpaid, unpaid_cleared = None, 0
    if thr is not None and len(pc) and 1.0 - on_c.mean() < min_cleared_share:
        unpaid, unpaid_cleared, thr = thr, int((~on_c).sum()), None
        on_c, on_p = _goes_on(pc, uc, None), _goes_on(pp, up, None)
    finite = bound[np.isfinite(bound)]
    return FirstLookCalibration(
        thr, float(margin_ln), float(finite.min()) if len(finite) else None,
        int(flagged.sum()), int((flagged & ~np.concatenate([on_c, on_p])).sum()),
        int(on_c.sum()), len(pc), int(on_p.sum()), len(pp), unpaid, unpaid_cleared)
