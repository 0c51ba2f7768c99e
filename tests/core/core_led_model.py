"""The LED model shared by core tests: integrated OOK barcode light per sensor row."""

from __future__ import annotations

import numpy as np

from lishield_guard.spec import BarcodeSpec


def row_waveform(spec: BarcodeSpec, *, row_time_s: float, n_rows: int, exposure_s: float,
                 switching_hz: float | None = None, t0_s: float = 0.0,
                 dt_s: float = 1e-6, phase: str = "restart") -> dict[str, np.ndarray]:
    """Per-row integrated LED intensity (0..1) per channel.

    ``phase="restart"`` restarts each tone ON at its slot start (spec.py); ``"free"`` lets
    every tone's timer run from t = 0 without ever restarting (f_n t mod 1), so patterns do
    not repeat exactly unless every f_n M / f_B is an integer.
    """
    f_b = switching_hz or spec.f_b_hz
    slot = 1.0 / f_b
    t = np.arange(0.0, t0_s + n_rows * row_time_s + exposure_s + 1e-3, dt_s)
    k = (np.floor(t / slot).astype(int)) % spec.n_tones
    ts = t - np.floor(t / slot) * slot
    order = np.array(spec.slot_order())
    starts = t0_s + np.arange(n_rows) * row_time_s
    i0 = np.round(starts / dt_s).astype(int)
    i1 = np.round((starts + exposure_s) / dt_s).astype(int)
    out = {}
    for c, fs in spec.channels:
        f = np.array(fs)[order[k]]
        on = (((ts if phase == "restart" else t) * f) % 1.0) < spec.duty
        cum = np.concatenate([[0.0], np.cumsum(on * dt_s)])
        out[c] = (cum[i1] - cum[i0]) / exposure_s
    return out
