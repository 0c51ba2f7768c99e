"""`lishield-guard firmware`: compile a barcode into an LED sequence file (C, JSON or binary)."""

from __future__ import annotations

import json
import math
import os
import warnings
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from lishield_guard.commands import ExitCode
from lishield_guard.commands.spec import load_spec_arg
from lishield_guard.errors import LishieldError
from lishield_guard.spec import NOTE_RULES, SpecWarning, check_spec

__all__ = ["read_seed", "register"]


class Format(StrEnum):
    """Output formats of the firmware command."""

    c = "c"
    json = "json"
    bin = "bin"


def read_seed(*, seed_env: str | None, seed_file: Path | None) -> bytes | None:
    """Read the intensity-randomization secret from an environment variable or a file.

    Parameters
    ----------
    seed_env : str, optional
        Name of an environment variable holding the seed (UTF-8 text).
    seed_file : Path, optional
        File holding the seed; one trailing newline is dropped.

    Returns
    -------
    seed : bytes or None
        None when neither source is given.

    Raises
    ------
    FirmwareError
        If both sources are given, the variable is unset or empty, or the file is unreadable
        or empty. Messages never include the seed.
    """
    from lishield_guard.errors import FirmwareError

    if seed_env and seed_file:
        raise FirmwareError("give either --seed-env or --seed-file, not both")
    if seed_env:
        value = os.environ.get(seed_env)
        if not value:
            raise FirmwareError(f"environment variable {seed_env} (--seed-env) is unset or empty")
        return value.encode("utf-8")
    if seed_file:
        try:
            raw = Path(seed_file).read_bytes()
        except OSError as exc:
            raise FirmwareError(f"cannot read --seed-file {str(seed_file)!r}: "
                                f"{exc.strerror}") from exc
        raw = raw[:-1] if raw.endswith(b"\n") else raw
        raw = raw[:-1] if raw.endswith(b"\r") else raw
        if not raw:
            raise FirmwareError(f"--seed-file {str(seed_file)!r} is empty")
        return raw
    return None


def _fmt_hz(x: float) -> str:
    return f"{x:.4f}" if math.isfinite(x) else "lost"


def _print_report(rep: dict, out: Path, fmt: str, n_bytes: int) -> None:
    typer.echo(f"wrote {out} ({fmt}, {n_bytes} bytes): spec {rep['spec']}, {rep['n_steps']} steps,"
               f" clock {rep['clock_hz']} Hz")
    typer.echo(f"  period {rep['period_ticks']} ticks = {rep['period_s'] * 1e3:.6g} ms "
               f"({rep['n_patterns']} pattern(s) of {rep['pattern_period_s'] * 1e3:.6g} ms; "
               f"spec {rep['spec_pattern_period_s'] * 1e3:.6g} ms)")
    typer.echo(f"  slot rate {rep['slot_rate_hz']:.6f} Hz (spec {rep['spec_slot_rate_hz']:g} Hz)")
    typer.echo("  channel  spec Hz     achieved Hz   rel. error")
    for t in rep["tones"]:
        typer.echo(f"  {t['channel']:<7}  {t['spec_hz']:>8g}  {_fmt_hz(t['achieved_hz']):>14}"
                   f"   {t['rel_error']:.2e}")
    w = rep["worst_ratio"]
    if w is not None:
        typer.echo(f"  worst ratio error {rep['worst_ratio_error']:.3e} "
                   f"({w['numerator']} / {w['denominator']})")


class AllowRule(StrEnum):
    """Flicker-free rules a spec may break on request (`lishield_guard.spec.check_spec`)."""

    flicker = "flicker"
    switching = "switching"


def firmware_cmd(
    spec: Annotated[str, typer.Argument(metavar="PRESET|SPEC.toml",
                                        help="Preset name or TOML spec file.")],
    fmt: Annotated[Format, typer.Option("--format", "-f", help="Output format.")] = Format.c,
    output: Annotated[Path, typer.Option("--output", "-o", help="File to write.",
                                         dir_okay=False)] = ...,
    clock_hz: Annotated[int, typer.Option("--clock-hz", min=1,
                                          help="Timer tick rate in Hz.")] = 1_000_000,
    seed_env: Annotated[str | None, typer.Option(
        "--seed-env", metavar="VAR",
        help="Environment variable holding the intensity-randomization secret.")] = None,
    seed_file: Annotated[Path | None, typer.Option(
        "--seed-file", dir_okay=False,
        help="File holding the intensity-randomization secret.")] = None,
    n_patterns: Annotated[int | None, typer.Option(
        "--n-patterns", min=1, help="Patterns per loop (default 8 if randomized, else 1).")
    ] = None,
    max_ratio_error: Annotated[float, typer.Option(
        "--max-ratio-error", help="Refuse when a tone ratio is off by more (relative).")
    ] = 1e-3,
    symbol: Annotated[str, typer.Option("--symbol", help="C identifier prefix (--format c).")
                      ] = "lsp_seq",
    report_json: Annotated[bool, typer.Option(
        "--json", help="Print the achieved-frequency report as JSON.")] = False,
    allow: Annotated[list[AllowRule] | None, typer.Option(
        "--allow", help="Play a spec that breaks this flicker-free rule, with a warning "
                        "(e.g. the paper's 200 Hz switching: --allow flicker). Repeatable.")
    ] = None,
) -> None:
    """Compile a barcode into a tick-timed LED sequence and write it as C, JSON or binary.

    The secret for intensity randomization (specs with intensity_levels > 1) is read from an
    environment variable (--seed-env) or a file (--seed-file), never from the command line,
    and is printed nowhere. Specs and formats: docs/firmware.md.

    Examples:
      lishield-guard firmware table1-seq1 --format c -o lishield_seq.h
      lishield-guard firmware venue.toml -f bin -o seq.bin --seed-env SECRET
      lishield-guard firmware paper200.toml --allow flicker -f json -o seq.json
    """
    from firmware.emit import to_binary, to_c_header, to_json  # lazy: core never imports firmware
    from firmware.sequence import achieved_report, compile_spec

    try:
        barcode = load_spec_arg(spec)
        seed = read_seed(seed_env=seed_env, seed_file=seed_file)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SpecWarning)
            seq = compile_spec(barcode, clock_hz=clock_hz, seed=seed, n_patterns=n_patterns,
                               max_ratio_error=max_ratio_error,
                               allow=tuple(r.value for r in allow or ()))
        for w in caught:
            if issubclass(w.category, SpecWarning):
                typer.echo(f"warning: {w.message}", err=True)
        for v in check_spec(barcode).violations:  # the notes `spec show` prints too
            if v.rule in NOTE_RULES:
                typer.echo(f"note: spec {barcode.name!r} [{v.rule}] {v.message}", err=True)
        del seed
        if fmt is Format.bin:
            data = to_binary(seq)
        elif fmt is Format.json:
            data = to_json(seq, indent=1).encode("utf-8")
        else:
            data = to_c_header(seq, symbol=symbol).encode("utf-8")
        try:
            output.write_bytes(data)
        except OSError as exc:
            raise _OutputError(f"cannot write {str(output)!r}: {exc.strerror}") from exc
    except (LishieldError, _OutputError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(int(ExitCode.USAGE)) from None
    rep = achieved_report(seq)
    if report_json:
        typer.echo(json.dumps(rep, indent=1, default=str))
    else:
        _print_report(rep, output, fmt.value, len(data))


class _OutputError(Exception):
    """The output file could not be written."""


def register(app: typer.Typer) -> None:
    """Add the ``firmware`` command to the main CLI app."""
    app.command("firmware")(firmware_cmd)
