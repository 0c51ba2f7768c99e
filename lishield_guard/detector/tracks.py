"""Short-time stripe-frequency tracks of row profiles (the default profile's core).

Pipeline for one plane and one axis::

    block row profiles (n_blocks, n_rows) -> relative contrast -> common part (mean over column
      blocks) + residual (what the blocks do not share) -> for several window
      lengths: frames down the rows, strongest spectral peak of each frame (interpolated),
      significant when its power beats kappa x the residual's noise power at that frequency
      -> one `Track` per window length

A barcode is time-multiplexed: its stripes hold one tone for a slot, then the next. Short
windows see single symbols, long ones resolve close tones. Stationary look-alikes (mains, PWM,
JPEG grid) hold one frequency all frame long; scene texture differs between column blocks, so it
raises the noise floor instead of producing significant peaks.

Significance: under noise, a frame's periodogram at a bin is P x Exp(1), and the noise power P
is itself estimated from the residual of ``n_blocks - 1`` column blocks (2 (n_blocks - 1)
degrees of freedom), so the ratio peak / estimated P is F(2, 2m)-distributed with
m = n_blocks - 1: P(ratio > x) = (1 + x/m)^(-m). The strongest of ``n_bins`` independent bins is
taken, so the per-bin probability is p / n_bins and the threshold is
x = m ((p / n_bins)^(-1/m) - 1), for a per-frame false-pass probability p
(`config.ToneConfig.peak_false_prob`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import scipy.fft
from scipy.ndimage import uniform_filter1d

from lishield_guard.detector.profiles import detrend_profiles
from lishield_guard.detector.usable import usable_blocks

__all__ = ["PlaneAnalysis", "Track", "analyse_profiles", "frequency_tracks", "part_tracks",
           "peak_threshold"]

WINDOW_ROWS = (32, 64, 128, 256, 512)  # short windows see one symbol, long ones resolve tones
HOP_FRACTION = 0.25
PAD_FACTOR = 8  # zero padding of each frame's FFT, for peak interpolation
MIN_CYCLES = 1.5  # a frame must hold this many cycles of a frequency to estimate it
JPEG_GRID_CPR = (0.125, 0.25, 0.375, 0.0625, 0.1875)  # 8-row DCT grid and 4:2:0 chroma grid
JPEG_MASK_REL = 0.01


@dataclass(frozen=True)
class Track:
    """Dominant stripe frequency of successive frames of one window length.

    Attributes
    ----------
    window_rows : int
        Frame length in rows; frames advance by a quarter of it.
    lo_cpr, hi_cpr : float
        Frequencies this window can estimate (>= MIN_CYCLES per frame), cycles per row.
    freq_cpr : ndarray of shape (n_frames,)
        Interpolated frequency of the strongest spectral peak of each frame, cycles per row.
    snr : ndarray, same shape
        Peak power over the residual noise power at that frequency (unitless; 0 where the
        peak is unusable: on the searched range's edge, or no power at all).
    threshold : float
        The snr a frame must exceed to be significant (see `peak_threshold`).
    n_bins : float
        Independent bins searched per frame (for recomputing the threshold).
    n_blocks : int
        Column blocks behind the noise estimate.
    """

    window_rows: int
    lo_cpr: float
    hi_cpr: float
    freq_cpr: np.ndarray
    snr: np.ndarray
    threshold: float
    n_bins: float
    n_blocks: int

    @property
    def significant(self) -> np.ndarray:
        """Frames whose peak passes the significance test, bool of shape (n_frames,)."""
        return self.snr > self.threshold

    @property
    def significant_fraction(self) -> float:
        """Fraction of frames whose peak is significant (unitless)."""
        return float(self.significant.mean()) if self.snr.size else 0.0

    def with_false_prob(self, false_prob: float) -> Track:
        """The same track judged at another per-frame false-pass probability."""
        thr = peak_threshold(false_prob, n_bins=self.n_bins, n_blocks=self.n_blocks)
        return replace(self, threshold=thr)


@dataclass(frozen=True)
class PlaneAnalysis:
    """Frequency tracks of one plane along one axis, plus what was skipped.

    ``common`` is the common log-contrast row signal (n_rows,), used by pattern folding;
    ``blocks`` the log contrast of each usable column block (n_blocks, n_rows), used by the
    period sweep's coherence test; ``fine_blocks`` the same for narrower sub-blocks, used by
    the exact-model fit to weight the columns by how quiet their scene is; ``band_cpr`` the
    stripe frequencies the tracks searched, cycles per row. Sub-blocks may instead be given
    as their row means, ``fine_profiles``, detrended at ``trend_sigma_rows`` on first use
    (`fit_blocks`).
    """

    n_rows: int
    n_blocks_used: int
    tracks: tuple[Track, ...]
    skipped: tuple[str, ...]
    common: np.ndarray | None = None
    blocks: np.ndarray | None = None
    fine_blocks: np.ndarray | None = None
    band_cpr: tuple[float, float] = (0.0, 0.45)
    fine_profiles: np.ndarray | None = field(default=None, repr=False)
    trend_sigma_rows: float = 0.0

    @property
    def fit_blocks(self) -> np.ndarray | None:
        """The blocks the sweep and the exact fit weigh: sub-blocks where analysed."""
        if self.fine_blocks is not None:
            return self.fine_blocks
        return self.blocks if self._fine_contrast is None else self._fine_contrast

    @cached_property
    def _fine_contrast(self) -> np.ndarray | None:
        # the usable sub-blocks' log contrast, detrended on first use: most planes of an
        # ordinary photo never reach a stage that weighs sub-blocks
        if self.fine_profiles is None:
            return None
        return detrend_profiles(self.fine_profiles,
                                sigma_rows=self.trend_sigma_rows)[0].astype(np.float32)

    @property
    def max_significant_fraction(self) -> float:
        """Largest significant fraction over all tracks (0 when there are none)."""
        return max((t.significant_fraction for t in self.tracks), default=0.0)

    def with_false_prob(self, false_prob: float) -> PlaneAnalysis:
        """The same analysis judged at another per-frame false-pass probability."""
        tracks = tuple(t.with_false_prob(false_prob) for t in self.tracks)
        if self.fine_profiles is None:
            return replace(self, tracks=tracks)
        # detrended once here and shared, not once per copy
        return replace(self, tracks=tracks, fine_blocks=self.fit_blocks, fine_profiles=None)


def analyse_profiles(profiles: np.ndarray, *, full_scale: float, band_cpr: tuple[float, float],
                     trend_sigma_rows: float, false_prob: float,
                     fine_profiles: np.ndarray | None = None) -> PlaneAnalysis:
    """Frequency tracks for the block row profiles of one plane.

    Parameters
    ----------
    profiles : ndarray of shape (n_blocks, n_rows)
        Row means per column block (`block_row_profiles`).
    full_scale : float
        Pixel value of white (255, 65535, or the float plane's maximum).
    band_cpr : (float, float)
        Lowest and highest stripe frequency searched, cycles per row.
    trend_sigma_rows : float
        Gaussian trend filter sigma, rows.
    false_prob : float
        Probability that a frame of pure noise passes the significance test.
    fine_profiles : ndarray of shape (n_sub_blocks, n_rows), optional
        Row means of narrower sub-blocks; their usable ones are kept as ``fine_blocks``.
    """
    n_blocks, n_rows = profiles.shape
    keep, skipped = usable_blocks(profiles, full_scale=full_scale)
    if keep.sum() < 2:
        return PlaneAnalysis(n_rows, int(keep.sum()), (), tuple(skipped) +
                             ("fewer than 2 usable column blocks: no coherence test possible",))
    contrast, _ = detrend_profiles(profiles[keep], sigma_rows=trend_sigma_rows)
    nb = contrast.shape[0]
    band = (band_cpr[0], min(band_cpr[1], 0.45))
    # in log contrast the LED term is the same in every block (gain 1): the mean is its
    # estimate and the residual holds only what blocks do not share
    common, tracks = frequency_tracks(contrast, band_cpr=band, false_prob=false_prob)
    fine = None
    if fine_profiles is not None:
        fine_keep, _ = usable_blocks(fine_profiles, full_scale=full_scale)
        if fine_keep.sum() >= 2:
            fine = fine_profiles[fine_keep]
    return PlaneAnalysis(n_rows, nb, tracks, tuple(skipped), common.astype(np.float32),
                         contrast.astype(np.float32), None, band, fine, trend_sigma_rows)


def frequency_tracks(contrast: np.ndarray, *, band_cpr: tuple[float, float], false_prob: float
                     ) -> tuple[np.ndarray, tuple[Track, ...]]:
    """The common row signal of some column blocks and its tracks, one per window length.

    Parameters
    ----------
    contrast : ndarray of shape (n_blocks, n_rows)
        Detrended log contrast of at least 2 column blocks.
    band_cpr : (float, float)
        Lowest and highest stripe frequency searched, cycles per row (the top is capped at
        0.45).
    false_prob : float
        Probability that a frame of pure noise passes the significance test.

    Returns
    -------
    common : ndarray of shape (n_rows,)
        Mean over the blocks: the estimate of the LED term, which is the same in every block.
    tracks : tuple of Track
        One per window length of `WINDOW_ROWS` that fits the rows and the band.
    """
    nb, n_rows = contrast.shape
    common = contrast.mean(axis=0)
    resid = contrast - common
    noise_scale = 1.0 / ((nb - 1) * nb)
    return common, tuple(_track(common, resid, w, t_lo, hi, false_prob, noise_scale)
                         for w, t_lo, hi in _windows(n_rows, band_cpr))


def _windows(n_rows: int, band_cpr: tuple[float, float]) -> list[tuple[int, float, float]]:
    """(window length, lowest, highest frequency in cycles per row) of every window of
    `WINDOW_ROWS` that fits ``n_rows`` and holds `MIN_CYCLES` of a frequency in the band (its
    top capped at 0.45)."""
    lo, hi = band_cpr[0], min(band_cpr[1], 0.45)
    out = []
    for w in WINDOW_ROWS:
        if w > n_rows:
            break
        t_lo = max(lo, MIN_CYCLES / w)
        if t_lo < hi:
            out.append((w, t_lo, hi))
    return out


def _mask_grid(power: np.ndarray, nfft: int, w: int) -> None:
    """Zero, in place, the bins of frame power spectra (``nfft``-point, window ``w``) near the
    JPEG block grid's frequencies (`JPEG_GRID_CPR`)."""
    freqs = np.arange(power.shape[-1]) / nfft
    for g in JPEG_GRID_CPR:
        power[..., np.abs(freqs - g) <= max(JPEG_MASK_REL * g, 1.0 / w)] = 0.0


def _strongest(power: np.ndarray, noise: np.ndarray, k_lo: int, k_hi: int, pad_factor: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each frame's strongest bin of ``power`` (padded grid) in [k_lo, k_hi], its power and its
    ratio to ``noise`` (the unpadded grid, interpolated linearly); the ratio is 0 on the
    band's edge or without power. Returns (bin, peak power, snr), each of shape (n_frames,)."""
    k = power[:, k_lo: k_hi + 1].argmax(axis=1) + k_lo
    rows = np.arange(power.shape[0])
    peak = power[rows, k]
    edge = (k <= k_lo) | (k >= k_hi)
    pos = k / pad_factor
    i0 = np.minimum(pos.astype(int), noise.shape[1] - 2)
    frac = pos - i0
    floor = noise[rows, i0] * (1.0 - frac) + noise[rows, i0 + 1] * frac
    snr = np.where(edge | ~(peak > 0), 0.0, peak / np.maximum(floor, 1e-300))
    return k, peak, snr


def part_tracks(blocks: np.ndarray, parts: dict[str, slice], *, band_cpr: tuple[float, float],
                false_prob: float, pad_factor: int = 2) -> dict[str, tuple[Track, ...]]:
    """Tracks of the common signal of several subsets of column blocks at once.

    Each window's frames are transformed once per block; a subset's common spectrum is the
    mean of its blocks' spectra (the transform is linear) and its noise power the spread of
    its blocks' spectra about that mean (on the unpadded grid, smoothed over 3 bins, as in
    `frequency_tracks`), so the subsets cost little more than one of them. Peaks are not
    interpolated: enough to count significant frames, not to place tones.

    Parameters
    ----------
    blocks : ndarray of shape (n_blocks, n_rows)
        Detrended log contrast of column blocks.
    parts : dict of str to slice
        Named contiguous subsets of the blocks, each of at least 2 blocks.
    band_cpr, false_prob
        As for `frequency_tracks`.
    pad_factor : int
        Zero padding of each frame's FFT; 2 loses at most about 0.4 dB of a peak's power.

    Returns
    -------
    dict of str to tuple of Track
        The tracks of each part, one per window length that fits.
    """
    n_blocks, n_rows = blocks.shape
    bounds = {name: cols.indices(n_blocks)[:2] for name, cols in parts.items()}
    edges = sorted({e for ab in bounds.values() for e in ab})
    out: dict[str, list[Track]] = {name: [] for name in parts}
    for w, t_lo, hi in _windows(n_rows, band_cpr):
        hop = max(1, int(w * HOP_FRACTION))
        nfft = pad_factor * w
        fr = _frames(blocks, w, hop)
        fr = ((fr - fr.mean(axis=-1, keepdims=True)) * np.hanning(w)).astype(np.float32)
        k_lo, k_hi = int(np.ceil(t_lo * nfft)), int(np.floor(hi * nfft))
        top = min(k_hi + 2 * pad_factor, nfft // 2 + 1)
        spec = scipy.fft.rfft(fr, nfft, axis=-1)[..., :top]
        power = (spec.real ** 2 + spec.imag ** 2)[..., ::pad_factor]  # the unpadded grid
        # sums over the stretches between part edges; a part's sum adds its stretches
        pieces = {(a, b): (spec[a:b].sum(axis=0), power[a:b].sum(axis=0))
                  for a, b in zip(edges[:-1], edges[1:], strict=False)}
        n_bins = (k_hi - k_lo) / pad_factor
        for name, (a, b) in bounds.items():
            nb = b - a
            own = [v for (pa, pb), v in pieces.items() if a <= pa and pb <= b]
            mean = sum(v[0] for v in own) / nb
            common = (mean.real ** 2 + mean.imag ** 2).astype(np.float64)
            spread = sum(v[1] for v in own) - nb * common[..., ::pad_factor]
            noise = uniform_filter1d(np.maximum(spread, 0.0), size=3, axis=-1,
                                     mode="nearest") / ((nb - 1) * nb)
            _mask_grid(common, nfft, w)
            k, _, snr = _strongest(common, noise, k_lo, k_hi, pad_factor)
            thr = peak_threshold(false_prob, n_bins=n_bins, n_blocks=nb)
            out[name].append(Track(w, float(t_lo), float(hi), k / nfft, snr, thr,
                                   float(n_bins), int(nb)))
    return {name: tuple(tracks) for name, tracks in out.items()}


def _frames(x: np.ndarray, w: int, hop: int) -> np.ndarray:
    n = x.shape[-1]
    starts = np.arange(0, n - w + 1, hop)
    view = np.lib.stride_tricks.sliding_window_view(x, w, axis=-1)
    return view[..., starts, :]


def peak_threshold(false_prob: float, *, n_bins: float, n_blocks: int) -> float:
    """Peak-to-noise power ratio passed by noise with probability ``false_prob`` (see module)."""
    m = max(n_blocks - 1, 1)
    p_bin = false_prob / max(n_bins, 1.0)
    return m * (p_bin ** (-1.0 / m) - 1.0)


def _track(common: np.ndarray, resid: np.ndarray, w: int, lo: float, hi: float,
           false_prob: float, noise_scale: float) -> Track:
    hop = max(1, int(w * HOP_FRACTION))
    win = np.hanning(w)
    nfft = PAD_FACTOR * w
    fc = _frames(common, w, hop)
    fc = (fc - fc.mean(axis=-1, keepdims=True)) * win
    spec = np.abs(scipy.fft.rfft(fc.astype(np.float32), nfft, axis=-1)).astype(np.float64) ** 2
    fr = _frames(resid, w, hop)
    fr = ((fr - fr.mean(axis=-1, keepdims=True)) * win).astype(np.float32)
    # the noise floor is smooth: estimated on the unpadded grid (3 bins, as wide as the
    # padded grid's 2 PAD_FACTOR + 1) and interpolated onto the padded one
    coarse = (np.abs(scipy.fft.rfft(fr, w, axis=-1)) ** 2).sum(axis=0) * (noise_scale * 1.0)
    coarse = uniform_filter1d(coarse.astype(np.float64), size=3, axis=-1, mode="nearest")
    k_lo = int(np.ceil(lo * nfft))
    k_hi = int(np.floor(hi * nfft))
    _mask_grid(spec, nfft, w)
    k, peak, snr = _strongest(spec, coarse, k_lo, k_hi, PAD_FACTOR)
    rows = np.arange(spec.shape[0])
    # parabolic interpolation on log power around the peak bin
    km = np.clip(k - 1, 0, spec.shape[1] - 1)
    kp = np.clip(k + 1, 0, spec.shape[1] - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b, c = (np.log(np.maximum(spec[rows, km], 1e-300)), np.log(np.maximum(peak, 1e-300)),
                   np.log(np.maximum(spec[rows, kp], 1e-300)))
        den = a - 2 * b + c
        delta = np.where(den < 0, 0.5 * (a - c) / np.where(den < 0, den, -1.0), 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    freq = (k + delta) / nfft
    n_bins = (k_hi - k_lo) / PAD_FACTOR
    thr = peak_threshold(false_prob, n_bins=n_bins, n_blocks=resid.shape[0])
    return Track(w, float(lo), float(hi), freq, snr, thr, float(n_bins), int(resid.shape[0]))
