"""Match a barcode spec's tones against band tracks at an unknown common scale (row time).

A tone f_n (Hz) appears at sigma * f_n cycles per row, with sigma = row time x downscale, the
same for every tone and channel. On a log-frequency axis the scale is a shift, so matching is a
1-D search over ln(sigma) inside its physical range: for each shift, the *occupancy* of a tone
is the fraction of rows whose significant instantaneous frequency lies within ``tone_rel_tol``
of sigma * f_n.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lishield_guard.config import DetectorConfig
from lishield_guard.spec import BarcodeSpec
from lishield_guard.spectrum import PlaneAnalysis

__all__ = ["SpecMatch", "match_spec", "scale_range_cpr_per_hz"]

LOG_BIN = 0.002  # histogram bin width in ln(cycles/row)


@dataclass(frozen=True)
class SpecMatch:
    """Best placement of one spec's tones on the band tracks.

    Attributes
    ----------
    spec : str
        Spec name.
    sigma_cpr_per_hz : float
        Fitted common scale (cycles per row per Hz = row time in s x downscale).
    occupancy : dict
        channel -> list of per-tone occupancies (fraction of rows), in tone order.
    matched : dict
        channel -> list of matched tone frequencies in Hz.
    n_matched : int
        Tones matched over all channels.
    purity : float
        Matched occupancy / significant fraction of the bands used (unitless).
    switches : int
        Changes from one matched tone to another down the rows (symbol timing evidence).
    protected : bool
        All decision rules hold.
    reason : str
        Why the rules hold or which one fails.
    """

    spec: str
    sigma_cpr_per_hz: float
    occupancy: dict
    matched: dict
    n_matched: int
    required: int
    purity: float
    switches: int
    protected: bool
    reason: str

    @property
    def score(self) -> float:
        """Evidence strength in [0, 1]: purity times the fraction of required tones found."""
        if self.required <= 0:
            return 0.0
        return float(min(1.0, self.n_matched / self.required) * min(1.0, self.purity))

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence."""
        return {"spec": self.spec, "sigma_cpr_per_hz": self.sigma_cpr_per_hz,
                "row_rate_hz_if_not_resized": (1.0 / self.sigma_cpr_per_hz
                                               if self.sigma_cpr_per_hz > 0 else None),
                "occupancy": {c: [round(o, 4) for o in v] for c, v in self.occupancy.items()},
                "matched_hz": self.matched, "n_matched": self.n_matched,
                "required": self.required, "purity": round(self.purity, 4),
                "switches": self.switches, "reason": self.reason}


def scale_range_cpr_per_hz(config: DetectorConfig) -> tuple[float, float]:
    """Physically possible sigma: [1 / max_row_rate_hz, max_downscale / min_row_rate_hz]."""
    return 1.0 / config.max_row_rate_hz, config.max_downscale / config.min_row_rate_hz


def _histograms(analysis: PlaneAnalysis, grid_lo: float, n_bins: int) -> np.ndarray:
    """Cumulative log-frequency histograms of significant IF, shape (n_bands, n_bins + 1)."""
    out = np.zeros((len(analysis.bands), n_bins + 1))
    for k, band in enumerate(analysis.bands):
        f = band.if_cpr[band.significant]
        if f.size == 0:
            continue
        idx = np.floor((np.log(f) - grid_lo) / LOG_BIN).astype(int)
        idx = idx[(idx >= 0) & (idx < n_bins)]
        out[k, 1:] = np.cumsum(np.bincount(idx, minlength=n_bins))
    return out / max(analysis.n_rows - 1, 1)


def match_spec(spec: BarcodeSpec, planes: dict[str, PlaneAnalysis],
               config: DetectorConfig) -> SpecMatch:
    """Best scale and tone occupancies of ``spec`` on the band tracks of its channels' planes.

    ``planes`` maps channel name (``W``, ``R``, ``G``, ``B``) to the analysis of the plane
    that carries it (luma for ``W``; a colour plane, or luma for a gray image).
    """
    s_lo, s_hi = scale_range_cpr_per_hz(config)
    tol = math.log1p(config.tone_rel_tol)
    tones = {c: np.log(np.array(fs)) for c, fs in spec.channels}
    all_lo = min(t.min() for t in tones.values())
    all_hi = max(t.max() for t in tones.values())
    grid_lo = math.log(s_lo) + all_lo - 2 * tol
    grid_hi = math.log(s_hi) + all_hi + 2 * tol
    n_bins = int(math.ceil((grid_hi - grid_lo) / LOG_BIN))
    shifts = np.arange(math.log(s_lo), math.log(s_hi) + LOG_BIN, LOG_BIN)
    rgb = spec.is_rgb
    need = config.min_tones_rgb if rgb else config.min_tones

    total_occ = np.zeros(shifts.size)
    n_hit = np.zeros(shifts.size, dtype=int)
    ch_hit = np.zeros(shifts.size, dtype=int)
    sig_used = np.zeros(shifts.size)
    per_channel: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for c, logs in tones.items():
        analysis = planes[c]
        if not analysis.bands:
            continue
        cum = _histograms(analysis, grid_lo, n_bins)
        los = np.array([b.lo_cpr for b in analysis.bands])
        his = np.array([b.hi_cpr for b in analysis.bands])
        centre = np.log(np.sqrt(los * his))
        # band per shift: the one whose centre is nearest the tones' centre, if it holds them
        mid = shifts + 0.5 * (logs.min() + logs.max())
        band = np.abs(mid[:, None] - centre[None, :]).argmin(axis=1)
        fits = (np.log(los[band]) <= shifts + logs.min() - tol) & (
            np.log(his[band]) >= shifts + logs.max() + tol)
        occ = np.zeros((shifts.size, logs.size))
        for n, lt in enumerate(logs):
            a = np.clip(np.floor((shifts + lt - tol - grid_lo) / LOG_BIN).astype(int), 0, n_bins)
            b = np.clip(np.floor((shifts + lt + tol - grid_lo) / LOG_BIN).astype(int) + 1, 0,
                        n_bins)
            occ[:, n] = cum[band, b] - cum[band, a]
        occ[~fits] = 0.0
        sig = np.array([bd.significant_fraction for bd in analysis.bands])[band] * fits
        hit = (occ >= config.min_occupancy) & (occ <= config.max_occupancy)
        total_occ += (occ * hit).sum(axis=1)
        n_hit += hit.sum(axis=1)
        ch_hit += hit.any(axis=1)
        sig_used += sig
        per_channel[c] = (occ, hit, band)

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
                                             hit[best], config.tone_rel_tol))
    switches = max((_switches(lab) for lab in labels_by_channel), default=0)
    n_matched = int(n_hit[best])
    p = float(min(purity[best], 1.0))
    if n_matched < need:
        reason = f"{n_matched} tone(s) found, {need} needed"
    elif rgb and ch_hit[best] < 2:
        reason = "RGB barcode tones found in only one colour channel"
    elif p < config.min_purity:
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


def _labels(analysis: PlaneAnalysis, band: int, sigma: float, freqs, hit: np.ndarray,
            rel_tol: float) -> np.ndarray:
    """Per-row index of the matched tone the IF sits on (-1 for none)."""
    track = analysis.bands[band]
    lab = np.full(track.if_cpr.size, -1)
    for n, (f, h) in enumerate(zip(freqs, hit, strict=True)):
        if not h:
            continue
        on = track.significant & (np.abs(track.if_cpr / (sigma * f) - 1.0) <= rel_tol)
        lab[on] = n
    return lab


def _switches(labels: np.ndarray) -> int:
    """How often the assigned tone changes down the rows, ignoring unassigned rows."""
    seq = labels[labels >= 0]
    if seq.size < 2:
        return 0
    return int((np.diff(seq) != 0).sum())
