"""`lishield-guard bench`: detector settings timed against the Pillow decode floor, with error."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import typer

from lishield_guard.commands import fail
from lishield_guard.errors import LishieldError

__all__ = ["bench_command", "make_target_images", "register"]

QUICK_N_PER_CLASS = 20
QUICK_BUDGET_S = 15.0  # dataset timing budget of --quick; the whole run stays under a minute
FULL_N_PER_CLASS = 200
TARGET_SIZES = {"12mp": (3024, 4032), "1080p": (1080, 1920)}  # (n_rows, n_cols), landscape
TARGET_QUALITY = 90


def make_target_images(cache_dir: Path, *, seed: int = 0) -> dict[str, Path]:
    """Write (once) the speed-target JPEGs: a 12 MP and a 1080p clean capture at quality 90.

    Both are synth negatives under steady light (a photo-like random scene, sensor noise, 4:2:0
    chroma, no downscaling or rotation): with no barcode the detector does all of its work.

    Parameters
    ----------
    cache_dir : Path
        Folder for ``target-12mp-q90.jpg`` and ``target-1080p-q90.jpg``; existing files are
        reused.
    seed : int
        Item seed of the scene.

    Returns
    -------
    dict
        ``"12mp"`` and ``"1080p"`` -> path.
    """
    from synth.dataset import MIXES, render_item, sample_item

    mix = MIXES["negatives-only"].with_overrides({
        "jpeg_quality_range": f"{TARGET_QUALITY},{TARGET_QUALITY}", "downscale_prob": "0",
        "rotate_prob": "0", "negative_probs": "1,0,0,0", "subsampling_420_prob": "1"})
    cache_dir.mkdir(parents=True, exist_ok=True)
    out = {}
    for key, size in TARGET_SIZES.items():
        path = cache_dir / f"target-{key}-q{TARGET_QUALITY}.jpg"
        if not path.exists():
            data, _ = render_item(sample_item(0, seed=seed, mix=mix, size=size))
            tmp = path.with_suffix(".tmp")
            tmp.write_bytes(data)
            tmp.replace(path)
        out[key] = path
    return out


def _cached_dataset(cache_dir: Path, n_per_class: int, seed: int, progress: bool) -> Path:
    from synth.dataset import write_dataset

    ds = cache_dir / f"synth-1080p-{n_per_class}x2-seed{seed}"
    if not (ds / "manifest.jsonl").exists():
        typer.echo(f"generating {n_per_class}+{n_per_class} 1080p synth images into {ds}",
                   err=True)
        write_dataset(ds, n_pos=n_per_class, n_neg=n_per_class, seed=seed, size="1080p",
                      jobs=2, progress=progress)
    return ds


def _split(values: list[str]) -> list[str]:
    return [p.strip() for v in values for p in v.split(",") if p.strip()]


def bench_command(
    dataset: Path | None = typer.Option(None, "--dataset", help="Synth dataset folder (with "
                                        "manifest.jsonl); default: a cached one under --out."),
    clean: list[Path] = typer.Option([], "--clean", metavar="DIR",
                                     help="Folder of clean real photos (all negatives). "
                                          "Repeatable."),
    quick: bool = typer.Option(False, "--quick", help=f"Small run (< 1 min): "
                               f"{QUICK_N_PER_CLASS}+{QUICK_N_PER_CLASS} generated images, "
                               f"15 s timing budget, 3 paired runs of default per target image."),
    out: Path = typer.Option(Path("out/bench"), "--out", help="Output folder."),
    profiles: list[str] = typer.Option([], "--profiles", metavar="NAME[,NAME...]",
                                       help="Settings to run, comma-separated (default all): "
                                            "paper, default, default-ref, fast, fast-half."),
    repeat: int = typer.Option(1, "--repeat", help="Interleaved runs per dataset image."),
    jobs: int = typer.Option(1, "--jobs", "-j",
                             help="Worker processes for the dataset (each image is still "
                                  "paired with its own floor decode; 1 = least contention)."),
    target_repeat: int | None = typer.Option(None, "--target-repeat",
                                             help="Paired runs on each target image "
                                                  "(default 3 with --quick, else 9)."),
    time_budget_s: float | None = typer.Option(None, "--time-budget-s",
                                               help="Stop timing new dataset images after this "
                                                    f"many seconds (--quick: {QUICK_BUDGET_S:g})."),
    n_per_class: int | None = typer.Option(None, "--n-per-class",
                                           help="Size of the generated dataset per class "
                                                f"(default {QUICK_N_PER_CLASS} with --quick, "
                                                f"else {FULL_N_PER_CLASS})."),
    seed: int = typer.Option(0, "--seed", help="Seed of generated datasets and targets."),
    targets: bool = typer.Option(True, "--targets/--no-targets",
                                 help="Measure the 12 MP / 1080p speed and memory targets."),
    config: Path | None = typer.Option(None, "--config", help="Base config TOML (default: "
                                       "the shipped one); settings change its detector."),
    progress: bool = typer.Option(True, "--progress/--no-progress",
                                  help="Progress bars on stderr."),
) -> None:
    """Time detector settings against Pillow's full RGB decode and report TPR/FPR per setting.

    Writes bench.json, bench.csv and bench.png (time ratio vs error, Pareto front) to --out.

    Examples:
      lishield-guard bench --quick
      lishield-guard bench --dataset eval --profiles default,paper --jobs 2
    """
    from tqdm import tqdm

    from lishield_guard import bench
    from lishield_guard.config import load_config

    t_start = time.perf_counter()
    try:
        base = load_config(config)
        settings = bench.make_settings(_split(profiles) or list(bench.SETTINGS), base)
    except (LishieldError, ValueError) as exc:
        raise fail(str(exc)) from None
    if repeat < 1:
        raise fail(f"--repeat must be >= 1, got {repeat}")
    n = n_per_class or (QUICK_N_PER_CLASS if quick else FULL_N_PER_CLASS)
    dataset, items, target_paths = _inputs(dataset, clean, out / "cache", n, seed, targets,
                                           progress)
    if quick and clean:  # the time budget keeps a prefix: mix clean photos into it
        import random

        random.Random(seed).shuffle(items)

    def bar(it, desc="bench"):
        return tqdm(it, desc=desc, unit="img", file=sys.stderr, disable=not progress)

    budget = time_budget_s if time_budget_s is not None else (QUICK_BUDGET_S if quick else None)
    core = bench.run(items, settings, config_path=config, jobs=jobs, repeat=repeat,
                     time_budget_s=budget, targets=target_paths,
                     target_repeat=target_repeat or (3 if quick else 9), quick=quick,
                     progress=bar, on_note=lambda m: typer.echo(m, err=True))
    report = {"dataset": str(dataset), "clean": [str(c) for c in clean], **core}
    report["elapsed_s"] = time.perf_counter() - t_start
    paths = bench.write_report(report, out)
    typer.echo(bench.format_table(report))
    typer.echo(f"wrote {paths['json']}, {paths['csv']}, {paths['png']} "
               f"({report['elapsed_s']:.1f} s)")


def _inputs(dataset: Path | None, clean: list[Path], cache: Path, n_per_class: int, seed: int,
            targets: bool, progress: bool) -> tuple[Path, list, dict[str, Path]]:
    """The dataset folder (generated and cached when not given), its items and the clean
    folders' items, and the target images (or {})."""
    from lishield_guard import bench

    try:
        if dataset is None:
            dataset = _cached_dataset(cache, n_per_class, seed, progress)
        items = bench.synth_items(dataset)
        for folder in clean:
            if not folder.is_dir():
                raise fail(f"--clean {str(folder)!r} is not a folder")
            items += bench.clean_items(folder)
        target_paths = make_target_images(cache, seed=seed) if targets else {}
    except OSError as exc:
        raise fail(f"cannot read or write the dataset: {exc}") from None
    except LishieldError as exc:
        raise fail(str(exc)) from None
    if not items:
        raise fail("no images to benchmark")
    return dataset, items, target_paths


def register(app: typer.Typer) -> None:
    """Add the ``bench`` command to the CLI."""
    app.command("bench")(bench_command)
