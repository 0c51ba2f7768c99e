"""Calibrate and certify the video threshold on whole clean clips (one clip, one sample).

Every clip is screened exhaustively once (`clip_scores`: every planned frame's logit and the
run sizes); the stopping rule (`screen.combine_frames`) is then replayed at any threshold, so
the calibrated rate is the rate of the screen as it runs, early stops and repeated looks
included. Clean clips are split by a hash of their name into a tuning part, which sets the
threshold, and a certification part, which bounds the per-clip false-alarm rate (exact
binomial bound; frames of a clip are never counted as separate samples). A second,
dependence-free bound comes from single clean frames by Markov's inequality (`markov_far`).
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import asdict, dataclass

import numpy as np

from lishield_guard.config import AppConfig
from lishield_guard.settings import VideoConfig
from lishield_guard.stats import upper_bound
from lishield_guard.video.decode import open_video
from lishield_guard.video.screen import COMBINE_LAMBDA, clip_logit, screen_video

__all__ = ["ClipScores", "VideoCalibration", "calibrate_video", "clip_scores",
           "flag_threshold", "markov_far", "run_video_calibration", "score_clips"]

MIN_TAIL_CLIPS = 8  # fewer clean tuning clips than this cannot set a threshold
TAIL_QUANTILE = 0.9  # the clean clips above this quantile of the tuning part fit the tail ...
TAIL_FAR_FRACTION = 0.1  # ... and the threshold is where it predicts a tenth of the target


@dataclass(frozen=True)
class ClipScores:
    """One clip's exhaustive screen: frame logits in screening order and frames per run."""

    name: str
    logits: tuple[float, ...]
    run_sizes: tuple[int, ...]
    first_logit: float  # the first screened frame alone (what a photo screen of it sees)
    label: int | None = None
    error: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready."""
        return asdict(self)


def clip_scores(source, name: str, config: AppConfig, vcfg: VideoConfig,
                label: int | None = None) -> ClipScores:
    """Screen every planned frame of one clip (no early stop); an input error is recorded in
    ``error``, never raised."""
    from lishield_guard.errors import LishieldError

    try:
        with open_video(source, vcfg.limits) as reader:
            rec = screen_video(reader, config, vcfg, exhaustive=True)
    except LishieldError as exc:
        return ClipScores(name, (), (), -math.inf, label, f"{exc.code}: {exc}")
    runs = 1 + max((f.run for f in rec.frames), default=-1)
    sizes = tuple(sum(1 for f in rec.frames if f.run == r and f.undetermined is None)
                  for r in range(runs))
    first = next((f.logit for f in rec.frames if f.undetermined is None), -math.inf)
    return ClipScores(name, tuple(float(x) for x in rec.logits), sizes, float(first), label)


def flag_threshold(c: ClipScores, vcfg: VideoConfig) -> float:
    """The lowest threshold at which the screen flags clip ``c`` (the clear rule fixed at
    ``vcfg.clear_logit``): the largest clip logit of the checkpoints it reaches before it is
    cleared; -inf when it is cleared before ``min_frames`` determined frames or has none."""
    x = np.asarray(c.logits, np.float64)
    best, n = -math.inf, 0
    for size in c.run_sizes:
        n += size
        if n < vcfg.min_frames:
            continue
        s = clip_logit(x[:n])
        best = max(best, s)
        if s < vcfg.clear_logit:
            break
    return best


def markov_far(frame_logits, threshold_logit: float, n_looks: int,
               lam: float = COMBINE_LAMBDA) -> float:
    """A per-clip false-alarm bound that holds whatever the dependence between frames:
    P(log-mean-exp >= t) <= E[exp(lam L)] exp(-lam t) per look (Markov's inequality on the mean
    of exp(lam L), whose expectation is that of one frame), times the number of looks. The
    expectation is estimated from clean frames (``frame_logits``)."""
    x = np.asarray(frame_logits, np.float64)
    x = x[np.isfinite(x)]
    if not len(x):
        return 1.0
    m = float(x.max())
    e = math.exp(lam * (m - threshold_logit)) * float(np.mean(np.exp(lam * (x - m))))
    return min(1.0, n_looks * e)


def _in_cert(name: str, fraction: float, seed: int) -> bool:
    h = hashlib.sha256(f"{seed}:{name}".encode()).digest()
    return int.from_bytes(h[:8], "big") / 2**64 < fraction


@dataclass(frozen=True)
class VideoCalibration:
    """The calibrated video threshold and its certification."""

    threshold_logit: float
    clear_logit: float
    target_far: float
    n_tune: int
    n_cert: int
    flagged_tune: int
    flagged_cert: int
    far_bound: float
    met: bool
    markov_bound: float
    n_errors: int
    tpr: float | None = None
    n_pos: int = 0

    def to_dict(self) -> dict:
        """JSON-ready."""
        return asdict(self)


def calibrate_video(clean: list[ClipScores], vcfg: VideoConfig, *, target_far: float = 0.005,
                    cert_fraction: float = 0.5, seed: int = 0, nudge: float = 1e-3,
                    positives: list[ClipScores] | None = None,
                    certify: list[ClipScores] | None = None) -> VideoCalibration:
    """Set ``threshold_logit`` and bound the per-clip false-alarm rate on held-out clips.

    The threshold is the higher of: just above every clean tuning clip's flag threshold, and
    where an exponential fit of the tuning clips' tail (those above `TAIL_QUANTILE`) predicts
    `TAIL_FAR_FRACTION` x ``target_far`` (`calibration.evidence.tail_threshold`, as for
    photos): the largest of a few hundred clips is no margin, the fitted tail keeps one chosen
    on the tuning part alone.

    Raises
    ------
    ValueError
        Fewer than `MIN_TAIL_CLIPS` clean tuning clips.
    """
    ok = [c for c in clean if c.error is None]
    extra = [c for c in certify or () if c.error is None]
    cert = [c for c in ok if _in_cert(c.name, cert_fraction, seed)] + extra
    tune = [c for c in ok if not _in_cert(c.name, cert_fraction, seed)]
    ok += extra
    if len(tune) < MIN_TAIL_CLIPS:
        raise ValueError(f"need at least {MIN_TAIL_CLIPS} clean tuning clips, got {len(tune)}")
    from lishield_guard.calibration.evidence import LearnedGrid, tail_threshold

    tune_thr = np.array([flag_threshold(c, vcfg) for c in tune])
    grid = LearnedGrid(tail_quantile=TAIL_QUANTILE, tail_far_fraction=TAIL_FAR_FRACTION)
    thr = max(float(np.max(tune_thr)) + nudge, tail_threshold(tune_thr, target_far, grid),
              vcfg.clear_logit)
    cert_thr = np.array([flag_threshold(c, vcfg) for c in cert])
    k = int(np.sum(cert_thr >= thr))
    bound = upper_bound(k, len(cert)) if cert else 1.0
    looks = max((len(c.run_sizes) for c in ok), default=1)
    markov = markov_far([x for c in tune for x in c.logits], thr, looks)
    tpr, n_pos = None, 0
    if positives:
        pos = [c for c in positives if c.error is None]
        n_pos = len(pos)
        tpr = float(np.mean([flag_threshold(c, vcfg) >= thr for c in pos])) if pos else None
    return VideoCalibration(threshold_logit=round(thr, 4), clear_logit=vcfg.clear_logit,
                            target_far=target_far, n_tune=len(tune), n_cert=len(cert),
                            flagged_tune=int(np.sum(tune_thr >= thr)), flagged_cert=k,
                            far_bound=bound, met=bool(bound <= target_far),
                            markov_bound=markov,
                            n_errors=len(clean) + len(certify or ()) - len(ok), tpr=tpr,
                            n_pos=n_pos)


def _score_work(args: tuple) -> ClipScores:
    from lishield_guard.batch.pool import worker_state

    path, label = args
    config, vcfg = worker_state()
    return clip_scores(path, os.path.basename(path), config, vcfg, label)


def score_clips(paths, config: AppConfig, vcfg: VideoConfig, *, label: int | None = None,
                jobs: int = 1, progress: bool = False, desc: str = "clips") -> list[ClipScores]:
    """`clip_scores` of every clip in ``paths``, in worker processes, in input order."""
    from lishield_guard.batch.pool import progress_bar, run_pool

    paths = [str(p) for p in paths]
    out: list[ClipScores] = []
    with progress_bar(desc, total=len(paths), enabled=progress) as bar:
        for (path, _), res in run_pool(_score_work, [(p, label) for p in paths], jobs=jobs,
                                       state=(config, vcfg), ordered=True):
            out.append(res if isinstance(res, ClipScores) else
                       ClipScores(os.path.basename(path), (), (), -math.inf, label,
                                  f"worker_crashed: {res}"))
            bar.update()
    return out


def _barcode_clips(folder) -> list:
    """The clips of ``folder``; only its label-1 clips when it has a dataset manifest."""
    import json

    from lishield_guard.batch import VIDEO, list_files

    clips = list_files(folder, kinds=(VIDEO,))
    manifest = folder / "manifest.jsonl"
    if not manifest.exists():
        return clips
    labels = {json.loads(ln)["file"]: json.loads(ln).get("label")
              for ln in manifest.read_text().splitlines() if ln.strip()}
    return [p for p in clips if labels.get(p.name, 1) == 1]


def run_video_calibration(clean: list, *, base: AppConfig, out, report=None, positives=None,
                          certify: list | None = None, target_far: float = 0.005,
                          cert_fraction: float = 0.5,
                          seed: int = 0, jobs: int = 1, progress: bool = False,
                          command: str = "") -> VideoCalibration:
    """List the clips, score them, set and certify the threshold, write the config.

    Parameters
    ----------
    clean : list of path
        Folders of clean clips (no barcode; any look-alike light), listed recursively.
    base : AppConfig
        The config whose ``[video]`` threshold is replaced in the written file, with the
        digest of the decision weights it was calibrated for beside it.
    out : path
        Config TOML to write (``threshold_logit`` set; the header states the certification).
    report : path, optional
        Folder for ``clips.jsonl`` (every clip's frame logits) and ``summary.json``.
    certify : list of path, optional
        Folders of clean clips used whole for certification (none of them tunes).
    positives : path, optional
        Folder of barcode clips: their TPR at the chosen threshold is reported (a folder with
        a ``manifest.jsonl``, as `synth dataset --videos` writes, contributes its label-1
        clips only).

    Raises
    ------
    ValueError
        No clips, or too few clean tuning clips.
    """
    import dataclasses
    import datetime
    import json
    from pathlib import Path

    from lishield_guard.batch import VIDEO, list_files
    from lishield_guard.config import dump_config

    vcfg = base.video
    clips = [p for d in clean for p in list_files(d, kinds=(VIDEO,))]
    if not clips:
        raise ValueError(f"no video clips under {', '.join(map(str, clean))}")
    scores = score_clips(clips, base, vcfg, label=0, jobs=jobs, progress=progress,
                         desc="clean clips")
    pos = score_clips(_barcode_clips(Path(positives)), base, vcfg, label=1, jobs=jobs,
                      progress=progress, desc="barcode clips") if positives else None
    held = [p for d in certify or () for p in list_files(d, kinds=(VIDEO,))]
    held_scores = score_clips(held, base, vcfg, label=0, jobs=jobs, progress=progress,
                              desc="certification clips") if held else []
    cal = calibrate_video(scores, vcfg, target_far=target_far, cert_fraction=cert_fraction,
                          seed=seed, positives=pos, certify=held_scores)
    from lishield_guard.detector.decision import decision_model

    cfg = dataclasses.replace(base, video=dataclasses.replace(  # bound to the weights it used
        vcfg, threshold_logit=cal.threshold_logit,
        model_digest=decision_model(base.detector).digest))
    header = (f"calibrated by {command or 'run_video_calibration'} on "
              f"{datetime.date.today().isoformat()}\n"
              f"video: {cal.n_tune} clean tuning clips, {cal.n_cert} certification clips, "
              f"{cal.flagged_cert} flagged; per-clip FAR <= {cal.far_bound:.4g} (exact 95% "
              f"bound), target {target_far:g}: {'MET' if cal.met else 'NOT MET'}; "
              f"dependence-free bound {cal.markov_bound:.3g}")
    Path(out).write_text(dump_config(cfg, header="\n".join(
        [ln for ln in base.header.splitlines() if ln] + [header])))
    if report is not None:
        rep = Path(report)
        rep.mkdir(parents=True, exist_ok=True)
        with open(rep / "clips.jsonl", "w", encoding="utf-8") as fh:
            for c in [*scores, *held_scores, *(pos or [])]:
                fh.write(json.dumps(c.to_dict()) + "\n")
        (rep / "summary.json").write_text(json.dumps(cal.to_dict(), indent=1))
    return cal
