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
from lishield_guard.detector.spectra import AXIS_NAMES, USABLE_TILES, axis_too_small, \
    block_profiles_rgb

__all__ = ["FirstLook", "first_look", "peak_of_profiles"]


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
        Whether some axis had enough usable blocks (an unusable image goes on to the
        decision, which says why it cannot look).
    """

    peak: float
    where: str
    usable: bool

    def clears(self, first_look_ln: float | None) -> bool:
        """Whether the image is clean without the full decision (``first_look_ln`` None: the
        first look is off and never clears)."""
        return first_look_ln is not None and self.usable and self.peak < first_look_ln


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
            fr = tfinput._frames(logp, level, x)
            if fr is None:
                break
            spec = rfft(fr[0], n=tfinput.NFFT, axis=-1, workers=1)  # (blocks, t, nf)
            coh, _ = tfinput._coherent(spec, use, sel, incoherent=False)
            # the bins the decision reads: from 2 cycles per frame up (the log grid's range)
            peak = float(np.log(coh[..., tfinput.FIRST_BIN:].max() + tfinput._EPS))
            if peak > best:
                best = peak
                where = (f"stripes along {AXIS_NAMES[axis]}, frames of "
                         f"{tfinput.FRAME_LINES << level} lines")
    return best, where


def first_look(luma: np.ndarray) -> FirstLook:
    """`FirstLook` of decoded luma (stored orientation, both axes).

    Parameters
    ----------
    luma : ndarray of shape (n_rows, n_cols)
        uint8, uint16 or float32 pixels.
    """
    from lishield_guard.detector.usable import MIN_USABLE_BLOCKS, full_scale_of, usable_blocks

    axes = tuple(a for a in (0, 1) if axis_too_small(luma.shape, a) is None)
    if not axes:
        return FirstLook(float("-inf"), "image too small", False)
    full = full_scale_of(luma)
    profiles = {a: p[:1] for a, p in block_profiles_rgb(luma, axes=axes).items()}
    keep = {a: usable_blocks(p[0], full_scale=full, tiles=USABLE_TILES)[0]
            for a, p in profiles.items()}
    usable = any(int(k.sum()) >= MIN_USABLE_BLOCKS for k in keep.values())
    peak, where = peak_of_profiles(profiles, full_scale=full, keep=keep)
    return FirstLook(peak, where, usable)
