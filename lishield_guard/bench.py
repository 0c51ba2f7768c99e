"""Benchmark detector settings: time per image against the Pillow decode floor, and error rates."""

from __future__ import annotations

import dataclasses
import gc
import io
import json
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lishield_guard.batch import IMAGE, list_files, run_pool, worker_state
from lishield_guard.bench_report import (
    MAIN_SETTING,
    REFERENCE_OF,
    TARGETS,
    evaluate_targets,
    format_table,
    plot_report,
    write_report,
)
from lishield_guard.config import AppConfig
from lishield_guard.errors import LishieldError
from lishield_guard.profiles import DEFAULT, PAPER
from lishield_guard.stats import pareto_front, percentile, rate_with_ci

__all__ = [
    "FLOOR",
    "SETTINGS",
    "TARGETS",
    "BenchItem",
    "BenchSetting",
    "run",
    "clean_items",
    "evaluate_targets",
    "format_table",
    "make_settings",
    "measure_memory",
    "pillow_rgb_floor",
    "plot_report",
    "run_bench",
    "run_bench_parallel",
    "summarize",
    "synth_items",
    "time_target",
    "write_report",
]

FLOOR = "pillow-rgb"  # the decode floor: Pillow full RGB decode + np.asarray

# Detector settings by name: DetectorConfig fields changed from the base config.
SETTINGS: dict[str, dict] = {
    PAPER: {"profile": PAPER},
    MAIN_SETTING: {"profile": DEFAULT},
    REFERENCE_OF[MAIN_SETTING]: {"profile": DEFAULT, "profiles.fast_decode": False},
    "fast": {"profile": DEFAULT, "profiles.orientations": "rows"},
    "fast-half": {"profile": DEFAULT, "profiles.orientations": "rows",
                  "profiles.max_decode_rows": 512},
}

@dataclass(frozen=True)
class BenchSetting:
    """One detector setting under test.

    Attributes
    ----------
    name : str
        Key of `SETTINGS` (or any label).
    config : AppConfig
        Full config passed to `lishield_guard.detect`.
    """

    name: str
    config: AppConfig


@dataclass(frozen=True)
class BenchItem:
    """One image of the benchmark.

    Attributes
    ----------
    path : Path
        Image file.
    label : int
        1 barcode, 0 no barcode.
    group : str
        ``"synth"`` or ``"clean:<folder name>"``.
    kind : str
        Synth kind (barcode, steady, mains, pwm, texture) or ``"clean"``.
    """

    path: Path
    label: int
    group: str = "synth"
    kind: str = "?"


def make_settings(names: Iterable[str], base: AppConfig) -> list[BenchSetting]:
    """Settings by name, each a copy of ``base`` with the `SETTINGS` changes applied.

    Raises
    ------
    ValueError
        For a name not in `SETTINGS`.
    """
    out = []
    for name in names:
        if name not in SETTINGS:
            raise ValueError(f"unknown setting {name!r}; known: {', '.join(SETTINGS)}")
        det = base.detector.with_values(SETTINGS[name])
        out.append(BenchSetting(name, dataclasses.replace(base, detector=det)))
    return out


def synth_items(dataset: Path) -> list[BenchItem]:
    """Items of a synth dataset folder (its ``manifest.jsonl``), in manifest order."""
    manifest = Path(dataset) / "manifest.jsonl"
    items = []
    for line in manifest.read_text(encoding="utf-8").splitlines():
        if line.strip():
            rec = json.loads(line)
            items.append(BenchItem(Path(dataset) / rec["file"], int(rec["label"]), "synth",
                                   str(rec.get("kind", "?"))))
    return items


def clean_items(folder: Path) -> list[BenchItem]:
    """Every image under a folder of clean photos (the types `scan` reads), all labelled 0,
    sorted by path."""
    folder = Path(folder)
    return [BenchItem(p, 0, f"clean:{folder.name}", "clean")
            for p in list_files(folder, kinds=(IMAGE,))]


def pillow_rgb_floor(path: Path) -> np.ndarray:
    """Decode an image fully to 8-bit RGB with Pillow: the floor every setting is compared to."""
    from PIL import Image

    with Image.open(path) as img:
        return np.asarray(img.convert("RGB"))


def _timed(fn: Callable[[], object]) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _time_one(path: Path, settings: Sequence[BenchSetting], *, repeat: int, offset: int
              ) -> tuple[list[float], dict[str, list[float]], dict[str, object]]:
    """Floor and every setting on one image, interleaved ``repeat`` times, order rotated.

    Returns the floor times (s), each setting's times (s) and each setting's first verdict
    (or the exception it raised); every verdict's ``timings_ms`` is collected under
    ``verdicts["<name>:stages"]``.
    """
    from lishield_guard.detector import detect

    floor_s: list[float] = []
    times_s: dict[str, list[float]] = {s.name: [] for s in settings}
    verdicts: dict[str, object] = {}
    jobs: list[BenchSetting | None] = [None, *settings]
    for r in range(repeat):
        k = (offset + r) % len(jobs)
        for job in jobs[k:] + jobs[:k]:
            if job is None:
                dt, _ = _timed(lambda: pillow_rgb_floor(path))
                floor_s.append(dt)
                continue
            try:
                dt, v = _timed(lambda job=job: detect(path, job.config))
            except LishieldError as exc:
                verdicts[job.name] = exc
                continue
            times_s[job.name].append(dt)
            verdicts.setdefault(job.name, v)
            verdicts.setdefault(f"{job.name}:stages", []).append(v.timings_ms)
    return floor_s, times_s, verdicts


def run_bench(items: Sequence[BenchItem], settings: Sequence[BenchSetting], *, repeat: int = 1,
              progress: Callable[[Iterable], Iterable] | None = None,
              time_budget_s: float | None = None, deadline_unix_s: float | None = None
              ) -> dict:
    """Time every setting and the Pillow floor on every item, interleaved per image.

    Parameters
    ----------
    items : sequence of BenchItem
        Images with labels.
    settings : sequence of BenchSetting
        Detector settings.
    repeat : int
        Interleaved repetitions per image (>= 1); the median per image is kept.
    progress : callable, optional
        Wraps the item iterable (e.g. ``tqdm``).
    time_budget_s : float, optional
        Stop starting new items after this many seconds (the rest are left out and counted in
        ``n_skipped``); pass items in random order so the prefix stays representative.
    deadline_unix_s : float, optional
        The same as an absolute ``time.time()`` (shared by worker processes).

    Returns
    -------
    dict
        ``n_skipped`` and ``records``: one dict per item with ``path``, ``label``, ``group``,
        ``kind``, ``floor_ms`` and per setting ``ms``, ``ratio`` (unitless, time / floor time
        of the same image), ``protected`` and ``stages_ms`` (the verdict's timings) or ``error``.
    """
    if repeat < 1:
        raise ValueError(f"need repeat >= 1, got repeat={repeat!r}")
    if items:  # warm-up: imports, lazy library init, page cache
        _time_one(items[0].path, settings, repeat=1, offset=0)
    records = []
    if time_budget_s is not None:
        end = time.time() + time_budget_s
        deadline_unix_s = end if deadline_unix_s is None else min(end, deadline_unix_s)
    seq = progress(items) if progress else items
    for i, it in enumerate(seq):
        if deadline_unix_s is not None and time.time() > deadline_unix_s:
            break
        gc.collect()
        rec: dict = {"path": str(it.path), "label": it.label, "group": it.group,
                     "kind": it.kind, "settings": {}}
        try:
            floor_s, times_s, verdicts = _time_one(it.path, settings, repeat=repeat, offset=i)
        except Exception as exc:  # noqa: BLE001 - Pillow cannot read it: not a benchmark image
            rec["error"] = f"floor decode failed: {exc}"
            records.append(rec)
            continue
        floor_ms = float(np.median(floor_s)) * 1e3
        rec["floor_ms"] = floor_ms
        for s in settings:
            v = verdicts.get(s.name)
            if isinstance(v, Exception) or v is None:
                rec["settings"][s.name] = {"error": str(v)}
                continue
            ms = float(np.median(times_s[s.name])) * 1e3
            ratios = [t / f for t, f in zip(times_s[s.name], floor_s, strict=False)]
            rec["settings"][s.name] = {
                "ms": ms, "ratio": float(np.median(ratios)), "protected": bool(v.protected),
                "stages_ms": {k: float(x) for k, x in v.timings_ms.items()}}
        records.append(rec)
    return {"records": records, "repeat": repeat, "settings": [s.name for s in settings],
            "n_skipped": len(items) - len(records)}


def _bench_worker(chunk: list[BenchItem]) -> dict:
    """Worker body of `run_bench_parallel`: settings rebuilt from names and a config path."""
    from lishield_guard.config import load_config

    names, config_path, repeat, deadline_unix_s = worker_state()
    if deadline_unix_s is not None and time.time() > deadline_unix_s:
        return {"records": [], "n_skipped": len(chunk)}
    settings = make_settings(names, load_config(config_path))
    return run_bench(chunk, settings, repeat=repeat, deadline_unix_s=deadline_unix_s)


def run_bench_parallel(items: Sequence[BenchItem], names: Sequence[str], *,
                       config_path: Path | None = None, jobs: int = 2, repeat: int = 1,
                       progress: Callable[[Iterable], Iterable] | None = None,
                       time_budget_s: float | None = None, chunk: int = 8) -> dict:
    """`run_bench` over ``jobs`` spawned worker processes (each interleaves per image).

    Every image is still timed against the Pillow floor in the same process right before or
    after, so the paired ratios stay meaningful; absolute times include contention between
    workers. Settings are rebuilt in each worker from ``names`` and ``config_path``.

    Parameters
    ----------
    items : sequence of BenchItem
        Images with labels.
    names : sequence of str
        Keys of `SETTINGS`.
    config_path : Path, optional
        Base config; default the shipped one.
    jobs : int
        Worker processes (>= 1).
    repeat : int
        Interleaved repetitions per image.
    progress : callable, optional
        Wraps an iterable of chunks' image counts (e.g. ``tqdm``-like, updated per chunk).
    time_budget_s : float, optional
        Wall-time budget of the whole run (see `run_bench`).
    chunk : int
        Images per task.

    Returns
    -------
    dict
        As `run_bench`, records in item order.
    """
    cfg = None if config_path is None else str(config_path)
    chunks = [list(items[i:i + chunk]) for i in range(0, len(items), chunk)]
    deadline = None if time_budget_s is None else time.time() + time_budget_s
    records: list[dict] = []
    results = run_pool(_bench_worker, chunks, jobs=max(1, jobs), ordered=True,
                       state=(list(names), cfg, repeat, deadline), in_process=False,
                       max_in_flight=len(chunks) or 1)
    for _, out in (progress(results) if progress else results):
        if isinstance(out, Exception):
            raise out
        records += out["records"]
    return {"records": records, "repeat": repeat, "settings": list(names),
            "n_skipped": len(items) - len(records)}


def run(items: Sequence[BenchItem], settings: Sequence[BenchSetting], *,
        config_path: Path | None = None, jobs: int = 1, repeat: int = 1,
        time_budget_s: float | None = None, targets: dict[str, Path] | None = None,
        target_repeat: int = 9, quick: bool = False,
        progress: Callable[..., Iterable] | None = None,
        on_note: Callable[[str], None] = print) -> dict:
    """A whole benchmark: every setting on every item, then the speed and memory targets.

    Parameters
    ----------
    items, settings, config_path, jobs, repeat, time_budget_s
        As `run_bench` / `run_bench_parallel` (``jobs > 1`` runs the items in the pool).
    targets : dict, optional
        ``"12mp"`` and ``"1080p"`` target images (see ``lishield-guard bench``); None skips
        the targets and the memory probe.
    target_repeat : int
        Paired runs per target image.
    quick : bool
        Time only the default setting on the targets, without warm-up.
    progress : callable, optional
        ``progress(iterable, desc)`` wraps what is iterated (e.g. a tqdm factory).
    on_note : callable
        Called with notes (a time budget reached).

    Returns
    -------
    dict
        The report `write_report` writes (without ``dataset``, ``clean`` and ``elapsed_s``).
    """
    names = [s.name for s in settings]
    if jobs > 1:
        run_ = run_bench_parallel(items, names, config_path=config_path, jobs=jobs,
                                  repeat=repeat, time_budget_s=time_budget_s,
                                  progress=progress and (lambda f: progress(f, "bench chunks")))
    else:
        run_ = run_bench(items, settings, repeat=repeat, progress=progress,
                         time_budget_s=time_budget_s)
    if run_["n_skipped"]:
        on_note(f"time budget of {time_budget_s:g} s reached, "
                f"{run_['n_skipped']} of {len(items)} images left out")
    rows = summarize(run_)
    measured: dict = {}
    memory = None
    if targets:
        # --quick times only what the targets need (the default setting) on the big images
        t_settings = [s for s in settings if s.name == MAIN_SETTING or not quick]
        seq = list(targets.items())
        for key, path in (progress(seq, "targets") if progress else seq):
            measured[key] = time_target(path, t_settings, repeat=target_repeat,
                                        warm_up=not quick)
        mem_names = [n for n in names if n == MAIN_SETTING or not quick]
        memory = measure_memory(targets["12mp"], mem_names, config_path=config_path, jobs=2)
    return {"quick": quick, "repeat": repeat, "jobs": jobs, "n_skipped": run_["n_skipped"],
            "settings": {s.name: SETTINGS[s.name] for s in settings},
            "rows": rows, "targets_measured": measured, "memory": memory,
            "targets": evaluate_targets(rows, measured, memory), "records": run_["records"]}


def summarize(run: dict) -> list[dict]:
    """Per-setting speed and error from `run_bench` output.

    Returns
    -------
    list of dict
        One row per setting: ``setting``, ``n_images``, ``n_errors``, ``median_ms``,
        ``p95_ms``, ``median_ratio``, ``p95_ratio`` (time / Pillow RGB decode time, paired per
        image), ``tpr`` and ``fpr`` (`rate_with_ci` dicts; FPR over every negative),
        ``fpr_by_group``, ``error`` (1 - TPR + FPR), ``stages_median_ms`` and
        ``stages_share`` (fraction of summed stage time), ``floor_median_ms``.
    """
    rows = []
    recs = [r for r in run["records"] if "error" not in r]
    floor_ms = [r["floor_ms"] for r in recs]
    for name in run["settings"]:
        ok = [(r, r["settings"][name]) for r in recs if "ms" in r["settings"].get(name, {})]
        ms = [s["ms"] for _, s in ok]
        ratio = [s["ratio"] for _, s in ok]
        pos = [s["protected"] for r, s in ok if r["label"] == 1]
        neg = [s["protected"] for r, s in ok if r["label"] == 0]
        tpr = rate_with_ci(sum(pos), len(pos))
        fpr = rate_with_ci(sum(neg), len(neg))
        by_group = {}
        for g in sorted({r["group"] for r, _ in ok if r["label"] == 0}):
            gn = [s["protected"] for r, s in ok if r["label"] == 0 and r["group"] == g]
            by_group[g] = rate_with_ci(sum(gn), len(gn))
        stages: dict[str, list[float]] = {}
        for _, s in ok:
            for k, x in s["stages_ms"].items():
                stages.setdefault(k, []).append(x)
        total = sum(sum(v) for v in stages.values()) or 1.0
        err = None
        if tpr["rate"] is not None or fpr["rate"] is not None:
            err = (1 - (tpr["rate"] if tpr["rate"] is not None else 1.0)) + (fpr["rate"] or 0.0)
        rows.append({
            "setting": name, "n_images": len(ok), "n_errors": len(recs) - len(ok),
            "median_ms": percentile(ms, 50), "p95_ms": percentile(ms, 95),
            "median_ratio": percentile(ratio, 50), "p95_ratio": percentile(ratio, 95),
            "tpr": tpr, "fpr": fpr, "fpr_by_group": by_group, "error": err,
            "stages_median_ms": {k: percentile(v, 50) for k, v in stages.items()},
            "stages_share": {k: sum(v) / total for k, v in stages.items()},
            "floor_median_ms": percentile(floor_ms, 50),
        })
    front = pareto_front([[r["median_ratio"], r["error"] if r["error"] is not None else math.nan]
                          for r in rows]) if rows else []
    for i, r in enumerate(rows):
        r["pareto"] = bool(i in set(int(j) for j in front))
    return rows


def time_target(path: Path, settings: Sequence[BenchSetting], *, repeat: int,
                warm_up: bool = True) -> dict:
    """Paired time ratios of every setting on one image (the speed targets' measurement).

    Parameters
    ----------
    path : Path
        The image.
    settings : sequence of BenchSetting
        Detector settings.
    repeat : int
        Interleaved paired runs (>= 1).
    warm_up : bool
        Run everything once, untimed, first.

    Returns
    -------
    dict
        ``path``, ``shape`` (n_rows, n_cols), ``repeat``, ``floor_median_ms`` and per setting
        ``median_ms``, ``median_ratio`` (median over repeats of time / floor time in the same
        repeat) and ``stages_median_ms``.
    """
    if warm_up:
        _time_one(path, settings, repeat=1, offset=0)
    gc.collect()
    floor_s, times_s, verdicts = _time_one(path, settings, repeat=repeat, offset=0)
    shape = pillow_rgb_floor(path).shape[:2]
    out: dict = {"path": str(path), "shape": [int(shape[0]), int(shape[1])], "repeat": repeat,
                 "floor_median_ms": float(np.median(floor_s)) * 1e3, "settings": {}}
    for s in settings:
        t = times_s[s.name]
        if not t:
            out["settings"][s.name] = {"error": "detect failed"}
            continue
        stages = verdicts[f"{s.name}:stages"]
        out["settings"][s.name] = {
            "median_ms": float(np.median(t)) * 1e3,
            "median_ratio": float(np.median([a / b for a, b in zip(t, floor_s, strict=False)])),
            "stages_median_ms": {k: float(np.median([st.get(k, 0.0) for st in stages]))
                                 for k in stages[0]}}
    return out


def _proc_status_bytes(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024  # kB
    raise OSError(f"{key} not in /proc/self/status")


def _memory_probe(path: str, setting: str | None, config_path: str | None) -> dict:
    """Child-process body of `measure_memory` (a fresh interpreter per measurement)."""
    import tracemalloc

    from PIL import Image

    from lishield_guard.config import load_config
    from lishield_guard.detector import detect

    config = None if setting is None else make_settings([setting], load_config(config_path))[0]

    def run(src):
        return pillow_rgb_floor(src) if config is None else detect(src, config.config)

    # Warm-up on a tiny JPEG: loads every lazy library without leaving a large heap behind.
    rng = np.random.default_rng(0)
    buf = io.BytesIO()
    Image.fromarray((rng.random((256, 256, 3)) * 255).astype(np.uint8)).save(buf, "JPEG")
    run(buf.getvalue() if config is not None else io.BytesIO(buf.getvalue()))
    gc.collect()
    # ru_maxrss survives exec (it would report the parent's peak); VmHWM is per address space
    # and writing 5 to clear_refs resets it to the current RSS (Linux >= 4.0).
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    base = _proc_status_bytes("VmRSS")
    run(path)
    peak = _proc_status_bytes("VmHWM")
    gc.collect()
    tracemalloc.start()
    run(path)
    traced_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"rss_delta_bytes": int(max(peak - base, 0)),
            "tracemalloc_peak_bytes": int(traced_peak), "baseline_rss_bytes": int(base)}


def measure_memory(path: Path, names: Sequence[str], *, config_path: Path | None = None,
                   jobs: int = 1) -> dict:
    """Peak memory above baseline of the Pillow floor and of named settings on one image.

    Each measurement runs in a fresh spawned interpreter (Linux ``/proc`` needed), warmed up on
    a tiny JPEG so library initialisation is part of the baseline.

    Parameters
    ----------
    path : Path
        The image (the targets use a 12 MP JPEG).
    names : sequence of str
        Keys of `SETTINGS`; the child rebuilds each from ``config_path``.
    config_path : Path, optional
        Base config file; default the shipped config.
    jobs : int
        Parallel child processes (memory is per process, so they do not interfere).

    Returns
    -------
    dict
        ``rgb_bytes`` (size of the decoded 8-bit RGB array) and per setting name (and `FLOOR`)
        ``rss_delta_bytes`` (peak RSS minus RSS after warm-up: every allocator counted),
        ``tracemalloc_peak_bytes`` (Python and numpy allocations only) and ``x_rgb``
        (rss_delta_bytes / rgb_bytes, unitless), or ``error``.
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from PIL import Image

    with Image.open(path) as img:
        n_cols, n_rows = img.size
    rgb_bytes = n_rows * n_cols * 3
    cfg = None if config_path is None else str(config_path)
    out: dict = {"path": str(path), "rgb_bytes": rgb_bytes, "settings": {}}
    with ProcessPoolExecutor(max_workers=max(1, jobs), mp_context=mp.get_context("spawn"),
                             max_tasks_per_child=1) as ex:
        futs = {name: ex.submit(_memory_probe, str(path), None if name == FLOOR else name, cfg)
                for name in [FLOOR, *names]}
        for name, fut in futs.items():
            try:
                m = fut.result()
            except Exception as exc:  # noqa: BLE001 - a failed probe is reported, not fatal
                out["settings"][name] = {"error": f"{type(exc).__name__}: {exc}"}
                continue
            m["x_rgb"] = m["rss_delta_bytes"] / rgb_bytes
            out["settings"][name] = m
    return out
