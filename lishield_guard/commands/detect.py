"""`lishield-guard detect IMG`: one verdict in words or JSON, optionally with a spectrum plot."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import typer

from lishield_guard.commands import ExitCode
from lishield_guard.config import AppConfig
from lishield_guard.errors import ConfigError, LishieldError

__all__ = ["detect_command", "plot_verdict", "register", "resolve_config"]

PROFILES = ("default", "paper")


def _fail(message: str, code: ExitCode = ExitCode.USAGE) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(int(code))


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


def _describe(v, label: str, *, explain: bool) -> str:
    d = v.to_dict()
    ev = v.evidence or {}
    lines = []
    if v.protected:
        lines.append(f"{label}: PROTECTED by policy {v.policy!r}")
    else:
        lines.append(f"{label}: not protected (no policy barcode found)")
    unit = "ratios" if v.profile == "paper" else "tones"
    lines.append(f"  matches: {v.matches}/{v.required} {unit} required  "
                 f"score: {v.score:.3f}  profile: {v.profile}")
    reason = ev.get("reason")
    if reason is None and v.profile == "paper":
        reason = (f"{v.matches} ratio match(es) among {len(ev.get('frequencies_hz', []))} "
                  f"peak frequencies; spec {ev.get('best_spec')}")
    lines.append(f"  reason: {reason}")
    if v.skipped:
        lines.append("  skipped: " + "; ".join(v.skipped))
    t = d["timings_ms"]
    total = sum(t.values())
    lines.append("  timings: " + ", ".join(f"{k} {ms:.1f} ms" for k, ms in t.items())
                 + f" (total {total:.1f} ms)")
    if explain:
        best = ev.get("best")
        if best:
            sigma = best.get("sigma_cpr_per_hz") or 0.0
            rate = best.get("row_rate_hz_if_not_resized")
            lines.append(f"  best spec: {best.get('spec')}  scale: {sigma:.4g} cycles/row per Hz"
                         + (f" (row rate {rate:,.0f} Hz if not resized)" if rate else ""))
            for ch, hz in (best.get("matched_hz") or {}).items():
                tones = ", ".join(f"{f:g} Hz ({f * sigma:.4f} c/row)" for f in hz) or "none"
                lines.append(f"    {ch}: matched {tones}")
            lines.append(f"    purity {best.get('purity')}  switches {best.get('switches')}"
                         f"  occupancy {best.get('occupancy')}")
            for stage in ("fold", "sweep"):  # template fits: folded, and tiled over the frame
                info = best.get(stage)
                if info:
                    lines.append(f"    {stage}: " + ", ".join(
                        f"{k} {v}" for k, v in info.items() if k not in ("spec", "fit")))
                if info and info.get("fit"):  # the sweep's exact-model refinement
                    lines.append("    exact fit: " + ", ".join(
                        f"{k} {v}" for k, v in info["fit"].items() if k != "spec"))
            for c in ev.get("candidates", []):
                lines.append(f"    candidate {c.get('axis')}/{c.get('spec')}: "
                             f"{c.get('n_matched')}/{c.get('required')} ({c.get('reason')})")
        if "frequencies_hz" in ev:
            lines.append("  peak frequencies (Hz at nominal row rate): "
                         + ", ".join(f"{f:g}" for f in ev["frequencies_hz"]))
    return "\n".join(lines)


def _best_axis(ev: dict) -> int:
    best = ev.get("best") or {}
    for c in ev.get("candidates", []):
        if c.get("spec") == best.get("spec") and c.get("matched_hz") == best.get("matched_hz"):
            return 1 if c.get("axis") == "columns" else 0
    return 0


def _tone_marks_cpr(v, config: AppConfig) -> list[tuple[str, float, float]]:
    """(channel, Hz, cycles/row) of every matched or detected tone in the evidence."""
    ev = v.evidence or {}
    marks = []
    if v.profile == "paper":
        rate = config.detector.nominal_row_rate_hz
        marks = [("W", f, f / rate) for f in ev.get("frequencies_hz", [])]
    else:
        best = ev.get("best") or {}
        sigma = best.get("sigma_cpr_per_hz") or 0.0
        for ch, hz in (best.get("matched_hz") or {}).items():
            marks.extend((ch, f, f * sigma) for f in hz)
    return marks


def plot_verdict(source: Any, verdict, config: AppConfig, out_png: Path) -> Path:
    """Draw row profiles, their spectrum and the matched tones of one verdict to a PNG.

    Parameters
    ----------
    source : bytes, str or Path
        The image the verdict was computed on.
    verdict : Verdict
        Its verdict (evidence gives the tones and their scale).
    config : AppConfig
        Config of the detection (block count, band, nominal row rate).
    out_png : Path
        Where to write the figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from lishield_guard.barcode import scale_range_cpr_per_hz
    from lishield_guard.decode import decode
    from lishield_guard.profile import block_row_profiles, detrend_profiles

    det = config.detector
    decoded = decode(source, limits=config.limits)
    axis = _best_axis(verdict.evidence or {}) if verdict.profile == "default" else 0
    profiles = block_row_profiles(decoded.luma, n_col_blocks=det.n_col_blocks, axis=axis)
    n_rows = profiles.shape[1]
    freqs_hz = [f for p in config.policies for s in p.specs for f in s.all_freqs_hz]
    lo_cpr = min(freqs_hz) * scale_range_cpr_per_hz(det)[0] if freqs_hz else 0.0
    sigma_rows = min(0.5 / lo_cpr if lo_cpr > 0 else n_rows, n_rows / 6.0)
    contrast, _ = detrend_profiles(profiles, sigma_rows=sigma_rows)
    n_fft = 1 << int(math.ceil(math.log2(max(n_rows, 2)))) + 1
    win = np.hanning(n_rows)
    power = np.abs(np.fft.rfft(contrast * win, n=n_fft, axis=-1)) ** 2
    f_cpr = np.fft.rfftfreq(n_fft)

    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(10, 7), constrained_layout=True)
    rows = np.arange(n_rows)
    for b in range(contrast.shape[0]):
        ax0.plot(rows, contrast[b] * 100, lw=0.5, alpha=0.35)
    ax0.plot(rows, contrast.mean(axis=0) * 100, color="k", lw=0.8, label="mean of blocks")
    ax0.set_xlabel("sensor row" if axis == 0 else "sensor row (image columns)")
    ax0.set_ylabel("contrast (%)")
    ax0.set_title(f"Detrended row profiles ({contrast.shape[0]} column blocks)")
    ax0.legend(loc="upper right")
    for b in range(power.shape[0]):
        ax1.semilogy(f_cpr, power[b] + 1e-20, lw=0.4, alpha=0.3)
    ax1.semilogy(f_cpr, power.mean(axis=0) + 1e-20, color="k", lw=0.8, label="mean power")
    colours = {"W": "tab:purple", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    seen = set()
    for ch, hz, cpr in _tone_marks_cpr(verdict, config):
        lab = None if ch in seen else f"{ch} tones"
        seen.add(ch)
        ax1.axvline(cpr, color=colours.get(ch, "tab:orange"), ls="--", lw=1, label=lab)
        ax1.annotate(f"{hz:g} Hz", (cpr, 0.95), xycoords=("data", "axes fraction"),
                     rotation=90, va="top", fontsize=8)
    ax1.set_xlim(0, 0.5)
    ax1.set_xlabel("frequency (cycles per row)")
    ax1.set_ylabel("power (a.u.)")
    state = f"PROTECTED ({verdict.policy})" if verdict.protected else "not protected"
    ax1.set_title(f"Spectrum: {state}, {verdict.matches}/{verdict.required} "
                  f"[{verdict.profile} profile]")
    ax1.legend(loc="upper right")
    fig.savefig(out_png, dpi=100)
    plt.close(fig)
    return out_png


def detect_command(
    image: str = typer.Argument(..., metavar="IMG", help="Image file, or - for stdin bytes."),
    explain: bool = typer.Option(False, "--explain", help="Also print the evidence."),
    plot: Path | None = typer.Option(None, "--plot", metavar="FILE.png",
                                     help="Write row profiles and spectrum with matched tones."),
    config: Path | None = typer.Option(None, "--config", help="Config TOML (default: shipped)."),
    profile: str | None = typer.Option(None, "--profile", help="Detector profile: default|paper."),
    as_json: bool = typer.Option(False, "--json", help="Print Verdict.to_dict() as JSON."),
) -> None:
    """Decide whether one image carries a policy barcode (exit 1 protected, 0 not, 2 bad input)."""
    from lishield_guard.detect import detect

    try:
        cfg = resolve_config(config, profile)
    except LishieldError as exc:
        raise _fail(str(exc)) from None
    if image == "-":
        source: Any = sys.stdin.buffer.read()
        label = "<stdin>"
    else:
        if not Path(image).is_file():
            raise _fail(f"no such file: {image!r}")
        source, label = image, image
    try:
        verdict = detect(source, cfg)
    except LishieldError as exc:
        raise _fail(f"{label}: {exc} [{exc.code}]") from None
    except Exception as exc:  # noqa: BLE001 - a bug, but still no traceback for the user
        raise _fail(f"{label}: internal error: {type(exc).__name__}: {exc}",
                    ExitCode.ERROR) from None
    if as_json:
        typer.echo(json.dumps(verdict.to_dict(), indent=2))
    else:
        typer.echo(_describe(verdict, label, explain=explain))
    if plot is not None:
        try:
            plot_verdict(source, verdict, cfg, plot)
        except OSError as exc:
            raise _fail(f"cannot write plot {str(plot)!r}: {exc.strerror}", ExitCode.ERROR) \
                from None
        typer.echo(f"plot written to {plot}", err=True)
    raise typer.Exit(int(ExitCode.PROTECTED if verdict.protected else ExitCode.CLEAN))


def register(app: typer.Typer) -> None:
    """Add the ``detect`` command to the main CLI app."""
    app.command(name="detect")(detect_command)
