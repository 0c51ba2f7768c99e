"""`lishield-guard calibrate`: sweep thresholds on clean images and positives, ship a config."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import pickle
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import typer

from lishield_guard.commands import ExitCode

__all__ = ["calibrate_command", "register"]

IMAGE_EXTS = {".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff", ".bmp", ".heic", ".heif"}
NULL_MODEL_SAMPLE = 300  # clean images the null model is evaluated on


def _fail(message: str, code: ExitCode = ExitCode.USAGE) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(int(code))


def _list_images(folder: Path) -> list[tuple[Path, dict]]:
    """Images under ``folder`` (sorted) with their manifest.jsonl rows when present."""
    rows: dict[str, dict] = {}
    for mf in sorted(folder.rglob("manifest.jsonl")):
        for line in mf.read_text(encoding="utf-8").splitlines():
            if line.strip():
                r = json.loads(line)
                if "file" in r:
                    rows[str((mf.parent / r["file"]).resolve())] = r
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_EXTS and p.is_file())
    return [(p, rows.get(str(p.resolve()), {})) for p in files]


def _hash(*parts) -> str:
    return hashlib.sha1(repr(parts).encode()).hexdigest()[:20]


# --- worker side (module-level for pickling)
_W: dict = {}


def _init_worker(cfg, grid, paper_grid, cache_dir: str | None) -> None:
    _W.update(cfg=cfg, grid=grid, paper_grid=paper_grid, cache=cache_dir,
              cfg_key=_hash(repr(cfg.detector), repr(cfg.policies), repr(cfg.limits)))


def _cached(key: str, compute):
    cache = _W["cache"]
    path = os.path.join(cache, key + ".pkl") if cache else None
    if path and os.path.exists(path):
        try:
            with open(path, "rb") as fh:
                return pickle.load(fh), True
        except Exception:  # noqa: BLE001 - a corrupt cache entry is recomputed
            pass
    value = compute()
    if path:
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    return value, False


def _work(path: str) -> dict:
    from lishield_guard.calibrate import candidate_table, image_record

    cfg, grid, pgrid = _W["cfg"], _W["grid"], _W["paper_grid"]
    st = os.stat(path)
    key = _hash(os.path.abspath(path), st.st_size, st.st_mtime_ns, _W["cfg_key"])
    try:
        rec, hit = _cached("ev-" + key + "-" + _hash(repr(pgrid)),
                           lambda: image_record(path, cfg, paper_grid=pgrid))
        (table, match_ms), _ = _cached("tab-" + key + "-" + _hash(repr(grid)),
                                       lambda: candidate_table(rec["evidence"], cfg, grid))
    except Exception as exc:  # noqa: BLE001 - one bad file never stops calibration
        return {"path": path, "error": f"{type(exc).__name__}: {exc}"}
    return {"path": path, "error": None, "table": table, "match_ms": match_ms,
            "evidence_ms": rec["evidence_ms"], "paper_peaks": rec["paper_peaks"],
            "paper_ms": rec["paper_ms"], "paper_decode_ms": rec["paper_decode_ms"],
            "cached": hit}


def _null_work(args) -> dict:
    path, det = args
    from lishield_guard.calibrate import null_model_far

    cfg = _W["cfg"]
    st = os.stat(path)
    key = _hash(os.path.abspath(path), st.st_size, st.st_mtime_ns, _W["cfg_key"])
    rec, _ = _cached("ev-" + key + "-" + _hash(repr(_W["paper_grid"])), lambda: None)
    if rec is None:
        return {}
    app = type(cfg)(detector=det, limits=cfg.limits, policies=cfg.policies)
    measured = null_model_far(rec["evidence"], app)
    noise = null_model_far(rec["evidence"], app, q=det.peak_false_prob)
    return {"measured": measured, "noise": noise}


def _run_pool(paths: list[str], fn, init_args, jobs: int, desc: str, quiet: bool) -> list:
    from tqdm import tqdm

    out = []
    bar = tqdm(total=len(paths), desc=desc, unit="img", file=sys.stderr, disable=quiet,
               dynamic_ncols=True)
    try:
        if jobs <= 1:
            _init_worker(*init_args)
            for p in paths:
                out.append(fn(p))
                bar.update(1)
        else:
            with ProcessPoolExecutor(jobs, initializer=_init_worker, initargs=init_args) as pool:
                for r in pool.map(fn, paths, chunksize=4):
                    out.append(r)
                    bar.update(1)
    finally:
        bar.close()
    return out


def calibrate_command(
    clean: list[Path] = typer.Option(..., "--clean", metavar="DIR",
                                     help="Folder of clean images (repeatable; no barcodes)."),
    positives: Path = typer.Option(..., "--positives", metavar="DIR",
                                   help="Folder of barcode captures (synth dataset layout)."),
    target_far: float = typer.Option(1e-3, "--target-far",
                                     help="Target image false-alarm rate (95 % one-sided bound)."),
    out: Path = typer.Option(..., "--out", metavar="FILE", help="Calibrated config TOML to write."),
    report: Path = typer.Option(..., "--report", metavar="DIR",
                                help="Report folder: summary.md, plots, tables, evidence cache."),
    config: Path | None = typer.Option(None, "--config", help="Base config (default: shipped)."),
    jobs: int = typer.Option(0, "--jobs", "-j", help="Worker processes (default: all cores)."),
    profiles: str = typer.Option("default,paper", "--profiles",
                                 help="Profiles to sweep: default, paper or both."),
    no_cache: bool = typer.Option(False, "--no-cache", help="Do not read or write the cache."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars."),
) -> None:
    """Sweep decision thresholds, bound the false-alarm rate, and write the best config.

    Selects the setting with the highest detection rate whose exact one-sided 95 %
    Clopper-Pearson upper bound on the clean-set false-alarm rate is <= --target-far.
    Exit status: 0 when the target is met, 3 when no setting meets it (the config with the
    lowest bound is still written, marked NOT MET in its header), 2 on usage errors.
    """
    import numpy as np

    from lishield_guard import calibrate as cal
    from lishield_guard.config import AppConfig, dump_config, load_config
    from lishield_guard.errors import LishieldError

    if not 0 < target_far < 1:
        raise _fail(f"--target-far must be in (0, 1), got {target_far!r}")
    for d in [*clean, positives]:
        if not d.is_dir():
            raise _fail(f"not a folder: {str(d)!r}")
    want = {p.strip() for p in profiles.split(",") if p.strip()}
    if not want or want - {"default", "paper"}:
        raise _fail(f"--profiles takes default and/or paper, got {profiles!r}")
    try:
        base = load_config(config)
    except LishieldError as exc:
        raise _fail(str(exc)) from None
    base = AppConfig(detector=base.detector.replace(profile="default"), limits=base.limits,
                     policies=base.policies, source=base.source)
    jobs = jobs or os.cpu_count() or 1
    report.mkdir(parents=True, exist_ok=True)
    cache_dir = None if no_cache else str(report / "cache")
    if cache_dir:
        os.makedirs(cache_dir, exist_ok=True)
    grid = cal.DefaultGrid()
    pgrid = cal.PaperGrid()

    clean_items = [it for d in clean for it in _list_images(d)]
    pos_items = [(p, r) for p, r in _list_images(positives) if r.get("label", 1) == 1]
    if not clean_items or not pos_items:
        raise _fail(f"need images in both sets: {len(clean_items)} clean, "
                    f"{len(pos_items)} positives")
    t0 = time.perf_counter()
    init = (base, grid, pgrid, cache_dir)
    res_clean = _run_pool([str(p) for p, _ in clean_items], _work, init, jobs, "clean", quiet)
    res_pos = _run_pool([str(p) for p, _ in pos_items], _work, init, jobs, "positives", quiet)
    errors = [r for r in res_clean + res_pos if r["error"]]
    ok_c = [(r, m) for r, (_, m) in zip(res_clean, clean_items, strict=True) if not r["error"]]
    ok_p = [(r, m) for r, (_, m) in zip(res_pos, pos_items, strict=True) if not r["error"]]
    if not ok_c or not ok_p:
        raise _fail("every image of a set failed to decode", ExitCode.ERROR)
    t_evidence = time.perf_counter() - t0

    settings, clean_prot, pos_prot, clean_hits, clean_cands, times = [], [], [], [], [], []
    ev_ms = np.mean([r["evidence_ms"] for r, _ in ok_c + ok_p])
    if "default" in want:
        tab_c = np.stack([r["table"] for r, _ in ok_c])
        tab_p = np.stack([r["table"] for r, _ in ok_p])
        s, pc, hc, cc = cal.default_scores(tab_c, grid)
        _, pp, _, _ = cal.default_scores(tab_p, grid)
        match_ms = np.mean([r["match_ms"] for r, _ in ok_c + ok_p], axis=0)
        n_gate = len(grid.gate_combos())
        settings += s
        clean_prot.append(pc)
        pos_prot.append(pp)
        clean_hits.append(hc)
        clean_cands.append(np.broadcast_to(cc, pc.shape))
        times.append(ev_ms + np.repeat(match_ms, n_gate))
    if "paper" in want:
        s, pc, hc, cc = cal.paper_scores([r["paper_peaks"] for r, _ in ok_c], base, pgrid)
        _, pp, _, _ = cal.paper_scores([r["paper_peaks"] for r, _ in ok_p], base, pgrid)
        dec_ms = np.mean([r["paper_decode_ms"] for r, _ in ok_c + ok_p])
        pk_ms = {k: np.mean([r["paper_ms"][k] for r, _ in ok_c + ok_p]) for k in
                 ok_c[0][0]["paper_ms"]}
        settings += s
        clean_prot.append(pc)
        pos_prot.append(pp)
        clean_hits.append(hc)
        clean_cands.append(cc)
        times.append(np.array([dec_ms + pk_ms[(int(st.as_dict["n_b"]),
                                                int(st.as_dict["max_peaks"]))] for st in s]))
    groups = [cal.group_labels(m) for _, m in ok_p]
    summaries = cal.summarise(settings, np.concatenate(clean_prot), np.concatenate(pos_prot),
                              clean_hits=np.concatenate(clean_hits),
                              clean_cands=np.concatenate(clean_cands),
                              time_ms=np.concatenate(times), pos_groups=groups)
    best, met = cal.select_setting(summaries, target_far)
    bi = summaries.index(best)
    all_clean_prot = np.concatenate(clean_prot)
    n_needed = cal.images_needed(target_far)

    # false alarms of the chosen setting, by clean subset
    fa_by: dict[str, list[int]] = {}
    fa_files = []
    for j, (r, m) in enumerate(ok_c):
        kind = m.get("kind") or Path(r["path"]).parent.name
        fa_by.setdefault(kind, [0, 0])
        fa_by[kind][1] += 1
        if all_clean_prot[bi, j]:
            fa_by[kind][0] += 1
            fa_files.append(r["path"])

    chosen_det = best.setting.apply(base.detector)
    null = None
    if best.setting.profile == "default" and cache_dir:
        rng = np.random.default_rng(0)
        idx = rng.permutation(len(ok_c))[:NULL_MODEL_SAMPLE]
        nres = _run_pool([(ok_c[i][0]["path"], chosen_det) for i in idx], _null_work, init,
                         jobs, "null model", quiet)
        nres = [x for x in nres if x]
        if nres:
            null = {"n_images": len(nres),
                    "far_measured_q": float(np.mean([x["measured"]["far"] for x in nres])),
                    "far_noise_q": float(np.mean([x["noise"]["far"] for x in nres])),
                    "p_cand_measured_q": float(np.mean([x["measured"]["p_candidate"]
                                                        for x in nres])),
                    "p_cand_noise_q": float(np.mean([x["noise"]["p_candidate"] for x in nres]))}

    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    header = "\n".join([
        "lishield-guard calibrated config (written by `lishield-guard calibrate`).",
        f"date: {date}",
        f"clean: {', '.join(str(d) for d in clean)} ({len(ok_c)} images)",
        f"positives: {positives} ({len(ok_p)} images)",
        f"base config: {base.source}",
        f"chosen: {best.setting.label()}",
        f"false alarms: {best.false_alarms}/{best.n_clean}; FAR 95% one-sided upper bound "
        f"{best.far_upper:.3g} (target {target_far:g}: {'met' if met else 'NOT MET'})",
        f"detection on positives: {best.detected}/{best.n_pos} = {best.detection:.3f}",
    ] + ([] if met else [f"TARGET NOT MET: {n_needed} clean images with 0 false alarms are "
                         f"needed to show FAR <= {target_far:g}; do not ship as calibrated."]))
    cfg_out = AppConfig(detector=chosen_det, limits=base.limits, policies=base.policies)
    text = dump_config(cfg_out, header=header)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    load_config(out)  # what we ship must load

    from lishield_guard.calibrate_report import write_report

    info = {"clean_dirs": [str(d) for d in clean], "positives": str(positives),
            "n_clean": len(ok_c), "n_pos": len(ok_p), "errors": errors[:20],
            "n_errors": len(errors), "target_far": target_far, "met": met,
            "images_needed": n_needed, "config_out": str(out), "date": date,
            "null_model": null, "fa_by_subset": fa_by, "fa_files": fa_files[:50],
            "evidence_s": t_evidence, "total_s": time.perf_counter() - t0,
            "cached": sum(1 for r, _ in ok_c + ok_p if r.get("cached")),
            "command": " ".join(["lishield-guard", *sys.argv[1:]]),
            "grid": {"default": vars(grid) if False else grid.__dict__,
                     "paper": pgrid.__dict__}}
    paths = write_report(report, summaries, best, info)
    typer.echo(f"{len(summaries)} settings on {len(ok_c)} clean + {len(ok_p)} positive images "
               f"in {info['total_s']:.0f} s", err=True)
    typer.echo(f"chosen: {best.setting.label()}", err=True)
    typer.echo(f"FAR {best.false_alarms}/{best.n_clean}, 95% upper bound {best.far_upper:.3g}; "
               f"detection {best.detection:.3f}", err=True)
    typer.echo(f"config: {out}\nreport: {paths['summary']}", err=True)
    if not met:
        typer.echo(f"warning: no setting meets FAR <= {target_far:g} at 95 % confidence; "
                   f"{n_needed} clean images with no false alarm would be needed "
                   f"(have {len(ok_c)}). Wrote the lowest-bound setting, marked NOT MET.",
                   err=True)
        raise typer.Exit(int(ExitCode.ERROR))


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main CLI app."""
    app.command(name="calibrate")(calibrate_command)
