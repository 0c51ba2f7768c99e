"""The default profile's per-image record and its one decision rule (detection and calibration).

`measure` turns decoded pixels into a `DecisionRecord` with fixed work for a given image size:
block profiles of both axes (`spectra.block_profiles_rgb`, one pass over the pixels), the
usable-block check, the time-frequency input (`tfinput`, one instance per axis and pyramid
level) and the network's instance logits. `rule_at` is the decision rule, written once:
detection applies it to one record, calibration to a table of cached logits (it takes
arrays). Nothing here searches: the cost is bounded by the image size whatever the image
shows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np

from lishield_guard.config import DetectorConfig
from lishield_guard.detector import tfinput
from lishield_guard.detector.learned import DecisionModel, load_model, score_windows, shipped_model
from lishield_guard.detector.spectra import AXIS_NAMES, USABLE_TILES, analysable
from lishield_guard.detector.tfinput import TimeFreqInput
from lishield_guard.detector.usable import MIN_USABLE_BLOCKS

__all__ = ["DecisionRecord", "decision_model", "measure", "rule", "rule_at", "spectrum_view",
           "window_label"]

@dataclass(frozen=True)
class DecisionRecord:
    """Every measurement the default profile decides on, for one image.

    Attributes
    ----------
    logits : ndarray of shape (n_instances,), float32
        The network's logit of every instance, one per analysed (axis, level) (empty when
        nothing could be analysed).
    spectra : TimeFreqInput
        The network's input (kept for the explanation and the figure).
    undetermined : str or None
        Why the image could not be analysed at all (None when it was).
    usable_notes : tuple of str
        Column blocks left out of the analysis of an axis and why (black, saturated, flat).
    """

    logits: np.ndarray
    spectra: TimeFreqInput
    undetermined: str | None = None
    usable_notes: tuple[str, ...] = field(default=())

    @property
    def best(self) -> int:
        """Index of the deciding instance (the largest logit), -1 when there is none."""
        return int(np.argmax(self.logits)) if len(self.logits) else -1

    @property
    def logit(self) -> float:
        """The image's decision logit: the largest instance logit (-inf when none)."""
        return float(self.logits[self.best]) if len(self.logits) else float("-inf")


def rule_at(logit, threshold_logit):
    """The decision rule: protected when the image logit reaches the threshold (numbers, or
    arrays that broadcast: calibration applies it to every image at every threshold)."""
    out = np.asarray(logit) >= np.asarray(threshold_logit)
    return out if out.ndim else bool(out)


def rule(logit, det: DetectorConfig):
    """`rule_at` with the configured ``learned.threshold_logit``."""
    return rule_at(logit, det.learned.threshold_logit)


def decision_model(det: DetectorConfig) -> DecisionModel:
    """The configured decision weights (``learned.model``, or the shipped ones)."""
    return shipped_model() if det.learned.model is None else _load(det.learned.model)


@cache
def _load(path: str) -> DecisionModel:
    # Keyed on the path: weights rewritten in place during a process are not reloaded (the
    # evidence cache and `config.load_config`'s digest check key on the file's content).
    return load_model(path)


def window_label(spectra: TimeFreqInput, index: int) -> str:
    """Where instance ``index`` lies, in words (``"stripes along rows; columns 25%-75%, frames
    of 256 rows"``)."""
    across = "columns" if spectra.axes[index] == "rows" else "rows"
    along = "rows" if spectra.axes[index] == "rows" else "columns"
    c0, c1 = spectra.windows[index]
    frame = tfinput.FRAME_LINES << spectra.levels[index]
    return (f"stripes along {spectra.axes[index]}; {across} {c0:.0%}-{c1:.0%}, "
            f"frames of {frame} {along}")


def spectrum_view(spectra: TimeFreqInput, index: int
                  ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The whitened coherent log power of instance ``index`` per colour plane (``"R"``,
    ``"G"``, ``"B"`` and ``"L"``, their mean), averaged over its frames, and its frequency grid
    in cycles per analysed line: what the explanation (`explain.match_specs`) reads."""
    x, ch = spectra.x[index], tfinput.CHANNELS
    planes = {"R": x[ch.index("coh_R")], "G": x[ch.index("coh_G")],
              "B": x[ch.index("coh_B")], "L": x[ch.index("coh_mean")]}
    return planes, tfinput.freq_grid_cpr() / (1 << spectra.levels[index])


def measure(pixels: np.ndarray, det: DetectorConfig, *, model: DecisionModel | None = None
            ) -> DecisionRecord:
    """The default profile's measurements of one image (see the module docstring).

    Parameters
    ----------
    pixels : ndarray of shape (n_rows, n_cols, 3) or (n_rows, n_cols)
        Decoded pixels in stored orientation (uint8, uint16 or float32).
    det : DetectorConfig
        ``profiles.orientations`` picks the axes; ``learned.model`` the weights.
    model : DecisionModel, optional
        Weights to use instead of the configured ones.

    Returns
    -------
    DecisionRecord
        ``undetermined`` says why when no axis could be analysed (too small, no dynamic
        range, clipped, fewer than `usable.MIN_USABLE_BLOCKS` usable column blocks).
    """
    axes = (0, 1) if det.profiles.orientations == "both" else (0,)
    model = model or decision_model(det)
    a = analysable(pixels, axes, tiles=USABLE_TILES)
    if not a["profiles"]:
        return DecisionRecord(np.zeros(0, np.float32),
                              tfinput.profiles_input({}, full_scale=1.0, skipped=a["skipped"]),
                              "image too small: " + "; ".join(a["skipped"]))
    notes = tuple(f"{AXIS_NAMES[ax]}: " + ", ".join(why) for ax, why in a["notes"].items()
                  if why)
    usable = {ax: p for ax, p in a["profiles"].items()
              if int(a["keep"][ax].sum()) >= MIN_USABLE_BLOCKS}
    spectra = tfinput.profiles_input(usable, full_scale=a["full_scale"], keep=a["keep"],
                                     skipped=a["skipped"])
    if not usable:
        lo, hi = float(np.min(pixels)), float(np.max(pixels))
        why = (f"no dynamic range: every pixel is {lo:g}" if lo == hi else
               f"too few usable column blocks on every analysed axis ({'; '.join(notes)})")
        return DecisionRecord(np.zeros(0, np.float32), spectra, why, notes)
    logits = score_windows(spectra.x, model)
    if not len(logits):  # an analysable axis always has a frame; never call nothing clean
        return DecisionRecord(logits, spectra, "no frame of the analysable axes to score",
                              notes)
    return DecisionRecord(logits, spectra, None, notes)
