"""Benchmark detector settings: time per image against the Pillow decode floor, and error rates."""

from __future__ import annotations

import csv
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
from lishield_guard.config import AppConfig
from lishield_guard.errors import LishieldError
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
    "paper": {"profile": "paper"},
    "default": {"profile": "default"},
    "default-ref": {"profile": "default", "profiles.fast_decode": False},
    "fast": {"profile": "default", "profiles.orientations": "rows"},
    "fast-half": {"profile": "default", "profiles.orientations": "rows",
                  "profiles.max_decode_rows": 512},
}
# Setting -> the same setting decoded on the reference path (target c compares the two).
REFERENCE_OF = {"default": "default-ref"}

# The issue's targets (unitless ratios; rates in percentage points).
TARGETS = {
    "a_12mp_ratio_max": 0.35,
    "b_1080p_ratio_max": 0.6,
    "c_rate_change_max_pp": 0.5,
    "d_peak_memory_max_x_rgb": 1.5,
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
        t_settings = [s for s in settings if s.name == "default" or not quick]
        seq = list(targets.items())
        for key, path in (progress(seq, "targets") if progress else seq):
            measured[key] = time_target(path, t_settings, repeat=target_repeat,
                                        warm_up=not quick)
        mem_names = [n for n in names if n == "default" or not quick]
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


def evaluate_targets(rows: Sequence[dict], targets: dict | None, memory: dict | None) -> list:
    """The issue's four targets as measured: (a) 12 MP ratio, (b) 1080p ratio, (c) fast path
    rate change, (d) 12 MP peak memory.

    Parameters
    ----------
    rows : sequence of dict
        `summarize` output.
    targets : dict or None
        ``{"12mp": time_target(...), "1080p": time_target(...)}``.
    memory : dict or None
        `measure_memory` output on the 12 MP image.

    Returns
    -------
    list of dict
        ``id``, ``what``, ``measured``, ``limit``, ``met`` (bool, or None when not measured),
        ``detail``.
    """
    out = []
    targets = targets or {}
    for tid, key, limit in (("a", "12mp", TARGETS["a_12mp_ratio_max"]),
                            ("b", "1080p", TARGETS["b_1080p_ratio_max"])):
        t = targets.get(key, {}).get("settings", {}).get("default", {})
        m = t.get("median_ratio")
        out.append({"id": tid, "what": f"default profile time / Pillow RGB decode, {key} JPEG",
                    "measured": m, "limit": limit, "met": None if m is None else m <= limit,
                    "detail": (f"{t['median_ms']:.1f} ms vs floor "
                               f"{targets[key]['floor_median_ms']:.1f} ms, median of "
                               f"{targets[key]['repeat']} paired runs") if m is not None else
                    "not measured"})
    by = {r["setting"]: r for r in rows}
    for fast, ref in REFERENCE_OF.items():
        if fast in by and ref in by:
            f, r = by[fast], by[ref]
            d_tpr = _pp(f["tpr"]["rate"], r["tpr"]["rate"])
            d_fpr = _pp(f["fpr"]["rate"], r["fpr"]["rate"])
            worst = max(abs(d) for d in (d_tpr, d_fpr) if d is not None) if (
                d_tpr is not None or d_fpr is not None) else None
            lim = TARGETS["c_rate_change_max_pp"]
            res = (f["tpr"]["n"], f["fpr"]["n"])
            out.append({"id": "c", "what": f"{fast} vs {ref}: |change| of TPR and FPR (pp)",
                        "measured": worst, "limit": lim,
                        "met": None if worst is None else worst < lim,
                        "detail": f"TPR {_pp_text(d_tpr)}, FPR {_pp_text(d_fpr)} on {res[0]} "
                                  f"pos / {res[1]} neg (one image = "
                                  f"{100 / max(min(res), 1):.2f} pp)"})
    m = (memory or {}).get("settings", {}).get("default", {})
    x = m.get("x_rgb")
    out.append({"id": "d", "what": "default profile peak memory above baseline / 8-bit RGB size, "
                                   "12 MP", "measured": x,
                "limit": TARGETS["d_peak_memory_max_x_rgb"],
                "met": None if x is None else x <= TARGETS["d_peak_memory_max_x_rgb"],
                "detail": (f"RSS +{m['rss_delta_bytes'] / 2**20:.1f} MiB (tracemalloc peak "
                           f"{m['tracemalloc_peak_bytes'] / 2**20:.1f} MiB) vs RGB "
                           f"{memory['rgb_bytes'] / 2**20:.1f} MiB") if x is not None else
                "not measured"})
    return out


def _pp(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else (a - b) * 100.0


def _pp_text(d: float | None) -> str:
    """A change in percentage points, or why there is none (no image of that label timed)."""
    return "not measured (no image)" if d is None else f"{d:+.2f} pp"


def _fmt_rate(r: dict) -> str:
    if r["rate"] is None:
        return "-"
    return f"{r['rate']:.3f} [{r['ci'][0]:.3f},{r['ci'][1]:.3f}]"


def format_table(report: dict) -> str:
    """The terminal table: one line per setting, then the targets."""
    rows = report["rows"]
    mem = (report.get("memory") or {}).get("settings", {})
    tg = report.get("targets_measured") or {}
    head = (f"{'setting':12s} {'n':>4s} {'med ms':>7s} {'p95 ms':>7s} {'x floor':>7s} "
            f"{'p95 x':>6s} {'12MP x':>6s} {'1080p x':>7s} {'TPR [95% CI]':>20s} "
            f"{'FPR [95% CI]':>20s} {'error':>6s} {'mem x':>5s} P")
    lines = [head, "-" * len(head)]
    for r in rows:
        name = r["setting"]
        m = mem.get(name, {}).get("x_rgb")
        t12 = tg.get("12mp", {}).get("settings", {}).get(name, {}).get("median_ratio")
        t10 = tg.get("1080p", {}).get("settings", {}).get(name, {}).get("median_ratio")
        lines.append(
            f"{name:12s} {r['n_images']:4d} {r['median_ms']:7.1f} {r['p95_ms']:7.1f} "
            f"{r['median_ratio']:7.3f} {r['p95_ratio']:6.3f} "
            f"{_num(t12, 6, 3)} {_num(t10, 7, 3)} {_fmt_rate(r['tpr']):>20s} "
            f"{_fmt_rate(r['fpr']):>20s} {_num(r['error'], 6, 3)} {_num(m, 5, 2)} "
            f"{'*' if r['pareto'] else ' '}")
    floor = rows[0]["floor_median_ms"] if rows else float("nan")
    lines.append(f"floor = Pillow Image.open().convert('RGB') + np.asarray, median "
                 f"{floor:.1f} ms/image on the dataset; x = paired per-image ratio; "
                 f"P = Pareto front (x floor, error); mem x = 12 MP peak RSS above baseline / "
                 f"RGB array size")
    for g in rows[0]["fpr_by_group"] if rows else {}:
        lines.append(f"FPR {g}: " + ", ".join(f"{r['setting']} {_fmt_rate(r['fpr_by_group'][g])}"
                                              for r in rows if g in r["fpr_by_group"]))
    lines.append("targets:")
    for t in report.get("targets", []):
        state = {True: "MET", False: "NOT MET", None: "n/a"}[t["met"]]
        meas = "-" if t["measured"] is None else f"{t['measured']:.3f}"
        lines.append(f"  ({t['id']}) {t['what']}: {meas} (limit {t['limit']}) {state} -- "
                     f"{t['detail']}")
    return "\n".join(lines)


def _num(x: float | None, width: int, prec: int) -> str:
    return f"{'-':>{width}s}" if x is None or not math.isfinite(x) else f"{x:{width}.{prec}f}"


def plot_report(report: dict, out_png: Path) -> Path:
    """Median time ratio against error per setting, with the Pareto front, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in report["rows"] if r["error"] is not None]
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for i, r in enumerate(rows):
        x = r["median_ratio"]
        ax.scatter([x], [r["error"]], s=60, color="C0" if not r["pareto"] else "C3", zorder=3)
        ax.annotate(r["setting"], (x, r["error"]), textcoords="offset points",
                    xytext=(6, 4 + 11 * (i % 3)), fontsize=9)
        fnr = 1 - r["tpr"]["rate"] if r["tpr"]["rate"] is not None else None
        if fnr is not None:
            ax.scatter([x], [fnr], marker="v", color="0.5", s=25, zorder=2)
        if r["fpr"]["rate"] is not None:
            ax.scatter([x], [r["fpr"]["rate"]], marker="^", color="0.5", s=25, zorder=2)
    front = sorted((r for r in rows if r["pareto"]), key=lambda r: r["median_ratio"])
    if front:
        xs, ys = [front[0]["median_ratio"]], [front[0]["error"]]
        for r in front[1:]:
            xs += [r["median_ratio"], r["median_ratio"]]
            ys += [ys[-1], r["error"]]
        ax.plot(xs, ys, color="C3", lw=1.5, label="Pareto front", zorder=1)
    ax.scatter([], [], color="C0", label="error = 1 - TPR + FPR")
    ax.scatter([], [], color="C3", label="on the Pareto front")
    ax.scatter([], [], marker="v", color="0.5", label="1 - TPR")
    ax.scatter([], [], marker="^", color="0.5", label="FPR")
    ax.axvline(1.0, color="0.7", ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("median time / Pillow full RGB decode of the same image (unitless)")
    ax.set_ylabel("error rate")
    n = rows[0]["n_images"] if rows else 0
    ax.set_title(f"lishield-guard bench: speed vs error ({n} images)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


CSV_FIELDS = ("setting", "n_images", "n_errors", "median_ms", "p95_ms", "median_ratio",
              "p95_ratio", "ratio_12mp", "ratio_1080p", "tpr", "tpr_lo", "tpr_hi", "fpr",
              "fpr_lo", "fpr_hi", "error", "peak_rss_delta_mib", "peak_tracemalloc_mib",
              "peak_x_rgb", "pareto")


def write_report(report: dict, out_dir: Path) -> dict[str, Path]:
    """Write ``bench.json``, ``bench.csv`` and ``bench.png`` into ``out_dir`` (created)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "bench.json", "csv": out_dir / "bench.csv",
             "png": out_dir / "bench.png"}
    paths["json"].write_text(json.dumps(_jsonable(report), indent=2), encoding="utf-8")
    mem = (report.get("memory") or {}).get("settings", {})
    tg = report.get("targets_measured") or {}
    with open(paths["csv"], "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in report["rows"]:
            m = mem.get(r["setting"], {})
            w.writerow({
                "setting": r["setting"], "n_images": r["n_images"], "n_errors": r["n_errors"],
                "median_ms": r["median_ms"], "p95_ms": r["p95_ms"],
                "median_ratio": r["median_ratio"], "p95_ratio": r["p95_ratio"],
                "ratio_12mp": tg.get("12mp", {}).get("settings", {}).get(
                    r["setting"], {}).get("median_ratio"),
                "ratio_1080p": tg.get("1080p", {}).get("settings", {}).get(
                    r["setting"], {}).get("median_ratio"),
                "tpr": r["tpr"]["rate"], "tpr_lo": r["tpr"]["ci"][0], "tpr_hi": r["tpr"]["ci"][1],
                "fpr": r["fpr"]["rate"], "fpr_lo": r["fpr"]["ci"][0], "fpr_hi": r["fpr"]["ci"][1],
                "error": r["error"],
                "peak_rss_delta_mib": _mib(m.get("rss_delta_bytes")),
                "peak_tracemalloc_mib": _mib(m.get("tracemalloc_peak_bytes")),
                "peak_x_rgb": m.get("x_rgb"), "pareto": r["pareto"]})
    plot_report(report, paths["png"])
    return paths


def _mib(b: int | None) -> float | None:
    return None if b is None else b / 2**20


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    return obj
