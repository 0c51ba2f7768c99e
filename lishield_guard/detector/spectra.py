"""Block line profiles: the learned stage's only O(pixels) work, and which blocks can show stripes.

Per axis (rows, then columns), every line's mean within each of `N_BLOCKS` blocks across it,
per colour plane (`block_profiles_rgb`, one pass over the pixels); everything after it costs
O(lines) (`tfinput`). Why blocks: light multiplies reflectance, so in ln(block mean) the LED
adds the same term to every block of a line while the scene term differs per block; the
stripes are what the blocks have in common (DESIGN.md, "Physics that decides accuracy").
`analysable` also says which blocks are usable (`usable.usable_blocks`: black, saturated and
flat blocks are left out) and which axes are too small to look at.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["AXIS_NAMES", "COL_WINDOWS", "MIN_ACROSS", "MIN_LINES", "N_BLOCKS", "USABLE_TILES",
           "analysable", "axis_too_small", "block_profiles_rgb"]

N_BLOCKS = 32  # column blocks per axis
MIN_LINES = 64  # an axis needs at least this many lines ...
MIN_ACROSS = 64  # ... each at least this many pixels long
#: Column windows as (start, end) fractions of the line length (whole blocks).
COL_WINDOWS = ((0.0, 1.0), (0.0, 0.5), (0.5, 1.0), (0.25, 0.75), (0.0, 0.25), (0.25, 0.5),
               (0.5, 0.75), (0.75, 1.0))
AXIS_NAMES = {0: "rows", 1: "columns"}
USABLE_TILES = 8  # row ranges per block judged apart (`usable.usable_blocks`): a lamp in a
#                   dark room lights a few rows of blocks that are black on average


def _edges(n: int, k: int) -> np.ndarray:
    return np.linspace(0, n, k + 1).round().astype(np.int64)


def block_profiles_rgb(rgb: np.ndarray, *, axes: tuple[int, ...] = (0, 1),
                       n_blocks: int = N_BLOCKS) -> dict[int, np.ndarray]:
    """Mean of every line within each of ``n_blocks`` blocks across it, per colour plane.

    Parameters
    ----------
    rgb : ndarray of shape (n_rows, n_cols, 3) or (n_rows, n_cols)
        uint8, uint16 or float32 pixels (a 2-D plane stands for three equal planes).
    axes : tuple of {0, 1}
        0: lines are stored rows (sensor rows); 1: lines are stored columns.
    n_blocks : int
        Blocks across the lines (clipped to the pixels across).

    Returns
    -------
    dict
        axis -> ndarray of shape (3, n_blocks, n_lines), float32: exact block means.

    Notes
    -----
    One pass over the pixels for both axes: an integral image (``cv2.integral``, int32 sums
    for 8-bit images that cannot overflow, float64 otherwise), then four lookups per block
    and line. No rounding of the means: stripes can be far below one grey level.
    """
    n_rows, n_cols = rgb.shape[:2]
    exact = rgb.dtype == np.uint8 and n_rows * n_cols * 255 < 2**31
    src = rgb if rgb.dtype in (np.uint8, np.uint16, np.float32, np.float64) else \
        rgb.astype(np.float32)
    integ = cv2.integral(src, sdepth=cv2.CV_32S if exact else cv2.CV_64F)
    if integ.ndim == 2:
        integ = integ[:, :, None]
    out = {}
    for axis in axes:
        n_across = n_cols if axis == 0 else n_rows
        cuts = _edges(n_across, max(1, min(n_blocks, n_across)))
        if axis == 0:
            sums = np.diff(np.diff(integ[:, cuts, :], axis=1), axis=0)  # (rows, blocks, ch)
            sums = sums.transpose(2, 1, 0)
        else:
            sums = np.diff(np.diff(integ[cuts, :, :], axis=0), axis=1)  # (blocks, cols, ch)
            sums = sums.transpose(2, 0, 1)
        width = np.diff(cuts).astype(np.float32)[None, :, None]
        prof = sums.astype(np.float32) / width
        if len(width[0]) < n_blocks:  # fewer pixels across than blocks: repeat the last
            prof = np.concatenate([prof] + [prof[:, -1:]] * (n_blocks - prof.shape[1]), 1)
        out[axis] = np.repeat(prof, 3, axis=0) if prof.shape[0] == 1 else prof
    return out


def axis_too_small(shape: tuple[int, ...], axis: int) -> str | None:
    """Why ``axis`` of an image of ``shape`` cannot be analysed (None: it can)."""
    lines, across = shape[axis], shape[1 - axis]
    if lines < MIN_LINES:
        return f"only {lines} < {MIN_LINES} lines"
    if across < MIN_ACROSS:
        return f"lines only {across} < {MIN_ACROSS} pixels long"
    return None


def analysable(pixels: np.ndarray, axes: tuple[int, ...] = (0, 1), *, tiles: int = 1) -> dict:
    """The profiles of every axis of an image that is large enough, and which of their blocks
    can show stripes.

    ``tiles``: row ranges per block judged apart by `usable.usable_blocks` (`USABLE_TILES`
    for the time-frequency decision: a lamp lighting a few rows of a dark room).

    Returns
    -------
    dict
        ``skipped`` (axes too small, and why), ``profiles`` (axis -> `block_profiles_rgb`),
        ``keep`` (axis -> usable blocks, `usable.usable_blocks` of the colours' mean),
        ``notes`` (axis -> why blocks were left out) and ``full_scale`` (the value of white).
    """
    from lishield_guard.detector.usable import full_scale_of, usable_blocks

    skipped = tuple(f"{AXIS_NAMES[a]}: {why}" for a in axes
                    if (why := axis_too_small(pixels.shape, a)) is not None)
    ok = tuple(a for a in axes if axis_too_small(pixels.shape, a) is None)
    full = full_scale_of(pixels)
    profiles = block_profiles_rgb(pixels, axes=ok) if ok else {}
    keep, notes = {}, {}
    for a, p in profiles.items():
        keep[a], notes[a] = usable_blocks(p.mean(axis=0), full_scale=full, tiles=tiles)
    return {"skipped": skipped, "profiles": profiles, "keep": keep, "notes": notes,
            "full_scale": full}
