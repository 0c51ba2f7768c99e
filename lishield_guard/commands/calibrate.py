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
from lishield_guard.threads import one_thread_per_worker

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
EVIDENCE_PREFIX = "ev8-"  # bump when image_record's layout changes (code edits key the cache)


def _code_key() -> str:
    """Hash of the core's source: cached evidence is only reused by the code that made it."""
    import lishield_guard

    root = Path(lishield_guard.__file__).parent
    h = hashlib.sha1()
    for f in sorted(root.glob("*.py")):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _init_worker(cfg, grid, paper_grid, cache_dir: str | None) -> None:
    one_thread_per_worker()
    _W.update(cfg=cfg, grid=grid, paper_grid=paper_grid, cache=cache_dir,
              cfg_key=_hash(repr(cfg.detector), repr(cfg.policies), repr(cfg.limits),
                            _code_key()))


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
        rec, hit = _cached(EVIDENCE_PREFIX + key + "-" + _hash(repr(pgrid)),
                           lambda: image_record(path, cfg, paper_grid=pgrid))
        (table, match_ms), _ = _cached("tab-" + key + "-" + _hash(repr(grid)),
                                       lambda: candidate_table(rec["evidence"], cfg, grid))
    except Exception as exc:  # noqa: BLE001 - one bad file never stops calibration
        return {"path": path, "error": f"{type(exc).__name__}: {exc}"}
    return {"path": path, "error": None, "table": table, "match_ms": match_ms,
            "folds": rec["folds"], "sweeps": rec["sweeps"], "evidence_ms": rec["evidence_ms"],
            "paper_peaks": rec["paper_peaks"],
            "paper_ms": rec["paper_ms"], "paper_decode_ms": rec["paper_decode_ms"],
            "cached": hit}


def _null_work(args) -> dict:
    path, det = args
    from lishield_guard.calibrate import null_model_far

    cfg = _W["cfg"]
    st = os.stat(path)
    key = _hash(os.path.abspath(path), st.st_size, st.st_mtime_ns, _W["cfg_key"])
    rec, _ = _cached(EVIDENCE_PREFIX + key + "-" + _hash(repr(_W["paper_grid"])), lambda: None)
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
        s, pc, hc, cc = cal.default_scores(tab_c, grid, [r["folds"] for r, _ in ok_c],
                                           base.detector,
                                           sweeps=[r["sweeps"] for r, _ in ok_c])
        _, pp, _, _ = cal.default_scores(tab_p, grid, [r["folds"] for r, _ in ok_p],
                                         base.detector,
                                         sweeps=[r["sweeps"] for r, _ in ok_p])
        match_ms = np.mean([r["match_ms"] for r, _ in ok_c + ok_p], axis=0)
        n_gate = len(s) // len(grid.match_combos())
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

    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
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

    info = {"clean_dirs": [str(d) for d in clean], "positives": str(positives),
            "n_clean": len(ok_c), "n_pos": len(ok_p), "errors": errors[:20],
            "n_errors": len(errors), "target_far": target_far, "met": met,
            "images_needed": n_needed, "config_out": str(out), "date": date,
            "null_model": null, "fa_by_subset": fa_by, "fa_files": fa_files[:50],
            "evidence_s": t_evidence, "total_s": time.perf_counter() - t0,
            "cached": sum(1 for r, _ in ok_c + ok_p if r.get("cached")),
            "command": " ".join(["lishield-guard", *sys.argv[1:]]),
            "grid": {"default": grid.__dict__, "paper": pgrid.__dict__}}
    paths = _write_report(report, summaries, best, info)
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


def _heat(ax, summaries, profile, fixed: dict, xk: str, yk: str, value: str, title: str):
    import numpy as np

    pts = {}
    for s in summaries:
        d = s.setting.as_dict
        if s.setting.profile != profile:
            continue
        if any(d.get(k) != v for k, v in fixed.items() if k not in (xk, yk)):
            continue
        pts[(d[xk], d[yk])] = getattr(s, value)
    xs = sorted({k[0] for k in pts})
    ys = sorted({k[1] for k in pts})
    z = np.full((len(ys), len(xs)), np.nan)
    for (x, y), v in pts.items():
        z[ys.index(y), xs.index(x)] = v
    im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
    ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
    ax.set_xlabel(xk)
    ax.set_ylabel(yk)
    ax.set_title(title, fontsize=9)
    for i in range(len(ys)):
        for j in range(len(xs)):
            if np.isfinite(z[i, j]):
                ax.text(j, i, f"{z[i, j]:.3g}", ha="center", va="center", fontsize=7,
                        color="w")
    ax.figure.colorbar(im, ax=ax)


def _write_report(report: Path, summaries, best, info: dict) -> dict:
    """summary.md, settings.jsonl and PNG plots into ``report``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    with open(report / "settings.jsonl", "w", encoding="utf-8") as fh:
        for s in summaries:
            fh.write(json.dumps(s.to_dict()) + "\n")
    paths["settings"] = report / "settings.jsonl"

    # heatmaps (paper Figs. 21-22 analogues)
    fixed_d = best.setting.as_dict if best.setting.profile == "default" else next(
        (s.setting.as_dict for s in summaries if s.setting.profile == "default"), {})
    paper_best = max((s for s in summaries if s.setting.profile == "paper"),
                     key=lambda s: (s.far_upper <= info["target_far"], s.detection), default=None)
    panels = []
    if fixed_d:
        panels += [("default", fixed_d, "tone_rel_tol", "peak_false_prob", "false_match_fraction",
                    "default: false candidate matches (>= min_tones) on clean"),
                   ("default", fixed_d, "tone_rel_tol", "peak_false_prob", "far_upper",
                    "default: FAR 95% upper bound"),
                   ("default", fixed_d, "tone_rel_tol", "peak_false_prob", "detection",
                    "default: detection rate"),
                   ("default", fixed_d, "min_purity", "min_occupancy", "detection",
                    "default: detection rate")]
    if paper_best is not None:
        pd_ = paper_best.setting.as_dict
        panels += [("paper", pd_, "ratio_tol", "n_b", "false_match_fraction",
                    "paper: fraction of false ratio matches (Fig. 21)"),
                   ("paper", pd_, "ratio_tol", "gamma", "far", "paper: clean FAR (Fig. 22)"),
                   ("paper", pd_, "ratio_tol", "gamma", "detection", "paper: detection"),
                   ("paper", pd_, "ratio_tol", "max_peaks", "detection", "paper: detection")]
    if panels:
        n_cols = 4
        n_rows = math.ceil(len(panels) / n_cols)
        fig, axes = plt.subplots(n_rows, n_cols, figsize=(4.6 * n_cols, 3.8 * n_rows),
                                 squeeze=False)
        for ax, (prof, fixed, xk, yk, val, title) in zip(axes.flat, panels, strict=False):
            _heat(ax, summaries, prof, fixed, xk, yk, val, title)
        for ax in list(axes.flat)[len(panels):]:
            ax.axis("off")
        fig.tight_layout()
        fig.savefig(report / "heatmaps.png", dpi=110)
        plt.close(fig)
        paths["heatmaps"] = report / "heatmaps.png"

    # ROC-style: detection vs FAR upper bound
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for prof, marker in (("default", "o"), ("paper", "s")):
        pts = [(s.far_upper, s.detection) for s in summaries if s.setting.profile == prof]
        if pts:
            x, y = zip(*pts, strict=True)
            ax.scatter(x, y, s=12, marker=marker, alpha=0.6, label=f"{prof} profile")
    ax.scatter([best.far_upper], [best.detection], s=120, facecolors="none", edgecolors="r",
               label="chosen")
    ax.axvline(info["target_far"], color="k", ls="--", lw=1, label="target FAR")
    ax.set_xscale("log")
    ax.set_xlabel("clean-set FAR, 95% one-sided upper bound")
    ax.set_ylabel("detection rate on positives")
    ax.set_title(f"{len(summaries)} settings, {info['n_clean']} clean / {info['n_pos']} positives")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(report / "roc.png", dpi=110)
    plt.close(fig)
    paths["roc"] = report / "roc.png"

    # detection per kind of positive
    bars = [(f"{k}: {v}", d["rate"], d["n"]) for k, vals in best.per_group.items()
            for v, d in vals.items() if k != "kind"]
    if bars:
        fig, ax = plt.subplots(figsize=(7, 0.28 * len(bars) + 1.2))
        labels, rates, ns = zip(*bars, strict=True)
        ax.barh(range(len(bars)), rates, color="tab:blue")
        ax.set_yticks(range(len(bars)), [f"{lab} (n={n})" for lab, n in
                                         zip(labels, ns, strict=True)], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_xlabel("detection rate")
        ax.set_title(f"chosen: {best.setting.label()}", fontsize=7)
        fig.tight_layout()
        fig.savefig(report / "detection_by_kind.png", dpi=110)
        plt.close(fig)
        paths["by_kind"] = report / "detection_by_kind.png"

    # markdown
    b = best
    lines = [
        "# Calibration report", "",
        f"- date: {info['date']}",
        f"- command: `{info['command']}`",
        f"- clean: {', '.join(info['clean_dirs'])} - **{info['n_clean']} images**",
        f"- positives: {info['positives']} - **{info['n_pos']} images**",
        f"- unreadable images skipped: {info['n_errors']}",
        f"- time: {info['total_s']:.0f} s ({info['evidence_s']:.0f} s per-image evidence; "
        f"{info['cached']} images from cache)",
        f"- settings swept: {len(summaries)}",
        f"- config written: `{info['config_out']}`", "",
        "## Chosen setting", "",
        f"`{b.setting.label()}`", "",
        f"- false alarms on clean: {b.false_alarms}/{b.n_clean} (FAR {b.far:.4g})",
        f"- FAR upper bound, exact one-sided 95 % Clopper-Pearson: **{b.far_upper:.4g}** "
        f"(two-sided 95 % interval upper end: {b.far_upper_two_sided:.4g})",
        f"- target FAR {info['target_far']:g}: **{'met' if info['met'] else 'NOT MET'}**",
        f"- detection on positives: **{b.detected}/{b.n_pos} = {b.detection:.3f}**",
        f"- fraction of false candidate matches on clean: {b.false_match_fraction:.4g}",
        f"- decision time: {b.time_ms_per_image:.1f} ms/image (decode + profile + match)", "",
        f"With 0 false alarms, n >= ln(0.05)/ln(1 - {info['target_far']:g}) = "
        f"{info['images_needed']} clean images are needed to show FAR <= {info['target_far']:g}"
        f" at 95 % (one-sided); this clean set has {info['n_clean']}, so the smallest bound it "
        f"can show is {1 - 0.05 ** (1 / info['n_clean']):.3g}.", "",
    ]
    if not info["met"]:
        lines += ["**No setting meets the target.** The config holds the setting with the "
                  "lowest bound and says NOT MET in its header.", ""]
    lines += ["### False alarms of the chosen setting by clean subset", "",
              "| subset | false alarms | images |", "|---|---|---|"]
    lines += [f"| {k} | {v[0]} | {v[1]} |" for k, v in sorted(info["fa_by_subset"].items())]
    if info["fa_files"]:
        lines += ["", "False-alarm files: " + ", ".join(f"`{f}`" for f in info["fa_files"][:20])]
    lines += ["", "### Detection by kind of positive", "",
              "| group | value | detected | n | rate |", "|---|---|---|---|---|"]
    for k, vals in b.per_group.items():
        for v, d in vals.items():
            lines.append(f"| {k} | {v} | {d['detected']} | {d['n']} | {d['rate']:.3f} |")
    nm = info.get("null_model")
    lines += ["", "## Null model vs measurement (default profile, chosen setting)", ""]
    if nm:
        lines += [
            "Chance matches of random significant peaks, uniform in log frequency (derivation "
            "in `lishield_guard/calibrate.py`), averaged over "
            f"{nm['n_images']} clean images:", "",
            "| quantity | null model, q = peak_false_prob | null model, q = measured per "
            "track | measured on clean set |", "|---|---|---|---|",
            f"| image false-alarm rate | {nm['far_noise_q']:.3g} | {nm['far_measured_q']:.3g} "
            f"| {b.far:.3g} ({b.false_alarms}/{b.n_clean}) |",
            f"| candidate with >= min_tones (no purity test) | {nm['p_cand_noise_q']:.3g} | "
            f"{nm['p_cand_measured_q']:.3g} | {b.false_match_fraction:.3g} |", "",
            "The model assumes peaks independent and log-uniform; real look-alikes (mains, PWM "
            "harmonic combs) put peaks at structured frequencies, so a measured rate above the "
            "model flags structured interference rather than noise.", ""]
    else:
        lines += ["(not evaluated: the chosen setting is not the default profile, or no cache)",
                  ""]
    lines += ["## Top settings (by detection, among bound <= target first)", "",
              "| setting | FA/n | FAR bound | detection | false match frac | ms/img |",
              "|---|---|---|---|---|---|"]
    ranked = sorted(summaries, key=lambda s: (s.far_upper > info["target_far"], -s.detection,
                                              s.far_upper))
    for s in ranked[:15]:
        lines.append(f"| {s.setting.label()} | {s.false_alarms}/{s.n_clean} | "
                     f"{s.far_upper:.3g} | {s.detection:.3f} | {s.false_match_fraction:.3g} | "
                     f"{s.time_ms_per_image:.0f} |")
    for prof in ("default", "paper"):
        cand = [s for s in summaries if s.setting.profile == prof]
        if cand:
            top = max(cand, key=lambda s: (s.far_upper <= info["target_far"], s.detection))
            lines.append(f"\nBest {prof}-profile setting: `{top.setting.label()}`: FA "
                         f"{top.false_alarms}/{top.n_clean}, bound {top.far_upper:.3g}, "
                         f"detection {top.detection:.3f}.")
    lines += ["", "## Plots", ""]
    lines += [f"- `{p.name}`" for k, p in paths.items() if k != "settings"]
    lines += [f"\n![{k}]({p.name})" for k, p in paths.items() if str(p).endswith(".png")]
    (report / "summary.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    paths["summary"] = report / "summary.md"
    return paths


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main CLI app."""
    app.command(name="calibrate")(calibrate_command)
