"""The learned stage's input: short-time whitened spectra in time order, summarised per scale.

An image's block line profiles (`spectra.analysable`: R, G, B, 32 blocks across, every line,
per axis) become one *instance* per axis and pyramid level: the profiles averaged over 2^k
lines, cut into frames of `FRAME_LINES` lines with half-frame hops, each frame's spectrum
whitened per block and combined across the blocks of a column window, on a log-frequency grid
of `N_FREQ` bins. Per instance, `CHANNELS` summarise the frames in time order:

- ``coh_mean``, ``coh_max``: coherent luma power (the mean plane of R, G, B), averaged over
  the frames and at its largest: stripes common to every block of the window grow with their
  number, scene rows do not (DESIGN.md, "Physics that decides accuracy");
- ``inc_mean``: incoherent luma power (what the blocks show one by one);
- ``coh_R``, ``coh_G``, ``coh_B``, ``max_R``, ``max_G``, ``max_B``: coherent power per colour
  plane, averaged over the frames and at its largest (an RGB barcode plays a tone in every
  plane at once, each plane's tones taking turns);
- ``turn_<d>``: ln of mean_t[c_t(f) c_t(f·r)] / (mean_t c_t(f) · mean_t c_t(f·r)), the
  co-occurrence in time of the coherent power at f and at f·r, r = 2^(d/24): below 0 when the
  two take turns (a white LED's tones, one per slot), above 0 when they come and go together
  (a lamp on part of the frame), 0 when steady (a PWM lamp's harmonics). The offsets cover
  the ratios of the shipped presets (2:3:4, 5:6:7, 8:9:10);
- ``freq``, ``level``, ``frames``: the bin's position, the level and the number of frames.

Why a pyramid: a frame of 64 lines at level k spans 64·2^k lines, so the levels cover one
switching slot at any row rate and resize (50-4000 lines), and the same network (shared
weights) reads every level: a row rate twice as high is the next level. Each instance keeps
only its column window with the strongest coherent line (the same rule at training and at
detection), which bounds the network's work to ``2 x MAX_LEVELS`` instances per image.

The cost is bounded by the image size: per axis, an FFT of every frame of every level (about
twice the lines of level 0), a few passes over (planes, blocks, frames, bins) arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from lishield_guard.detector.spectra import AXIS_NAMES, COL_WINDOWS, N_BLOCKS

__all__ = ["CHANNELS", "FRAME_LINES", "HOP_LINES", "INPUT_VERSION", "MAX_LEVELS", "N_FREQ",
           "TURN_OFFSETS", "TimeFreqInput", "freq_grid_cpr", "level_instances",
           "profiles_input"]

INPUT_VERSION = "tf-pyramid-v2"
FRAME_LINES = 64
HOP_LINES = 32
NFFT = 128  # frames zero-padded twice over
FIRST_BIN = 4  # the FFT bin (of NFFT) of the log grid's lowest frequency, 2 cycles per frame
BINS_PER_OCTAVE = 24
N_FREQ = 96  # 4 octaves: 2 cycles per frame .. 0.5 cycles per (decimated) line
F_MAX_CPR = 0.5
MAX_LEVELS = 6  # frames of 64 .. 2048 lines
TURN_OFFSETS = (4, 5, 6, 8, 10, 12, 14, 24)  # log-frequency bins (ratios 1.12 .. 2)
POWER_CHANNELS = ("coh_mean", "coh_max", "inc_mean", "coh_R", "coh_G", "coh_B", "max_R",
                  "max_G", "max_B")
TURN_CHANNELS = tuple(f"turn_{d}" for d in TURN_OFFSETS)
CONST_CHANNELS = ("freq", "level", "frames")
CHANNELS = POWER_CHANNELS + TURN_CHANNELS + CONST_CHANNELS
FLOOR_OCTAVES = 1.0
LOG_CLIP = (-6.0, 14.0)  # ln(whitened power), unitless
TURN_CLIP = (-4.0, 4.0)
_EPS = 1e-9


@dataclass(frozen=True)
class TimeFreqInput:
    """The learned stage's input for one image.

    Attributes
    ----------
    x : ndarray of shape (n_instances, len(CHANNELS), N_FREQ), float32
        One instance per analysed (axis, level), axes in order, levels ascending.
    axes : tuple of str
        Axis of each instance (``"rows"``: stripes along the stored rows).
    levels : tuple of int
        Pyramid level of each instance (frames span FRAME_LINES x 2^level lines).
    windows : tuple of (float, float)
        The column window (start, end fractions across the lines) each instance kept.
    n_lines : dict
        Axis name -> lines in its profiles.
    skipped : tuple of str
        Axes not analysed and why.
    """

    x: np.ndarray
    axes: tuple[str, ...]
    levels: tuple[int, ...]
    windows: tuple[tuple[float, float], ...]
    n_lines: dict
    skipped: tuple[str, ...] = ()


@cache
def freq_grid_cpr() -> np.ndarray:
    """Bin centres in cycles per (decimated) line, ascending, ending at 0.5.

    Examples
    --------
    >>> g = freq_grid_cpr()
    >>> round(float(g[-1]), 3), round(float(g[0] * FRAME_LINES), 2)
    (0.5, 2.06)
    """
    k = np.arange(N_FREQ, dtype=np.float64) - (N_FREQ - 1)
    return F_MAX_CPR * 2.0 ** (k / BINS_PER_OCTAVE)


@cache
def _log_map() -> np.ndarray:
    """(NFFT // 2 + 1, N_FREQ) float32: FFT-bin power -> log-bin power, the mean over the FFT
    bins a log bin spans, or linear interpolation where it spans none."""
    n_fft_bins = NFFT // 2 + 1
    f_fft = np.arange(n_fft_bins) / NFFT
    g = freq_grid_cpr()
    half = 2.0 ** (0.5 / BINS_PER_OCTAVE)
    m = np.zeros((n_fft_bins, N_FREQ), np.float64)
    for j, f in enumerate(g):
        inside = np.flatnonzero((f_fft >= f / half) & (f_fft < f * half))
        if inside.size >= 2:
            m[inside, j] = 1.0 / inside.size
        else:
            x = f * NFFT
            i0 = min(int(np.floor(x)), n_fft_bins - 2)
            t = x - i0
            m[i0, j], m[i0 + 1, j] = 1 - t, t
    return m.astype(np.float32)


@cache
def _hann() -> np.ndarray:
    return np.hanning(FRAME_LINES + 2)[1:-1].astype(np.float32)


@cache
def _window_matrix() -> np.ndarray:
    m = np.zeros((len(COL_WINDOWS), N_BLOCKS), np.float32)
    for w, (a, z) in enumerate(COL_WINDOWS):
        m[w, int(round(a * N_BLOCKS)):int(round(z * N_BLOCKS))] = 1.0
    return m


@cache
def _floor_spans() -> tuple[np.ndarray, np.ndarray]:
    n = NFFT // 2 + 1
    i = np.arange(n, dtype=np.float64)
    half = 2.0 ** (FLOOR_OCTAVES / 2)
    lo = np.clip(np.floor(i / half), 0, n - 1).astype(np.int64)
    hi = np.clip(np.ceil(i * half) + 1, lo + 3, n).astype(np.int64)
    return np.minimum(lo, hi - 3), hi


def _floor(power: np.ndarray) -> np.ndarray:
    """Geometric mean of ``power`` (last axis: FFT bins) over one octave around each bin."""
    cs = np.cumsum(np.log(power + _EPS), axis=-1)
    cs = np.concatenate([np.zeros_like(cs[..., :1]), cs], axis=-1)
    lo, hi = _floor_spans()
    return np.exp((cs[..., hi] - cs[..., lo]) / (hi - lo))


def _pyramid(logp: np.ndarray) -> list[np.ndarray]:
    """The profiles of every level that holds a frame: level k averages 2^k lines (pairwise
    means of the level below, the odd last line dropped)."""
    out = [logp]
    while len(out) < MAX_LEVELS and out[-1].shape[-1] // 2 >= FRAME_LINES:
        x = out[-1]
        n = x.shape[-1] // 2
        out.append((x[..., 0:2 * n:2] + x[..., 1:2 * n:2]) * np.float32(0.5))
    return out if logp.shape[-1] >= FRAME_LINES else []


def _frames(x: np.ndarray) -> np.ndarray:
    """Detrended, tapered frames of one level's profiles (``(..., N_BLOCKS, n_lines)`` with
    at least `FRAME_LINES` lines, `_pyramid`): ``(..., N_BLOCKS, n_frames, FRAME_LINES)``,
    centred in the lines."""
    n = x.shape[-1]
    t = (n - FRAME_LINES) // HOP_LINES + 1
    start = (n - (FRAME_LINES + HOP_LINES * (t - 1))) // 2
    idx = start + HOP_LINES * np.arange(t)[:, None] + np.arange(FRAME_LINES)[None, :]
    fr = x[..., idx]  # (..., blocks, t, FRAME_LINES)
    fr = fr - fr.mean(axis=-1, keepdims=True)
    return fr * _hann()


def _turns(c: np.ndarray) -> np.ndarray:
    """`TURN_CHANNELS` of coherent power c of shape (..., n_frames, N_FREQ)."""
    s = c.copy()  # tolerate a bin of mismatch: the largest of three neighbours
    s[..., 1:] = np.maximum(s[..., 1:], c[..., :-1])
    s[..., :-1] = np.maximum(s[..., :-1], c[..., 1:])
    mean = s.mean(axis=-2)  # (..., N_FREQ)
    out = np.zeros(c.shape[:-2] + (len(TURN_OFFSETS), N_FREQ), np.float32)
    for i, d in enumerate(TURN_OFFSETS):
        joint = (s[..., :-d] * s[..., d:]).mean(axis=-2)
        out[..., i, :-d] = np.log((joint + _EPS) / (mean[..., :-d] * mean[..., d:] + _EPS))
    return np.clip(out, *TURN_CLIP)


def _inverse_floor(spec: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Weight of every block of block spectra ``spec`` (..., N_BLOCKS, n_frames, nf): the
    inverse of its noise floor (the octave-smoothed power by which it differs from the mean
    of the usable blocks, averaged over the frames), 0 for unusable blocks; (..., blocks, nf)."""
    resid = spec - spec[..., keep, :, :].mean(axis=-3, keepdims=True)
    floor = _floor((resid.real ** 2 + resid.imag ** 2).mean(axis=-2))
    return (keep[:, None] / floor).astype(np.float32)


def _coherent(spec: np.ndarray, keep: np.ndarray, sel: np.ndarray, *, incoherent: bool = True
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Whitened coherent and incoherent power of one plane's block spectra.

    spec: (N_BLOCKS, n_frames, nf) complex; sel: (n_windows, N_BLOCKS) 0/1. Every block is
    weighted by `_inverse_floor`, so a peak's height is its significance. Returns
    (n_windows, n_frames, nf) coherent and incoherent (None unless ``incoherent``) power.
    """
    inv = _inverse_floor(spec, keep)
    nb, nt, nf = spec.shape
    num = (sel.astype(np.complex64) @ (spec * inv[:, None, :]).reshape(nb, -1)).reshape(
        len(sel), nt, nf)
    den = (sel @ inv)[:, None, :] + _EPS
    coh = (num.real ** 2 + num.imag ** 2) / den
    if not incoherent:
        return coh, None
    pw = (spec.real ** 2 + spec.imag ** 2) * inv[:, None, :]
    n_kept = np.maximum(sel @ keep.astype(np.float32), 1.0)
    inc = (sel @ pw.reshape(nb, -1)).reshape(len(sel), nt, nf) / n_kept[:, None, None]
    return coh, inc


def _coherent_planes(spec: np.ndarray, keep: np.ndarray, row: np.ndarray) -> np.ndarray:
    """`_coherent`'s coherent power of every colour plane at once, for one column window:
    spec (3, N_BLOCKS, n_frames, nf), row (N_BLOCKS,) 0/1 -> (3, n_frames, nf)."""
    inv = _inverse_floor(spec, keep) * row[:, None]  # (3, blocks, nf)
    num = np.einsum("pbtf,pbf->ptf", spec, inv.astype(np.complex64))
    den = inv.sum(axis=1)[:, None, :] + _EPS
    return (num.real ** 2 + num.imag ** 2) / den


def level_instances(x_level: np.ndarray, keep: np.ndarray, level: int
                    ) -> tuple[np.ndarray, int]:
    """The instance of one axis and level, and the column window it kept.

    Parameters
    ----------
    x_level : ndarray of shape (3, N_BLOCKS, n_lines), float32
        The level's ln(block line means) per colour plane (`_pyramid`: lines averaged
        2^level at a time; at least `FRAME_LINES` of them).
    keep : ndarray of bool, shape (N_BLOCKS,)
        Usable blocks (others get no weight and stay out of the noise estimate).
    level : int
        Pyramid level.

    Returns
    -------
    (x, window)
        x of shape (len(CHANNELS), N_FREQ) float32; window an index into `COL_WINDOWS`
        (the one whose coherent luma line is strongest).
    """
    from scipy.fft import rfft

    fr = _frames(x_level)
    n_frames = fr.shape[2]
    spec = rfft(fr, n=NFFT, axis=-1, workers=1)  # (3, blocks, t, nf) complex64
    use = keep if keep.any() else np.ones(N_BLOCKS, bool)
    sel = _window_matrix()
    lm = _log_map()
    coh, inc = _coherent(spec.mean(axis=0), use, sel)  # luma: the planes' mean
    coh = coh @ lm  # (windows, t, N_FREQ)
    w = int(np.argmax(coh.max(axis=(1, 2))))
    c = coh[w]
    rgb = _coherent_planes(spec, use, sel[w]) @ lm  # (3, t, N_FREQ)
    x = np.empty((len(CHANNELS), N_FREQ), np.float32)
    powers = [c.mean(axis=0), c.max(axis=0), (inc[w] @ lm).mean(axis=0),
              *(p.mean(axis=0) for p in rgb), *(p.max(axis=0) for p in rgb)]
    x[:len(POWER_CHANNELS)] = np.clip(np.log(np.stack(powers) + _EPS), *LOG_CLIP)
    x[len(POWER_CHANNELS):len(POWER_CHANNELS) + len(TURN_CHANNELS)] = _turns(c)
    x[-3] = np.linspace(-1.0, 1.0, N_FREQ, dtype=np.float32)
    x[-2] = level / (MAX_LEVELS - 1)
    x[-1] = np.log2(n_frames) / 6.0
    return x, w


def profiles_input(profiles: dict[int, np.ndarray], *, full_scale: float,
                   keep: dict | None = None, skipped: tuple[str, ...] = ()) -> TimeFreqInput:
    """The instances of every axis and level of an image's block profiles.

    Parameters
    ----------
    profiles : dict
        Axis (0 rows, 1 columns) -> (3, N_BLOCKS, n_lines) block line means
        (`spectra.block_profiles_rgb`, or the profile renderer's).
    full_scale : float
        Pixel value of white; profiles are floored at 1/512 of it before the logarithm.
    keep : dict, optional
        Axis -> usable blocks (`usable.usable_blocks`); default every block.
    skipped : tuple of str
        Axes not analysed and why (kept in the result).
    """
    xs, axes, levels, windows, n_lines = [], [], [], [], {}
    for axis, prof in sorted(profiles.items()):
        logp = np.log(np.maximum(prof, np.float32(full_scale / 512.0))).astype(np.float32)
        k = np.ones(N_BLOCKS, bool) if keep is None else np.asarray(keep[axis], bool)
        n_lines[AXIS_NAMES[axis]] = int(prof.shape[-1])
        for level, x_level in enumerate(_pyramid(logp)):
            got = level_instances(x_level, k, level)
            xs.append(got[0])
            axes.append(AXIS_NAMES[axis])
            levels.append(level)
            windows.append(COL_WINDOWS[got[1]])
    x = np.stack(xs) if xs else np.zeros((0, len(CHANNELS), N_FREQ), np.float32)
    return TimeFreqInput(x, tuple(axes), tuple(levels), tuple(windows), n_lines,
                         tuple(skipped))
