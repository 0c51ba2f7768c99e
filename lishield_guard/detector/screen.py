"""First stage: clear planes with no column-coherent periodic stripes before any pattern search.

An ordinary photo under steady light has no row signal that every column block shares. The
short-time tracks (`tracks.analyse_profiles`) already test each frame's strongest peak
against the residual between column blocks; under noise a frame passes at threshold
``peak_threshold(p)`` with probability p. At a loose p (0.01 by default, against 1e-5 for the
tone tracks) a plane passes on any of three pieces of evidence, tried cheapest first:

1. **one track**: ``min_frames`` frames of one window length above the threshold;
2. **two windows**: frames above the threshold in two window lengths whose peaks agree within
   one frequency bin of the longer window (a faint stripe seen once by each of two windows:
   two looks at one frequency, where noise peaks fall anywhere in the band);
3. **one half**: a light that covers part of the frame (a lamp lighting one side of the scene)
   puts its stripes in some column blocks only, and the blocks it misses raise the residual
   the peaks are tested against (with half the blocks lit, the ratio stays near
   n_blocks - 1 however deep the stripes); scene texture confined to part of the frame does
   the same to a faint light that covers all of it. So each half of the columns (left,
   centre, right; 8 of 16 sub-blocks) is tested on its own (`tracks.part_tracks`), at a
   stricter ``partial_false_prob`` shared by the three halves and ``partial_min_frames``
   frames.

A plane that fails all three has no frame the tone tracks could count, and the expensive stages
(folding, the period sweep, the exact fit) are skipped for it. The screen is meant to be loose:
its miss rate on barcodes and its pass rate on real photos are what is measured
(`tests/core/test_screen.py`; ``lishield-guard bench`` reports the fraction of clean photos it
clears).

A JPEG's own block grid (8x8 DCT blocks, 16-row MCUs with 4:2:0 chroma) is a periodic,
column-coherent pattern too: frames whose peak sits on a harmonic of that grid
(`jpeg_grid_cpr`, at the decoding scale) are not counted.

A plane that has stripes is then asked whether they are *steady*: when one stationary square
wave (any frequency, duty, phase and exposure: `fit.lookalike_rho`) fits its rows at rho
>= `numerics.LOOKALIKE_DOMINANT_RHO`, the stripes are a PWM-dimmed or mains-flickering light
or a regular texture, and no barcode could explain the rows well enough to pass even the
laxest gain rule; the plane is cleared as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lishield_guard.detector.numerics import LOOKALIKE_DOMINANT_RHO, steady_rho
from lishield_guard.detector.tracks import PlaneAnalysis, Track, part_tracks, peak_threshold

__all__ = ["PARTS", "ScreenResult", "jpeg_grid_cpr", "screen_plane"]


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
    via : str or None
        The evidence the stripes passed on: ``"one track"``, ``"two windows"``, or
        ``"left half"``, ``"centre half"``, ``"right half"``; None when there were none.
    part_frames : int
        Most frames above the halves' threshold in any track of any half (0 when the halves
        were not tested).
    """

    passed: bool
    frames: int
    window_rows: int
    false_prob: float
    steady_rho: float | None = None
    via: str | None = None
    part_frames: int = 0

    def to_dict(self) -> dict:
        """JSON-ready fields."""
        return {"passed": self.passed, "frames": self.frames, "window_rows": self.window_rows,
                "false_prob": self.false_prob, "steady_rho": self.steady_rho,
                "via": self.via, "part_frames": self.part_frames}


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


def _hits(track: Track, false_prob: float, grid_cpr: tuple[float, ...]) -> np.ndarray:
    """Frames of ``track`` above the threshold at ``false_prob`` whose peak is off the grid."""
    hits = track.snr > peak_threshold(false_prob, n_bins=track.n_bins, n_blocks=track.n_blocks)
    if grid_cpr:
        off = np.min(np.abs(track.freq_cpr[:, None] - np.asarray(grid_cpr)[None, :]), axis=1)
        hits &= off > 0.5 / track.window_rows
    return hits


def _count(tracks: tuple[Track, ...], hits: list[np.ndarray]) -> tuple[int, int, float]:
    """Most hits (`_hits`, per track) in any one track, that track's window length and its
    hits' median frequency (cycles per row)."""
    best, best_w, best_f = 0, 0, 0.0
    for track, h in zip(tracks, hits, strict=True):
        count = int(np.count_nonzero(h))
        if count > best:
            best, best_w = count, track.window_rows
            best_f = float(np.median(track.freq_cpr[h]))
    return best, best_w, best_f


def _coincident(tracks: tuple[Track, ...], hits: list[np.ndarray]) -> float | None:
    """A frequency (cycles per row) where hits (`_hits`, per track) of two tracks of different
    window lengths agree within one bin of the longer window; None when none do."""
    found = [(t.window_rows, t.freq_cpr[h]) for t, h in zip(tracks, hits, strict=True)]
    found = [(w, f) for w, f in found if f.size]
    for i, (w_a, f_a) in enumerate(found):
        for w_b, f_b in found[i + 1:]:
            gap = np.abs(f_a[:, None] - f_b[None, :])
            if gap.min() <= 1.0 / max(w_a, w_b):
                a, b = np.unravel_index(int(gap.argmin()), gap.shape)
                return float(0.5 * (f_a[a] + f_b[b]))
    return None


PARTS = ("left", "centre", "right")
PART_PAD_FACTOR = 4  # counting frames needs no fine peak placement (`part_tracks`)
PART_BLOCKS = 16  # column sub-blocks the halves are drawn from (8 per half: as many
#                   degrees of freedom as the test on all blocks)


def _best_part(analysis: PlaneAnalysis, false_prob: float, grid_cpr: tuple[float, ...]
               ) -> tuple[str | None, int, int, float]:
    """The half of the column sub-blocks with the most frames above the threshold at
    ``false_prob`` / 3 (Bonferroni over the three halves): (part, frames, window, frequency)."""
    fine = analysis.fit_blocks
    if fine is None or fine.shape[0] < PART_BLOCKS:
        return None, 0, 0, 0.0
    # adjacent sub-blocks averaged into PART_BLOCKS, every usable one in some block
    blocks = np.stack([g.mean(axis=0) for g in np.array_split(fine, PART_BLOCKS)])
    h, q = PART_BLOCKS // 2, PART_BLOCKS // 4
    parts = dict(zip(PARTS, (slice(0, h), slice(q, q + h), slice(h, PART_BLOCKS)),
                     strict=True))
    tracks = part_tracks(blocks, parts, band_cpr=analysis.band_cpr, false_prob=false_prob,
                         pad_factor=PART_PAD_FACTOR)
    best = (None, 0, 0, 0.0)
    for name in PARTS:
        part = tracks[name]
        count, w, f = _count(part, [_hits(t, false_prob / len(PARTS), grid_cpr)
                                    for t in part])
        if count > best[1]:
            best = (name, count, w, f)
    return best


def screen_plane(analysis: PlaneAnalysis, *, false_prob: float | None, min_frames: int,
                 grid_cpr: tuple[float, ...] = (), partial_false_prob: float | None = None,
                 partial_min_frames: int = 3) -> ScreenResult:
    """Whether one plane has column-coherent stripes worth the pattern search (see module):
    ``min_frames`` frames of one track, or two windows agreeing, significant at
    ``false_prob``; or ``partial_min_frames`` frames of one half of the columns significant at
    ``partial_false_prob``. Stripes that one steady square wave explains are cleared all the
    same.

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
    partial_false_prob : float or None
        Per-frame false-pass probability of the test on halves, shared by the three halves;
        None: halves are not tested.
    partial_min_frames : int
        Frames (>= 1) one track of one half must hold above its threshold.

    Returns
    -------
    ScreenResult
    """
    if false_prob is None:
        return ScreenResult(True, -1, 0, 0.0)
    hits = [_hits(t, false_prob, grid_cpr) for t in analysis.tracks]
    best, best_w, freq = _count(analysis.tracks, hits)
    via, part_frames = "one track", 0
    if best < min_frames:
        freq = _coincident(analysis.tracks, hits)
        via = "two windows"
    if best < min_frames and freq is None:
        part = None
        if partial_false_prob is not None:
            part, part_frames, _, freq = _best_part(analysis, partial_false_prob, grid_cpr)
        if part is None or part_frames < partial_min_frames:
            return ScreenResult(False, best, best_w, float(false_prob), part_frames=part_frames)
        via = f"{part} half"
    steady = None
    if analysis.fit_blocks is not None and freq > 0:
        steady = steady_rho(analysis.fit_blocks, STEADY_WINDOW_CYCLES / freq)
    passed = steady is None or steady < LOOKALIKE_DOMINANT_RHO
    return ScreenResult(passed, best, best_w, float(false_prob), steady, via, part_frames)
