"""Match a barcode spec's tones against band tracks at an unknown common scale (row time).

A tone f_n (Hz) appears at sigma * f_n cycles per row, with sigma = row time x downscale, the
same for every tone and channel. On a log-frequency axis the scale is a shift, so matching is a
1-D search over ln(sigma) inside its physical range: for each shift, the *occupancy* of a tone
is the fraction of frames (short windows down the rows) whose significant peak lies within
``tone_rel_tol`` of sigma * f_n.
"""

from __future__ import annotations

import math

import numpy as np

from lishield_guard.config import DetectorConfig
from lishield_guard.detector.results import SpecMatch
from lishield_guard.detector.tracks import PlaneAnalysis
from lishield_guard.spec import BarcodeSpec

__all__ = ["match_spec", "scale_range_cpr_per_hz"]

LOG_BIN = 0.002  # histogram bin width in ln(cycles/row)
MIN_FRAMES = 2  # a tone seen in one frame only is not evidence
RESOLVE_CYCLES = 1.0  # tone spacing x window length needed to tell two tones apart


def scale_range_cpr_per_hz(config: DetectorConfig) -> tuple[float, float]:
    """Physically possible sigma: [1 / max_row_rate_hz, max_downscale / min_row_rate_hz]."""
    pr = config.profiles
    return 1.0 / pr.max_row_rate_hz, pr.max_downscale / pr.min_row_rate_hz


def _histograms(analysis: PlaneAnalysis, grid_lo: float, n_bins: int) -> np.ndarray:
    """Cumulative log-frequency histograms of significant peaks, shape (n_tracks, n_bins + 1).

    Counts are divided by each track's frame count, so values are fractions of the frame.
    """
    out = np.zeros((len(analysis.tracks), n_bins + 1))
    for k, track in enumerate(analysis.tracks):
        f = track.freq_cpr[track.significant]
        if f.size:
            idx = np.floor((np.log(f) - grid_lo) / LOG_BIN).astype(int)
            idx = idx[(idx >= 0) & (idx < n_bins)]
            out[k, 1:] = np.cumsum(np.bincount(idx, minlength=n_bins)) / track.freq_cpr.size
    return out


def match_spec(spec: BarcodeSpec, planes: dict[str, PlaneAnalysis],
               config: DetectorConfig) -> SpecMatch:
    """Best scale and tone occupancies of ``spec`` on the band tracks of its channels' planes.

    ``planes`` maps channel name (``W``, ``R``, ``G``, ``B``) to the analysis of the plane
    that carries it (luma for ``W``; a colour plane, or luma for a gray image).
    """
    s_lo, s_hi = scale_range_cpr_per_hz(config)
    tol = math.log1p(config.tones.rel_tol)
    tones = {c: np.log(np.array(fs)) for c, fs in spec.channels}
    all_lo = min(t.min() for t in tones.values())
    all_hi = max(t.max() for t in tones.values())
    grid_lo = math.log(s_lo) + all_lo - 2 * tol
    grid_hi = math.log(s_hi) + all_hi + 2 * tol
    n_bins = int(math.ceil((grid_hi - grid_lo) / LOG_BIN))
    shifts = np.arange(math.log(s_lo), math.log(s_hi) + LOG_BIN, LOG_BIN)
    rgb = spec.is_rgb
    need = config.tones.min_tones_rgb if rgb else config.tones.min_tones

    total_occ = np.zeros(shifts.size)
    n_hit = np.zeros(shifts.size, dtype=int)
    ch_hit = np.zeros(shifts.size, dtype=int)
    sig_used = np.zeros(shifts.size)
    per_channel: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for c, logs in tones.items():
        analysis = planes[c]
        if not analysis.tracks:
            continue
        cum = _histograms(analysis, grid_lo, n_bins)
        los = np.log([t.lo_cpr for t in analysis.tracks])
        his = np.log([t.hi_cpr for t in analysis.tracks])
        sigf = np.array([t.significant_fraction for t in analysis.tracks])
        # occupancy of every tone, for every track and shift: (n_tracks, n_shifts, n_tones)
        occ = np.zeros((len(analysis.tracks), shifts.size, logs.size))
        for n, lt in enumerate(logs):
            a = np.clip(np.floor((shifts + lt - tol - grid_lo) / LOG_BIN).astype(int), 0, n_bins)
            b = np.clip(np.floor((shifts + lt + tol - grid_lo) / LOG_BIN).astype(int) + 1, 0,
                        n_bins)
            occ[:, :, n] = cum[:, b] - cum[:, a]
        fits = (los[:, None] <= shifts[None, :] + logs.min() - tol) & (
            his[:, None] >= shifts[None, :] + logs.max() + tol)
        # a window resolves two tones only when they differ by >= RESOLVE_CYCLES per window;
        # shorter windows would scatter one steady tone over several neighbouring tones
        if logs.size > 1:
            spacing_cpr = np.exp(shifts) * float(np.diff(np.exp(logs)).min())
            windows = np.array([t.window_rows for t in analysis.tracks], dtype=float)
            fits &= windows[:, None] * spacing_cpr[None, :] >= RESOLVE_CYCLES
        occ[~fits] = 0.0
        n_frames = np.array([t.freq_cpr.size for t in analysis.tracks], dtype=float)
        floor = np.maximum(config.tones.min_occupancy, MIN_FRAMES / n_frames)[:, None, None]
        hit_all = (occ >= floor - 1e-12) & (occ <= config.tones.max_occupancy)
        # per shift, the window length that explains the most: most tones, then occupancy
        track_rank = hit_all.sum(axis=2) * 10.0 + (occ * hit_all).sum(axis=2)
        track = track_rank.argmax(axis=0)
        cols = np.arange(shifts.size)
        occ_b, hit = occ[track, cols], hit_all[track, cols]
        total_occ += (occ_b * hit).sum(axis=1)
        n_hit += hit.sum(axis=1)
        ch_hit += hit.any(axis=1)
        sig_used += sigf[track] * fits[track, cols]
        per_channel[c] = (occ_b, hit, track)

    purity = np.divide(total_occ, sig_used, out=np.zeros_like(total_occ), where=sig_used > 0)
    # rank shifts: most tones, then most matched occupancy
    rank = n_hit * 10.0 + np.minimum(purity, 1.0) + total_occ
    best = int(rank.argmax())
    sigma = float(math.exp(shifts[best]))
    occupancy, matched = {}, {}
    labels_by_channel = []
    for c, (occ, hit, band) in per_channel.items():
        freqs = dict(spec.channels)[c]
        occupancy[c] = [float(o) for o in occ[best]]
        matched[c] = [float(f) for f, h in zip(freqs, hit[best], strict=True) if h]
        if hit[best].sum() >= 1:
            labels_by_channel.append(_labels(planes[c], int(band[best]), sigma, freqs,
                                             hit[best], config.tones.rel_tol))
    switches = max((_switches(lab) for lab in labels_by_channel), default=0)
    n_matched = int(n_hit[best])
    p = float(min(purity[best], 1.0))
    if n_matched < need:
        reason = f"{n_matched} tone(s) found, {need} needed"
    elif rgb and ch_hit[best] < 2:
        reason = "RGB barcode tones found in only one colour channel"
    elif p < config.tones.min_purity:
        reason = f"matched tones explain {p:.2f} of the significant stripes < min_purity"
    elif switches < 1:
        reason = "tones never alternate down the rows (no symbol timing)"
    else:
        reason = (f"{n_matched} tone(s) alternate down the rows at a common scale, explaining "
                  f"{p:.2f} of the significant stripes")
        return SpecMatch(spec.name, sigma, occupancy, matched, n_matched, need, p, switches,
                         True, reason)
    return SpecMatch(spec.name, sigma, occupancy, matched, n_matched, need, p, switches, False,
                     reason)


def _labels(analysis: PlaneAnalysis, track_index: int, sigma: float, freqs, hit: np.ndarray,
            rel_tol: float) -> np.ndarray:
    """Per-frame index of the matched tone the stripes sit on (-1 for none)."""
    track = analysis.tracks[track_index]
    lab = np.full(track.freq_cpr.size, -1)
    for n, (f, h) in enumerate(zip(freqs, hit, strict=True)):
        if not h:
            continue
        on = track.significant & (np.abs(track.freq_cpr / (sigma * f) - 1.0) <= rel_tol)
        lab[on] = n
    return lab


def _switches(labels: np.ndarray) -> int:
    """How often the assigned tone changes down the rows, ignoring unassigned rows."""
    seq = labels[labels >= 0]
    if seq.size < 2:
        return 0
    return int((np.diff(seq) != 0).sum())
