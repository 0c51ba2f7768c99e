"""`lishield-guard detect IMG...`: verdicts in words or JSON, optionally with the figure of what
decided them."""

from __future__ import annotations

import dataclasses
import json
import sys
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from lishield_guard.commands import ExitCode, fail
from lishield_guard.errors import ConfigError, LishieldError
from lishield_guard.profiles import NAMES as PROFILES

if TYPE_CHECKING:  # numpy and the config load only when a command runs (lazy start-up)
    from lishield_guard.config import AppConfig

__all__ = ["PROFILES", "Profile", "detect_command", "plot_verdict", "register", "resolve_config"]


#: Detector profiles (`DetectorConfig.profile`): the names of the profile registry.
Profile = StrEnum("Profile", {name: name for name in PROFILES})


def resolve_config(config: Path | None, profile: str | None) -> AppConfig:
    """Load ``--config`` (or the shipped default) and apply a ``--profile`` override.

    Raises
    ------
    ConfigError
        Unreadable or invalid config file, or an unknown profile.
    """
    from lishield_guard.config import load_config

    cfg = load_config(config)
    if profile is not None:
        if profile not in PROFILES:
            raise ConfigError(f"--profile must be one of {', '.join(PROFILES)}, got {profile!r}")
        cfg = dataclasses.replace(cfg, detector=cfg.detector.replace(profile=profile))
    return cfg


def _num(value) -> str:
    """A stage result's value as printed: floats to 4 significant digits, or whole from 10^4
    (results are stored unrounded), everything else as is."""
    if not isinstance(value, float):
        return str(value)
    return f"{value:.0f}" if abs(value) >= 1e4 else f"{value:.4g}"


def _describe(v, label: str, *, explain: bool) -> str:
    d = v.to_dict()
    ev = v.evidence or {}
    lines = []
    status = getattr(v, "status", "protected" if v.protected else "clean")
    if status == "protected":
        lines.append(f"{label}: PROTECTED by policy {v.policy!r}")
    elif status == "undetermined":
        lines.append(f"{label}: UNDETERMINED (the detector could not look; not clean)")
    else:
        lines.append(f"{label}: clean, not protected (no policy barcode found)")
    # the numbers and the reason of the deciding profile or media kind (its typed evidence)
    lines.append(f"  matches: {v.evidence.counts(v)}  score: {v.score:.3f}  profile: "
                 f"{v.profile}")
    reason = v.evidence.reason
    lines.append(f"  reason: {reason}")
    if v.skipped:
        lines.append("  skipped: " + "; ".join(v.skipped))
    t = d["timings_ms"]
    total = sum(t.values())
    lines.append("  timings: " + ", ".join(f"{k} {ms:.1f} ms" for k, ms in t.items())
                 + f" (total {total:.1f} ms)")
    first = ev.get("first_look") if explain else None
    if isinstance(first, dict) and not first.get("cleared"):
        lines.append(f"  first look: peak {first['peak_ln']} ln at {first['where']}, "
                     + ("off (no calibrated threshold): went on" if first["threshold_ln"] is None
                        else f">= {first['threshold_ln']:.4f}: went on to the full decision"))
    if explain and isinstance(ev.get("video"), dict):
        lines += _explain_frames(ev["video"])
    elif explain and isinstance(ev.get("physics"), dict):
        ph = ev["physics"]
        lines.append(f"  physics (cascade profile, on request): "
                     f"{'explains it' if ph['protected'] else 'no pattern fit passes'}: "
                     f"{ph['reason']} ({sum(ph['timings_ms'].values()):.0f} ms)")
        lines += _explain_best(ph.get("best"))
    elif explain:
        lines += _explain_best(ev.get("best"))
        lines += _explain_candidates(ev.get("candidates", []), reason)
        if "frequencies_hz" in ev:
            lines.append("  peak frequencies (Hz at nominal row rate): "
                         + ", ".join(f"{f:g}" for f in ev["frequencies_hz"]))
    return "\n".join(lines)


def _explain_frames(video: dict) -> list[str]:
    """``--explain``'s lines on a clip: its header, why screening stopped, every frame."""
    info = video.get("info", {})
    lines = [f"  video: {info.get('codec')} {info.get('width')}x{info.get('height')}, "
             f"{info.get('duration_s')} s at {info.get('frame_rate_hz')} fps, rotation "
             f"{info.get('rotation_deg')}; {video.get('frames_screened')} frames screened, "
             f"{video.get('frames_decoded')} decoded; stopped: {video.get('stop')}; clip logit "
             f"after each run: {', '.join(f'{c:.2f}' for c in video.get('checkpoints', []))}"]
    for f in video.get("frames", []):
        score = "undetermined" if f.get("logit") is None else f"logit {f['logit']:.2f}"
        lines.append(f"    frame {f['index']} ({f['time_s']:.2f} s, run {f['run']}"
                     f"{', keyframe' if f.get('keyframe') else ''}): {score} "
                     f"{f.get('where') or f.get('undetermined') or ''}")
    return lines


def _with_physics(verdict, source, cfg):
    """A flagged default-profile verdict with the cascade's pattern search and exact capture-
    model fit on the same image attached as ``evidence["physics"]`` (its reason, stage and
    best fit): the explanation ``--explain`` asks for, run only on flagged images and outside
    the verdict's bounded cost."""
    from lishield_guard.detector import detect
    from lishield_guard.profiles import cascade

    c = detect(source, dataclasses.replace(
        cfg, detector=cfg.detector.replace(profile=cascade.NAME)))
    physics = {"profile": cascade.NAME, "protected": c.protected,
               "reason": c.evidence.get("reason"), "stage": c.evidence.get("stage"),
               "best": c.evidence.get("best"), "timings_ms": c.timings_ms}
    return dataclasses.replace(verdict,
                               evidence=dataclasses.replace(verdict.evidence, physics=physics))


def _explain_best(best: dict | None) -> list[str]:
    """``--explain``'s lines on the best candidate: its scale, matched tones, occupancy and
    pattern fits; one line when nothing was fitted (e.g. cleared by the first stage)."""
    if not best:
        return []
    sigma = best.get("sigma_cpr_per_hz") or 0.0
    if not sigma and not best.get("n_matched") and not any(best.get(k) for k in ("fold",
                                                                                "sweep")):
        return [f"  best spec: {best.get('spec')}  (nothing fitted: "
                f"{best.get('stage') or 'no tones'})"]
    rate = best.get("row_rate_hz_if_not_resized")
    source = {"sweep": "the sweep's fitted period"}.get(best.get("row_rate_from"),
                                                       "the tone scale")
    lines = [f"  best spec: {best.get('spec')}"
             + (f"  row rate {rate:,.0f} Hz if not resized (from {source})" if rate else ""),
             f"    tone scale: {sigma:.4g} cycles/row per Hz"]
    for ch, hz in (best.get("matched_hz") or {}).items():
        tones = ", ".join(f"{f:g} Hz ({f * sigma:.4f} c/row)" for f in hz) or "none"
        lines.append(f"    {ch}: matched {tones}")
    occupancy = {c: "[" + ", ".join(_num(o) for o in v) + "]"
                 for c, v in (best.get("occupancy") or {}).items()}
    line = f"    purity {_num(best.get('purity'))}  switches {best.get('switches')}"
    if occupancy:
        line += "  occupancy " + ", ".join(f"{c} {o}" for c, o in occupancy.items())
    lines.append(line)
    for stage in ("fold", "sweep"):  # template fits: folded, and tiled over the frame
        info = best.get(stage)
        if info:
            lines.append(f"    {stage}: " + ", ".join(
                f"{k} {_num(v)}" for k, v in info.items() if k not in ("spec", "fit")))
        if info and info.get("fit"):  # the sweep's exact-model refinement
            lines.append("    exact fit: " + ", ".join(
                f"{k} {_num(v)}" for k, v in info["fit"].items() if k != "spec"))
    return lines


def _explain_candidates(candidates: list[dict], verdict_reason: str | None) -> list[str]:
    """One line per distinct (count, reason) among the candidates, naming every candidate
    that shares it; a reason equal to the verdict's is not repeated."""
    groups: dict[tuple, list[str]] = {}
    for c in candidates:
        key = (c.get("n_matched"), c.get("required"), c.get("reason"))
        groups.setdefault(key, []).append(f"{c.get('axis')}/{c.get('spec')}")
    lines = []
    for (n, req, why), names in groups.items():
        said = "same reason as above" if why == verdict_reason else why
        label = "candidate" if len(names) == 1 else "candidates"
        lines.append(f"    {label} {', '.join(names)}: {n}/{req} ({said})")
    return lines


def plot_verdict(source: Any, verdict, config: AppConfig, out_png: Path) -> Path:
    """Write the verdict's figure (`lishield_guard.plot.plot_verdict`) to ``out_png``."""
    from lishield_guard.plot import plot_verdict as _plot

    return _plot(source, verdict, config, out_png)


PLOT_HELP = ("Write the figure of what decided the verdict: the network's logit for every "
             "axis and pyramid level, the deciding instance's spectrum with the tones of the "
             "spec that explains it best, and which frequencies take turns over its frames (the "
             "cascade profile: the fitted rows "
             "with the template and the look-alike; a clip: the deciding frame above the "
             "per-frame scores). With several images: a folder, one IMG-stem.png each (the "
             "folders too where stems repeat).")

PROFILE_HELP = ("default: the calibrated learned decision, fixed cost per image (use this). "
                "cascade: the pattern search, better on white (monochrome) LEDs but seconds per "
                "striped photo. paper: the paper's Algorithm 1 as published, a reference that "
                "flags about 95 % of photos taken under ordinary flickering light.")


def _exit_code(verdict) -> ExitCode:
    status = getattr(verdict, "status", "protected" if verdict.protected else "clean")
    if status == "protected":
        return ExitCode.PROTECTED
    if status == "undetermined":  # fail closed: never "clean"
        return ExitCode.ERROR
    return ExitCode.CLEAN


def _input_error(label: str, exc: BaseException) -> ExitCode:
    """Print an input's error line with its stable code (`lishield_guard.errors.classify`,
    the mapping scan and the service use too); its exit status from the one table
    (`lishield_guard.errors.ERROR_CODES`)."""
    from lishield_guard.errors import EXIT_INPUT_ERROR, classify, error_code

    code, message = classify(exc)
    typer.echo(f"error: {label}: {message} [{code}]", err=True)
    try:
        status = error_code(code).exit_status
    except KeyError:  # pragma: no cover - a test keeps every raised code in the table
        status = None
    return ExitCode(status if status is not None else EXIT_INPUT_ERROR)


def plot_names(images: list[str]) -> list[str]:
    """The figure's file name of each image when several go to one ``--plot`` folder: its
    stem, or where stems collide (``a/x.jpg``, ``b/x.jpg``) the fewest folders (then the
    suffix) that tell the images apart, so that no figure is written over another; the same
    path given twice gets ``-2``.

    Examples
    --------
    >>> plot_names(["a/x.jpg", "b/x.jpg", "y.png", "-"])
    ['a_x.png', 'b_x.png', 'y.png', 'stdin.png']
    >>> plot_names(["x.jpg", "x.png", "x.jpg"])
    ['x.jpg.png', 'x.png.png', 'x.jpg-2.png']
    """
    def parts(image: str) -> list[str]:
        if image == "-":
            return ["stdin"]
        return [q for q in Path(image).parts if q not in ("/", "..", ".")] or ["image"]

    def name(full: list[str], depth: int, suffix: bool) -> str:
        tail = full[-depth:]
        return "_".join([*tail[:-1], tail[-1] if suffix else Path(tail[-1]).stem])

    paths = [parts(image) for image in images]
    chosen = []
    for full in paths:
        options = [(d, k) for k in (False, True) for d in range(1, len(full) + 1)]
        depth, suffix = next(((d, k) for d, k in options if sum(
            name(o, d, k) == name(full, d, k) for o in paths) == 1), options[-1])
        chosen.append(name(full, depth, suffix))
    out = []
    for i, n in enumerate(chosen):
        taken = chosen[:i].count(n)
        out.append(f"{n}-{taken + 1}.png" if taken else f"{n}.png")
    return out


def _detect_one(image: str, cfg: AppConfig, *, explain: bool, as_json: bool,
                plot: Path | None) -> ExitCode:
    """Detect on one image (a path, or - for stdin), print its verdict (and write its plot
    to ``plot``); its exit code."""
    from lishield_guard.video import detect_media

    if image == "-":
        source: Any = sys.stdin.buffer.read()
        label = "<stdin>"
    else:
        source, label = image, image
    try:  # a missing or unreadable file is a typed error of the reader, as in scan records
        verdict = detect_media(source, cfg)
        if explain and verdict.protected and hasattr(verdict.evidence, "physics"):
            verdict = _with_physics(verdict, source, cfg)
    except Exception as exc:  # noqa: BLE001 - never clean; a bug still prints no traceback
        return _input_error(label, exc)
    if as_json:
        typer.echo(json.dumps({"path": label, **verdict.to_dict()}))
    else:
        typer.echo(_describe(verdict, label, explain=explain))
    if plot is not None:
        out = plot
        try:
            plot_verdict(source, verdict, cfg, out)
        except OSError as exc:
            raise fail(f"cannot write plot {str(out)!r}: {exc.strerror}", ExitCode.ERROR) \
                from None
        typer.echo(f"plot written to {out}", err=True)
    return _exit_code(verdict)


def detect_command(
    images: Annotated[list[str], typer.Argument(
        metavar="IMG...", show_default=False,
        help="Image files (JPEG, PNG, WebP, TIFF, BMP, HEIC) or video clips (MP4, MOV, WebM, "
             "MKV), or - for one on stdin. For folders and archives use `lishield-guard "
             "scan`.")],
    explain: Annotated[bool, typer.Option("--explain", help="Also print the evidence: fitted "
                                          "parameters, tones, every candidate.")] = False,
    plot: Annotated[Path | None, typer.Option(
        "--plot", metavar="FILE.png|DIR", help=PLOT_HELP)] = None,
    config: Annotated[Path | None, typer.Option(
        "--config", metavar="FILE.toml", help="Config (default: the shipped one).")] = None,
    profile: Annotated[Profile | None, typer.Option(
        "--profile", help=PROFILE_HELP, show_default=False)] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print one JSON object per image (Verdict.to_dict() plus path).")] = False,
    threads: Annotated[int, typer.Option(
        "--threads", min=1, help="Native (BLAS, OpenCV) threads. One is fastest for one image "
        "at a time, above all on a busy machine.")] = 1,
) -> None:
    """Decide whether images or video clips carry a policy barcode; print the verdict and why.

    A clip is screened frame by frame until its verdict is certain (at most 16 frames; the
    evidence of the frames adds up); --explain lists every screened frame's score and --plot
    draws the deciding frame and the per-frame scores.

    Exit status: 0 every image clean; 1 at least one protected (wins over errors); 2 usage
    error (bad arguments or config); 3 nothing protected but a missing, unreadable or
    undetermined image. Folders and archives: `lishield-guard scan`.

    Examples:
      lishield-guard detect photo.jpg
      lishield-guard detect a.jpg b.png --json
      lishield-guard detect photo.jpg --explain --plot verdict.png
      lishield-guard detect clip.mp4 --explain
    """
    from lishield_guard.threads import pin_native_threads

    try:
        cfg = resolve_config(config, profile)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    pin_native_threads(threads)
    if "-" in images and len(images) > 1:
        raise fail("- (stdin) reads one image; give files instead, or pipe one image")
    for image in images:
        if image != "-" and Path(image).is_dir():
            raise fail(f"{image!r} is a folder; scan folders and archives with "
                        f"`lishield-guard scan {image}`")
    if plot is not None and len(images) > 1:
        plot.mkdir(parents=True, exist_ok=True)
        outs: list[Path | None] = [plot / n for n in plot_names(images)]
    else:
        outs = [plot] * len(images)
    codes = [_detect_one(image, cfg, explain=explain, as_json=as_json, plot=out)
             for image, out in zip(images, outs, strict=True)]
    # protected wins over errors; an input error or an undetermined image is never clean
    if ExitCode.PROTECTED in codes:
        raise typer.Exit(int(ExitCode.PROTECTED))
    raise typer.Exit(max((int(c) for c in codes), default=int(ExitCode.CLEAN)))


def register(app: typer.Typer) -> None:
    """Add the ``detect`` command to the main CLI app."""
    app.command(name="detect")(detect_command)
