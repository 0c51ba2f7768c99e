"""The learned stage's input: whitened row spectra of image windows on a log-frequency grid.

An image becomes, per axis (rows, then columns), a stack of windows (a range of column blocks x
a range of rows), and per window nine spectra over `N_FREQ` log-spaced frequencies in cycles
per analysed row. This is the only O(pixels) work of the learned path (`block_profiles_rgb`);
everything after it costs O(rows).

Why this representation (DESIGN.md, "Physics that decides accuracy"):

- **Log profiles.** Light multiplies reflectance, so in ln(row mean) the LED adds the same
  term to every column block while the scene term differs per block.
- **Coherent against incoherent power.** ``coh`` is |sum of the blocks' whitened spectra|^2
  over the sum of their weights, ``inc`` the mean of their whitened powers. For content that
  differs per block (scene rows, noise) both have the same expectation; for stripes common to
  every block ``coh`` grows with the number of blocks. Textures that repeat across blocks
  but shift in phase (a slanted or curved pattern) lose coherence too.
- **Whitening.** Every block's spectrum is weighted by the inverse of its own noise floor
  (the geometric mean, over one octave around each frequency, of the power by which the
  block differs from the mean of all blocks: stripes common to all blocks are not noise)
  before blocks are combined: natural
  scenes put most of their row energy at low frequencies and textured blocks carry more of it
  than smooth ones, so a smooth wall counts for more than a plaid shirt, and a peak's height
  is its significance (a noise-weighted matched combination across blocks).
- **Log frequency.** The row rate of the camera and any resizing scale every frequency by one
  unknown factor: on a log axis that is a shift, and a convolutional network with a maximum
  over frequency is invariant to it by construction. Tone ratios become fixed distances.
- **Windows.** Halves, quarters and the centre of the columns and of the rows: a light that
  covers part of the frame, or a photo inside a border or a collage, fills one window even
  when it fills a small part of the image; and a quarter of the rows holds about one slot of
  an emitter switching at 200 Hz, where a tone's line is sharpest.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

__all__ = ["AXIS_NAMES", "CHANNELS", "COL_WINDOWS", "INPUT_VERSION", "MIN_ACROSS", "MIN_LINES",
           "N_BLOCKS", "N_FREQ", "ROW_WINDOWS", "SpectralInput", "axes_input", "axis_too_small",
           "analysable", "block_profiles_rgb", "freq_grid_cpr", "image_input", "window_spectra"]

#: Changes whenever the representation changes; a model card must name the same version.
INPUT_VERSION = "logf-windows-v1"
N_BLOCKS = 32  # column blocks per axis
BINS_PER_OCTAVE = 24
N_FREQ = 192  # 8 octaves: (0.5 / 256, 0.5] cycles per row
F_MAX_CPR = 0.5
FLOOR_OCTAVES = 1.0  # width of the geometric mean that estimates a block's noise floor
MIN_LINES = 64  # an axis needs at least this many lines ...
MIN_ACROSS = 64  # ... each at least this many pixels long
#: Column windows as (start, end) fractions of the line length (whole blocks).
COL_WINDOWS = ((0.0, 1.0), (0.0, 0.5), (0.5, 1.0), (0.25, 0.75), (0.0, 0.25), (0.25, 0.5),
               (0.5, 0.75), (0.75, 1.0))
#: Row windows as (start, end) fractions of the rows.
ROW_WINDOWS = ((0.0, 1.0), (0.0, 0.5), (0.5, 1.0), (0.25, 0.75), (0.0, 0.25), (0.25, 0.5),
               (0.5, 0.75), (0.75, 1.0))
#: Per window: whitened coherent and incoherent power of R, G, B and their mean (luma-like),
#: then the position on the frequency axis (-1 .. 1).
CHANNELS = ("coh_R", "coh_G", "coh_B", "coh_L", "inc_R", "inc_G", "inc_B", "inc_L", "freq")
AXIS_NAMES = {0: "rows", 1: "columns"}
_LOG_CLIP = (-6.0, 14.0)  # ln(whitened power) is clipped to this range (unitless)
_EPS_POWER = 1e-9  # floor added to every power: an exactly flat window has no spectrum
USABLE_TILES = 8  # row ranges per block judged apart (`usable.usable_blocks`): a lamp in a
#                   dark room lights a few rows of blocks that are black on average


@dataclass(frozen=True)
class SpectralInput:
    """The learned stage's input for one image.

    Attributes
    ----------
    x : ndarray of shape (n_windows, len(CHANNELS), N_FREQ), float32
        Whitened log spectra, every analysed axis' windows stacked (rows first).
    axes : tuple of str
        Axis name of each window (``"rows"`` or ``"columns"``).
    windows : tuple of (float, float, float, float)
        (start, end) fraction of the line length, then (start, end) fraction of the lines,
        of each window.
    n_lines : dict
        Analysed axis -> lines in its profiles (the rows of the spectrum's "cycles per row").
    skipped : tuple of str
        Axes not analysed and why.
    """

    x: np.ndarray
    axes: tuple[str, ...]
    windows: tuple[tuple[float, float, float, float], ...]
    n_lines: dict
    skipped: tuple[str, ...] = ()


@cache
def freq_grid_cpr() -> np.ndarray:
    """Centres of the `N_FREQ` log-spaced bins in cycles per row, ascending, ending at 0.5.

    Examples
    --------
    >>> g = freq_grid_cpr()
    >>> round(float(g[-1]), 3), round(float(g[-1] / g[-1 - BINS_PER_OCTAVE]), 3)
    (0.5, 2.0)
    """
    k = np.arange(N_FREQ, dtype=np.float64) - (N_FREQ - 1)
    return F_MAX_CPR * 2.0 ** (k / BINS_PER_OCTAVE)


@cache
def _bin_starts(nfft: int) -> np.ndarray:
    """First FFT bin (of an ``nfft``-point rFFT) of every log bin, for ``np.maximum.reduceat``:
    a log bin narrower than the FFT spacing starts where its neighbour does and so takes the
    FFT bin at its lower edge."""
    edges = freq_grid_cpr() * 2.0 ** (-0.5 / BINS_PER_OCTAVE)
    starts = np.ceil(edges * nfft).astype(np.int64)
    return np.clip(starts, 1, nfft // 2)


@cache
def _hann(n: int) -> np.ndarray:
    return np.hanning(n + 2)[1:-1].astype(np.float32)


@cache
def _col_windows() -> tuple[tuple[int, int], ...]:
    """`COL_WINDOWS` (fractions of the line) in blocks of `N_BLOCKS`."""
    return tuple((int(round(a * N_BLOCKS)), int(round(z * N_BLOCKS))) for a, z in COL_WINDOWS)


@cache
def _window_matrix() -> np.ndarray:
    """(len(COL_WINDOWS), N_BLOCKS) float32: row w is 1 on the blocks of window w."""
    m = np.zeros((len(COL_WINDOWS), N_BLOCKS), np.float32)
    for w, (c0, c1) in enumerate(_col_windows()):
        m[w, c0:c1] = 1.0
    return m


def _block_floor(power: np.ndarray) -> np.ndarray:
    """Noise floor of every spectrum (last axis, linear FFT bins): the geometric mean of the
    power over +-`FLOOR_OCTAVES`/2 around each bin (constant-Q; a narrow peak barely moves
    it), O(n) through a cumulative sum."""
    n = power.shape[-1]
    cs = np.cumsum(np.log(power + _EPS_POWER), axis=-1)
    cs = np.concatenate([np.zeros_like(cs[..., :1]), cs], axis=-1)
    lo, hi = _floor_spans(n)
    return np.exp((cs[..., hi] - cs[..., lo]) / (hi - lo))


@cache
def _floor_spans(n: int) -> tuple[np.ndarray, np.ndarray]:
    i = np.arange(n, dtype=np.float64)
    half = 2.0 ** (FLOOR_OCTAVES / 2)
    lo = np.clip(np.floor(i / half), 0, n - 1).astype(np.int64)
    hi = np.clip(np.ceil(i * half) + 1, lo + 3, n).astype(np.int64)
    lo = np.minimum(lo, hi - 3)
    return lo, hi


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


def _log_bins(power: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Peak-preserving map of rFFT power (last axis) onto the log grid (max per bin)."""
    return np.maximum.reduceat(power, starts, axis=-1)[..., :N_FREQ]


def window_spectra(log_profiles: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Whitened spectra of every window of one axis' log block profiles.

    Parameters
    ----------
    log_profiles : ndarray of shape (3, N_BLOCKS, n_lines), float32
        ln(block mean) per colour plane.
    keep : ndarray of bool, shape (N_BLOCKS,), optional
        Blocks that can show stripes (`usable.usable_blocks`); the others (black, saturated
        or exactly flat: a uniform border, clipped sky) get no weight and do not enter the
        noise estimate. Default: every block.

    Returns
    -------
    ndarray of shape (len(ROW_WINDOWS) * len(COL_WINDOWS), len(CHANNELS), N_FREQ), float32
        Row windows outermost, column windows inner, in `ROW_WINDOWS` and `COL_WINDOWS` order.
    """
    from scipy.fft import rfft

    n = log_profiles.shape[-1]
    out = np.empty((len(ROW_WINDOWS), len(COL_WINDOWS), len(CHANNELS), N_FREQ), np.float32)
    out[..., -1, :] = np.linspace(-1.0, 1.0, N_FREQ, dtype=np.float32)
    sel = _window_matrix()
    use = np.ones(N_BLOCKS, bool) if keep is None else np.asarray(keep, bool)
    if not use.any():
        use = np.ones(N_BLOCKS, bool)
    n_kept = np.maximum(sel @ use.astype(np.float32), 1.0)
    for r, (a, z) in enumerate(ROW_WINDOWS):
        r0, r1 = int(round(a * n)), int(round(z * n))
        seg = log_profiles[:, :, r0:r1]
        seg = (seg - seg.mean(axis=-1, keepdims=True)) * _hann(r1 - r0)
        nfft = 1 << int(np.ceil(np.log2(r1 - r0)))
        spec = rfft(seg, n=nfft, axis=-1, workers=1)  # (3, blocks, nf), complex64
        spec = np.concatenate([spec, spec.mean(axis=0, keepdims=True)])  # + luma-like mean
        pw = spec.real ** 2 + spec.imag ** 2
        resid = spec - spec[:, use].mean(axis=1, keepdims=True)  # what differs between blocks
        inv = use[None, :, None] / _block_floor(resid.real ** 2 + resid.imag ** 2)  # weights
        coh_c = np.matmul(sel, (spec * inv).astype(spec.dtype))  # (4, windows, nf)
        coh = (coh_c.real ** 2 + coh_c.imag ** 2) / (np.matmul(sel, inv) + _EPS_POWER)
        inc = np.matmul(sel, pw * inv) / n_kept[:, None]
        starts = _bin_starts(nfft)
        feats = np.log(np.concatenate([_log_bins(coh, starts), _log_bins(inc, starts)])
                       + _EPS_POWER)
        out[r, :, :-1] = np.clip(feats, *_LOG_CLIP).transpose(1, 0, 2)
    return out.reshape(-1, len(CHANNELS), N_FREQ)


def axis_too_small(shape: tuple[int, ...], axis: int) -> str | None:
    """Why ``axis`` of an image of ``shape`` cannot be analysed (None: it can)."""
    lines, across = shape[axis], shape[1 - axis]
    if lines < MIN_LINES:
        return f"only {lines} < {MIN_LINES} lines"
    if across < MIN_ACROSS:
        return f"lines only {across} < {MIN_ACROSS} pixels long"
    return None


def axes_input(profiles: dict[int, np.ndarray], *, full_scale: float,
               skipped: tuple[str, ...] = (), keep: dict | None = None) -> SpectralInput:
    """`window_spectra` of the block profiles of each axis (`block_profiles_rgb`), stacked.

    ``full_scale`` is the pixel value of white; profiles are floored at 1/512 of it before the
    logarithm (a black block has no stripes to show, only noise). ``keep``: axis -> usable
    blocks (`window_spectra`); default every block.
    """
    xs, names, windows, n_lines = [], [], [], {}
    cols = [(c0 / N_BLOCKS, c1 / N_BLOCKS) for c0, c1 in _col_windows()]
    for axis, prof in profiles.items():
        logp = np.log(np.maximum(prof, np.float32(full_scale / 512.0)))
        x = window_spectra(logp, None if keep is None else keep.get(axis))
        xs.append(x)
        names += [AXIS_NAMES[axis]] * len(x)
        windows += [(c0, c1, r0, r1) for r0, r1 in ROW_WINDOWS for c0, c1 in cols]
        n_lines[AXIS_NAMES[axis]] = int(prof.shape[-1])
    x = np.concatenate(xs) if xs else np.zeros((0, len(CHANNELS), N_FREQ), np.float32)
    return SpectralInput(x, tuple(names), tuple(windows), n_lines, tuple(skipped))


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


def image_input(rgb: np.ndarray, *, axes: tuple[int, ...] = (0, 1)) -> SpectralInput:
    """`axes_input` of every axis of an image that is large enough (`analysable`), usable or
    not: training data, whose input always has every window.

    Parameters
    ----------
    rgb : ndarray of shape (n_rows, n_cols, 3) or (n_rows, n_cols)
        Pixels as decoded (uint8, uint16 or float32; a 2-D plane is grey).
    axes : tuple of {0, 1}
        Axes to analyse: 0 the stored rows, 1 the stored columns (a rotation baked in).
    """
    a = analysable(rgb, axes)
    return axes_input(a["profiles"], full_scale=a["full_scale"], skipped=a["skipped"],
                      keep=a["keep"])
