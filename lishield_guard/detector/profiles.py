"""Reduce pixels to row profiles per column block: the detector's only O(pixels) step."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["block_row_profiles", "detrend_profiles", "gaussian_smooth", "merge_blocks"]


def block_row_profiles(plane: np.ndarray, *, n_col_blocks: int, axis: int = 0,
                       sub_blocks: int = 1) -> np.ndarray:
    """Mean brightness of every row within each of ``n_col_blocks`` column blocks.

    Parameters
    ----------
    plane : ndarray of shape (n_rows, n_cols)
        uint8, uint16 or float32 pixels.
    n_col_blocks : int
        Number of equal-width column blocks (clipped to n_cols).
    axis : {0, 1}
        0 profiles sensor rows (stripes run along rows); 1 profiles columns instead, as if the
        image were transposed (rotation baked into pixels).
    sub_blocks : int
        Split every block into this many equal sub-blocks (nested: `merge_blocks` recovers the
        blocks' own means exactly).

    Returns
    -------
    profiles : ndarray of shape (n_blocks * sub_blocks, n_rows), float32
        ``profiles[b, i]`` is the mean of row i over (sub-)block b.

    Notes
    -----
    ``cv2.reduce`` with a float32 accumulator over each column block: no full-size copy and no
    rounding of the means (stripes can be far below one grey level).
    """
    n_rows, n_cols = plane.shape if axis == 0 else plane.shape[::-1]
    src = plane if plane.dtype in (np.uint8, np.uint16, np.float32) else plane.astype(np.float32)
    spans = _nested_edges(n_cols, int(n_col_blocks), int(sub_blocks))
    out = np.empty((len(spans), n_rows), dtype=np.float32)
    for b, (c0, c1) in enumerate(spans):
        if axis == 0:
            out[b] = cv2.reduce(src[:, c0:c1], 1, cv2.REDUCE_AVG, dtype=cv2.CV_32F)[:, 0]
        else:  # blocks of sensor columns are blocks of stored rows
            out[b] = cv2.reduce(src[c0:c1, :], 0, cv2.REDUCE_AVG, dtype=cv2.CV_32F)[0]
    return out


def _edges(n: int, k: int) -> list[tuple[int, int]]:
    cuts = np.linspace(0, n, k + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]


def _nested_edges(n: int, k: int, sub: int) -> list[tuple[int, int]]:
    """Column spans of ``k`` blocks (clipped to n), each split into up to ``sub`` parts."""
    return [(a + s0, a + s1) for a, b in _edges(n, max(1, min(k, n)))
            for s0, s1 in _edges(b - a, max(1, min(sub, b - a)))]


def merge_blocks(fine: np.ndarray, n_cols: int, n_col_blocks: int, sub_blocks: int) -> np.ndarray:
    """Block profiles from the sub-block profiles of `block_row_profiles` (column-weighted
    means of each block's sub-blocks); ``n_cols`` is the profiled axis' column count."""
    coarse = _edges(n_cols, max(1, min(n_col_blocks, n_cols)))
    out = np.empty((len(coarse), fine.shape[1]), dtype=np.float32)
    i = 0
    for b, (a, z) in enumerate(coarse):
        parts = _edges(z - a, max(1, min(sub_blocks, z - a)))
        w = np.array([s1 - s0 for s0, s1 in parts], dtype=np.float64)
        out[b] = (w / w.sum()) @ fine[i:i + len(parts)].astype(np.float64)
        i += len(parts)
    return out


def detrend_profiles(profiles: np.ndarray, *, sigma_rows: float) -> tuple[np.ndarray, np.ndarray]:
    """Log contrast of each profile against its smooth trend.

    Parameters
    ----------
    profiles : ndarray of shape (n_blocks, n_rows)
        Row means, any positive scale.
    sigma_rows : float
        Standard deviation of the Gaussian trend filter, in rows.

    Returns
    -------
    contrast : ndarray of shape (n_blocks, n_rows), float64
        ln(profile) - trend (unitless; about the relative contrast for small stripes).
    trend : ndarray, same shape
        The smoothed ln(profile).

    Notes
    -----
    Light multiplies reflectance: a block's row mean is L(i) x mean reflectance of the block's
    row i, and stays a product after the camera's power-law gamma. In the log domain the LED
    term is added identically to every block and the scene term is separate, so scene and
    stripes do not intermodulate. Values are floored at 1e-3 of the largest profile value.
    """
    p = profiles.astype(np.float64)
    floor = max(float(p.max(initial=0.0)) * 1e-3, 1e-12)
    logp = np.log(np.maximum(p, floor))
    trend = gaussian_smooth(logp, sigma_rows=max(float(sigma_rows), 1.0))
    return logp - trend, trend


def gaussian_smooth(x: np.ndarray, *, sigma_rows: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian smoothing along the last axis with reflected edges, by FFT convolution.

    Equal to ``scipy.ndimage.gaussian_filter1d(x, sigma_rows, mode="reflect")`` (same
    truncated kernel) to rounding, but O(n log n): trend filters are hundreds of rows wide.
    """
    from scipy.ndimage import gaussian_filter1d
    from scipy.signal import fftconvolve

    radius = int(truncate * sigma_rows + 0.5)
    n = x.shape[-1]
    if radius < 32 or radius >= n:
        return gaussian_filter1d(x, sigma_rows, axis=-1, mode="reflect", truncate=truncate)
    taps = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (taps / sigma_rows) ** 2)
    kernel /= kernel.sum()
    pad = [(0, 0)] * (x.ndim - 1) + [(radius, radius)]
    padded = np.pad(x, pad, mode="symmetric")  # ndimage's "reflect" repeats the edge sample
    shape = (1,) * (x.ndim - 1) + (kernel.size,)
    return fftconvolve(padded, kernel.reshape(shape), mode="valid", axes=-1)
