"""The figure of a default-profile (learned) verdict: what the network saw and what decided.

Three panels, drawn from the record the decision used (`profiles.learned.LearnedEvidence`:
no second decode, measure or rule): the logit of every window against the threshold, the
deciding window's whitened coherent spectrum on the log-frequency grid with the named spec's
tones marked, and the deciding column range's spectrum in each quarter of the rows (a
barcode's tones take turns from slot to slot; a steady light's stay). matplotlib is used
through its object-oriented API only (threads of the service).
"""

from __future__ import annotations

import textwrap

import numpy as np

from lishield_guard.figure_text import DPI, FIGSIZE_IN
from lishield_guard.verdict import verdict_title

__all__ = ["learned_caption", "learned_figure"]

CHANNEL_COLOURS = {"W": "k", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}
QUARTERS = ((0.0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.0))  # row windows of the bottom panel


def learned_caption(flagged: bool) -> str:
    """What `learned_figure` shows, in words (``flagged``: the rule's answer)."""
    lead = "the window that decided" if flagged else "the highest-scoring window"
    return ("Top: the network's logit for every window (axis and row range down, column range "
            "across); crosses mark those at or above the calibrated threshold. Middle: "
            f"{lead}'s whitened coherent spectrum (luma and the "
            "colour planes) on the log-frequency axis, with the tones of the configured spec "
            "that explains it best. Bottom: the same column range's luma spectrum in each "
            "quarter of the rows: a barcode's tones take turns, a steady light's stay.")


def learned_figure(verdict, ev):
    """Build the figure of one default-profile verdict (see the module docstring).

    Parameters
    ----------
    verdict : Verdict
        A verdict of the default profile (or of a clip, for its best frame).
    ev : LearnedEvidence
        Its evidence: the record the decision used, the threshold, the named spec's fit.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    from lishield_guard.detector.spectra import CHANNELS, COL_WINDOWS, ROW_WINDOWS, freq_grid_cpr

    rec = ev.record
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    ax_units, ax_spec, ax_rows = fig.subplots(3, 1, height_ratios=[1.0, 1.4, 1.1])
    fig.suptitle(verdict_title(verdict), fontsize=14, fontweight="bold",
                 color="crimson" if verdict.protected else "seagreen")
    thr = ev.threshold_logit
    n_c = len(COL_WINDOWS)
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
    ax_units.set_title(textwrap.fill(ev.reason, 140), loc="left", fontsize=8)

    w = rec.best
    grid = freq_grid_cpr()
    x = rec.spectra.x[w]
    for name, c in (("coh_L", "tab:purple"), ("coh_R", "tab:red"), ("coh_G", "tab:green"),
                    ("coh_B", "tab:blue")):
        ax_spec.plot(grid, x[CHANNELS.index(name)], color=c, lw=1.4 if name == "coh_L" else 0.7,
                     label=name.replace("coh_", "coherent "))
    fit = ev.spec_fit
    if fit is not None:
        for ch, tones in fit.tones_cpr.items():
            for t in tones:
                ax_spec.axvline(t, color=CHANNEL_COLOURS.get(ch, "k"), ls=":", lw=1)
        ax_spec.set_title(f"dotted: tones of {fit.spec} at its best scale "
                          f"(template score {round(fit.score, 3)})", loc="left", fontsize=9)
    ax_spec.set_xscale("log")
    ax_spec.set_xlabel("cycles per analysed row (log scale: the unknown row rate is a shift)")
    ax_spec.set_ylabel("ln(power / noise floor)")
    ax_spec.legend(fontsize=8, ncol=4)

    axis, (c0, c1, _, _) = rec.spectra.axes[w], rec.spectra.windows[w]
    luma = CHANNELS.index("coh_L")
    for q, (r0, r1) in enumerate(QUARTERS):
        k = next((i for i, (a, win) in enumerate(zip(rec.spectra.axes, rec.spectra.windows,
                                                     strict=True))
                  if a == axis and win == (c0, c1, r0, r1)), None)
        if k is not None:
            ax_rows.plot(grid, rec.spectra.x[k][luma] + 4.0 * (len(QUARTERS) - 1 - q),
                         color=f"C{q}", lw=0.9, label=f"lines {r0:.0%}-{r1:.0%}")
    ax_rows.set_xscale("log")
    ax_rows.set_xlabel("cycles per analysed row")
    ax_rows.set_ylabel("ln(power / floor), offset by quarter")
    ax_rows.legend(fontsize=7, ncol=4, loc="upper left")
    ax_rows.set_title(f"{axis}, column range {c0:.0%}-{c1:.0%}: the coherent luma spectrum of "
                      f"each quarter of the lines", loc="left", fontsize=9)
    return fig
