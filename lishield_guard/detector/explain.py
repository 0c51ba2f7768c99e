"""Name the spec a flagged capture carries, and its tones, from the decision input (bounded work).

The learned stage says *whether* a barcode is there; this stage says *which* configured spec
explains the stripes best, at what scale, with which tones, reading only the whitened
coherent spectra of the instance that decided (`decision.spectrum_view`). Each spec's tone
template is slid along the log-frequency axis (every scale the grid holds) and scored by the
mean whitened log power at its tones. A white (mono) spec's tones must show in every colour
plane (its score takes the weakest plane), an RGB spec's tones in their own plane well above
the other planes (`RGB_MARGIN`): a white light shows every tone in every plane, an RGB one
each tone in one plane, so neither kind of spec can claim the other kind's capture. Work:
specs x tones x grid bins, whatever the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lishield_guard.detector.tfinput import BINS_PER_OCTAVE
from lishield_guard.spec import BarcodeSpec

__all__ = ["SpecFit", "match_specs", "peak_tones"]

TONE_SLACK_BINS = 1  # a tone may sit one bin (1/24 octave, 3 %) off its template position
RGB_MARGIN = 2.0  # an RGB spec's tones must stand this far (ln units) above their level in the
#                   other colour planes, or its score pays the difference


@dataclass(frozen=True)
class SpecFit:
    """How well one spec's tone template explains one window's spectra.

    Attributes
    ----------
    spec : str
        Spec name.
    score : float
        Mean whitened log power at the template's tones (ln units, unitless): mono specs in the
        weakest colour plane, RGB specs in their own planes less any shortfall of their margin
        over the other planes (`RGB_MARGIN`).
    scale_cpr_per_hz : float
        The template's best scale: cycles per analysed row of a 1 Hz tone (row time times
        the decode scale).
    tones_cpr : dict
        Channel -> the tones' positions in cycles per row at that scale.
    tone_levels : dict
        Channel -> whitened log power found at each tone (ln units).
    leak : float or None
        RGB specs: mean level of each channel's tones in the other planes (ln units; a white
        light leaks fully); None for mono specs.
    """

    spec: str
    score: float
    scale_cpr_per_hz: float
    tones_cpr: dict
    tone_levels: dict
    leak: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready, rounded."""
        return {"spec": self.spec, "score": round(self.score, 3),
                "scale_cpr_per_hz": float(f"{self.scale_cpr_per_hz:.4g}"),
                "tones_cpr": {c: [round(v, 5) for v in t] for c, t in self.tones_cpr.items()},
                "tone_levels": {c: [round(v, 2) for v in t] for c, t in self.tone_levels.items()},
                "leak": None if self.leak is None else round(self.leak, 3)}


def _slack_max(x: np.ndarray) -> np.ndarray:
    """Maximum over +-`TONE_SLACK_BINS` bins along the last axis."""
    out = x.copy()
    for d in range(1, TONE_SLACK_BINS + 1):
        out[..., d:] = np.maximum(out[..., d:], x[..., :-d])
        out[..., :-d] = np.maximum(out[..., :-d], x[..., d:])
    return out


def _template(spec: BarcodeSpec) -> dict[str, np.ndarray]:
    """Channel -> tone offsets in bins from the spec's lowest tone."""
    f1 = spec.f1_hz
    return {c: np.round(np.log2(np.asarray(fs) / f1) * BINS_PER_OCTAVE).astype(int)
            for c, fs in spec.channels}


def match_specs(window, specs: list[BarcodeSpec],
                scale_range_cpr_per_hz: tuple[float, float] | None = None) -> list[SpecFit]:
    """Best placement of every spec's tone template on one window, best spec first.

    Parameters
    ----------
    window : (dict, ndarray)
        Whitened coherent log power per colour plane (``"R"``, ``"G"``, ``"B"``, ``"L"``) and
        its log-frequency grid in cycles per analysed row (`decision.spectrum_view`).
    specs : list of BarcodeSpec
        The configured specs.
    scale_range_cpr_per_hz : (float, float), optional
        Scales a capture can have (cycles per analysed row of a 1 Hz tone: the row time times
        the decode scale): templates are placed only there. A placement outside it would
        put a spec's tones where no camera can (JPEG and video block-grid lines near
        0.4 cycles per row look like a white spec's tones there). None: every placement.

    Returns
    -------
    list of SpecFit
        Sorted by score, highest first (empty when no spec fits on the grid).
    """
    raw, grid = window
    planes = {c: _slack_max(v) for c, v in raw.items()}
    n = len(grid)
    fits = []
    for spec in specs:
        tmpl = _template(spec)
        span = max(int(v.max()) for v in tmpl.values())
        if span >= n:
            continue
        starts = np.arange(n - span)  # every placement of the lowest tone
        if scale_range_cpr_per_hz is not None:
            lo, hi = scale_range_cpr_per_hz
            scale = grid[starts] / spec.f1_hz
            starts = starts[(scale >= lo) & (scale <= hi)]
            if not len(starts):
                continue
        if spec.is_rgb:
            own = np.mean([planes[c][starts[:, None] + off].mean(axis=1)
                           for c, off in tmpl.items()], axis=0)
            leak = np.mean([np.mean([planes[o][starts[:, None] + off].mean(axis=1)
                                     for o in "RGB" if o != c], axis=0)
                            for c, off in tmpl.items()], axis=0)
            score = own - np.maximum(leak - own + RGB_MARGIN, 0.0)
        else:  # a white light shows each tone in every colour plane: the weakest counts
            off = next(iter(tmpl.values()))
            score = np.min([planes[c][starts[:, None] + off].mean(axis=1) for c in "RGB"],
                           axis=0)
            leak = None
        i = int(np.argmax(score))
        k = int(starts[i])
        f0 = float(grid[k])
        fits.append(SpecFit(
            spec.name, float(score[i]), f0 / spec.f1_hz,
            {c: [float(grid[k + o]) for o in off] for c, off in tmpl.items()},
            {c: [float(planes[c if spec.is_rgb else "L"][k + o]) for o in off]
             for c, off in tmpl.items()},
            None if leak is None else float(leak[i])))
    return sorted(fits, key=lambda f: -f.score)


def peak_tones(window, *, min_level: float = 3.0, max_tones: int = 8
               ) -> list[tuple[float, float]]:
    """Local maxima of the window's luma coherent spectrum above ``min_level`` (ln units of
    power over the floor; 3.0 is 20x), strongest first, as (cycles per row, level).
    ``window``: as for `match_specs`."""
    planes, grid = window
    x = planes["L"]
    peaks = [(float(grid[i]), float(x[i])) for i in range(1, len(x) - 1)
             if x[i] >= min_level and x[i] >= x[i - 1] and x[i] > x[i + 1]]
    return sorted(peaks, key=lambda p: -p[1])[:max_tones]
