"""Band-limited instantaneous-frequency analysis of row profiles (the default profile's core).

Pipeline for one plane and one axis::

    block row profiles (n_blocks, n_rows) -> relative contrast -> common part (mean over blocks)
      + noise floor (inter-block residual) -> per log-spaced band: analytic signal z(i),
      significant samples |z|^2 > kappa * noise power, instantaneous frequency IF(i) in cycles/row
      -> `BandTrack` per band (IF and significance per row)

A barcode is time-multiplexed: inside a band, the IF of its stripes sits on one tone for a slot,
then jumps to the next. Stationary look-alikes (mains, PWM, JPEG grid) hold one IF all frame
long; scene texture differs between column blocks, so it raises the noise floor instead of
producing significant samples.

Significance: for complex Gaussian noise of power P, ``|z|^2 / P`` is Exp(1)-distributed, so a
sample passes ``|z|^2 > kappa * P`` with probability ``exp(-kappa)``; ``kappa = ln(1/p)``
gives a per-sample false-pass probability p (DetectorConfig.peak_false_prob).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.fft import next_fast_len, rfft
from scipy.ndimage import uniform_filter1d

from lishield_guard.profile import detrend_profiles

__all__ = ["BandTrack", "PlaneAnalysis", "analyse_profiles", "band_centres_cpr"]

BAND_HALF_RATIO = 1.6  # a band spans [c / 1.6, c * 1.6]: wide enough for f_M / f_1 = 2
BAND_STEP_RATIO = 2 ** 0.25  # neighbouring band centres
JPEG_GRID_CPR = (0.125, 0.25, 0.375, 0.0625, 0.1875)  # 8-row DCT grid and 4:2:0 chroma grid
JPEG_MASK_REL = 0.01


@dataclass(frozen=True)
class BandTrack:
    """Instantaneous frequency inside one band.

    Attributes
    ----------
    lo_cpr, hi_cpr : float
        Band edges in cycles per row.
    if_cpr : ndarray of shape (n_rows - 1,)
        Instantaneous frequency between rows i and i+1, cycles per row.
    significant : ndarray of bool, same shape
        Both rows' band amplitude passed the noise test and IF lies inside the band.
    """

    lo_cpr: float
    hi_cpr: float
    if_cpr: np.ndarray
    significant: np.ndarray

    @property
    def significant_fraction(self) -> float:
        """Fraction of rows whose band signal is significant (unitless)."""
        return float(self.significant.mean()) if self.significant.size else 0.0


@dataclass(frozen=True)
class PlaneAnalysis:
    """Band tracks of one plane along one axis, plus what was skipped."""

    n_rows: int
    n_blocks_used: int
    bands: tuple[BandTrack, ...]
    skipped: tuple[str, ...]

    @property
    def max_significant_fraction(self) -> float:
        """Largest significant fraction over all bands (0 when there are none)."""
        return max((b.significant_fraction for b in self.bands), default=0.0)


def band_centres_cpr(lo_cpr: float, hi_cpr: float) -> np.ndarray:
    """Log-spaced band centres covering [lo_cpr, hi_cpr]."""
    if hi_cpr <= lo_cpr:
        return np.zeros(0)
    n = int(math.ceil(math.log(hi_cpr / lo_cpr) / math.log(BAND_STEP_RATIO))) + 1
    return lo_cpr * BAND_STEP_RATIO ** np.arange(n)


def _usable_blocks(profiles: np.ndarray, full_scale: float) -> tuple[np.ndarray, list[str]]:
    means = profiles.mean(axis=1)
    black = means < 0.02 * full_scale
    saturated = means > 0.98 * full_scale
    spread = profiles.max(axis=1) - profiles.min(axis=1)
    flat = spread <= 1e-6 * max(full_scale, 1e-12)
    keep = ~(black | saturated | flat)
    notes = []
    for name, mask in (("black", black), ("saturated", saturated), ("flat", flat & ~black &
                                                                        ~saturated)):
        if mask.any():
            notes.append(f"{int(mask.sum())} {name} column block(s)")
    return keep, notes


def analyse_profiles(profiles: np.ndarray, *, full_scale: float, band_cpr: tuple[float, float],
                     trend_sigma_rows: float, kappa: float) -> PlaneAnalysis:
    """Band tracks for block row profiles of one plane.

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
    kappa : float
        Significance threshold on |z|^2 / noise power (ln of 1 / false-pass probability).
    """
    n_blocks, n_rows = profiles.shape
    keep, skipped = _usable_blocks(profiles, full_scale)
    if keep.sum() < 2:
        return PlaneAnalysis(n_rows, int(keep.sum()), (), tuple(skipped) +
                             ("fewer than 2 usable column blocks: no coherence test possible",))
    contrast, _ = detrend_profiles(profiles[keep], sigma_rows=trend_sigma_rows)
    nb = contrast.shape[0]
    nfft = next_fast_len(2 * n_rows, real=True)
    taper = _tukey(n_rows, 0.1)
    blocks = rfft(contrast * taper, nfft, axis=-1)
    freqs = np.arange(blocks.shape[1]) / nfft
    lo, hi = band_cpr
    in_band = (freqs >= lo) & (freqs <= min(hi, 0.5))
    spec, gains = _common_part(blocks, in_band)
    resid = blocks - gains[:, None] * spec[None, :]
    # per-block noise PSD from the residual (nb - 1 degrees of freedom per bin), then the
    # noise of the gain-weighted common part
    noise = (np.abs(resid) ** 2).sum(axis=0) / ((nb - 1) * float((gains ** 2).sum()))
    noise = uniform_filter1d(noise, size=33, mode="nearest")
    for g in JPEG_GRID_CPR:
        spec[np.abs(freqs - g) <= JPEG_MASK_REL * g] = 0.0
    hi = min(hi, 0.5 / BAND_HALF_RATIO)
    bands = []
    for c in band_centres_cpr(lo * BAND_HALF_RATIO, hi):
        b_lo, b_hi = c / BAND_HALF_RATIO, c * BAND_HALF_RATIO
        gain = _band_gain(freqs, b_lo, b_hi)
        if not gain.any():
            continue
        z = _analytic(spec * gain, nfft)[:n_rows]
        noise_pow = 4.0 * float((gain ** 2 * noise).sum()) / (nfft * n_rows)
        power = z.real ** 2 + z.imag ** 2
        strong = power > kappa * max(noise_pow, 1e-30) if noise_pow > 0 else np.zeros(n_rows, bool)
        inst = np.angle(z[1:] * np.conj(z[:-1])) / (2 * np.pi)
        sig = strong[1:] & strong[:-1] & (inst >= b_lo) & (inst <= b_hi)
        bands.append(BandTrack(float(b_lo), float(b_hi), inst, sig))
    return PlaneAnalysis(n_rows, nb, tuple(bands), tuple(skipped))


def _common_part(blocks: np.ndarray, in_band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Common spectrum of the column blocks and each block's gain on it (mean gain 1).

    Stripes are the same shape in every column block, but clipping, gamma and JPEG change
    their depth from block to block; fitting a gain per block (on the searched band only)
    keeps that depth difference out of the residual, which must hold only what the blocks do
    not share (texture, noise).
    """
    nb = blocks.shape[0]
    common = blocks.mean(axis=0)
    ref = common[in_band]
    energy = float(np.vdot(ref, ref).real)
    if energy <= 0:
        return common, np.ones(nb)
    gains = (blocks[:, in_band] @ np.conj(ref)).real / energy
    mean_gain = float(gains.mean())
    if not mean_gain > 0:
        return common, np.ones(nb)
    gains = np.clip(gains / mean_gain, 0.0, None)
    common = gains @ blocks / float(gains @ gains)
    return common, gains


def _tukey(n: int, alpha: float) -> np.ndarray:
    from scipy.signal.windows import tukey

    return tukey(n, alpha)


def _band_gain(freqs: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Raised-cosine band-pass in log frequency: flat in the middle, tapering 10% each side."""
    gain = np.zeros_like(freqs)
    pos = freqs > 0
    lf = np.full_like(freqs, -np.inf)
    lf[pos] = np.log(freqs[pos])
    a, b = math.log(lo), math.log(hi)
    edge = 0.1 * (b - a)
    inside = (lf >= a) & (lf <= b)
    gain[inside] = 1.0
    rise = inside & (lf < a + edge)
    gain[rise] = 0.5 - 0.5 * np.cos(np.pi * (lf[rise] - a) / edge)
    fall = inside & (lf > b - edge)
    gain[fall] = 0.5 - 0.5 * np.cos(np.pi * (b - lf[fall]) / edge)
    return gain


def _analytic(one_sided: np.ndarray, nfft: int) -> np.ndarray:
    """Analytic signal from a one-sided (rfft) spectrum with no DC or Nyquist content."""
    full = np.zeros(nfft, dtype=complex)
    full[: one_sided.size] = 2.0 * one_sided
    full[0] = 0.0
    return np.fft.ifft(full)

