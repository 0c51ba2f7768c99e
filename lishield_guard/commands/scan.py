"""`lishield-guard scan`: parallel, resumable scan of files, folders, lists and archives."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import typer

from lishield_guard.commands import ExitCode
from lishield_guard.errors import LishieldError

__all__ = ["register", "scan_command"]


def _fail(message: str, code: ExitCode = ExitCode.USAGE) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(int(code))


def _read_list(src: str) -> list[str]:
    try:
        text = sys.stdin.read() if src == "-" else Path(src).read_text(encoding="utf-8")
    except OSError as exc:
        raise _fail(f"cannot read --from-list {src!r}: {exc.strerror}") from None
    return [ln.rstrip("\r") for ln in text.splitlines() if ln.strip()]


def _summary(counts: Counter, codes: Counter, n_resumed: int, elapsed_s: float) -> str:
    n = counts["protected"] + counts["clean"] + counts["error"]
    n_img = counts["protected"] + counts["clean"]
    rate = n_img / elapsed_s if elapsed_s > 0 else 0.0
    parts = [f"scanned {n} input(s) in {elapsed_s:.1f} s ({rate:.1f} images/s):",
             f"{counts['protected']} protected, {counts['clean']} clean, "
             f"{counts['error']} error/skipped"]
    if n_resumed:
        parts.append(f"({n_resumed} already recorded, not rescanned)")
    text = " ".join(parts)
    if codes:
        text += "\n  by code: " + ", ".join(f"{c}={k}" for c, k in codes.most_common())
    return text


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
    profile: str | None = typer.Option(None, "--profile", help="Detector profile: default|paper."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Scan many images; one record per input (JSON Lines or CSV), written as results arrive.

    Exit status: 0 when nothing is protected, 1 when at least one image is, 2 on usage errors.
    """
    from lishield_guard.commands.detect import resolve_config
    from lishield_guard.scan import RecordWriter, filter_new, iter_items, read_done_keys, run_scan

    if fmt not in ("jsonl", "csv"):
        raise _fail(f"--format must be jsonl or csv, got {fmt!r}")
    if dask is not None and dask != "local":
        raise _fail(f"--dask only accepts 'local', got {dask!r} (use --scheduler for a cluster)")
    if dask and scheduler:
        raise _fail("use either --dask local or --scheduler, not both")
    if resume and output == "-":
        raise _fail("--resume needs --output FILE")
    if jobs < 0:
        raise _fail(f"--jobs must be >= 1, got {jobs}")
    jobs = jobs or os.cpu_count() or 1
    inputs = list(paths or [])
    missing = [p for p in inputs if not os.path.exists(p)]
    if missing:
        raise _fail(f"no such file or folder: {missing[0]!r}")
    if from_list is not None:
        inputs += _read_list(from_list)
    if not inputs:
        raise _fail("nothing to scan: give PATH... or --from-list")
    try:
        cfg = resolve_config(config, profile)
    except LishieldError as exc:
        raise _fail(str(exc)) from None
    if output != "-" and not resume and os.path.exists(output) and os.path.getsize(output):
        raise _fail(f"{output!r} exists; use --resume to continue it, or remove it")

    done: set[str] = read_done_keys(output, fmt) if resume else set()
    n_resumed = 0

    def on_skip(_item) -> None:
        nonlocal n_resumed
        n_resumed += 1
        if bar is not None:  # counted in the total, so the bar still reaches 100 %
            bar.update(1)

    kw = {"include": include, "exclude": exclude, "max_bytes": cfg.limits.max_bytes}
    items = filter_new(iter_items(inputs, **kw), done, on_skip)

    show = not quiet and sys.stderr.isatty()
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=None, unit="img", file=sys.stderr, dynamic_ncols=True,
                   smoothing=0.05)

        def count() -> None:  # total for the ETA, counted while the scan already runs
            n = sum(1 for _ in iter_items(inputs, **{**kw, "read_data": False}))
            bar.total = n
            bar.refresh()

        threading.Thread(target=count, daemon=True).start()

    client = cluster = None
    if dask or scheduler:
        import logging

        from distributed import Client, LocalCluster

        try:
            if dask:
                cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
                client = Client(cluster)
            else:
                client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise _fail(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None

    counts: Counter = Counter()
    codes: Counter = Counter()
    t0 = time.perf_counter()
    try:
        with RecordWriter(None if output == "-" else output, fmt) as writer:
            for rec in run_scan(items, config=cfg, jobs=jobs, client=client):
                writer.write(rec)
                if rec["error"] is not None:
                    counts["error"] += 1
                    codes[rec["code"]] += 1
                elif rec["protected"]:
                    counts["protected"] += 1
                else:
                    counts["clean"] += 1
                if bar is not None:
                    bar.update(1)
    except OSError as exc:
        raise _fail(f"cannot write {output!r}: {exc}", ExitCode.ERROR) from None
    except KeyboardInterrupt:
        raise _fail("interrupted; rerun with --resume to continue", ExitCode.ERROR) from None
    finally:
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    if not quiet:
        typer.echo(_summary(counts, codes, n_resumed, time.perf_counter() - t0), err=True)
    raise typer.Exit(int(ExitCode.PROTECTED if counts["protected"] else ExitCode.CLEAN))


def register(app: typer.Typer) -> None:
    """Add the ``scan`` command to the main CLI app."""
    app.command(name="scan")(scan_command)
