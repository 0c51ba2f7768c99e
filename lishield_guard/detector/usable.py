"""Whether the detector can look at a frame at all: dynamic range, clipping, usable blocks.

A frame on which the stripe test cannot run (every pixel the same value, every column block
black or saturated, or fewer than two usable column blocks on every analysed axis) is
*undetermined*, never clean. `unusable_reason` says why, or returns None when the frame can
be analysed; a frame that is merely dark but keeps usable blocks is analysed as usual.

The block rule is the one the frequency tracks apply (`tracks.analyse_profiles`): a column
block is unusable when its mean is below `BLACK_FRACTION` or above `SATURATED_FRACTION` of
full scale, or when its row profile does not vary at all (`FLAT_FRACTION`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from lishield_guard.detector.profiles import block_row_profiles

__all__ = ["BLACK_FRACTION", "FLAT_FRACTION", "MIN_USABLE_BLOCKS", "SATURATED_FRACTION",
           "full_scale_of", "unusable_reason", "usable_blocks"]

BLACK_FRACTION = 0.02  # block mean below this fraction of full scale: black (tracks' rule)
SATURATED_FRACTION = 0.98  # block mean above this fraction of full scale: saturated
FLAT_FRACTION = 1e-6  # row-profile spread at or below this fraction of full scale: flat
MIN_USABLE_BLOCKS = 2  # the column-coherence test needs two blocks to compare

_AXIS_NAMES = {0: "rows", 1: "columns"}


def full_scale_of(plane: np.ndarray) -> float:
    """Pixel value of white: 255 (uint8), 65535 (uint16), else the plane's maximum (or 1).

    Examples
    --------
    >>> full_scale_of(np.zeros((2, 2), dtype=np.uint8))
    255.0
    """
    if plane.dtype == np.uint8:
        return 255.0
    if plane.dtype == np.uint16:
        return 65535.0
    top = float(np.max(plane)) if plane.size else 0.0
    return top if top > 0 else 1.0


def usable_blocks(profiles: np.ndarray, *, full_scale: float, tiles: int = 1
                  ) -> tuple[np.ndarray, list[str]]:
    """Which column blocks' row profiles can carry stripes, and why the others cannot.

    Parameters
    ----------
    profiles : ndarray of shape (n_blocks, n_rows)
        Row means per column block (`profiles.block_row_profiles`), pixel units.
    full_scale : float
        Pixel value of white (`full_scale_of`), > 0.
    tiles : int
        Row ranges per block judged apart (>= 1): a block is black or saturated only when
        every one of its tiles is, so a lamp that lights a few rows of a dark room keeps its
        blocks (the learned decision uses 8; the cascade 1).

    Returns
    -------
    keep : ndarray of bool, shape (n_blocks,)
        True for a usable block.
    notes : list of str
        ``"<n> black column block(s)"``, ``"<n> saturated ..."``, ``"<n> flat ..."`` for the
        kinds present.

    Examples
    --------
    >>> keep, notes = usable_blocks(np.full((3, 8), 255.0), full_scale=255.0)
    >>> keep.tolist(), notes
    ([False, False, False], ['3 saturated column block(s)'])
    """
    n = profiles.shape[1]
    k = max(1, min(int(tiles), n))
    edges = np.linspace(0, n, k + 1).round().astype(int)
    tile_means = np.add.reduceat(profiles, edges[:-1], axis=1) / np.diff(edges)
    lit = (tile_means >= BLACK_FRACTION * full_scale) & \
        (tile_means <= SATURATED_FRACTION * full_scale)
    means = profiles.mean(axis=1)
    black = ~lit.any(axis=1) & (means < BLACK_FRACTION * full_scale) if k > 1 else \
        means < BLACK_FRACTION * full_scale
    saturated = ~lit.any(axis=1) & ~black if k > 1 else means > SATURATED_FRACTION * full_scale
    spread = profiles.max(axis=1) - profiles.min(axis=1)
    flat = spread <= FLAT_FRACTION * max(full_scale, 1e-12)
    keep = ~(black | saturated | flat)
    notes = []
    for name, mask in (("black", black), ("saturated", saturated),
                       ("flat", flat & ~black & ~saturated)):
        if mask.any():
            notes.append(f"{int(mask.sum())} {name} column block(s)")
    return keep, notes


def _axis_state(plane: np.ndarray, axis: int, n_col_blocks: int) -> tuple[bool, bool, str]:
    """(usable, clipped: every block black or saturated, notes) of one plane on one axis."""
    scale = full_scale_of(plane)
    profiles = block_row_profiles(plane, n_col_blocks=n_col_blocks, axis=axis)
    keep, notes = usable_blocks(profiles, full_scale=scale)
    means = profiles.mean(axis=1)
    clipped = bool(np.all((means < BLACK_FRACTION * scale) | (means > SATURATED_FRACTION * scale)))
    return int(keep.sum()) >= MIN_USABLE_BLOCKS, clipped, ", ".join(notes)


def unusable_reason(luma: np.ndarray, *, axes: Sequence[int] = (0, 1), n_col_blocks: int = 8,
                    min_lines: int = 64, min_across: int = 64,
                    colour_planes: Callable[[], Sequence[np.ndarray]] | None = None
                    ) -> str | None:
    """Why the stripe test cannot run on this frame, or None when it can.

    Parameters
    ----------
    luma : ndarray of shape (n_rows, n_cols)
        Brightness plane as decoded (uint8, uint16 or float32), stored orientation.
    axes : sequence of {0, 1}, optional
        The axes the detector analyses (0: rows, 1: columns). Default both.
    n_col_blocks : int, optional
        Column blocks per axis (``detector.profiles.n_col_blocks``), >= 1. Default 8.
    min_lines, min_across : int, optional
        Smallest analysable axis, lines and pixels per line (`pipeline.MIN_ROWS`,
        `pipeline.MIN_ACROSS`). Axes smaller than this are left to the caller, which reports
        them as too small; when no axis is large enough the answer is None. Default 64.
    colour_planes : callable returning a sequence of ndarray, optional
        The R, G, B planes, called only when luma is unusable on every axis: a frame whose
        colour planes vary where luma does not is still analysed.

    Returns
    -------
    str or None
        None when some analysed axis has at least `MIN_USABLE_BLOCKS` usable column blocks
        (on luma or on a colour plane). Otherwise the reason, starting with
        ``"no dynamic range"`` (every pixel equal), ``"clipped on every analysed axis"``
        (every block black or saturated) or ``"too few usable column blocks"``.

    Notes
    -----
    The cost is one row-profile pass over luma on the first large-enough axis for an ordinary
    photo (it returns at the first usable axis); the colour planes are profiled only for a
    frame whose luma is unusable.

    Examples
    --------
    >>> unusable_reason(np.full((128, 128), 255, dtype=np.uint8))
    'no dynamic range: every pixel is 255 (rows, columns)'
    >>> rng = np.random.default_rng(0)
    >>> unusable_reason(rng.integers(20, 60, (128, 128)).astype(np.uint8)) is None
    True
    """
    n_rows, n_cols = luma.shape[:2]
    shape = {0: (n_rows, n_cols), 1: (n_cols, n_rows)}
    analysed = [a for a in dict.fromkeys(axes)
                if shape[a][0] >= min_lines and shape[a][1] >= min_across]
    if not analysed:
        return None  # the caller's size check reports it
    states = {}
    for axis in analysed:
        ok, clipped, notes = _axis_state(luma, axis, n_col_blocks)
        if ok:
            return None
        states[axis] = (clipped, notes)
    if colour_planes is not None:
        for plane in colour_planes():
            if any(_axis_state(plane, axis, n_col_blocks)[0] for axis in analysed):
                return None
    names = ", ".join(_AXIS_NAMES[a] for a in analysed)
    lo, hi = float(np.min(luma)), float(np.max(luma))
    if lo == hi:
        return f"no dynamic range: every pixel is {lo:g} ({names})"
    detail = "; ".join(f"{_AXIS_NAMES[a]}: {notes or 'no usable block'}"
                       for a, (_, notes) in states.items())
    if all(clipped for clipped, _ in states.values()):
        return f"clipped on every analysed axis ({detail})"
    return (f"too few usable column blocks (fewer than {MIN_USABLE_BLOCKS} on every analysed "
            f"axis: no coherence test possible; {detail})")
