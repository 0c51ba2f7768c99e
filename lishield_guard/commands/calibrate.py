"""`lishield-guard calibrate`: sweep thresholds on clean images and positives, ship a config.

A shell: it parses the options, builds the --quick sets (synthetic data comes from `synth`,
which only the CLI may import) and calls `lishield_guard.calibration.run`.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import typer

from lishield_guard.commands import ExitCode, fail
from lishield_guard.errors import ConfigError
from lishield_guard.profiles import CASCADE, DEFAULT, LEARNED, PAPER

__all__ = ["calibrate_command", "register"]

# --- built-in sets of --quick

QUICK_TARGET_FAR = 0.25  # shown by >= 11 certification images without a false alarm
QUICK_SIZE_RC = (480, 640)  # synthetic sensor (n_rows, n_cols)
# 300-600 CPU-seconds of evidence in all (measured 2026-11-24): 2.5-5 minutes on 2 idle cores
QUICK_COUNTS = {"photos": 18, "lookalikes": 12, "positives": 18}
QUICK_SEED = 24
QUICK_VERSION = 1  # bump when the built-in sets change


def _quick_photos(out: Path, *, n: int, seed: int) -> None:
    """``n`` clean variants of scikit-image's bundled photos (crop, resize, rotate, JPEG), the
    photos taken in turn, with a manifest naming each variant's ``source``."""
    import io

    import numpy as np
    from PIL import Image

    from synth.scene import PHOTO_NAMES, skimage_photo

    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(n):
        name = PHOTO_NAMES[i % len(PHOTO_NAMES)]
        rng = np.random.default_rng([seed, i])
        img = skimage_photo(name)
        n_rows, n_cols = img.shape[:2]
        ch, cw = (max(32, int(d * rng.uniform(0.4, 1.0))) for d in (n_rows, n_cols))
        r0, c0 = int(rng.integers(0, n_rows - ch + 1)), int(rng.integers(0, n_cols - cw + 1))
        long_px = int(rng.integers(400, 641))
        scale = long_px / max(ch, cw)
        pil = Image.fromarray(np.ascontiguousarray(img[r0:r0 + ch, c0:c0 + cw]))
        pil = pil.resize((max(1, round(cw * scale)), max(1, round(ch * scale))), Image.BICUBIC)
        rot = int(rng.choice([0, 90, 180, 270]))
        if rot:
            pil = pil.rotate(-rot, expand=True)
        quality = int(rng.integers(60, 96))
        buf = io.BytesIO()
        pil.save(buf, format="JPEG", quality=quality)
        fname = f"{i:06d}.jpg"
        (out / fname).write_bytes(buf.getvalue())
        rows.append({"file": fname, "label": 0, "kind": "photo", "source": name,
                     "crop": [r0, c0, ch, cw], "long_side_px": long_px, "rotation_deg": rot,
                     "jpeg_quality": quality})
    with open(out / "manifest.jsonl", "w", encoding="utf-8") as fh:
        fh.writelines(json.dumps(r) + "\n" for r in rows)


def _quick_sets(root: Path, *, jobs: int, progress: bool) -> tuple[list[Path], Path]:
    """Build (once; reused while `QUICK_VERSION` and the counts match) the --quick sets under
    ``root``: photo variants and synthetic look-alikes (clean), synthetic captures (positives).
    """
    from synth.dataset import write_dataset

    stamp = root / "quick.json"
    want = {"version": QUICK_VERSION, "counts": QUICK_COUNTS, "size_rc": list(QUICK_SIZE_RC),
            "seed": QUICK_SEED}
    photos, looks, pos = root / "photos", root / "lookalikes", root / "positives"
    if not (stamp.is_file() and json.loads(stamp.read_text(encoding="utf-8")) == want):
        typer.echo(f"building the --quick sets in {root} ...", err=True)
        for d in (photos, looks, pos):  # ours alone: stale files would join the sets
            shutil.rmtree(d, ignore_errors=True)
        _quick_photos(photos, n=QUICK_COUNTS["photos"], seed=QUICK_SEED)
        write_dataset(looks, n_pos=0, n_neg=QUICK_COUNTS["lookalikes"], seed=QUICK_SEED + 1,
                      mix="negatives-only", size=QUICK_SIZE_RC, jobs=jobs, progress=progress)
        write_dataset(pos, n_pos=QUICK_COUNTS["positives"], n_neg=0, seed=QUICK_SEED + 2,
                      mix="default", size=QUICK_SIZE_RC, jobs=jobs, progress=progress)
        stamp.write_text(json.dumps(want), encoding="utf-8")
    return [photos, looks], pos


CALIBRATE_HELP = """
    Sweep decision thresholds on a tuning part, certify the chosen setting on held-out images.

    The clean images and the positives are split, seeded and stratified by folder and kind,
    keeping every variant of one source photo on one side (or --certify gives an independent
    clean folder). Selection sees only the tuning part: the most sensitive setting whose exact
    one-sided 95% Clopper-Pearson bound on the tuning part's false-alarm rate is <= --target-far
    (or, if none, the one with the fewest false alarms). Its false-alarm bound and detection rate
    are then computed once, on the certification part, and only that bound can meet the target.
    Exit status: 0 when the certification part shows the target, 3 when it does not (the config
    is still written, marked NOT MET in its header), 2 on usage errors.

    Examples:

    \b
        lishield-guard calibrate --quick
        lishield-guard calibrate --clean clean/ --positives pos/ --out cal.toml --report r/
        lishield-guard calibrate --clean a/ --certify b/ --positives pos/ --out cal.toml --report r/
    """


def calibrate_command(
    clean: list[Path] = typer.Option(
        [], "--clean", metavar="DIR",
        help="Folder of clean images, no barcodes (repeatable). Required unless --quick."),
    positives: Path | None = typer.Option(
        None, "--positives", metavar="DIR",
        help="Folder of barcode captures (synth dataset layout). Required unless --quick."),
    out: Path | None = typer.Option(
        None, "--out", metavar="FILE",
        help="Calibrated config TOML to write. Default with --quick: REPORT/calibrated.toml."),
    report: Path | None = typer.Option(
        None, "--report", metavar="DIR",
        help="Report folder: summary.md, plots, tables, evidence cache. Default with --quick: "
             "./calibrate-quick."),
    certify: Path | None = typer.Option(
        None, "--certify", metavar="DIR",
        help="Independent folder of clean images to certify the chosen setting on; every "
             "--clean image then tunes (positives are still split)."),
    certify_fraction: float = typer.Option(
        0.5, "--certify-fraction",
        help="Share of the clean images (unless --certify) and of the positives held out for "
             "certification, in (0, 1)."),
    split_seed: int = typer.Option(0, "--split-seed",
                                   help="Seed of the tuning / certification split."),
    target_far: float | None = typer.Option(
        None, "--target-far",
        help="Target image false-alarm rate, to be shown by the exact one-sided 95% bound on "
             f"the certification part. Default 0.001 ({QUICK_TARGET_FAR:g} with --quick)."),
    quick: bool = typer.Option(
        False, "--quick",
        help="Calibrate on small built-in sets (scikit-image photo variants, synthetic "
             "look-alikes and captures) to see the whole report in a few minutes."),
    config: Path | None = typer.Option(None, "--config", help="Base config (default: shipped)."),
    jobs: int = typer.Option(0, "--jobs", "-j", help="Worker processes (default: all cores)."),
    profiles: str = typer.Option(
        DEFAULT, "--profiles",
        help=f"Profiles to sweep, comma-separated: {LEARNED} (the learned score's threshold; "
             f"one cheap measurement per image), {CASCADE} (the pattern search's thresholds; "
             f"seconds per striped image), {PAPER} (Algorithm 1)."),
    no_cache: bool = typer.Option(False, "--no-cache", help="Do not read or write the cache."),
    dry_run: bool = typer.Option(
        False, "--dry-run",
        help="Print the split (per stratum and source groups) and what its certification part "
             "can show, then stop before any image is analysed."),
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Progress bars on stderr."),
    quiet: bool = typer.Option(False, "--quiet", "-q", hidden=True,
                               help="Same as --no-progress (kept for old scripts)."),
) -> None:
    """Sweep decision thresholds on a tuning part, certify the chosen setting on held-out images."""
    from lishield_guard import calibration

    progress = progress and not quiet
    out, report, target_far = _check(clean, positives, out, report, certify, certify_fraction,
                                     target_far, quick, dry_run, jobs)
    want, base = _profiles_and_base(profiles, config)
    jobs = jobs or os.cpu_count() or 1
    if quick:
        report.mkdir(parents=True, exist_ok=True)
        clean, positives = _quick_sets(report / "quick-data", jobs=jobs, progress=progress)
    split = {"certify": certify, "certify_fraction": certify_fraction, "split_seed": split_seed,
             "target_far": target_far, "on_warning": lambda m: typer.echo(m, err=True)}
    try:
        if dry_run:
            typer.echo(calibration.plan(clean, positives, **split))
            return
        res = calibration.run(clean, positives, out=out, report=report, base=base, jobs=jobs,
                              profiles=frozenset(want), use_cache=not no_cache, quick=quick,
                              progress=progress,
                              command=" ".join(["lishield-guard", *sys.argv[1:]]), **split)
    except calibration.CalibrationError as exc:
        raise fail(str(exc), ExitCode.ERROR if exc.failed else ExitCode.USAGE) from None
    except ConfigError as exc:  # the configured weights cannot be read or do not match
        raise fail(str(exc), ExitCode.USAGE) from None
    typer.echo(calibration.report.console_report(res.info, res.best, res.n_settings,
                                                 res.report_paths["summary"]))
    if not res.met:
        typer.echo(f"warning: target FAR {target_far:g} NOT MET on the certification part: "
                   f"{res.reason}. The config is written, marked NOT MET.", err=True)
        raise typer.Exit(int(ExitCode.ERROR))


def _profiles_and_base(profiles: str, config: Path | None):
    """The profiles to sweep and the base config (usage errors exit 2)."""
    from lishield_guard.calibration import PROFILES
    from lishield_guard.config import load_config
    from lishield_guard.errors import LishieldError

    want = {p.strip() for p in profiles.split(",") if p.strip()}
    if not want or want - set(PROFILES):
        raise fail(f"--profiles takes {', '.join(PROFILES)} (one or more), got {profiles!r}")
    try:
        return want, load_config(config)
    except LishieldError as exc:
        raise fail(str(exc)) from None


def _check(clean, positives, out, report, certify, certify_fraction, target_far, quick,
           dry_run, jobs) -> tuple[Path, Path, float]:
    """Usage checks; the defaults of --quick. Returns (out, report, target_far)."""
    if quick:
        if clean or positives is not None:
            raise fail("--quick calibrates on built-in sets; drop --clean and --positives")
        report = report or Path("calibrate-quick")
        out = out or report / "calibrated.toml"
        target_far = QUICK_TARGET_FAR if target_far is None else target_far
    else:
        needed = (("--clean", clean), ("--positives", positives)) + (
            () if dry_run else (("--out", out), ("--report", report)))
        missing = [o for o, v in needed if not v]
        if missing:
            raise fail(f"missing {', '.join(missing)} (or use --quick for built-in sets)")
        target_far = 1e-3 if target_far is None else target_far
    if not 0 < target_far < 1:
        raise fail(f"--target-far must be in (0, 1), got {target_far!r}")
    if not 0 < certify_fraction < 1:
        raise fail(f"--certify-fraction must be in (0, 1), got {certify_fraction!r}")
    if jobs < 0:
        raise fail(f"--jobs must be >= 1 (0: all cores), got {jobs}")
    for d in [*clean, *([positives] if positives else []), *([certify] if certify else [])]:
        if not d.is_dir():
            raise fail(f"not a folder: {str(d)!r}")
    return out, report, target_far


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main CLI app."""
    app.command(name="calibrate", help=CALIBRATE_HELP)(calibrate_command)
