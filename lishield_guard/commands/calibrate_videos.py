"""`lishield-guard calibrate-videos`: set and certify the clip threshold on clean video clips.

A shell around `lishield_guard.video.calibrate.run_video_calibration`.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from lishield_guard.commands import ExitCode, fail

__all__ = ["calibrate_videos_command", "register"]


def calibrate_videos_command(
    clean: Annotated[list[Path], typer.Option(
        "--clean", metavar="DIR", help="Folder of clean clips, no barcode (repeatable).")],
    out: Annotated[Path, typer.Option("--out", metavar="FILE",
                                      help="Config TOML to write ([video] thresholds set).")],
    positives: Annotated[Path | None, typer.Option(
        "--positives", metavar="DIR",
        help="Folder of barcode clips: their TPR at the chosen threshold is reported.")] = None,
    certify: Annotated[list[Path] | None, typer.Option(
        "--certify", metavar="DIR", help="Folder of clean clips held out whole to certify "
                                         "(repeatable; none of them tunes).")] = None,
    report: Annotated[Path | None, typer.Option(
        "--report", metavar="DIR", help="Write clips.jsonl (frame logits) and summary.json "
                                        "here.")] = None,
    config: Annotated[Path | None, typer.Option(
        "--config", metavar="FILE.toml", help="Base config (default: the shipped one).")] = None,
    target_far: Annotated[float, typer.Option(
        "--target-far", help="Target per-clip false-alarm rate, shown by the exact one-sided "
                             "95% bound on the certification clips.")] = 0.005,
    certify_fraction: Annotated[float, typer.Option(
        "--certify-fraction", help="Share of the clean clips held out to certify.")] = 0.5,
    split_seed: Annotated[int, typer.Option("--split-seed", help="Seed of the split.")] = 0,
    jobs: Annotated[int, typer.Option("--jobs", "-j",
                                      help="Worker processes (default: all cores).")] = 0,
    progress: Annotated[bool, typer.Option("--progress/--no-progress",
                                           help="Progress bars on stderr.")] = True,
) -> None:
    """Set the clip threshold of video screening on clean clips and certify its false-alarm rate.

    Every clip is screened once on every planned frame; the screen's stopping rule (early
    flag, early clear, up to 16 frames) is replayed at each threshold, so the rate certified is
    that of the screen as it runs. One clip is one sample (frames of a clip are not
    independent). The threshold is placed just above every clean tuning clip; the held-out
    clips bound the per-clip rate (exact binomial bound). Exit status 3 when the target is not
    met (the config is still written, its header says NOT MET).

    Examples:
      lishield-guard calibrate-videos --clean clips/clean --clean out/clips --out video.toml
      lishield-guard calibrate-videos --clean clean --positives barcode --report rep --out v.toml
    """
    from lishield_guard.config import load_config
    from lishield_guard.errors import LishieldError
    from lishield_guard.video.calibrate import run_video_calibration

    if not 0 < target_far < 1 or not 0 < certify_fraction < 1 or jobs < 0:
        raise fail("need 0 < --target-far < 1, 0 < --certify-fraction < 1 and --jobs >= 0")
    for d in [*clean, *(certify or []), *([positives] if positives else [])]:
        if not d.is_dir():
            raise fail(f"not a folder: {str(d)!r}")
    try:
        cal = run_video_calibration(
            clean, base=load_config(config), out=out, report=report, positives=positives,
            certify=certify,
            target_far=target_far, cert_fraction=certify_fraction, seed=split_seed,
            jobs=jobs or os.cpu_count() or 1, progress=progress,
            command=" ".join(["lishield-guard", *sys.argv[1:]]))
    except (LishieldError, ValueError) as exc:
        raise fail(str(exc)) from None
    tpr = "" if cal.tpr is None else f"; barcode clips flagged {cal.tpr:.3f} of {cal.n_pos}"
    typer.echo(f"threshold_logit {cal.threshold_logit} (clear_logit {cal.clear_logit}); "
               f"clean clips: {cal.n_tune} tuning, {cal.n_cert} certification, "
               f"{cal.flagged_cert} flagged; per-clip FAR <= {cal.far_bound:.4g} (95%), target "
               f"{target_far:g}: {'MET' if cal.met else 'NOT MET'}; dependence-free bound "
               f"{cal.markov_bound:.3g}{tpr}; config written to {out}")
    if not cal.met:
        raise typer.Exit(int(ExitCode.ERROR))


def register(app: typer.Typer) -> None:
    """Add the ``calibrate-videos`` command to the main CLI app."""
    app.command(name="calibrate-videos")(calibrate_videos_command)
