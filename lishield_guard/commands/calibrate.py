"""`lishield-guard calibrate`: sweep thresholds on clean images and positives, ship a config."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import pickle
import shutil
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
EVIDENCE_PREFIX = "ev9-"  # bump when image_record's layout changes (code edits key the cache)


def _code_key() -> str:
    """Hash of the core's source, the detector package's included: cached evidence is only
    reused by the code that made it."""
    import lishield_guard

    root = Path(lishield_guard.__file__).parent
    h = hashlib.sha1()
    for f in sorted([*root.glob("*.py"), *root.glob("detector/*.py")]):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _init_worker(cfg, grid, paper_grid, cache_dir: str | None,
                 want: frozenset = frozenset({"cascade", "paper"})) -> None:
    one_thread_per_worker()
    _W.update(cfg=cfg, grid=grid, paper_grid=paper_grid, cache=cache_dir, want=want,
              cfg_key=_hash(repr(cfg.detector), repr(cfg.policies), repr(cfg.limits),
                            _code_key()))


def _cached(key: str, compute):
    """``compute()``'s value, read from or written to the cache; None is never stored (the
    null model looks evidence up with a compute of None: a miss there must stay a miss)."""
    cache = _W["cache"]
    path = os.path.join(cache, key + ".pkl") if cache else None
    if path and os.path.exists(path):
        try:
            with open(path, "rb") as fh:
                value = pickle.load(fh)
            if value is not None:
                return value, True
        except Exception:  # noqa: BLE001 - a corrupt cache entry is recomputed
            pass
    value = compute()
    if path and value is not None:
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    return value, False


def _work(path: str) -> dict:
    from lishield_guard.calibrate import candidate_table, image_record, learned_record

    cfg, grid, pgrid, want = _W["cfg"], _W["grid"], _W["paper_grid"], _W["want"]
    st = os.stat(path)
    key = _hash(os.path.abspath(path), st.st_size, st.st_mtime_ns, _W["cfg_key"])
    out: dict = {"path": path, "error": None, "cached": True}
    try:
        if "default" in want:
            lrn, hit = _cached("lrn-" + key, lambda: learned_record(path, cfg))
            out.update(lrn, cached=out["cached"] and hit)
        if want & {"cascade", "paper"}:
            rec, hit = _cached(EVIDENCE_PREFIX + key + "-" + _hash(repr(pgrid)),
                               lambda: image_record(path, cfg, paper_grid=pgrid))
            (table, match_ms), _ = _cached("tab-" + key + "-" + _hash(repr(grid)),
                                           lambda: candidate_table(rec["evidence"], cfg, grid))
            out.update(table=table, match_ms=match_ms, folds=rec["folds"],
                       sweeps=rec["sweeps"], evidence_ms=rec["evidence_ms"],
                       paper_peaks=rec["paper_peaks"], paper_ms=rec["paper_ms"],
                       paper_decode_ms=rec["paper_decode_ms"], cached=out["cached"] and hit)
    except Exception as exc:  # noqa: BLE001 - one bad file never stops calibration
        return {"path": path, "error": f"{type(exc).__name__}: {exc}"}
    return out


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
    noise = null_model_far(rec["evidence"], app, q=det.tones.peak_false_prob)
    return {"measured": measured, "noise": noise}


def _run_pool(paths: list, fn, init_args, jobs: int, desc: str, progress: bool) -> list:
    from tqdm import tqdm

    out = []
    bar = tqdm(total=len(paths), desc=desc, unit="img", file=sys.stderr, disable=not progress,
               dynamic_ncols=True)
    try:
        if jobs <= 1:
            _init_worker(*init_args)
            for p in paths:
                out.append(fn(p))
                bar.update(1)
        else:
            with ProcessPoolExecutor(jobs, initializer=_init_worker, initargs=init_args) as pool:
                chunk = max(1, min(4, len(paths) // (8 * jobs)))  # small sets: balance
                for r in pool.map(fn, paths, chunksize=chunk):
                    out.append(r)
                    bar.update(1)
    finally:
        bar.close()
    return out


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


# --- the split


def _split(items: list[tuple[Path, dict, str]], fraction: float, seed: int):
    """Certification mask of ``items`` (path, manifest row, origin), whole source groups at a
    time, stratified by origin, kind and preset; and the group key of each item."""
    from lishield_guard import calibrate as cal

    groups = cal.source_groups([cal.source_keys(m, str(p)) for p, m, _ in items])
    strata = [cal.stratum_key(m, origin) for _, m, origin in items]
    return cal.split_parts(groups, strata, fraction=fraction, seed=seed), groups


def _origin_names(dirs: list[Path]) -> list[str]:
    """Short unique labels of the input folders (their names, made unique by the parent)."""
    names = [d.name or str(d) for d in dirs]
    return [str(d) if names.count(n) > 1 else n for d, n in zip(dirs, names, strict=True)]


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
        "default", "--profiles",
        help="Profiles to sweep, comma-separated: default (the learned score's threshold; "
             "one cheap measurement per image), cascade (the pattern search's thresholds; "
             "seconds per striped image), paper (Algorithm 1)."),
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
    """Sweep decision thresholds on a tuning part, certify the chosen setting on held-out images.

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
    import numpy as np

    from lishield_guard import calibrate as cal
    from lishield_guard.config import AppConfig, dump_config, load_config
    from lishield_guard.errors import LishieldError
    from lishield_guard.stats import clopper_pearson

    t_start = time.perf_counter()
    progress = progress and not quiet
    if quick:
        if clean or positives is not None:
            raise _fail("--quick calibrates on built-in sets; drop --clean and --positives")
        report = report or Path("calibrate-quick")
        out = out or report / "calibrated.toml"
        target_far = QUICK_TARGET_FAR if target_far is None else target_far
    else:
        needed = (("--clean", clean), ("--positives", positives)) + (
            () if dry_run else (("--out", out), ("--report", report)))
        missing = [o for o, v in needed if not v]
        if missing:
            raise _fail(f"missing {', '.join(missing)} (or use --quick for built-in sets)")
        target_far = 1e-3 if target_far is None else target_far
    if not 0 < target_far < 1:
        raise _fail(f"--target-far must be in (0, 1), got {target_far!r}")
    if not 0 < certify_fraction < 1:
        raise _fail(f"--certify-fraction must be in (0, 1), got {certify_fraction!r}")
    if jobs < 0:
        raise _fail(f"--jobs must be >= 1 (0: all cores), got {jobs}")
    for d in [*clean, *([positives] if positives else []), *([certify] if certify else [])]:
        if not d.is_dir():
            raise _fail(f"not a folder: {str(d)!r}")
    want = {p.strip() for p in profiles.split(",") if p.strip()}
    if not want or want - {"default", "cascade", "paper"}:
        raise _fail(f"--profiles takes default, cascade and/or paper, got {profiles!r}")
    try:
        base = load_config(config)
    except LishieldError as exc:
        raise _fail(str(exc)) from None
    base = AppConfig(detector=base.detector.replace(profile="default"), limits=base.limits,
                     policies=base.policies, source=base.source)
    jobs = jobs or os.cpu_count() or 1
    if quick:
        report.mkdir(parents=True, exist_ok=True)
        clean, positives = _quick_sets(report / "quick-data", jobs=jobs, progress=progress)
    grid = cal.DefaultGrid()
    pgrid = cal.PaperGrid()

    # --- list and split (on the listed files, so an unreadable one does not move the split)
    origins = _origin_names(clean)
    clean_items = [(p, m, o) for d, o in zip(clean, origins, strict=True)
                   for p, m in _list_images(d)]
    pos_items = [(p, m, "positives") for p, m in _list_images(positives)
                 if m.get("label", 1) == 1]
    cert_items = [(p, m, "certify") for p, m in _list_images(certify)] if certify else []
    if not clean_items or not pos_items or (certify and not cert_items):
        raise _fail(f"need images in every set: {len(clean_items)} clean, {len(pos_items)} "
                    f"positives" + (f", {len(cert_items)} to certify on" if certify else ""))
    if certify:
        clean_keys = [cal.source_keys(m, str(p)) for p, m, _ in clean_items]
        cert_keys = [cal.source_keys(m, str(p)) for p, m, _ in cert_items]
        shared = sorted({k for ks in clean_keys for k in ks if k.startswith("src:")}
                        & {k for ks in cert_keys for k in ks})
        if shared:
            typer.echo(f"warning: --certify shares {len(shared)} source photo(s) with --clean "
                       f"(e.g. {shared[0][4:]!r}): its bound is then not independent of the "
                       f"tuning", err=True)
        clean_groups = cal.source_groups(clean_keys)
        cert_groups = cal.source_groups(cert_keys)
        tune_c, cert_c = clean_items, cert_items
        groups_tc, groups_cc = clean_groups, cert_groups
    else:
        mask, groups = _split(clean_items, certify_fraction, split_seed)
        tune_c = [it for it, m in zip(clean_items, mask, strict=True) if not m]
        cert_c = [it for it, m in zip(clean_items, mask, strict=True) if m]
        groups_tc = [g for g, m in zip(groups, mask, strict=True) if not m]
        groups_cc = [g for g, m in zip(groups, mask, strict=True) if m]
    pmask, pgroups = _split(pos_items, certify_fraction, split_seed)
    tune_p = [it for it, m in zip(pos_items, pmask, strict=True) if not m]
    cert_p = [it for it, m in zip(pos_items, pmask, strict=True) if m]
    for name, part in (("clean tuning", tune_c), ("clean certification", cert_c),
                       ("positive tuning", tune_p), ("positive certification", cert_p)):
        if not part:
            raise _fail(f"the split left the {name} part empty ({len(clean_items)} clean images"
                        f" in {len(set(groups_tc) | set(groups_cc))} source groups, "
                        f"{len(pos_items)} positives): add images, or change --certify-fraction")
    if dry_run:
        typer.echo(_plan(clean_items + cert_items, {str(p) for p, _, _ in cert_c},
                         len(set(groups_tc)), len(set(groups_cc)), len(tune_p), len(cert_p),
                         certify, certify_fraction, split_seed, target_far))
        return
    report.mkdir(parents=True, exist_ok=True)
    cache_dir = None if no_cache else str(report / "cache")
    if cache_dir:
        os.makedirs(cache_dir, exist_ok=True)

    # --- per-image evidence (cached), clean images in the order tuning, certification
    init = (base, grid, pgrid, cache_dir, frozenset(want))
    all_clean = tune_c + cert_c
    res_clean = _run_pool([str(p) for p, _, _ in all_clean], _work, init, jobs, "clean",
                          progress)
    all_pos = tune_p + cert_p
    res_pos = _run_pool([str(p) for p, _, _ in all_pos], _work, init, jobs, "positives",
                        progress)
    t_evidence = time.perf_counter() - t_start
    errors = [r for r in res_clean + res_pos if r["error"]]
    part_c = ["tune"] * len(tune_c) + ["cert"] * len(cert_c)
    part_p = ["tune"] * len(tune_p) + ["cert"] * len(cert_p)
    ok_c = [(r, it[1], pt) for r, it, pt in zip(res_clean, all_clean, part_c, strict=True)
            if not r["error"]]
    ok_p = [(r, it[1], pt) for r, it, pt in zip(res_pos, all_pos, part_p, strict=True)
            if not r["error"]]
    n_tc = sum(pt == "tune" for _, _, pt in ok_c)
    n_tp = sum(pt == "tune" for _, _, pt in ok_p)
    if not n_tc or n_tc == len(ok_c) or not n_tp or n_tp == len(ok_p):
        first = errors[0] if errors else {"path": "-", "error": "-"}
        raise _fail(f"every image of a part failed ({len(errors)} of "
                    f"{len(res_clean) + len(res_pos)} images; first: {first['path']}: "
                    f"{first['error']})", ExitCode.ERROR)

    # --- verdicts of every setting (columns: tuning images first, so tuning slices are views)
    blocks = []  # per profile: settings, clean_prot, pos_prot, clean_hits, clean_cands, time
    if "default" in want:  # the learned score: one logit per image, thresholds swept
        lc = np.array([-np.inf if r["logit"] is None else r["logit"] for r, _, _ in ok_c])
        lp = np.array([-np.inf if r["logit"] is None else r["logit"] for r, _, _ in ok_p])
        s, pc, pp = cal.learned_scores(lc, lp, cal.learned_thresholds(
            lc[:n_tc], cal.LearnedGrid(), target_far=target_far))
        l_ms = float(np.mean([r["learned_ms"] for r, _, _ in ok_c + ok_p]))
        blocks.append((s, pc, pp, pc, np.ones(pc.shape[1]), np.full(len(s), l_ms)))
    ev_ms = (np.mean([r["evidence_ms"] for r, _, _ in ok_c + ok_p])
             if want & {"cascade", "paper"} else 0.0)
    if "cascade" in want:
        s, pc, hc, cc = cal.default_scores(np.stack([r["table"] for r, _, _ in ok_c]), grid,
                                           [r["folds"] for r, _, _ in ok_c], base.detector,
                                           sweeps=[r["sweeps"] for r, _, _ in ok_c])
        _, pp, _, _ = cal.default_scores(np.stack([r["table"] for r, _, _ in ok_p]), grid,
                                         [r["folds"] for r, _, _ in ok_p], base.detector,
                                         sweeps=[r["sweeps"] for r, _, _ in ok_p])
        match_ms = np.mean([r["match_ms"] for r, _, _ in ok_c + ok_p], axis=0)
        n_gate = len(s) // len(grid.match_combos())
        blocks.append((s, pc, pp, hc, np.broadcast_to(cc, pc.shape),
                       ev_ms + np.repeat(match_ms, n_gate)))
    if "paper" in want:
        s, pc, hc, cc = cal.paper_scores([r["paper_peaks"] for r, _, _ in ok_c], base, pgrid)
        _, pp, _, _ = cal.paper_scores([r["paper_peaks"] for r, _, _ in ok_p], base, pgrid)
        dec_ms = np.mean([r["paper_decode_ms"] for r, _, _ in ok_c + ok_p])
        pk_ms = {k: np.mean([r["paper_ms"][k] for r, _, _ in ok_c + ok_p]) for k in
                 ok_c[0][0]["paper_ms"]}
        blocks.append((s, pc, pp, hc, cc, np.array([dec_ms + pk_ms[
            (int(st.as_dict["paper.n_b"]), int(st.as_dict["paper.max_peaks"]))] for st in s])))
    pos_labels = [cal.group_labels(m) for _, m, _ in ok_p]

    # --- selection on the tuning part only
    tuning = []
    for s, pc, pp, hc, cc, tm in blocks:
        tuning += cal.summarise(s, pc[:, :n_tc], pp[:, :n_tp], clean_hits=hc[:, :n_tc],
                                clean_cands=cc[..., :n_tc] if np.ndim(cc) == 2 else cc[:n_tc],
                                time_ms=tm, pos_groups=pos_labels[:n_tp])
    best, tune_met = cal.select_setting(tuning, target_far)
    bi = next(i for i, x in enumerate(tuning) if x is best)
    # --- certification: the one chosen setting, once, on the held-out part
    offset = 0
    for s, pc, pp, hc, cc, tm in blocks:
        if bi < offset + len(s):
            j = bi - offset
            clean_row = pc[j]
            cert = cal.summarise([s[j]], pc[j:j + 1, n_tc:], pp[j:j + 1, n_tp:],
                                 clean_hits=hc[j:j + 1, n_tc:],
                                 clean_cands=np.asarray(cc[j:j + 1, n_tc:] if np.ndim(cc) == 2
                                                        else cc[n_tc:]),
                                 time_ms=tm[j:j + 1], pos_groups=pos_labels[n_tp:])[0]
            break
        offset += len(s)
    tune_claim = cal.claim(best.false_alarms, best.n_clean, target_far)
    cert_claim = cal.claim(cert.false_alarms, cert.n_clean, target_far)
    met = cert_claim.met

    # false alarms of the chosen setting, by clean subset and part
    fa_by: dict[str, dict[str, list[int]]] = {}
    fa_files: dict[str, list[str]] = {"tune": [], "cert": []}
    for j, (r, m, pt) in enumerate(ok_c):
        kind = m.get("kind") or Path(r["path"]).parent.name
        cell = fa_by.setdefault(kind, {"tune": [0, 0], "cert": [0, 0]})[pt]
        cell[1] += 1
        if clean_row[j]:
            cell[0] += 1
            fa_files[pt].append(r["path"])

    chosen_det = best.setting.apply(base.detector)
    null = None
    if best.setting.profile == "cascade" and cache_dir:
        rng = np.random.default_rng(0)
        idx = rng.permutation(n_tc)[:NULL_MODEL_SAMPLE]
        nres = _run_pool([(ok_c[i][0]["path"], chosen_det) for i in idx], _null_work, init,
                         jobs, "null model", progress)
        nres = [x for x in nres if x]
        if nres:
            null = {"n_images": len(nres),
                    "far_measured_q": float(np.mean([x["measured"]["far"] for x in nres])),
                    "far_noise_q": float(np.mean([x["noise"]["far"] for x in nres])),
                    "p_cand_measured_q": float(np.mean([x["measured"]["p_candidate"]
                                                        for x in nres])),
                    "p_cand_noise_q": float(np.mean([x["noise"]["p_candidate"] for x in nres]))}

    def n_groups(gs, keep) -> int:
        return len({g for g, k in zip(gs, keep, strict=True) if k})

    ok_paths = {r["path"] for r, _, _ in ok_c + ok_p}
    split = {
        "mode": "certify" if certify else "split", "seed": split_seed,
        "fraction": certify_fraction, "certify_dir": str(certify) if certify else None,
        "clean": [n_tc, len(ok_c) - n_tc], "positives": [n_tp, len(ok_p) - n_tp],
        "clean_groups": [n_groups(groups_tc, [str(p) in ok_paths for p, _, _ in tune_c]),
                         n_groups(groups_cc, [str(p) in ok_paths for p, _, _ in cert_c])],
        "positive_groups": [
            n_groups([g for g, m in zip(pgroups, pmask, strict=True) if not m],
                     [str(p) in ok_paths for p, _, _ in tune_p]),
            n_groups([g for g, m in zip(pgroups, pmask, strict=True) if m],
                     [str(p) in ok_paths for p, _, _ in cert_p])]}
    parts = {}
    for key, summ, cl in (("tuning", best, tune_claim), ("certification", cert, cert_claim)):
        parts[key] = {"false_alarms": summ.false_alarms, "n_clean": summ.n_clean,
                      "far_upper": cl.far_upper, "far_upper_two_sided": cl.far_upper_two_sided,
                      "detected": summ.detected, "n_pos": summ.n_pos,
                      "detection": summ.detection,
                      "detection_ci": list(clopper_pearson(summ.detected, summ.n_pos)),
                      "met": cl.met, "reason": cl.reason}
    needs = {t: [cal.images_needed(t, false_alarms=k) for k in (0, 1, 2)]
             for t in sorted({0.1, 0.01, 1e-3, 1e-4, target_far}, reverse=True)}

    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = _header(date=date, clean=clean, positives=positives, base=base, best=best,
                     split=split, parts=parts, target_far=target_far, met=met, quick=quick,
                     cert_claim=cert_claim)
    cfg_out = AppConfig(detector=chosen_det, limits=base.limits, policies=base.policies)
    text = dump_config(cfg_out, header=header)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    load_config(out)  # what we ship must load

    info = {"clean_dirs": [str(d) for d in clean], "positives": str(positives),
            "n_clean": len(ok_c), "n_pos": len(ok_p), "errors": errors[:20],
            "n_errors": len(errors), "target_far": target_far, "met": met,
            "tune_met": tune_met, "images_needed": cert_claim.images_needed, "needs": needs,
            "config_out": str(out), "date": date, "quick": quick,
            "null_model": null, "fa_by_subset": fa_by,
            "fa_files": {k: v[:50] for k, v in fa_files.items()},
            "evidence_s": t_evidence, "total_s": time.perf_counter() - t_start,
            "cached": sum(1 for r, _, _ in ok_c + ok_p if r.get("cached")),
            "command": " ".join(["lishield-guard", *sys.argv[1:]]),
            "split": split, "parts": parts,
            "grid": {"default": grid.__dict__, "paper": pgrid.__dict__}}
    paths = _write_report(report, tuning, best, cert, info)
    with open(report / "certification.json", "w", encoding="utf-8") as fh:
        json.dump({k: info[k] for k in ("split", "parts", "target_far", "met", "tune_met",
                                        "needs", "date", "command", "config_out")}
                  | {"chosen": best.setting.label()}, fh, indent=1, default=str)
    typer.echo(_console_report(info, best, len(tuning), paths["summary"]))
    if not met:
        typer.echo(f"warning: target FAR {target_far:g} NOT MET on the certification part: "
                   f"{cert_claim.reason}. The config is written, marked NOT MET.", err=True)
        raise typer.Exit(int(ExitCode.ERROR))


def _plan(items, cert_paths: set[str], groups_t: int, groups_c: int, n_tp: int, n_cp: int,
          certify, fraction: float, seed: int, target_far: float) -> str:
    """--dry-run's text: images per stratum and part, and what the certification part can show
    if it holds no false alarm."""
    from lishield_guard import calibrate as cal

    counts: dict[str, list[int]] = {}
    for p, m, origin in items:
        counts.setdefault(cal.stratum_key(m, origin), [0, 0])[str(p) in cert_paths] += 1
    n_t = sum(v[0] for v in counts.values())
    n_c = sum(v[1] for v in counts.values())
    split = {"mode": "certify" if certify else "split", "seed": seed, "fraction": fraction,
             "certify_dir": str(certify) if certify else None, "clean": [n_t, n_c],
             "clean_groups": [groups_t, groups_c], "positives": [n_tp, n_cp]}
    width = max(len(k) for k in counts)
    lines = [_split_line(split), f"{'clean stratum'.ljust(width)}  tuning  certification"]
    lines += [f"{k.ljust(width)}  {v[0]:>6}  {v[1]:>13}" for k, v in sorted(counts.items())]
    best = cal.claim(0, n_c, target_far)
    lines.append(f"with no false alarm the certification part shows FAR <= {best.far_upper:.3g}: "
                 + (f"enough for the target {target_far:g}" if best.met else
                    f"NOT enough for the target {target_far:g} (needs >= "
                    f"{best.images_needed} clean certification images)"))
    return "\n".join(lines)


def _fmt_part(p: dict) -> tuple[str, str, str]:
    lo, hi = p["detection_ci"]
    return (f"{p['false_alarms']}/{p['n_clean']}", f"{p['far_upper']:.3g}",
            f"{p['detected']}/{p['n_pos']} = {p['detection']:.3f} [{lo:.3f}, {hi:.3f}]")


def _split_line(split: dict) -> str:
    how = (f"certification on the independent folder {split['certify_dir']}"
           if split["mode"] == "certify" else
           f"seed {split['seed']}, certification fraction {split['fraction']:g}")
    (tc, cc), (tg, cg) = split["clean"], split["clean_groups"]
    (tp, cp) = split["positives"]
    return (f"split ({how}): clean {tc} tuning / {cc} certification "
            f"({tg} / {cg} source groups); positives {tp} / {cp}")


def _header(*, date, clean, positives, base, best, split, parts, target_far, met, quick,
            cert_claim) -> str:
    t, c = parts["tuning"], parts["certification"]
    lines = [
        "lishield-guard calibrated config (written by `lishield-guard calibrate`).",
        f"date: {date}",
        *(["QUICK MODE: built-in demonstration sets, not a calibration for real uploads."]
          if quick else []),
        f"clean: {', '.join(str(d) for d in clean)}; positives: {positives}",
        _split_line(split),
        f"base config: {base.source}",
        f"chosen on the tuning part: {best.setting.label()}",
        f"tuning (selection): false alarms {t['false_alarms']}/{t['n_clean']}, FAR 95% "
        f"one-sided upper bound {t['far_upper']:.3g}; detection {t['detected']}/{t['n_pos']}"
        f" = {t['detection']:.3f}",
        f"certification: false alarms {c['false_alarms']}/{c['n_clean']}, FAR 95% one-sided "
        f"upper bound {c['far_upper']:.3g}; detection {c['detected']}/{c['n_pos']} = "
        f"{c['detection']:.3f} (95% CI {c['detection_ci'][0]:.3f}-{c['detection_ci'][1]:.3f})",
        f"target FAR {target_far:g} on the certification part: {'met' if met else 'NOT MET'}",
    ]
    if not met:
        lines.append(f"TARGET NOT MET: {cert_claim.reason}; do not ship as calibrated.")
    return "\n".join(lines)


def _console_report(info: dict, best, n_settings: int, summary_path: Path) -> str:
    t, c = info["parts"]["tuning"], info["parts"]["certification"]
    rows = [("", "false alarms", "FAR bound (95%, 1-sided)", "detection [95% CI]"),
            ("tuning (selection)", *_fmt_part(t)), ("certification", *_fmt_part(c))]
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    table = ["  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip()
             for r in rows]
    tf = info["target_far"]
    need = info["needs"][tf]
    lines = [
        f"{n_settings} settings on {info['n_clean']} clean + {info['n_pos']} positive images in "
        f"{info['total_s']:.0f} s ({info['cached']} from cache)",
        _split_line(info["split"]), *table,
        f"chosen (on the tuning part): {best.setting.label()}",
        f"target FAR {tf:g}: {'met' if info['met'] else 'NOT MET'} on the certification part "
        f"({c['reason']})",
        f"the tuning part alone would call it {'met' if info['tune_met'] else 'not met'}",
        f"showing FAR <= {tf:g} needs >= {need[0]} certification images with no false alarm "
        f"({need[1]} with one, {need[2]} with two)",
        f"config: {info['config_out']}", f"report: {summary_path}"]
    return "\n".join(lines)


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


def _write_report(report: Path, summaries, best, cert, info: dict) -> dict:
    """summary.md, settings.jsonl and PNG plots into ``report``; returns their paths.

    ``summaries`` are every setting's figures on the tuning part (what selection saw); ``cert``
    is the chosen setting's on the certification part.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    with open(report / "settings.jsonl", "w", encoding="utf-8") as fh:
        for s in summaries:
            fh.write(json.dumps(s.to_dict()) + "\n")
    paths["settings"] = report / "settings.jsonl"

    # heatmaps (paper Figs. 21-22 analogues), tuning part
    fixed_d = best.setting.as_dict if best.setting.profile == "cascade" else next(
        (s.setting.as_dict for s in summaries if s.setting.profile == "cascade"), {})
    paper_best = max((s for s in summaries if s.setting.profile == "paper"),
                     key=lambda s: (s.far_upper <= info["target_far"], s.detection), default=None)
    panels = []
    if fixed_d:
        tol, fp = "tones.rel_tol", "tones.peak_false_prob"
        panels += [("cascade", fixed_d, tol, fp, "false_match_fraction",
                    "cascade: false candidate matches (>= min_tones) on clean"),
                   ("cascade", fixed_d, tol, fp, "far_upper", "cascade: FAR 95% upper bound"),
                   ("cascade", fixed_d, tol, fp, "detection", "cascade: detection rate"),
                   ("cascade", fixed_d, "tones.min_purity", "tones.min_occupancy",
                    "detection", "cascade: detection rate")]
    if paper_best is not None:
        pd_ = paper_best.setting.as_dict
        tol = "paper.ratio_tol"
        panels += [("paper", pd_, tol, "paper.n_b", "false_match_fraction",
                    "paper: fraction of false ratio matches (Fig. 21)"),
                   ("paper", pd_, tol, "paper.gamma", "far", "paper: clean FAR (Fig. 22)"),
                   ("paper", pd_, tol, "paper.gamma", "detection", "paper: detection"),
                   ("paper", pd_, tol, "paper.max_peaks", "detection", "paper: detection")]
    if panels:
        n_cols = 4
        n_rows = math.ceil(len(panels) / n_cols)
        fig, axes = plt.subplots(n_rows, n_cols, figsize=(4.6 * n_cols, 3.8 * n_rows),
                                 squeeze=False)
        for ax, (prof, fixed, xk, yk, val, title) in zip(axes.flat, panels, strict=False):
            _heat(ax, summaries, prof, fixed, xk, yk, val, "tuning part - " + title)
        for ax in list(axes.flat)[len(panels):]:
            ax.axis("off")
        fig.tight_layout()
        fig.savefig(report / "heatmaps.png", dpi=110)
        plt.close(fig)
        paths["heatmaps"] = report / "heatmaps.png"

    # ROC-style: detection vs FAR upper bound on the tuning part, and the certified point
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for prof, marker in (("default", "o"), ("cascade", "^"), ("paper", "s")):
        pts = [(s.far_upper, s.detection) for s in summaries if s.setting.profile == prof]
        if pts:
            x, y = zip(*pts, strict=True)
            ax.scatter(x, y, s=12, marker=marker, alpha=0.6, label=f"{prof} profile (tuning)")
    ax.scatter([best.far_upper], [best.detection], s=120, facecolors="none", edgecolors="r",
               label="chosen, tuning part")
    ax.scatter([cert.far_upper], [cert.detection], s=160, marker="*", color="r",
               label="chosen, certification part")
    ax.axvline(info["target_far"], color="k", ls="--", lw=1, label="target FAR")
    ax.set_xscale("log")
    ax.set_xlabel("clean-set FAR, 95% one-sided upper bound")
    ax.set_ylabel("detection rate on positives")
    sp = info["split"]
    ax.set_title(f"{len(summaries)} settings; tuning {sp['clean'][0]} clean / "
                 f"{sp['positives'][0]} positives, certification {sp['clean'][1]} / "
                 f"{sp['positives'][1]}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(report / "roc.png", dpi=110)
    plt.close(fig)
    paths["roc"] = report / "roc.png"

    # detection per kind of positive, certification part
    bars = [(f"{k}: {v}", d["rate"], d["n"]) for k, vals in cert.per_group.items()
            for v, d in vals.items() if k != "kind"]
    if bars:
        fig, ax = plt.subplots(figsize=(7, 0.28 * len(bars) + 1.2))
        labels, rates, ns = zip(*bars, strict=True)
        ax.barh(range(len(bars)), rates, color="tab:blue")
        ax.set_yticks(range(len(bars)), [f"{lab} (n={n})" for lab, n in
                                         zip(labels, ns, strict=True)], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_xlabel("detection rate, certification part")
        ax.set_title(f"chosen: {best.setting.label()}", fontsize=7)
        fig.tight_layout()
        fig.savefig(report / "detection_by_kind.png", dpi=110)
        plt.close(fig)
        paths["by_kind"] = report / "detection_by_kind.png"

    # markdown
    b, tf = best, info["target_far"]
    pt, pc = info["parts"]["tuning"], info["parts"]["certification"]
    lines = [
        "# Calibration report", "",
        *(["**Quick mode**: small built-in sets (scikit-image photo variants, synthetic "
           "look-alikes and captures); it shows the procedure, not a false-alarm rate for "
           "real uploads.", ""] if info["quick"] else []),
        f"- date: {info['date']}",
        f"- command: `{info['command']}`",
        f"- clean: {', '.join(info['clean_dirs'])} - **{info['n_clean']} images**",
        f"- positives: {info['positives']} - **{info['n_pos']} images**",
        f"- {_split_line(sp)}",
        f"- unreadable images skipped: {info['n_errors']}",
        f"- time: {info['total_s']:.0f} s ({info['evidence_s']:.0f} s per-image evidence; "
        f"{info['cached']} images from cache)",
        f"- settings swept: {len(summaries)}",
        f"- config written: `{info['config_out']}`", "",
        "## Tuning and certification", "",
        "Selection saw only the tuning part. The certification part was scored once, for the "
        "chosen setting; only its bound can meet the target.", "",
        "| part | clean images (source groups) | false alarms | FAR bound, one-sided 95 % | "
        "two-sided 95 % upper end | detection [95 % CI] |",
        "|---|---|---|---|---|---|",
    ]
    for name, p, ng in (("tuning (selection)", pt, sp["clean_groups"][0]),
                        ("certification", pc, sp["clean_groups"][1])):
        fa, bound, det = _fmt_part(p)
        lines.append(f"| {name} | {p['n_clean']} ({ng}) | {fa} | {bound} | "
                     f"{p['far_upper_two_sided']:.3g} | {det} |")
    lines += [
        "", f"- **target FAR {tf:g}: {'met' if info['met'] else 'NOT MET'}** on the "
        f"certification part: {pc['reason']}.",
        f"- the tuning part alone would call it {'met' if info['tune_met'] else 'not met'}: "
        f"{pt['reason']}."]
    if info["tune_met"] and not info["met"]:
        lines.append("- **selection on the tuning part claims a target that the certification "
                     "part does not show**; the config says NOT MET.")
    if not info["tune_met"]:
        lines.append("- no setting met the target on the tuning part; selection took the "
                     "setting with the fewest tuning false alarms, then the highest detection.")
    lines += ["", "### Certification images a target needs", "",
              "Exact one-sided 95 % Clopper-Pearson bound (scipy `binomtest(...)"
              ".proportion_ci(method=\"exact\")`): clean images needed for the bound to reach "
              "the target with k false alarms among them.", "",
              "| target FAR | k = 0 | k = 1 | k = 2 |", "|---|---|---|---|"]
    for t, ns in info["needs"].items():
        mark = " (this run)" if t == tf else ""
        lines.append(f"| {t:g}{mark} | {ns[0]} | {ns[1]} | {ns[2]} |")
    lines += ["", f"The certification part has {pc['n_clean']} clean images: the smallest "
              f"bound it can give (no false alarm) is "
              f"{1 - 0.05 ** (1 / max(pc['n_clean'], 1)):.3g}.", ""]
    lines += [
        "## Chosen setting", "",
        f"`{b.setting.label()}`", "",
        f"- fraction of false candidate matches on clean (tuning): {b.false_match_fraction:.4g}",
        f"- decision time: {b.time_ms_per_image:.1f} ms/image (decode + profile + match)", "",
        "### False alarms of the chosen setting by clean subset", "",
        "| subset | tuning | certification |", "|---|---|---|"]
    for k, v in sorted(info["fa_by_subset"].items()):
        lines.append(f"| {k} | {v['tune'][0]}/{v['tune'][1]} | {v['cert'][0]}/{v['cert'][1]} |")
    for key, name in (("tune", "tuning"), ("cert", "certification")):
        if info["fa_files"][key]:
            lines += ["", f"False-alarm files ({name}): " + ", ".join(
                f"`{f}`" for f in info["fa_files"][key][:20])]
    lines += ["", "### Detection by kind of positive", "",
              "| group | value | tuning | certification | certification rate |",
              "|---|---|---|---|---|"]
    for k, vals in cert.per_group.items():
        for v, d in vals.items():
            t = b.per_group.get(k, {}).get(v)
            tcell = f"{t['detected']}/{t['n']}" if t else "-"
            lines.append(f"| {k} | {v} | {tcell} | {d['detected']}/{d['n']} | "
                         f"{d['rate']:.3f} |")
    nm = info.get("null_model")
    lines += ["", "## Null model vs measurement (default profile, chosen setting, tuning part)",
              ""]
    if nm:
        lines += [
            "Chance matches of random significant peaks, uniform in log frequency (derivation "
            "in `lishield_guard/calibrate.py`), averaged over "
            f"{nm['n_images']} clean tuning images:", "",
            "| quantity | null model, q = peak_false_prob | null model, q = measured per "
            "track | measured on clean tuning part |", "|---|---|---|---|",
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
    lines += ["## Top settings on the tuning part (by detection, among bound <= target first)",
              "", "| setting | FA/n | FAR bound | detection | false match frac | ms/img |",
              "|---|---|---|---|---|---|"]
    ranked = sorted(summaries, key=lambda s: (s.far_upper > tf, -s.detection, s.far_upper))
    for s in ranked[:15]:
        lines.append(f"| {s.setting.label()} | {s.false_alarms}/{s.n_clean} | "
                     f"{s.far_upper:.3g} | {s.detection:.3f} | {s.false_match_fraction:.3g} | "
                     f"{s.time_ms_per_image:.0f} |")
    for prof in ("default", "cascade", "paper"):
        cand = [s for s in summaries if s.setting.profile == prof]
        if cand:
            top = max(cand, key=lambda s: (s.far_upper <= tf, s.detection))
            lines.append(f"\nBest {prof}-profile setting on the tuning part: "
                         f"`{top.setting.label()}`: FA {top.false_alarms}/{top.n_clean}, bound "
                         f"{top.far_upper:.3g}, detection {top.detection:.3f}.")
    lines += ["", "## Plots", ""]
    lines += [f"- `{p.name}`" for k, p in paths.items() if k != "settings"]
    lines += [f"\n![{k}]({p.name})" for k, p in paths.items() if str(p).endswith(".png")]
    (report / "summary.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    paths["summary"] = report / "summary.md"
    return paths


def register(app: typer.Typer) -> None:
    """Add the ``calibrate`` command to the main CLI app."""
    app.command(name="calibrate")(calibrate_command)
