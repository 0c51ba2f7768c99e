"""The figure of a default-profile (learned) verdict: what the network saw and what decided.

Three panels, drawn from the record the decision used (`profiles.learned.LearnedEvidence`:
no second decode, measure or rule): the logit of every axis and pyramid level against the
threshold; the deciding instance's whitened coherent spectrum on the log-frequency grid (over
the frames: mean and largest) with the named spec's tones marked; and its turn channels, how
the power at two frequencies comes and goes over the frames (a white barcode's tones take
turns from slot to slot, a dimmed lamp's harmonics stay). matplotlib is used through its
object-oriented API only (threads of the service).
"""

from __future__ import annotations

import textwrap

import numpy as np

from lishield_guard.figure_text import DPI, FIGSIZE_IN
from lishield_guard.verdict import verdict_title

__all__ = ["learned_caption", "learned_figure"]

CHANNEL_COLOURS = {"W": "k", "L": "k", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}


def learned_caption(flagged: bool) -> str:
    """What `learned_figure` shows, in words (``flagged``: the rule's answer)."""
    lead = "the instance that decided" if flagged else "the highest-scoring instance"
    return ("Top: the network's logit for every axis and pyramid level (frames of 64 to 2048 "
            "lines) against the calibrated threshold. Middle: "
            f"{lead}'s whitened coherent spectrum (luma averaged over the frames and at its "
            "largest, and the colour planes) on the log-frequency axis, with the tones of the "
            "configured spec that explains it best. Bottom: how the power at two frequencies "
            "comes and goes over the frames (blue: they take turns, as a barcode's tones do; "
            "red: together, as a lamp on part of the frame; white: steady, as a dimmed "
            "lamp's harmonics).")


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

    from lishield_guard.detector.decision import spectrum_view
    from lishield_guard.detector.tfinput import CHANNELS, FRAME_LINES, TURN_OFFSETS

    rec = ev.record
    inp = rec.spectra
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    ax_units, ax_spec, ax_turn = fig.subplots(3, 1, height_ratios=[0.9, 1.4, 1.1])
    fig.suptitle(verdict_title(verdict), fontsize=14, fontweight="bold",
                 color="crimson" if verdict.protected else "seagreen")
    thr = ev.threshold_logit
    labels = [f"{a}\n{FRAME_LINES << lv}" for a, lv in zip(inp.axes, inp.levels, strict=True)]
    colours = ["crimson" if z >= thr else "slategray" for z in rec.logits]
    ax_units.bar(range(len(rec.logits)), rec.logits, color=colours)
    ax_units.axhline(thr, color="k", ls="--", lw=1, label=f"threshold {thr:.2f}")
    ax_units.set_xticks(range(len(labels)), labels, fontsize=7)
    ax_units.set_xlabel("axis, and the frame length in lines (pyramid level)")
    ax_units.set_ylabel("logit")
    ax_units.legend(fontsize=8, loc="upper right")
    ax_units.set_title(textwrap.fill(ev.reason, 140), loc="left", fontsize=8)

    w = rec.best
    planes, grid = spectrum_view(inp, w)
    x = inp.x[w]
    ax_spec.plot(grid, x[CHANNELS.index("coh_max")], color="tab:purple", lw=0.8, ls="--",
                 label="luma, largest over the frames")
    for name in ("L", "R", "G", "B"):
        ax_spec.plot(grid, planes[name], color=CHANNEL_COLOURS[name] if name != "L"
                     else "tab:purple", lw=1.4 if name == "L" else 0.7,
                     label=("luma" if name == "L" else name) + ", mean over the frames")
    title = (f"stripes along {inp.axes[w]}, frames of {FRAME_LINES << inp.levels[w]} lines, "
             f"across {inp.windows[w][0]:.0%}-{inp.windows[w][1]:.0%}")
    fit = ev.spec_fit
    if fit is not None:
        for ch, tones in fit.tones_cpr.items():
            for t in tones:
                ax_spec.axvline(t, color=CHANNEL_COLOURS.get(ch, "k"), ls=":", lw=1)
        title += (f"; dotted: tones of {fit.spec} at its best scale (template score "
                  f"{round(fit.score, 3)})")
    ax_spec.set_title(title, loc="left", fontsize=9)
    ax_spec.set_xscale("log")
    ax_spec.set_xlabel("cycles per analysed row (log scale: the unknown row rate is a shift)")
    ax_spec.set_ylabel("ln(power / noise floor)")
    ax_spec.legend(fontsize=7, ncol=3)

    turns = np.stack([x[CHANNELS.index(f"turn_{d}")] for d in TURN_OFFSETS])
    lim = max(float(np.abs(turns).max()), 0.5)
    edges = np.concatenate([grid[:1] / 2 ** (1 / 48), np.sqrt(grid[1:] * grid[:-1]),
                            grid[-1:] * 2 ** (1 / 48)])
    im = ax_turn.pcolormesh(edges, np.arange(len(TURN_OFFSETS) + 1) - 0.5, turns,
                            cmap="coolwarm", vmin=-lim, vmax=lim, shading="flat")
    fig.colorbar(im, ax=ax_turn, label="ln co-occurrence")
    ax_turn.set_xscale("log")
    ax_turn.set_yticks(range(len(TURN_OFFSETS)),
                       [f"x{2 ** (d / 24):.3f}" for d in TURN_OFFSETS], fontsize=7)
    ax_turn.set_xlabel("cycles per analysed row of the lower frequency")
    ax_turn.set_ylabel("ratio of the higher")
    return fig
