"""The first look: a cheap statistic of luma alone that clears ordinary photos early.

Almost every photo a hub screens is ordinary. Before the learned decision computes the colour
planes, every level of both axes and the network (`decision.measure`), the first look reads
what an ordinary photo lacks: a line common to the column blocks of some window, in some
frame, at some level. On luma (decoded without colour) it computes the whitened coherent power
of the same pyramid of short-time spectra (`tfinput`: frames of 64 to 2048 lines, eight
column windows), and keeps its largest value, ``peak`` (ln units over the noise floor).

An image whose peak stays below ``learned.first_look_ln`` is clean without the full decision;
the others go on to it. The threshold is set by ``calibrate`` for the weights in use: below
the smallest peak of every image the full decision flags among its positives and clean
images, with a margin (`calibration.firstlook`), so that the first look never clears what the
decision would flag there; ``make train`` reports the same on the training mix. Only work is
removed: an image that goes on pays the first look on top (about a quarter of the decision).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lishield_guard.detector import tfinput
from lishield_guard.detector.spectra import (
    AXIS_NAMES,
    USABLE_TILES,
    axis_too_small,
    block_profiles_rgb,
)

__all__ = ["LUMA_LIT", "FirstLook", "first_look", "peak_of_profiles", "surely_usable"]

# A column block the decision surely keeps, judged on luma alone (it judges the mean of R, G
# and B, `spectra.analysable`): the colours' mean lies between 0.568 x luma (all in green) and
# full - (full - luma) / 3, so luma in this range (fractions of full scale, unitless) keeps
# the mean inside `usable.BLACK_FRACTION` .. `usable.SATURATED_FRACTION` with room for rounding.
LUMA_LIT = (0.04, 0.93)
LUMA_MIN_SPREAD = 1e-3  # a row profile varying less than this (of full scale) may be flat


@dataclass(frozen=True)
class FirstLook:
    """The first look's measurement of one image.

    Attributes
    ----------
    peak : float
        The largest whitened coherent luma power over axes, levels, column windows, frames
        and frequencies, ln units (-inf when nothing could be analysed).
    where : str
        Axis and frame length of the peak, in words.
    usable : bool
        Whether the decision surely finds enough usable column blocks on some axis
        (`surely_usable`); an image that may be unusable goes on to the decision, which says
        why it cannot look (undetermined is never cleared to clean).
    """

    peak: float
    where: str
    usable: bool

    def clears(self, first_look_ln: float | None) -> bool:
        """Whether the image is clean without the full decision (``first_look_ln`` None: the
        first look is off and never clears; nothing measured, -inf: it never clears)."""
        return (first_look_ln is not None and self.usable and bool(np.isfinite(self.peak))
                and self.peak < first_look_ln)

    def to_dict(self, first_look_ln: float | None = None) -> dict:
        """JSON of the measurement and of its threshold (``cleared``: the image did not need
        the full decision)."""
        return {"peak_ln": round(self.peak, 4) if np.isfinite(self.peak) else None,
                "where": self.where, "usable": self.usable, "threshold_ln": first_look_ln,
                "cleared": self.clears(first_look_ln)}


def peak_of_profiles(profiles: dict[int, np.ndarray], *, full_scale: float,
                     keep: dict[int, np.ndarray]) -> tuple[float, str]:
    """The largest whitened coherent power (ln) of one-plane block profiles, and where.

    Parameters
    ----------
    profiles : dict
        Axis -> (1, N_BLOCKS, n_lines) block line means of luma (or of any one plane).
    full_scale : float
        Pixel value of white.
    keep : dict
        Axis -> usable blocks.
    """
    from scipy.fft import rfft

    best, where = float("-inf"), "nowhere"
    sel = tfinput._window_matrix()
    for axis, prof in sorted(profiles.items()):
        use = np.asarray(keep[axis], bool)
        if use.sum() < 2:
            continue
        logp = np.log(np.maximum(prof, np.float32(full_scale / 512.0))).astype(np.float32)
        for level, x in enumerate(tfinput._pyramid(logp)):
            fr = tfinput._frames(x)
            spec = rfft(fr[0], n=tfinput.NFFT, axis=-1, workers=1)  # (blocks, t, nf)
            coh, _ = tfinput._coherent(spec, use, sel, incoherent=False)
            # the bins the decision reads: from 2 cycles per frame up (the log grid's range)
            peak = float(np.log(coh[..., tfinput.FIRST_BIN:].max() + tfinput._EPS))
            if peak > best:
                best = peak
                where = (f"stripes along {AXIS_NAMES[axis]}, frames of "
                         f"{tfinput.FRAME_LINES << level} lines")
    return best, where


def surely_usable(profiles: np.ndarray, *, full_scale: float) -> np.ndarray:
    """The column blocks that the decision keeps whatever the colours behind this luma.

    A block is surely usable when its mean and the mean of one of its `USABLE_TILES` row
    ranges lie in `LUMA_LIT` and its profile varies by more than `LUMA_MIN_SPREAD` (both
    fractions of ``full_scale``): the decision's rule (`usable.usable_blocks` of the colour
    planes' mean, with one tile or with `USABLE_TILES`) then keeps it too.

    Parameters
    ----------
    profiles : ndarray of shape (n_blocks, n_lines)
        Luma line means per column block, pixel units.
    full_scale : float
        Pixel value of white, > 0.

    Returns
    -------
    ndarray of bool, shape (n_blocks,)

    Examples
    --------
    >>> surely_usable(np.array([[100.0, 101.0] * 32, [3.0, 4.0] * 32]), full_scale=255.0)
    array([ True, False])
    """
    lo, hi = LUMA_LIT[0] * full_scale, LUMA_LIT[1] * full_scale
    n = profiles.shape[1]
    edges = np.linspace(0, n, min(USABLE_TILES, n) + 1).round().astype(int)
    tiles = np.add.reduceat(profiles, edges[:-1], axis=1) / np.diff(edges)
    means = profiles.mean(axis=1)
    spread = profiles.max(axis=1) - profiles.min(axis=1)
    return (((tiles >= lo) & (tiles <= hi)).any(axis=1) & (means >= lo) & (means <= hi)
            & (spread > LUMA_MIN_SPREAD * full_scale))


def first_look(luma: np.ndarray, *, axes: tuple[int, ...] = (0, 1),
               full_scale: float | None = None) -> FirstLook:
    """`FirstLook` of decoded luma (stored orientation).

    Parameters
    ----------
    luma : ndarray of shape (n_rows, n_cols)
        uint8, uint16 or float32 pixels.
    axes : tuple of {0, 1}
        The axes the decision analyses (``profiles.orientations``): 0 the stored rows, 1 the
        stored columns.
    full_scale : float, optional
        Pixel value of white of the planes the decision reads (default `usable.full_scale_of`
        of luma; a float image's colour planes may reach higher than its luma).
    """
    from lishield_guard.detector.usable import MIN_USABLE_BLOCKS, full_scale_of, usable_blocks

    axes = tuple(a for a in axes if axis_too_small(luma.shape, a) is None)
    if not axes:
        return FirstLook(float("-inf"), "image too small", False)
    full = full_scale_of(luma) if full_scale is None else float(full_scale)
    profiles = {a: p[:1] for a, p in block_profiles_rgb(luma, axes=axes).items()}
    keep = {a: usable_blocks(p[0], full_scale=full, tiles=USABLE_TILES)[0]
            for a, p in profiles.items()}
    usable = any(int(surely_usable(p[0], full_scale=full).sum()) >= MIN_USABLE_BLOCKS
                 for p in profiles.values())
    peak, where = peak_of_profiles(profiles, full_scale=full, keep=keep)
    return FirstLook(peak, where, usable)
