"""First stage: clear planes with no column-coherent periodic stripes before any pattern search.

An ordinary photo under steady light has no row signal that every column block shares. The
short-time tracks (`spectrum.analyse_profiles`) already test each frame's strongest peak
against the residual between column blocks; under noise a frame passes at threshold
``peak_threshold(p)`` with probability p. The screen asks for ``min_frames`` such frames in
one track at a loose p (0.01 by default, against 1e-5 for the tone tracks), so:

- a plane that fails the screen has no frame that the tone tracks could count, and the
  expensive stages (folding, the period sweep, the exact fit) are skipped for it;
- the false-pass probability of a plane of pure noise is about
  1 - (1 - p)^(n_frames) per track for one frame: the screen is meant to be loose, and its
  miss rate on barcodes is what is measured (`tests/core/test_screen.py`, and
  ``lishield-guard bench`` reports the fraction of clean photos it clears).

A JPEG's own block grid (8x8 DCT blocks, 16-row MCUs with 4:2:0 chroma) is a periodic,
column-coherent pattern too: frames whose peak sits on a harmonic of that grid
(`jpeg_grid_cpr`, at the decoding scale) are not counted.

A plane that has stripes is then asked whether they are *steady*: when one stationary square
wave (any frequency, duty, phase and exposure: `modelfit.lookalike_rho`) fits its rows at rho
>= `modelfit.LOOKALIKE_DOMINANT_RHO`, the stripes are a PWM-dimmed or mains-flickering light
or a regular texture, and no barcode could explain the rows well enough to pass even the
laxest gain rule; the plane is cleared as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lishield_guard.modelfit import LOOKALIKE_DOMINANT_RHO, steady_rho
from lishield_guard.spectrum import PlaneAnalysis, peak_threshold

__all__ = ["ScreenResult", "jpeg_grid_cpr", "screen_plane"]


@dataclass(frozen=True)
class ScreenResult:
    """The first stage's decision on one plane of one axis.

    Attributes
    ----------
    passed : bool
        True when the plane goes on to the pattern search.
    frames : int
        Most frames above the screen threshold in any one track.
    window_rows : int
        Window length of that track (0 when there are no tracks).
    false_prob : float
        Per-frame false-pass probability the threshold was set for.
    steady_rho : float or None
        How well one steady square wave fits the rows, when the stripes were tested (the
        plane had enough frames); the plane is cleared at `LOOKALIKE_DOMINANT_RHO` or above.
    """

    passed: bool
    frames: int
    window_rows: int
    false_prob: float
    steady_rho: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready fields."""
        return {"passed": self.passed, "frames": self.frames, "window_rows": self.window_rows,
                "false_prob": self.false_prob, "steady_rho": self.steady_rho}


STEADY_WINDOW_CYCLES = 4.0  # the steady test high-passes at 1.5 cycles per this many stripes
JPEG_MCU_ROWS = 16  # the coarsest JPEG grid (4:2:0 MCUs); 8-row DCT blocks are its harmonics


def jpeg_grid_cpr(fmt: str, row_scale: float) -> tuple[float, ...]:
    """Frequencies (cycles per analysed row, in (0, 0.5]) of a JPEG's block grid: every
    harmonic of the 16-row MCU grid, aliased into the band, for rows decoded at 1/row_scale
    (DCT-domain scaling keeps the grid: 8 stored rows become 8 / row_scale). Empty for other
    formats."""
    if fmt.upper() not in ("JPEG", "MPO") or not row_scale > 0:
        return ()
    base = row_scale / JPEG_MCU_ROWS
    out = set()
    for k in range(1, JPEG_MCU_ROWS + 1):
        f = (k * base) % 1.0
        f = min(f, 1.0 - f)
        if f > 1e-9:
            out.add(round(f, 9))
    return tuple(sorted(out))


def screen_plane(analysis: PlaneAnalysis, *, false_prob: float | None, min_frames: int,
                 grid_cpr: tuple[float, ...] = ()) -> ScreenResult:
    """Whether one plane's tracks hold ``min_frames`` frames significant at ``false_prob``.

    Parameters
    ----------
    analysis : PlaneAnalysis
        Tracks of one plane along one axis.
    false_prob : float or None
        Per-frame false-pass probability in (0, 1); None passes every plane (screen off).
    min_frames : int
        Frames (>= 1) one track must hold above the threshold.
    grid_cpr : tuple of float
        Frequencies of the source's block grid (`jpeg_grid_cpr`): a frame whose peak lies
        within half a frequency bin of one of them is not counted.

    Returns
    -------
    ScreenResult
    """
    if false_prob is None:
        return ScreenResult(True, -1, 0, 0.0)
    best, best_w, best_f = 0, 0, 0.0
    for track in analysis.tracks:
        thr = peak_threshold(false_prob, n_bins=track.n_bins, n_blocks=track.n_blocks)
        hits = track.snr > thr
        if grid_cpr:
            off = np.min(np.abs(track.freq_cpr[:, None] - np.asarray(grid_cpr)[None, :]), axis=1)
            hits &= off > 0.5 / track.window_rows
        count = int(np.count_nonzero(hits))
        if count > best:
            best, best_w = count, track.window_rows
            best_f = float(np.median(track.freq_cpr[hits]))
    if best < min_frames:
        return ScreenResult(False, best, best_w, float(false_prob))
    steady = None
    if analysis.fit_blocks is not None and best_f > 0:
        steady = steady_rho(analysis.fit_blocks, STEADY_WINDOW_CYCLES / best_f)
    passed = steady is None or steady < LOOKALIKE_DOMINANT_RHO
    return ScreenResult(passed, best, best_w, float(false_prob), steady)
