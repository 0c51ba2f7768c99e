"""The figure of a default-profile (learned) verdict: what the network saw and what decided.

Three panels, rebuilt from the image and the verdict's evidence with the detector's own
functions (`detector.decision.measure`): the logit of every window against the threshold, the
deciding window's whitened coherent spectrum on the log-frequency grid with the best-fitting
spec's tones marked, and the deciding column range's row profile (log, high-
passed), so a person can see the stripes the network scored. matplotlib is used through its
object-oriented API only (threads of the service).
"""

from __future__ import annotations

import textwrap

import numpy as np

__all__ = ["learned_caption", "learned_figure"]

FIGSIZE_IN = (11.0, 9.5)
DPI = 100


def learned_caption(verdict) -> str:
    """What `learned_figure` shows, in words."""
    lead = ("the window that decided" if verdict.protected else "the highest-scoring window")
    return ("Top: the network's logit for every window (axis and row range down, column range "
            "across); crosses mark those at or above the calibrated threshold. Middle: "
            f"{lead}'s whitened coherent spectrum (luma and the "
            "colour planes) on the log-frequency axis, with the tones of the configured spec "
            "that explains it best. Bottom: that column range's row profile (log, high-passed)"
            ": the stripes themselves.")


def learned_figure(source, verdict, config):
    """Build the figure of one default-profile verdict (see the module docstring).

    Parameters
    ----------
    source : bytes, str, Path or ndarray
        The image the verdict was computed on.
    verdict : Verdict
        A verdict of the default profile (``evidence["stage"] == "learned"``).
    config : AppConfig
        The config of the detection.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    from lishield_guard.detector.decision import measure
    from lishield_guard.detector.pipeline import decode_for
    from lishield_guard.detector.spectra import (
        CHANNELS,
        COL_WINDOWS,
        ROW_WINDOWS,
        block_profiles_rgb,
        freq_grid_cpr,
    )

    ev = verdict.evidence or {}
    decoded = decode_for(source, config)
    pixels = decoded.rgb() if decoded.is_color else decoded.luma
    rec = measure(pixels, config.detector)
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    ax_units, ax_spec, ax_rows = fig.subplots(3, 1, height_ratios=[1.0, 1.4, 1.1])
    colour = "crimson" if verdict.protected else "seagreen"
    title = (f"PROTECTED: policy {verdict.policy!r}" if verdict.protected
             else "CLEAN: no policy barcode found")
    fig.suptitle(title, fontsize=14, fontweight="bold", color=colour)
    thr = config.detector.learned.threshold_logit
    n_c = len(COL_WINDOWS)
    if not len(rec.logits):
        ax_units.text(0.5, 0.5, rec.undetermined or "nothing analysed", ha="center")
        return fig
    grid_logits = rec.logits.reshape(-1, n_c)  # (axes x row windows, column windows)
    im = ax_units.imshow(grid_logits, aspect="auto", cmap="magma", interpolation="nearest")
    fig.colorbar(im, ax=ax_units, label="logit")
    hits = np.argwhere(grid_logits >= thr)
    ax_units.scatter(hits[:, 1], hits[:, 0], marker="x", color="cyan", s=20,
                     label=f"logit >= threshold {thr:.2f}")
    row_labels = [f"{ax}, lines {a:.0%}-{z:.0%}" for ax in dict.fromkeys(rec.spectra.axes)
                  for a, z in ROW_WINDOWS]
    ax_units.set_yticks(range(len(row_labels)), row_labels, fontsize=6)
    ax_units.set_xticks(range(n_c), [f"{a:.0%}-{z:.0%}" for a, z in COL_WINDOWS], fontsize=7)
    ax_units.set_xlabel("column range across the lines")
    if len(hits):
        ax_units.legend(fontsize=8, loc="upper right")
    ax_units.set_title(textwrap.fill(str(ev.get("reason", "")), 140), loc="left", fontsize=8)

    w = rec.best
    col = w % n_c
    grid = freq_grid_cpr()
    x = rec.spectra.x[w]
    for name, c in (("coh_L", "tab:purple"), ("coh_R", "tab:red"), ("coh_G", "tab:green"),
                    ("coh_B", "tab:blue")):
        ax_spec.plot(grid, x[CHANNELS.index(name)], color=c, lw=1.4 if name == "coh_L" else 0.7,
                     label=name.replace("coh_", "coherent "))
    fit = ev.get("spec_fit") or {}
    for ch, tones in (fit.get("tones_cpr") or {}).items():
        for t in tones:
            ax_spec.axvline(t, color={"W": "k", "R": "tab:red", "G": "tab:green",
                                      "B": "tab:blue"}.get(ch, "k"), ls=":", lw=1)
    ax_spec.set_xscale("log")
    ax_spec.set_xlabel("cycles per analysed row (log scale: the unknown row rate is a shift)")
    ax_spec.set_ylabel("ln(power / noise floor)")
    ax_spec.legend(fontsize=8, ncol=4)
    if fit:
        ax_spec.set_title(f"dotted: tones of {fit.get('spec')} at its best scale "
                          f"(template score {fit.get('score')})", loc="left", fontsize=9)

    axis = 0 if rec.spectra.axes[w] == "rows" else 1
    prof = block_profiles_rgb(pixels, axes=(axis,))[axis]
    a, z = COL_WINDOWS[col]
    blocks = prof.shape[1]
    seg = np.log(np.maximum(prof[:, int(a * blocks):int(z * blocks)].mean(axis=(0, 1)), 1e-3))
    k = max(3, len(seg) // 40) | 1
    trend = np.convolve(np.pad(seg, k // 2, mode="edge"), np.ones(k) / k, mode="valid")
    ax_rows.plot(seg - trend, color="tab:purple", lw=0.8)
    ax_rows.set_xlabel(f"{'row' if axis == 0 else 'column'} (as decoded)")
    ax_rows.set_ylabel("ln(row mean), high-passed")
    ax_rows.set_title(f"row profile of {rec.spectra.axes[w]}, column range {a:.0%}-{z:.0%}",
                      loc="left", fontsize=9)
    return fig
