"""Screen a video: score frames with the photo detector's learned decision and add the evidence up.

A clip is screened in *runs* of `VideoConfig.first_frames` frames (`plan_runs`): keyframes
first, spread over the clip (van der Corput order), so a scene that changes, a camera that
pans or a light that comes and goes is seen; then the frames right after them, which see the
light a frame interval later, at another phase of its cycle. Each frame gets its image logit
L (`decision.measure`: the largest window logit). After each run the frames so far are
combined into one clip logit

    S = (1 / lam) * log(mean_k exp(lam * L_k))        (log-mean-exp, `COMBINE_LAMBDA`)

which lies between the mean (evidence that adds up over frames too weak one by one) and the
maximum (one clear frame). The clip is protected as soon as S reaches
`VideoConfig.threshold_logit`, clean as soon as it is below `clear_logit` after a run (more
frames would rarely change the verdict), and otherwise screened further until
`max_frames`. Frames of one clip are not independent (one scene, one light): the threshold is
set and certified on whole clean clips, one clip one sample (`calibrate_video`), and the
stopping rule is part of what is calibrated, so neither the dependence nor the repeated looks
enter the false-alarm rate unaccounted. Markov's inequality also bounds the rate for any
dependence: P(S >= t) <= E[exp(lam * L)] * exp(-lam * t) over single clean frames.

The plan depends only on the container's header (duration, frame rate, keyframes), so
calibration and detection screen the same frames of a clip.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from lishield_guard.config import AppConfig
from lishield_guard.detector.decision import DecisionRecord, measure, window_label
from lishield_guard.profiles import learned, of
from lishield_guard.settings import VideoConfig
from lishield_guard.verdict import Evidence, Verdict, nothing_to_look_for, undetermined
from lishield_guard.video.decode import VideoInfo, VideoReader, open_video

__all__ = ["COMBINE_LAMBDA", "FrameScore", "VideoEvidence", "VideoRecord", "clip_logit",
           "combine_frames", "plan_runs", "replay", "screen_video", "video_verdict"]

COMBINE_LAMBDA = 1.0  # log-mean-exp temperature over frame logits (dev set: see docs/video.md)


@dataclass(frozen=True)
class FrameScore:
    """One screened frame: where it is and its image logit."""

    index: int
    time_s: float
    logit: float
    where: str
    keyframe: bool
    run: int
    undetermined: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready (the logit of an undetermined frame is None)."""
        return dict(asdict(self), time_s=round(self.time_s, 3),
                    logit=None if self.undetermined else round(self.logit, 4))


@dataclass(frozen=True)
class VideoRecord:
    """Every measurement a clip's verdict is decided on.

    Attributes
    ----------
    info : VideoInfo
        The container's header.
    frames : tuple of FrameScore
        Screened frames in the order they were screened.
    stop : str
        Why screening stopped: ``"flagged"``, ``"cleared"``, ``"max_frames"``, ``"end"``
        (the clip had no more frames to plan) or ``"decode_budget"``.
    best : DecisionRecord or None
        The record of the frame with the largest logit (for the explanation).
    decoded_frames : int
        Frames the decoder produced (screened or passed over).
    row_scale : int
        Frame rows per analysed row (frames scaled down to ``max_rows``).
    checkpoints : tuple of float
        The clip logit after each run.
    best_rgb : ndarray or None
        The pixels of the frame with the largest logit, as screened (the figure draws it).
    """

    info: VideoInfo
    frames: tuple[FrameScore, ...]
    stop: str
    best: DecisionRecord | None
    decoded_frames: int
    row_scale: int = 1
    checkpoints: tuple[float, ...] = field(default=())
    best_rgb: np.ndarray | None = None

    @property
    def logits(self) -> np.ndarray:
        """Logits of the determined frames, in screening order."""
        return np.array([f.logit for f in self.frames if f.undetermined is None], np.float64)


def clip_logit(logits, lam: float = COMBINE_LAMBDA) -> float:
    """The clip logit of frame logits: log-mean-exp with temperature ``lam`` (-inf when
    there are none)."""
    x = np.asarray(logits, np.float64)
    if x.size == 0:
        return -math.inf
    m = float(x.max())
    return m + float(np.log(np.mean(np.exp(lam * (x - m))))) / lam


def combine_frames(logits, run_sizes, threshold_logit: float, clear_logit: float,
                   min_frames: int = 1, lam: float = COMBINE_LAMBDA) -> tuple[str, int, float]:
    """The stopping rule on the frame logits of successive runs, written once (screening and
    calibration replay it).

    Parameters
    ----------
    logits : sequence of float
        Determined frame logits in screening order.
    run_sizes : sequence of int
        Determined frames per run, in order (their sum is ``len(logits)``).
    threshold_logit, clear_logit : float
        Flag when the clip logit reaches the first; clear when it is below the second.

    Returns
    -------
    (stop, n_used, clip_logit)
        ``stop`` is ``"flagged"``, ``"cleared"`` or ``"open"`` (every run used, neither rule
        fired); ``n_used`` the frames the verdict rests on.
    """
    x = np.asarray(logits, np.float64)
    n = 0
    s = -math.inf
    for size in run_sizes:
        n += int(size)
        if n < min_frames:
            continue
        s = clip_logit(x[:n], lam)
        if s >= threshold_logit:
            return "flagged", n, s
        if s < clear_logit:
            return "cleared", n, s
    return "open", n, s


def replay(logits, run_sizes, vcfg: VideoConfig, threshold_logit: float | None = None
           ) -> bool:
    """Whether a clip with these frame logits is flagged at ``threshold_logit`` (default the
    configured one), with the screen's stopping rule."""
    thr = vcfg.threshold_logit if threshold_logit is None else threshold_logit
    stop, _, _ = combine_frames(logits, run_sizes, thr, min(vcfg.clear_logit, thr),
                                vcfg.min_frames)
    return stop == "flagged"


def _van_der_corput(n: int) -> list[int]:
    """0..n-1 in an order that keeps every prefix spread out (bit-reversed fractions)."""
    def radical(i: int) -> float:
        out, f = 0.0, 0.5
        while i:
            out += f * (i & 1)
            i >>= 1
            f /= 2
        return out
    return sorted(range(n), key=lambda i: (radical(i), i))


def plan_runs(info: VideoInfo, vcfg: VideoConfig) -> list[list[float]]:
    """The frame times of every run, in screening order (at most ``max_frames`` frames).

    Candidates, in order: every keyframe of the container's index, visited spread out (a
    keyframe is intra coded: at low bitrates the frames after it copy most of it, stripes
    included, so keyframes carry the most independent looks at the light); then, keyframe by
    keyframe in the same order, the `first_frames` frames after it (a frame interval later the
    light is at another phase of its cycle; consecutive frames decode on from one seek). A
    clip that lists no keyframes starts at ``frame_stride_s`` multiples spread over it. Runs
    are `first_frames` consecutive candidates, each run decoded in time order.
    """
    dt = 1.0 / info.frame_rate_hz
    end = info.duration_s - 0.5 * dt
    keys = sorted(info.keyframes_s)
    if keys and keys[0] < 0:  # index times are decode times: the first keyframe shows at 0
        keys = [k - keys[0] for k in keys]
    keys = [k for k in keys if k <= end]
    if not keys:
        n = max(1, min(vcfg.max_frames, int(end / vcfg.frame_stride_s) + 1))
        keys = [end * i / n for i in range(n)]
    order = [keys[i] for i in _van_der_corput(len(keys))]
    n = vcfg.first_frames
    cand: list[float] = list(order)
    block = 0
    while len(cand) < vcfg.max_frames and block * n * dt <= end:
        for k in order:  # the frames after each keyframe, consecutive: one seek per block
            cand += [t for i in range(1, n + 1) if (t := k + (block * n + i) * dt) <= end]
        block += 1
    cand = cand[:vcfg.max_frames]
    return [sorted(cand[i:i + vcfg.first_frames])
            for i in range(0, len(cand), vcfg.first_frames)]


def _measure_run(reader: VideoReader, times, run: int, config: AppConfig, vcfg: VideoConfig,
                 timings: dict) -> list[tuple[FrameScore, DecisionRecord | None, np.ndarray]]:
    det = config.detector
    out = []
    t0 = time.perf_counter()
    frames = list(reader.frames(times, max_rows=vcfg.max_rows))
    timings["decode"] = timings.get("decode", 0.0) + (time.perf_counter() - t0) * 1e3
    for fr in frames:
        t0 = time.perf_counter()
        rec = measure(fr.rgb, det)
        timings["measure"] = timings.get("measure", 0.0) + (time.perf_counter() - t0) * 1e3
        if rec.undetermined is not None:
            out.append((FrameScore(fr.index, fr.time_s, -math.inf, "", fr.keyframe, run,
                                   rec.undetermined), None, fr.rgb))
        else:
            out.append((FrameScore(fr.index, fr.time_s, rec.logit,
                                   window_label(rec.spectra, rec.best), fr.keyframe, run),
                        rec, fr.rgb))
    return out


def screen_video(reader: VideoReader, config: AppConfig, vcfg: VideoConfig,
                 timings: dict | None = None, *, exhaustive: bool = False) -> VideoRecord:
    """Screen an opened clip run by run until the verdict is certain (see the module
    docstring); ``exhaustive`` screens every planned frame (calibration replays the stopping
    rule on them)."""
    timings = {} if timings is None else timings
    frames: list[FrameScore] = []
    sizes: list[int] = []
    best: DecisionRecord | None = None
    best_rgb = None
    stop = "end"
    plan = plan_runs(reader.info, vcfg)
    checkpoints = []
    for r, times in enumerate(plan):
        got = _measure_run(reader, times, r, config, vcfg, timings)
        for fs, rec, rgb in got:
            frames.append(fs)
            if rec is not None and (best is None or rec.logit > best.logit):
                best, best_rgb = rec, rgb
        sizes.append(sum(1 for fs, _, _ in got if fs.undetermined is None))
        if reader.budget_hit:
            stop = "decode_budget"
            break
        logits = [f.logit for f in frames if f.undetermined is None]
        decision, _, s = combine_frames(logits, sizes, vcfg.threshold_logit, vcfg.clear_logit,
                                        vcfg.min_frames)
        checkpoints.append(s)
        if decision != "open" and not exhaustive:
            stop = decision
            break
        stop = "max_frames" if sum(len(t) for t in plan[:r + 1]) >= vcfg.max_frames else "end"
    return VideoRecord(reader.info, tuple(frames), stop, best, reader.decoded_frames,
                       reader.row_scale(vcfg.max_rows), tuple(checkpoints), best_rgb)


def video_verdict(rec: VideoRecord, config: AppConfig, vcfg: VideoConfig,
                  timings: dict, skipped: list[str]) -> Verdict:
    """The clip's Verdict from its record: status by the stopping rule, the deciding frames,
    per-frame scores and the learned profile's evidence of the best frame
    (`profiles.learned.evidence`: the spec it names is the clip's)."""
    logits = rec.logits
    sizes = [sum(1 for f in rec.frames if f.run == r and f.undetermined is None)
             for r in range(1 + max((f.run for f in rec.frames), default=-1))]
    decision, n_used, s = combine_frames(logits, sizes, vcfg.threshold_logit,
                                         vcfg.clear_logit, vcfg.min_frames)
    n_undet = sum(1 for f in rec.frames if f.undetermined is not None)
    if n_undet:
        skipped.append(f"{n_undet} screened frames undetermined (e.g. "
                       f"{next(f.undetermined for f in rec.frames if f.undetermined)})")
    if rec.row_scale > 1:
        skipped.append(f"full resolution: frames scaled to 1/{rec.row_scale} (stripes need "
                       f"rows, not pixels)")
    if len(logits) < vcfg.min_frames or rec.best is None:
        why = (f"only {len(logits)} frames could be screened (need {vcfg.min_frames}; "
               f"stopped: {rec.stop})")
        return undetermined(why, looked_at=_looked_at(rec), profile=learned.NAME,
                            required=learned.required(config), skipped=skipped,
                            timings_ms=timings, extra={"video": _video_json(
                                rec, vcfg.threshold_logit, vcfg.clear_logit, s)})
    t0 = time.perf_counter()
    best_ev = learned.evidence(rec.best, config, row_scale=rec.row_scale)
    timings["explain"] = (time.perf_counter() - t0) * 1e3
    ev = VideoEvidence("", rec, best_ev, s, vcfg.threshold_logit, vcfg.clear_logit, n_used,
                       decision == "flagged")
    protected = ev.flagged
    return Verdict(protected=protected, policy=best_ev.policy if protected else None,
                   matches=int(protected), required=learned.required(config),
                   evidence=ev.with_reason(), skipped=tuple(skipped), timings_ms=timings,
                   profile=learned.NAME, score=learned.logit_score(s))


def _looked_at(rec: VideoRecord) -> str:
    """The clip, in words: its size and the frames screened."""
    return (f"{rec.info.width} x {rec.info.height} clip, {len(rec.frames)} frames screened "
            f"of {rec.info.n_frames}")


def _video_json(rec: VideoRecord, threshold_logit: float, clear_logit: float,
                clip: float) -> dict:
    """``evidence["video"]``: the header, why screening stopped, every frame's score."""
    return {"info": rec.info.to_dict(), "stop": rec.stop, "frames_screened": len(rec.frames),
            "frames_decoded": rec.decoded_frames, "clip_logit": round(clip, 4),
            "threshold_logit": threshold_logit, "clear_logit": clear_logit,
            "combine": f"log-mean-exp, lambda {COMBINE_LAMBDA:g}",
            "checkpoints": [round(c, 4) for c in rec.checkpoints],
            "frames": [f.to_dict() for f in rec.frames]}


@dataclass(frozen=True, eq=False)
class VideoEvidence(Evidence):
    """A clip's evidence: its record and the learned evidence of its best frame.

    Attributes
    ----------
    reason : str
        The clip's verdict in words (`with_reason` writes it).
    record : VideoRecord
        Every screened frame's score, the best frame's record and pixels.
    best : LearnedEvidence
        The learned profile's evidence of the best frame (its named spec is the clip's).
    clip_logit : float
        The clip logit the stopping rule ended on.
    threshold_logit, clear_logit : float
        The clip thresholds.
    n_used : int
        Frames the verdict rests on.
    flagged : bool
        The stopping rule's answer.
    """

    reason: str
    record: VideoRecord
    best: Evidence
    clip_logit: float
    threshold_logit: float
    clear_logit: float
    n_used: int
    flagged: bool

    @property
    def spec(self) -> str | None:
        """The best frame's named spec."""
        return self.best.spec

    @property
    def ranked(self) -> list[FrameScore]:
        """The determined frames, highest logit first."""
        return sorted((f for f in self.record.frames if f.undetermined is None),
                      key=lambda f: -f.logit)

    def with_reason(self) -> VideoEvidence:
        """This evidence with its reason written from its numbers."""
        order = self.ranked
        thr = self.threshold_logit
        if self.flagged:
            reason = (f"barcode in video: clip logit {self.clip_logit:.2f} >= threshold "
                      f"{thr:.2f} over {self.n_used} frames (deciding frames "
                      f"{', '.join(str(f.index) for f in order[:3])}); best frame: "
                      f"{self.best.reason}")
        else:
            reason = (f"clean video: clip logit {self.clip_logit:.2f} < threshold {thr:.2f} "
                      f"over {len(order)} frames (stopped: {self.record.stop}; highest frame "
                      f"logit {order[0].logit:.2f} at frame {order[0].index})")
        return dataclasses.replace(self, reason=reason)

    def to_dict(self) -> dict:
        """The best frame's evidence, with the clip's reason, numbers and frames."""
        order = self.ranked
        return dict(self.best.to_dict(), reason=self.reason, stage="video",
                    logit=round(self.clip_logit, 4), threshold_logit=self.threshold_logit,
                    deciding_frames=[f.index for f in order[:3]], best_frame=order[0].index,
                    video=_video_json(self.record, self.threshold_logit, self.clear_logit,
                                      self.clip_logit))

    def counts(self, verdict: Verdict) -> str:
        """``clip logit S >= threshold T over N frames``."""
        return (f"clip logit {round(self.clip_logit, 4)} {'>=' if self.flagged else '<'} "
                f"threshold {self.threshold_logit:.3g} over {len(self.record.frames)} frames")

    def caption(self, verdict: Verdict) -> str:
        """`video.figure.video_caption`."""
        from lishield_guard.video.figure import video_caption

        return video_caption()

    def figure(self, verdict: Verdict, config):
        """`video.figure.video_figure`, from the record."""
        from lishield_guard.video.figure import video_figure

        return video_figure(verdict, self)


def detect_video(source, config: AppConfig, vcfg: VideoConfig | None = None) -> Verdict:
    """Decide whether a video carries a barcode of a configured policy.

    Parameters
    ----------
    source : bytes, str or Path
        Encoded video bytes or a path (MP4/MOV/WebM/MKV).
    config : AppConfig
        Detector settings and policies (the learned decision screens every frame).
    vcfg : VideoConfig, optional
        Limits and the screening plan; default ``config.video`` or `VideoConfig()`.

    Returns
    -------
    Verdict
        ``evidence["video"]`` holds the per-frame scores and why screening stopped.

    Raises
    ------
    EmptyImageError, PayloadTooLargeError, UnsupportedImageError, CorruptVideoError,
    VideoTooLongError, ImageTooLargeError
        When the input cannot be screened as a video.
    """
    vcfg = vcfg or getattr(config, "video", None) or VideoConfig()
    timings: dict = {}
    t0 = time.perf_counter()
    reader = open_video(source, vcfg.limits)
    timings["open"] = (time.perf_counter() - t0) * 1e3
    with reader:
        why = nothing_to_look_for(config)
        why, skipped = (why, []) if why is not None else learned.scope(config)
        if of(config) is not learned:
            skipped.append(f"profile {config.detector.profile}: videos are screened with the "
                           f"{learned.NAME} profile's learned decision")
        if why is not None:
            info = reader.info
            return undetermined(why, looked_at=f"{info.width} x {info.height} clip, no frame "
                                f"screened", profile=learned.NAME,
                                required=learned.required(config), skipped=skipped,
                                timings_ms=timings)
        rec = screen_video(reader, config, vcfg, timings)
    return video_verdict(rec, config, vcfg, timings, skipped)
