"""Figures that need no record: a verdict's reason and numbers, an undetermined image's preview.

The other figures (`plot`, `figure_learned`, `video.figure`) share the panel of words and the
sizes defined here. matplotlib is imported lazily and used through its object-oriented API
only (service threads); nothing of the package is imported, so the verdict module itself can
draw these.
"""

from __future__ import annotations

import textwrap

import numpy as np

__all__ = ["DPI", "FIGSIZE_IN", "STATUS_COLOURS", "text_figure", "text_panel",
           "undetermined_figure"]

FIGSIZE_IN = (11.0, 9.5)
DPI = 100
STATUS_COLOURS = {"protected": "darkred", "clean": "darkgreen", "undetermined": "darkorange"}


def text_panel(ax, reason: str, lines: list[str], footer: str) -> None:
    """The reason, further lines and a footer, wrapped, in monospace, on a bare axis."""
    ax.axis("off")
    text = ["Reason: " + reason, *lines, footer]
    wrapped = "\n".join(textwrap.fill(t, 125, subsequent_indent="    ") for t in text)
    ax.text(0.0, 1.0, wrapped, va="top", ha="left", fontsize=8.5, family="monospace",
            transform=ax.transAxes)


def text_figure(title: str, status: str, reason: str, footer: str):
    """A figure of words only: the title, the reason and a footer (evidence without a record)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIGSIZE_IN[0], 3.0), dpi=DPI, layout="constrained")
    fig.suptitle(title, fontsize=14, fontweight="bold",
                 color=STATUS_COLOURS.get(status, "darkorange"))
    text_panel(fig.subplots(), reason, [], footer)
    return fig


def undetermined_figure(title: str, preview: np.ndarray | None, looked_at: str, reason: str,
                        skipped: tuple[str, ...]):
    """An undetermined verdict's figure: the image as decoded (its preview) and the reason,
    instead of empty axes."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIGSIZE_IN[0], 5.0), dpi=DPI, layout="constrained")
    ax_img, ax_text = fig.subplots(1, 2, width_ratios=[1.0, 1.6])
    fig.suptitle(title, fontsize=14, fontweight="bold", color=STATUS_COLOURS["undetermined"])
    if preview is not None:
        ax_img.imshow(preview, cmap="gray", vmin=0,
                      vmax=255 if preview.dtype == np.uint8 else None,
                      interpolation="nearest", aspect="auto")
        ax_img.set_title(f"the image as analysed: {looked_at}, values "
                         f"{float(preview.min()):g}-{float(preview.max()):g}",
                         loc="left", fontsize=9)
    else:
        ax_img.text(0.5, 0.5, looked_at, ha="center", va="center", wrap=True)
    ax_img.set_xticks([])
    ax_img.set_yticks([])
    text = ["The detector could not look at this image; it is not clean.",
            "", "Reason: " + (reason or "(no reason given)")]
    if skipped:
        text += ["", "Skipped: " + "; ".join(skipped)]
    ax_text.axis("off")
    ax_text.text(0.0, 1.0, "\n".join(textwrap.fill(t, 70) for t in text), va="top",
                 ha="left", fontsize=10, family="monospace", transform=ax_text.transAxes)
    return fig
