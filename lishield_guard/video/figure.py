"""The figure of a video verdict: the deciding frame and every screened frame's score.

Two panels, rebuilt from the clip and the verdict's evidence: the frame with the largest logit
as the screen decoded it (the stripes a person can check), and the logit of every screened
frame in screening order, coloured by run, against the clip threshold, with the clip logit
after each run. matplotlib is used through its object-oriented API only (service threads).
"""

from __future__ import annotations

import textwrap

import numpy as np

__all__ = ["video_caption", "video_figure"]

FIGSIZE_IN = (11.0, 8.5)


def video_caption(verdict) -> str:
    """What `video_figure` shows, in words."""
    return ("Top: the frame with the largest logit, as the screen decoded it (stored "
            "orientation). Bottom: the logit of every screened frame in the order they were "
            "screened (bars, one colour per run), the clip logit after each run (line) and "
            "the clip threshold (dashed); the clip is flagged when the line reaches it.")


def _best_frame(source, video: dict, config) -> np.ndarray | None:
    """The screened frame with the largest logit, decoded again (None when none was)."""
    from lishield_guard.video.decode import open_video

    frames = [f for f in video.get("frames", []) if f.get("logit") is not None]
    if not frames:
        return None
    best = max(frames, key=lambda f: f["logit"])
    with open_video(source, config.video.limits) as reader:
        got = list(reader.frames([best["time_s"]], max_rows=config.video.max_rows))
    return got[0].rgb if got else None


def video_figure(source, verdict, config):
    """Build the figure of one video verdict (see the module docstring).

    Parameters
    ----------
    source : bytes, str or Path
        The clip the verdict was computed on.
    verdict : Verdict
        Its verdict (``evidence["video"]`` holds the per-frame scores).
    config : AppConfig
        The config of the screen (limits, the clip threshold).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    from lishield_guard.plot import verdict_title

    ev = verdict.evidence or {}
    video = ev.get("video") or {}
    fig = Figure(figsize=FIGSIZE_IN)
    ax_img, ax_bar = fig.subplots(2, 1, height_ratios=(3, 2))
    fig.suptitle(verdict_title(verdict), fontsize=12)
    frame = _best_frame(source, video, config) if video else None
    if frame is not None:
        ax_img.imshow(frame)
    ax_img.set_axis_off()
    reason = str(ev.get("reason") or verdict.undetermined or "")
    ax_img.set_title("\n".join(textwrap.wrap(reason, 130)[:3]), fontsize=8)
    frames = video.get("frames", [])
    logits = [np.nan if f.get("logit") is None else f["logit"] for f in frames]
    colours = [f"C{f.get('run', 0) % 10}" for f in frames]
    x = np.arange(len(frames))
    ax_bar.bar(x, np.nan_to_num(logits, nan=0.0), color=colours)
    ax_bar.set_xticks(x, [str(f["index"]) for f in frames], fontsize=7, rotation=90)
    ends = np.cumsum([sum(1 for f in frames if f.get("run") == r)
                      for r in range(len(video.get("checkpoints", [])))]) - 1
    if len(ends):
        ax_bar.plot(ends, video["checkpoints"], "k.-", label="clip logit after each run")
    thr = video.get("threshold_logit", config.video.threshold_logit)
    ax_bar.axhline(thr, color="k", ls="--", lw=1, label=f"clip threshold {thr:.2f}")
    ax_bar.set_xlabel("screened frame (index in the clip)")
    ax_bar.set_ylabel("frame logit")
    ax_bar.legend(fontsize=8, loc="best")
    info = video.get("info", {})
    ax_bar.set_title(f"{info.get('codec', '?')} {info.get('width', '?')}x"
                     f"{info.get('height', '?')}, {info.get('duration_s', '?')} s; "
                     f"{video.get('frames_screened', 0)} frames screened, "
                     f"{video.get('frames_decoded', 0)} decoded; stopped: "
                     f"{video.get('stop', '?')}", fontsize=9)
    return fig
