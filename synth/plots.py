"""Diagnostic plot of one capture: LED waveform, row profile and its spectrum (matplotlib Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lishield_guard.camera import CameraModel, hz_to_cpr

__all__ = ["capture_plot", "row_profile"]

_COLOURS = {"W": "k", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}


def row_profile(frame: np.ndarray) -> np.ndarray:
    """Mean value of every row per channel, shape (n_rows, n_channels), float64."""
    f = np.asarray(frame)
    if f.ndim == 2:
        f = f[:, :, None]
    return f.mean(axis=1, dtype=np.float64)


def capture_plot(path: str | Path, *, light, camera: CameraModel, frame: np.ndarray,
                 start_s: float) -> Path:
    """Write a PNG with three panels: LED waveform, row profile, and its spectrum.

    Parameters
    ----------
    path : str or Path
        Output PNG.
    light : synth.light.SequenceLight
        The LED (``intensity`` is sampled only for drawing).
    camera : CameraModel
        Timing used for the capture (row time converts Hz to cycles per row).
    frame : ndarray of shape (n_rows, n_cols, 3)
        Sensor-oriented frame.
    start_s : float
        Exposure start of row 0, in seconds.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 9))
    # 1. waveform over two loops of the sequence (or the frame readout, if shorter)
    span_s = min(2 * getattr(light, "period_s", camera.readout_s), camera.readout_s + 1e-3)
    t = start_s + np.linspace(0.0, span_s, 4000)
    if hasattr(light, "intensity"):
        vals = light.intensity(t)
    else:
        dt = span_s / 4000
        vals = (light.cumulative(t + dt) - light.cumulative(t)) / dt
    chans = tuple(light.channels)
    for i, c in enumerate(chans):
        axes[0].step((t - start_s) * 1e3, vals[:, i] + 1.1 * i, where="post",
                     color=_COLOURS.get(c, "k"), lw=0.8, label=c)
    axes[0].set_xlabel("time from frame start (ms)")
    axes[0].set_ylabel("LED level (offset per channel)")
    axes[0].set_title(f"LED waveform; exposure {camera.exposure_s * 1e3:.3f} ms, "
                      f"row rate {camera.row_rate_hz / 1e3:.1f} kHz")
    axes[0].legend(loc="upper right")
    # 2. row profile
    prof = row_profile(frame)
    names = ("R", "G", "B") if prof.shape[1] == 3 else ("W",)
    for i, c in enumerate(names):
        axes[1].plot(prof[:, i], color=_COLOURS.get(c, "k"), lw=0.7, label=c)
    axes[1].set_xlabel("sensor row")
    axes[1].set_ylabel("mean value")
    axes[1].set_title("row profile")
    # 3. spectrum of the luma profile, in cycles per row, tones marked
    luma = prof.mean(axis=1)
    x = luma - np.polyval(np.polyfit(np.arange(luma.size), luma, 2), np.arange(luma.size))
    n_fft = 8 * int(2 ** np.ceil(np.log2(x.size)))
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size), n_fft)) ** 2
    f_cpr = np.fft.rfftfreq(n_fft)
    axes[2].semilogy(f_cpr, spec + 1e-12, lw=0.7, color="k")
    seq = getattr(light, "sequence", None)
    if seq is not None:
        for c, tones in seq.spec.channels:
            for f in tones:
                axes[2].axvline(hz_to_cpr(f, row_time_s=camera.row_time_s),
                                color=_COLOURS.get(c, "k"), ls="--", lw=0.8)
    top = 0.5
    if seq is not None:
        top = min(0.5, 3 * hz_to_cpr(seq.spec.all_freqs_hz[-1], row_time_s=camera.row_time_s))
    axes[2].set_xlim(0, top)
    axes[2].set_xlabel("cycles per row (dashed: barcode tones)")
    axes[2].set_ylabel("power")
    axes[2].set_title("spectrum of the detrended luma row profile")
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
