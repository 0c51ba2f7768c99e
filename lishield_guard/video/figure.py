"""The figure of a video verdict: the deciding frame and every screened frame's score.

Two panels, drawn from the clip's record (`video.screen.VideoEvidence`: nothing is decoded
again): the frame with the largest logit as the screen decoded it (the stripes a person can
check), and the logit of every screened frame in screening order, coloured by run, against
the clip threshold, with the clip logit after each run. matplotlib is used through its
object-oriented API only (service threads).
"""

from __future__ import annotations

import textwrap

import numpy as np

from lishield_guard.verdict import verdict_title

__all__ = ["video_caption", "video_figure"]

FIGSIZE_IN = (11.0, 8.5)


def video_caption() -> str:
    """What `video_figure` shows, in words."""
    return ("Top: the frame with the largest logit, as the screen decoded it (stored "
            "orientation). Bottom: the logit of every screened frame in the order they were "
            "screened (bars, one colour per run), the clip logit after each run (line) and "
            "the clip threshold (dashed); the clip is flagged when the line reaches it.")


def video_figure(verdict, ev):
    """The matplotlib ``Figure`` of a clip's ``verdict`` (see the module docstring), drawn from
    its evidence ``ev`` (`VideoEvidence`: every screened frame's score, the best frame's
    pixels) under the verdict's title."""
    from matplotlib.figure import Figure

    rec = ev.record
    fig = Figure(figsize=FIGSIZE_IN)
    ax_img, ax_bar = fig.subplots(2, 1, height_ratios=(3, 2))
    fig.suptitle(verdict_title(verdict), fontsize=12)
    if rec.best_rgb is not None:
        ax_img.imshow(rec.best_rgb)
    ax_img.set_axis_off()
    ax_img.set_title("\n".join(textwrap.wrap(ev.reason, 130)[:3]), fontsize=8)
    frames = rec.frames
    logits = [np.nan if f.undetermined else f.logit for f in frames]
    x = np.arange(len(frames))
    ax_bar.bar(x, np.nan_to_num(logits, nan=0.0), color=[f"C{f.run % 10}" for f in frames])
    ax_bar.set_xticks(x, [str(f.index) for f in frames], fontsize=7, rotation=90)
    ends = np.cumsum([sum(1 for f in frames if f.run == r)
                      for r in range(len(rec.checkpoints))]) - 1
    if len(ends):
        ax_bar.plot(ends, rec.checkpoints, "k.-", label="clip logit after each run")
    thr = ev.threshold_logit
    ax_bar.axhline(thr, color="k", ls="--", lw=1, label=f"clip threshold {thr:.2f}")
    ax_bar.set_xlabel("screened frame (index in the clip)")
    ax_bar.set_ylabel("frame logit")
    ax_bar.legend(fontsize=8, loc="best")
    info = rec.info
    ax_bar.set_title(f"{info.codec} {info.width}x{info.height}, {round(info.duration_s, 3)} s; "
                     f"{len(frames)} frames screened, {rec.decoded_frames} decoded; stopped: "
                     f"{rec.stop}", fontsize=9)
    return fig
