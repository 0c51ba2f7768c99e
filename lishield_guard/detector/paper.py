"""The paper's Algorithm 1 (LiShield Sec. 5), implemented literally as the baseline profile."""

from __future__ import annotations

import math

import numpy as np

from lishield_guard.config import DetectorConfig, Policy
from lishield_guard.spec import BarcodeSpec

__all__ = ["block_peaks_hz", "column_row_means", "count_ratio_matches", "required_matches",
           "run_paper"]


def _cuts(n: int, k: int) -> np.ndarray:
    return np.linspace(0, n, k + 1).round().astype(int)


def column_row_means(plane: np.ndarray, config: DetectorConfig) -> np.ndarray:
    """Mean of every row within each of the n_bc column blocks, shape (n_bc, n_rows), float64:
    a block's row means are its rows' slice of these."""
    col_cuts = _cuts(plane.shape[1], config.paper.n_block_cols)
    return np.array([plane[:, c0:c1].mean(axis=1, dtype=np.float64) if c1 > c0
                     else np.full(plane.shape[0], np.nan)
                     for c0, c1 in zip(col_cuts[:-1], col_cuts[1:], strict=True)])


def block_peaks_hz(plane: np.ndarray, config: DetectorConfig,
                   row_means: np.ndarray | None = None) -> np.ndarray:
    """Unique peak frequencies (Hz at the nominal row rate) over all n_br x n_bc blocks.

    For every block: mean of each row, linear detrend, FFT magnitude, then the ``max_peaks``
    (M_p) largest local maxima with ``band_hz[0] <= f <= band_hz[1]``, where bin k of a block
    of L rows is at k * nominal_row_rate_hz / L Hz. ``row_means``: `column_row_means` of the
    plane, when already computed.
    """
    from scipy.signal import detrend

    n_rows, n_cols = plane.shape
    lo_hz, hi_hz = config.paper.band_hz
    row_cuts = _cuts(n_rows, config.paper.n_block_rows)
    col_cuts = _cuts(n_cols, config.paper.n_block_cols)
    means = column_row_means(plane, config) if row_means is None else row_means
    found: set[float] = set()
    for r0, r1 in zip(row_cuts[:-1], row_cuts[1:], strict=True):
        length = int(r1 - r0)
        if length < 4:
            continue
        freqs = np.fft.rfftfreq(length, d=1.0 / config.paper.nominal_row_rate_hz)
        in_band = (freqs >= lo_hz) & (freqs <= hi_hz)
        if not in_band.any():
            continue
        for b, (c0, c1) in enumerate(zip(col_cuts[:-1], col_cuts[1:], strict=True)):
            if c1 <= c0:
                continue
            s_r = means[b, r0:r1]
            d = detrend(s_r)
            if not np.abs(d).max(initial=0.0) > 1e-9 * max(np.abs(s_r).max(initial=0.0), 1e-12):
                continue  # a flat block: its "peaks" would be floating-point round-off
            mag = np.abs(np.fft.rfft(d))
            peak = np.zeros_like(in_band)
            peak[1:-1] = (mag[1:-1] >= mag[:-2]) & (mag[1:-1] >= mag[2:])
            cand = np.flatnonzero(peak & in_band & (mag > 0))
            if cand.size == 0:
                continue
            top = cand[np.argsort(mag[cand])[::-1][: config.paper.max_peaks]]
            found.update(float(f) for f in freqs[top])
    return np.array(sorted(found), dtype=float)


def count_ratio_matches(freqs_hz: np.ndarray, ratio_set: np.ndarray, ratio_tol: float) -> int:
    """m_b: how many pairwise ratios f_i / f_j (f_i > f_j) lie within ratio_tol of S_b."""
    f = np.asarray(freqs_hz, dtype=float)
    if f.size < 2 or ratio_set.size == 0:
        return 0
    i, j = np.triu_indices(f.size, k=1)
    ratios = np.maximum(f[i], f[j]) / np.minimum(f[i], f[j])
    near = np.abs(ratios[:, None] - ratio_set[None, :]) <= ratio_tol
    return int(near.any(axis=1).sum())


def required_matches(spec: BarcodeSpec, config: DetectorConfig) -> int:
    """M_b = ceil(gamma * M_R + M_att), with M_R the number of tone pairs of the spec."""
    n = len(spec.all_freqs_hz)
    m_r = n * (n - 1) // 2
    return int(math.ceil(config.paper.gamma * m_r + config.paper.m_att - 1e-9))


def run_paper(planes: dict[str, np.ndarray], policies: tuple[Policy, ...],
              config: DetectorConfig, row_means: dict[str, np.ndarray] | None = None) -> dict:
    """Algorithm 1 over the given planes (luma, or R/G/B); returns the verdict fields.

    Frequencies of every plane and block are pooled (within and across colour channels), as
    the paper does; each policy spec is tested with its own S_b and M_b. ``row_means``: each
    plane's `column_row_means`, when already computed.
    """
    pooled = [block_peaks_hz(p, config, None if row_means is None else row_means[k])
              for k, p in planes.items()]
    freqs = np.unique(np.concatenate(pooled)) if pooled else np.zeros(0)
    best = {"protected": False, "policy": None, "matches": 0, "required": 0, "spec": None,
            "margin": -math.inf}
    for policy in policies:
        for spec in policy.specs:
            m_b = count_ratio_matches(freqs, spec.ratio_values(), config.paper.ratio_tol)
            need = required_matches(spec, config)
            margin = m_b - need
            if margin > best["margin"]:
                best = {"protected": m_b >= need, "policy": policy.id if m_b >= need else None,
                        "matches": m_b, "required": need, "spec": spec.name, "margin": margin}
    evidence = {"frequencies_hz": [round(float(f), 3) for f in freqs],
                "planes": list(planes), "best_spec": best["spec"],
                "blocks": config.paper.n_block_rows * config.paper.n_block_cols}
    return {**best, "evidence": evidence}
