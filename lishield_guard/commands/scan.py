"""`lishield-guard scan`: parallel, resumable scan of files, folders, lists and archives."""

from __future__ import annotations

import os
import sys
from collections import Counter
from pathlib import Path

import typer

from lishield_guard.commands import ExitCode, fail
from lishield_guard.errors import LishieldError
from lishield_guard.profiles import NAMES as PROFILES

__all__ = ["exit_code_for", "register", "scan_command"]


def _read_list(src: str) -> list[str]:
    try:  # names that are not UTF-8 survive as surrogate escapes (os.fsdecode's form)
        raw = sys.stdin.buffer.read() if src == "-" else Path(src).read_bytes()
        text = raw.decode("utf-8", errors="surrogateescape")
    except OSError as exc:
        raise fail(f"cannot read --from-list {src!r}: {exc.strerror}") from None
    return [ln.rstrip("\r") for ln in text.splitlines() if ln.strip()]


def exit_code_for(counts: Counter, *, fail_on_error: bool = True) -> ExitCode:
    """The scan's exit code from record counts by status (see `ExitCode`).

    Protected wins over errors; errors and undetermined results give 3 unless
    ``fail_on_error`` is False.

    Examples
    --------
    >>> int(exit_code_for(Counter(clean=5, error=2)))
    3
    >>> int(exit_code_for(Counter(protected=1, error=2)))
    1
    """
    if counts["protected"]:
        return ExitCode.PROTECTED
    if fail_on_error and (counts["error"] or counts["undetermined"]):
        return ExitCode.ERROR
    return ExitCode.CLEAN


def _summary(counts: Counter, codes: Counter, n_resumed: int, n_ignored: int,
             elapsed_s: float, whole: Counter | None) -> str:
    n = sum(counts[k] for k in ("protected", "clean", "undetermined", "error"))
    n_img = counts["protected"] + counts["clean"] + counts["undetermined"]
    rate = n_img / elapsed_s if elapsed_s > 0 else 0.0
    parts = [f"scanned {n} input(s) in {elapsed_s:.1f} s ({rate:.1f} images/s):",
             f"{counts['protected']} protected, {counts['clean']} clean, "
             f"{counts['undetermined']} undetermined, {counts['error']} error/skipped"]
    if n_ignored:
        parts.append(f"({n_ignored} non-image file(s) ignored)")
    if n_resumed:
        parts.append(f"({n_resumed} already recorded, not rescanned)")
    text = " ".join(parts)
    if whole is not None:
        text += (f"\n  whole output file: {whole['protected']} protected, {whole['clean']} "
                 f"clean, {whole['undetermined']} undetermined, {whole['error']} error/skipped")
    if codes:
        text += "\n  by code: " + ", ".join(f"{c}={k}" for c, k in codes.most_common())
    return text


SCAN_HELP = """
    Scan many images; one record per input (JSON Lines or CSV), written as results arrive.

    Each record has a status: protected, clean, undetermined (the detector could not look,
    e.g. an image under 64 lines on every axis) or error. Folders and archives are searched
    for images by name and by signature (sidecars and hidden non-images are ignored); only
    regular files are read. The exit status covers the whole output file, records of earlier
    runs included after --resume.

    \b
    Exit status (one table for every command):
      0  every record clean
      1  at least one image protected (wins over errors)
      2  usage error
      3  nothing protected, but input errors or undetermined results present
         (0 with --no-fail-on-error)

    Examples:

    \b
        lishield-guard scan photos/ -o out.jsonl -j 4
        lishield-guard scan archive.tar.gz -o out.jsonl --resume --no-progress
        lishield-guard scan --from-list paths.txt --include '*.jpg' -o out.csv --format csv
    """


def scan_command(
    paths: list[str] = typer.Argument(None, metavar="PATH...",
                                      help="Files, folders, .zip and .tar[.gz] archives."),
    output: str = typer.Option("-", "--output", "-o", metavar="FILE",
                               help="Output file (JSON Lines or CSV), or - for stdout."),
    fmt: str = typer.Option("jsonl", "--format", help="jsonl or csv."),
    from_list: str | None = typer.Option(None, "--from-list", metavar="FILE",
                                         help="Also scan the paths listed in FILE (- = stdin)."),
    include: list[str] = typer.Option([], "--include", metavar="GLOB",
                                      help="Only scan matching images in folders/archives."),
    exclude: list[str] = typer.Option([], "--exclude", metavar="GLOB",
                                      help="Skip matching files, folders and archives."),
    jobs: int = typer.Option(0, "--jobs", "-j", help="Worker processes (default: all cores)."),
    resume: bool = typer.Option(False, "--resume",
                                help="Append to --output, skipping inputs already recorded."),
    dask: str | None = typer.Option(None, "--dask", metavar="local",
                                    help="Run on a Dask LocalCluster with --jobs workers."),
    scheduler: str | None = typer.Option(None, "--scheduler", metavar="tcp://HOST:PORT",
                                         help="Run on an existing Dask scheduler."),
    config: Path | None = typer.Option(None, "--config", help="Config TOML (default: shipped)."),
    profile: str | None = typer.Option(None, "--profile",
                                       help=f"Detector profile: {'|'.join(PROFILES)}."),
    progress: bool | None = typer.Option(None, "--progress/--no-progress",
                                         help="Progress bar on stderr (default: when stderr "
                                         "is a terminal)."),
    fail_on_error: bool = typer.Option(True, "--fail-on-error/--no-fail-on-error",
                                       help="Exit 3 when, with nothing protected, records "
                                       "hold input errors or undetermined results (default); "
                                       "--no-fail-on-error exits 0 then."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Scan many images; one record per input (JSON Lines or CSV), written as results arrive."""
    from lishield_guard import scan
    from lishield_guard.commands.detect import resolve_config

    _check(fmt, dask, scheduler, resume, output, jobs)
    jobs = jobs or os.cpu_count() or 1
    inputs = list(paths or [])  # a missing path is an input error: a not_found record, exit 3
    if from_list is not None:
        inputs += _read_list(from_list)
    if not inputs:
        raise fail("nothing to scan: give PATH... or --from-list")
    try:
        cfg = resolve_config(config, profile)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    if (not scan.is_stream(output) and not resume and os.path.isfile(output)
            and os.path.getsize(output)):  # /dev/stdout, pipes and ttys are written as they are
        raise fail(f"{output!r} exists; use --resume to continue it, or remove it")
    show = not quiet and (sys.stderr.isatty() if progress is None else progress)
    try:
        with scan.dask_client(local=bool(dask), scheduler=scheduler, jobs=jobs) as client:
            tally = scan.scan_to_output(inputs, output=output, fmt=fmt, config=cfg, jobs=jobs,
                                        resume=resume, include=include, exclude=exclude,
                                        client=client, progress=show)
    except scan.DaskUnreachable as exc:
        raise fail(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None
    except OSError as exc:
        raise fail(f"cannot write {output!r}: {exc}", ExitCode.ERROR) from None
    except KeyboardInterrupt:
        raise fail("interrupted; rerun with --resume to continue", ExitCode.ERROR) from None
    if not quiet:
        typer.echo(_summary(tally.counts, tally.codes, tally.n_resumed, tally.n_ignored,
                            tally.elapsed_s, tally.whole if resume else None), err=True)
    whole = tally.whole
    raise typer.Exit(int(exit_code_for(whole if whole is not None else tally.counts,
                                       fail_on_error=fail_on_error)))


def _check(fmt: str, dask: str | None, scheduler: str | None, resume: bool, output: str,
           jobs: int) -> None:
    """Usage checks of the options."""
    from lishield_guard.scan import is_stream

    if fmt not in ("jsonl", "csv"):
        raise fail(f"--format must be jsonl or csv, got {fmt!r}")
    if dask is not None and dask != "local":
        raise fail(f"--dask only accepts 'local', got {dask!r} (use --scheduler for a cluster)")
    if dask and scheduler:
        raise fail("use either --dask local or --scheduler, not both")
    if resume and is_stream(output):
        raise fail("--resume needs --output FILE (a regular file)")
    if jobs < 0:
        raise fail(f"--jobs must be >= 1, got {jobs}")


def register(app: typer.Typer) -> None:
    """Add the ``scan`` command to the main CLI app."""
    app.command(name="scan", help=SCAN_HELP)(scan_command)
