"""One calibration run: list, split, measure (pooled, cached), select, certify, write.

`run` is what ``lishield-guard calibrate`` calls; `plan` is its ``--dry-run``. Images are listed
by `lishield_guard.batch.list_files` (the types `scan` reads), measured in the pool of
`lishield_guard.batch.run_pool` and cached by `lishield_guard.batch.EvidenceCache`.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lishield_guard.batch import (
    IMAGE,
    EvidenceCache,
    WorkerCrashed,
    list_files,
    run_pool,
    worker_state,
)
from lishield_guard.batch.pool import progress_bar
from lishield_guard.calibration.bounds import claim, images_needed, null_model_far
from lishield_guard.calibration.evidence import (
    PROFILES,
    CascadeGrid,
    LearnedGrid,
    PaperGrid,
    candidate_table,
    cascade_scores,
    image_record,
    learned_record,
    learned_scores,
    learned_thresholds,
    paper_scores,
)
from lishield_guard.calibration.firstlook import FirstLookCalibration, calibrate_first_look
from lishield_guard.calibration.report import config_header, plan_text, write_report
from lishield_guard.calibration.selection import group_labels, select_setting, summarise
from lishield_guard.calibration.split import source_groups, source_keys, split_parts, stratum_key
from lishield_guard.config import AppConfig, dump_config, load_config
from lishield_guard.detector.decision import decision_model
from lishield_guard.profiles import cascade, learned, paper
from lishield_guard.stats import clopper_pearson

__all__ = ["PROFILES", "CalibrationError", "CalibrationResult", "calibration_cache",
           "list_images", "plan", "run"]

PATTERN_PROFILES = frozenset({cascade.NAME, paper.NAME})  # measured by `image_record`
NULL_MODEL_SAMPLE = 300  # clean images the null model is evaluated on


class CalibrationError(ValueError):
    """The inputs cannot be calibrated on (an empty set or part); ``failed`` is True when every
    image of a part failed to be measured (a failure of the run rather than of its use)."""

    def __init__(self, message: str, *, failed: bool = False) -> None:
        super().__init__(message)
        self.failed = failed


@dataclass(frozen=True)
class CalibrationResult:
    """What a run wrote and found.

    Attributes
    ----------
    config_path, report_paths
        The calibrated config TOML and the report files (``summary``, ``settings``, plots).
    info : dict
        Everything the report states (split, parts, target, timings, false-alarm files).
    best, cert
        The chosen setting's summary on the tuning part and on the certification part.
    n_settings : int
        Settings swept.
    met : bool
        Whether the certification part shows the target false-alarm rate.
    reason : str
        Why (or why not), in words.
    """

    config_path: Path
    report_paths: dict
    info: dict
    best: Any
    cert: Any
    n_settings: int
    met: bool
    reason: str


def list_images(folder: Path | None) -> list[tuple[Path, dict]]:
    """Images under ``folder`` (sorted; every type `scan` reads) with their manifest.jsonl rows
    when present."""
    if folder is None:
        return []
    rows: dict[str, dict] = {}
    for mf in sorted(folder.rglob("manifest.jsonl")):
        for line in mf.read_text(encoding="utf-8").splitlines():
            if line.strip():
                r = json.loads(line)
                if "file" in r:
                    rows[str((mf.parent / r["file"]).resolve())] = r
    return [(p, rows.get(str(p.resolve()), {})) for p in list_files(folder, kinds=(IMAGE,))]


def _origin_names(dirs: list[Path]) -> list[str]:
    """Short unique labels of the input folders (their names, made unique by the parent)."""
    names = [d.name or str(d) for d in dirs]
    return [str(d) if names.count(n) > 1 else n for d, n in zip(dirs, names, strict=True)]


def _split(items: list[tuple[Path, dict, str]], fraction: float, seed: int):
    """Certification mask of ``items`` (path, manifest row, origin), whole source groups at a
    time, stratified by origin, kind and preset; and the group key of each item."""
    groups = source_groups([source_keys(m, str(p)) for p, m, _ in items])
    strata = [stratum_key(m, origin) for _, m, origin in items]
    return split_parts(groups, strata, fraction=fraction, seed=seed), groups


@dataclass
class _Parts:
    """The listed images and their split into tuning and certification parts."""

    clean_items: list
    cert_items: list
    tune_c: list
    cert_c: list
    tune_p: list
    cert_p: list
    groups_tc: list
    groups_cc: list
    pgroups: list
    pmask: Any


def _parts(clean: list[Path], positives: Path, certify: Path | None, fraction: float,
           seed: int, on_warning: Callable[[str], None]) -> _Parts:
    """List and split (on the listed files, so an unreadable one does not move the split)."""
    origins = _origin_names(clean)
    clean_items = [(p, m, o) for d, o in zip(clean, origins, strict=True)
                   for p, m in list_images(d)]
    pos_items = [(p, m, "positives") for p, m in list_images(positives)
                 if m.get("label", 1) == 1]
    cert_items = [(p, m, "certify") for p, m in list_images(certify)]
    if not clean_items or not pos_items or (certify and not cert_items):
        raise CalibrationError(
            f"need images in every set: {len(clean_items)} clean, {len(pos_items)} positives"
            + (f", {len(cert_items)} to certify on" if certify else ""))
    if certify:
        clean_keys = [source_keys(m, str(p)) for p, m, _ in clean_items]
        cert_keys = [source_keys(m, str(p)) for p, m, _ in cert_items]
        shared = sorted({k for ks in clean_keys for k in ks if k.startswith("src:")}
                        & {k for ks in cert_keys for k in ks})
        if shared:
            on_warning(f"warning: --certify shares {len(shared)} source photo(s) with --clean "
                         f"(e.g. {shared[0][4:]!r}): its bound is then not independent of the "
                         f"tuning")
        tune_c, cert_c = clean_items, cert_items
        groups_tc, groups_cc = source_groups(clean_keys), source_groups(cert_keys)
    else:
        mask, groups = _split(clean_items, fraction, seed)
        tune_c = [it for it, m in zip(clean_items, mask, strict=True) if not m]
        cert_c = [it for it, m in zip(clean_items, mask, strict=True) if m]
        groups_tc = [g for g, m in zip(groups, mask, strict=True) if not m]
        groups_cc = [g for g, m in zip(groups, mask, strict=True) if m]
    pmask, pgroups = _split(pos_items, fraction, seed)
    tune_p = [it for it, m in zip(pos_items, pmask, strict=True) if not m]
    cert_p = [it for it, m in zip(pos_items, pmask, strict=True) if m]
    for name, part in (("clean tuning", tune_c), ("clean certification", cert_c),
                       ("positive tuning", tune_p), ("positive certification", cert_p)):
        if not part:
            raise CalibrationError(
                f"the split left the {name} part empty ({len(clean_items)} clean images in "
                f"{len(set(groups_tc) | set(groups_cc))} source groups, {len(pos_items)} "
                f"positives): add images, or change --certify-fraction")
    return _Parts(clean_items, cert_items, tune_c, cert_c, tune_p, cert_p, groups_tc, groups_cc,
                  pgroups, pmask)


def plan(clean: list[Path], positives: Path, *, certify: Path | None = None,
         certify_fraction: float = 0.5, split_seed: int = 0, target_far: float = 1e-3,
         on_warning: Callable[[str], None] = print) -> str:
    """``--dry-run``: the split per stratum and part, and what its certification part can show
    if it holds no false alarm; no image is analysed.

    Raises
    ------
    CalibrationError
        When a set or a part of the split is empty.
    """
    pt = _parts(clean, positives, certify, certify_fraction, split_seed, on_warning)
    return plan_text(pt.clean_items + pt.cert_items, {str(p) for p, _, _ in pt.cert_c},
                     len(set(pt.groups_tc)), len(set(pt.groups_cc)), len(pt.tune_p),
                     len(pt.cert_p), certify, certify_fraction, split_seed, target_far)


# --- worker side: one image's evidence, read from or written to the cache


def _work(path: str) -> dict:
    st = worker_state()
    cfg, grid, pgrid, want, cache = st["cfg"], st["grid"], st["paper_grid"], st["want"], \
        st["cache"]
    out: dict = {"path": path, "error": None, "cached": True}
    try:
        if learned.NAME in want:
            lrn, hit = cache.get(learned_record, path, compute=lambda: learned_record(path, cfg))
            out.update(lrn, cached=out["cached"] and hit)
        if want & PATTERN_PROFILES:
            rec, hit = cache.get(image_record, path, pgrid,
                                 compute=lambda: image_record(path, cfg, paper_grid=pgrid))
            (table, match_ms), _ = cache.get(
                candidate_table, path, grid,
                compute=lambda: candidate_table(rec["evidence"], cfg, grid))
            out.update(table=table, match_ms=match_ms, folds=rec["folds"],
                       sweeps=rec["sweeps"], evidence_ms=rec["evidence_ms"],
                       paper_peaks=rec["paper_peaks"], paper_ms=rec["paper_ms"],
                       paper_decode_ms=rec["paper_decode_ms"], cached=out["cached"] and hit)
    except Exception as exc:  # noqa: BLE001 - one bad file never stops calibration
        return {"path": path, "error": f"{type(exc).__name__}: {exc}"}
    return out


def _null_work(args) -> dict:
    path, det = args
    st = worker_state()
    cfg = st["cfg"]
    rec, _ = st["cache"].get(image_record, path, st["paper_grid"], compute=lambda: None)
    if rec is None:
        return {}
    app = dataclasses.replace(cfg, detector=det)
    measured = null_model_far(rec["evidence"], app)
    noise = null_model_far(rec["evidence"], app, q=det.tones.peak_false_prob)
    return {"measured": measured, "noise": noise}


def _measure(fn, args: list, state: dict, jobs: int, desc: str, progress: bool) -> list:
    """``fn`` on every argument in the pool, results in input order, a progress bar."""
    out = []
    with progress_bar(desc, total=len(args), enabled=progress) as bar:
        for arg, r in run_pool(fn, args, jobs=jobs, state=state, ordered=True,
                               preload=("lishield_guard.calibration",)):
            if isinstance(r, WorkerCrashed):
                r = {"path": arg if isinstance(arg, str) else arg[0], "error": str(r)}
            out.append(r)
            bar.update(1)
    return out


# --- the run


def run(clean: list[Path], positives: Path, *, out: Path, report: Path,
        base: AppConfig, target_far: float, certify: Path | None = None,
        certify_fraction: float = 0.5, split_seed: int = 0, jobs: int = 1,
        profiles: frozenset[str] = frozenset({learned.NAME}), use_cache: bool = True,
        quick: bool = False, progress: bool = False, command: str = "",
        on_warning: Callable[[str], None] = print) -> CalibrationResult:
    """Sweep decision thresholds on a tuning part, certify the chosen setting on held-out images,
    write the calibrated config and the report.

    Parameters
    ----------
    clean : list of Path
        Folders of clean images (no barcodes).
    positives : Path
        Folder of barcode captures (synth dataset layout; ``label`` 0 rows are left out).
    out, report : Path
        Config TOML to write; report folder (summary, plots, tables, evidence cache).
    base : AppConfig
        Config the chosen setting is applied to (its detector profile is set to the learned
        one); every group it holds (``[video]`` too) is written back unchanged but for the
        chosen setting and, for a learned threshold, the weights' digest beside it.
    target_far : float
        Target image false-alarm rate in (0, 1), shown by the exact one-sided 95 % bound on the
        certification part.
    certify : Path, optional
        Independent clean folder to certify on (every ``clean`` image then tunes).
    certify_fraction : float
        Share of the clean images (unless ``certify``) and of the positives held out.
    split_seed : int
        Seed of the split.
    jobs : int
        Worker processes.
    profiles : frozenset of str
        Profiles swept (names in `PROFILES`).
    use_cache : bool
        Read and write the evidence cache under ``report / "cache"``.
    quick, progress, command
        Marked in the report; progress bars on stderr; the command line the report quotes.
    on_warning : callable
        Called with each warning line.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CalibrationError
        When a set or a part is empty, or every image of a part failed.
    """
    t_start = time.perf_counter()
    base = dataclasses.replace(base, detector=base.detector.replace(profile=learned.NAME))
    want = frozenset(profiles)
    grid, pgrid = CascadeGrid(), PaperGrid()
    pt = _parts(clean, positives, certify, certify_fraction, split_seed, on_warning)
    report.mkdir(parents=True, exist_ok=True)
    cache = calibration_cache(report / "cache" if use_cache else None, base)
    state = {"cfg": base, "grid": grid, "paper_grid": pgrid, "cache": cache, "want": want}

    # --- per-image evidence (cached), clean images in the order tuning, certification
    all_clean, all_pos = pt.tune_c + pt.cert_c, pt.tune_p + pt.cert_p
    res_clean = _measure(_work, [str(p) for p, _, _ in all_clean], state, jobs, "clean",
                         progress)
    res_pos = _measure(_work, [str(p) for p, _, _ in all_pos], state, jobs, "positives",
                       progress)
    t_evidence = time.perf_counter() - t_start
    errors = [r for r in res_clean + res_pos if r["error"]]
    part_c = ["tune"] * len(pt.tune_c) + ["cert"] * len(pt.cert_c)
    part_p = ["tune"] * len(pt.tune_p) + ["cert"] * len(pt.cert_p)
    ok_c = [(r, it[1], p) for r, it, p in zip(res_clean, all_clean, part_c, strict=True)
            if not r["error"]]
    ok_p = [(r, it[1], p) for r, it, p in zip(res_pos, all_pos, part_p, strict=True)
            if not r["error"]]
    n_tc = sum(p == "tune" for _, _, p in ok_c)
    n_tp = sum(p == "tune" for _, _, p in ok_p)
    if not n_tc or n_tc == len(ok_c) or not n_tp or n_tp == len(ok_p):
        first = errors[0] if errors else {"path": "-", "error": "-"}
        raise CalibrationError(f"every image of a part failed ({len(errors)} of "
                               f"{len(res_clean) + len(res_pos)} images; first: "
                               f"{first['path']}: {first['error']})", failed=True)

    blocks = _verdict_blocks(ok_c, ok_p, want, base, grid, pgrid, n_tc, target_far)
    pos_labels = [group_labels(m) for _, m, _ in ok_p]
    tuning, best, tune_met, cert, clean_row = _select_and_certify(blocks, n_tc, n_tp,
                                                                   pos_labels, target_far)
    tune_claim = claim(best.false_alarms, best.n_clean, target_far)
    cert_claim = claim(cert.false_alarms, cert.n_clean, target_far)
    chosen_det = best.setting.apply(base.detector)
    null = None
    if best.setting.profile == cascade.NAME and use_cache:
        null = _null_model(ok_c, n_tc, chosen_det, state, jobs, progress)

    split = _split_info(pt, ok_c, ok_p, n_tc, n_tp, certify, certify_fraction, split_seed)
    parts = {}
    for key, summ, cl in (("tuning", best, tune_claim), ("certification", cert, cert_claim)):
        parts[key] = {"false_alarms": summ.false_alarms, "n_clean": summ.n_clean,
                      "far_upper": cl.far_upper, "far_upper_two_sided": cl.far_upper_two_sided,
                      "detected": summ.detected, "n_pos": summ.n_pos,
                      "detection": summ.detection,
                      "detection_ci": list(clopper_pearson(summ.detected, summ.n_pos)),
                      "met": cl.met, "reason": cl.reason}
    needs = {t: [images_needed(t, false_alarms=k) for k in (0, 1, 2)]
             for t in sorted({0.1, 0.01, 1e-3, 1e-4, target_far}, reverse=True)}

    met = cert_claim.met
    date = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = config_header(date=date, clean=clean, positives=positives, base=base, best=best,
                           split=split, parts=parts, target_far=target_far, met=met,
                           quick=quick, cert_claim=cert_claim)
    first = None
    if best.setting.profile == learned.NAME:  # the thresholds are bound to these weights
        first = _first_look(ok_c, ok_p, chosen_det)
        header += "\n" + first.line()
        chosen_det = chosen_det.replace(learned=chosen_det.learned.replace(
            model_digest=decision_model(chosen_det).digest,
            first_look_ln=first.first_look_ln))
    cfg_out = dataclasses.replace(base, detector=chosen_det, source=str(out), header="")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(dump_config(cfg_out, header=header), encoding="utf-8")
    load_config(out)  # what we ship must load

    fa_by, fa_files = _false_alarms(ok_c, clean_row)
    info = {"clean_dirs": [str(d) for d in clean], "positives": str(positives),
            "n_clean": len(ok_c), "n_pos": len(ok_p), "errors": errors[:20],
            "n_errors": len(errors), "target_far": target_far, "met": met,
            "tune_met": tune_met, "images_needed": cert_claim.images_needed, "needs": needs,
            "config_out": str(out), "date": date, "quick": quick,
            "null_model": null, "fa_by_subset": fa_by,
            "first_look": None if first is None else first.to_dict() | {"line": first.line()},
            "fa_files": {k: v[:50] for k, v in fa_files.items()},
            "evidence_s": t_evidence, "total_s": time.perf_counter() - t_start,
            "cached": sum(1 for r, _, _ in ok_c + ok_p if r.get("cached")),
            "command": command, "split": split, "parts": parts,
            "grid": {cascade.NAME: grid.__dict__, paper.NAME: pgrid.__dict__}}
    paths = write_report(report, tuning, best, cert, info)
    with open(report / "certification.json", "w", encoding="utf-8") as fh:
        json.dump({k: info[k] for k in ("split", "parts", "target_far", "met", "tune_met",
                                        "needs", "date", "command", "config_out")}
                  | {"chosen": best.setting.label()}, fh, indent=1, default=str)
    return CalibrationResult(out, paths, info, best, cert, len(tuning), met, cert_claim.reason)


def calibration_cache(folder: Path | None, base: AppConfig) -> EvidenceCache:
    """The evidence cache of a run on ``base``: its entries are keyed by the code and the
    shipped data (`batch.cache.code_version`), the detector settings, policies and limits, and
    the digest of the decision weights in use (``learned.model`` may lie outside the package):
    a retrained model never reuses the old model's logits."""
    return EvidenceCache(folder, repr(base.detector), repr(base.policies), repr(base.limits),
                         decision_model(base.detector).digest)


def _first_look(ok_c, ok_p, det) -> FirstLookCalibration:
    """``learned.first_look_ln`` for the chosen decision (`calibration.firstlook`): below the
    first-look peak of every image, clean or positive, both parts, that it flags; from the
    peaks `learned_record` measured in the same pass as the logits."""
    from lishield_guard.detector.decision import rule

    def cols(ok):
        return ([r["first_look"] for r, _, _ in ok], [r["first_look_usable"] for r, _, _ in ok],
                [r["logit"] is not None and bool(rule(r["logit"], det)) for r, _, _ in ok])

    return calibrate_first_look(*cols(ok_c), *cols(ok_p))


def _verdict_blocks(ok_c, ok_p, want, base: AppConfig, grid, pgrid, n_tc: int,
                    target_far: float) -> list:
    """Verdicts of every setting, per profile: (settings, clean_prot, pos_prot, clean_hits,
    clean_cands, time_ms); columns hold the tuning images first, so tuning slices are views."""
    blocks = []
    if learned.NAME in want:  # the learned score: one logit per image, thresholds swept
        lc = np.array([-np.inf if r["logit"] is None else r["logit"] for r, _, _ in ok_c])
        lp = np.array([-np.inf if r["logit"] is None else r["logit"] for r, _, _ in ok_p])
        s, pc, pp = learned_scores(lc, lp, learned_thresholds(
            lc[:n_tc], LearnedGrid(), target_far=target_far))
        l_ms = float(np.mean([r["learned_ms"] for r, _, _ in ok_c + ok_p]))
        blocks.append((s, pc, pp, pc, np.ones(pc.shape[1]), np.full(len(s), l_ms)))
    ev_ms = (np.mean([r["evidence_ms"] for r, _, _ in ok_c + ok_p])
             if want & PATTERN_PROFILES else 0.0)
    if cascade.NAME in want:
        s, pc, hc, cc = cascade_scores(np.stack([r["table"] for r, _, _ in ok_c]), grid,
                                       [r["folds"] for r, _, _ in ok_c], base.detector,
                                       sweeps=[r["sweeps"] for r, _, _ in ok_c])
        _, pp, _, _ = cascade_scores(np.stack([r["table"] for r, _, _ in ok_p]), grid,
                                     [r["folds"] for r, _, _ in ok_p], base.detector,
                                     sweeps=[r["sweeps"] for r, _, _ in ok_p])
        match_ms = np.mean([r["match_ms"] for r, _, _ in ok_c + ok_p], axis=0)
        n_gate = len(s) // len(grid.match_combos())
        blocks.append((s, pc, pp, hc, np.broadcast_to(cc, pc.shape),
                       ev_ms + np.repeat(match_ms, n_gate)))
    if paper.NAME in want:
        s, pc, hc, cc = paper_scores([r["paper_peaks"] for r, _, _ in ok_c], base, pgrid)
        _, pp, _, _ = paper_scores([r["paper_peaks"] for r, _, _ in ok_p], base, pgrid)
        dec_ms = np.mean([r["paper_decode_ms"] for r, _, _ in ok_c + ok_p])
        pk_ms = {k: np.mean([r["paper_ms"][k] for r, _, _ in ok_c + ok_p]) for k in
                 ok_c[0][0]["paper_ms"]}
        blocks.append((s, pc, pp, hc, cc, np.array([dec_ms + pk_ms[
            (int(st.as_dict["paper.n_b"]), int(st.as_dict["paper.max_peaks"]))] for st in s])))
    return blocks


def _select_and_certify(blocks: list, n_tc: int, n_tp: int, pos_labels: list,
                        target_far: float):
    """Selection on the tuning part only; then the one chosen setting, once, on the held-out
    part. Returns (tuning summaries, best, tune_met, cert summary, its clean verdict row)."""
    tuning = []
    for s, pc, pp, hc, cc, tm in blocks:
        tuning += summarise(s, pc[:, :n_tc], pp[:, :n_tp], clean_hits=hc[:, :n_tc],
                            clean_cands=cc[..., :n_tc] if np.ndim(cc) == 2 else cc[:n_tc],
                            time_ms=tm, pos_groups=pos_labels[:n_tp])
    best, tune_met = select_setting(tuning, target_far)
    bi = next(i for i, x in enumerate(tuning) if x is best)
    offset = 0
    for s, pc, pp, hc, cc, tm in blocks:
        if bi < offset + len(s):
            j = bi - offset
            cert = summarise([s[j]], pc[j:j + 1, n_tc:], pp[j:j + 1, n_tp:],
                             clean_hits=hc[j:j + 1, n_tc:],
                             clean_cands=np.asarray(cc[j:j + 1, n_tc:] if np.ndim(cc) == 2
                                                    else cc[n_tc:]),
                             time_ms=tm[j:j + 1], pos_groups=pos_labels[n_tp:])[0]
            return tuning, best, tune_met, cert, pc[j]
        offset += len(s)
    raise AssertionError("the chosen setting is in no block")


def _false_alarms(ok_c, clean_row) -> tuple[dict, dict]:
    """False alarms of the chosen setting, by clean subset and part; and their files."""
    fa_by: dict[str, dict[str, list[int]]] = {}
    fa_files: dict[str, list[str]] = {"tune": [], "cert": []}
    for j, (r, m, pt) in enumerate(ok_c):
        kind = m.get("kind") or Path(r["path"]).parent.name
        cell = fa_by.setdefault(kind, {"tune": [0, 0], "cert": [0, 0]})[pt]
        cell[1] += 1
        if clean_row[j]:
            cell[0] += 1
            fa_files[pt].append(r["path"])
    return fa_by, fa_files


def _null_model(ok_c, n_tc: int, chosen_det, state: dict, jobs: int, progress: bool):
    """The null model of the chosen cascade setting on a sample of clean tuning images."""
    idx = np.random.default_rng(0).permutation(n_tc)[:NULL_MODEL_SAMPLE]
    nres = _measure(_null_work, [(ok_c[i][0]["path"], chosen_det) for i in idx], state, jobs,
                    "null model", progress)
    nres = [x for x in nres if x and "error" not in x]
    if not nres:
        return None
    return {"n_images": len(nres),
            "far_measured_q": float(np.mean([x["measured"]["far"] for x in nres])),
            "far_noise_q": float(np.mean([x["noise"]["far"] for x in nres])),
            "p_cand_measured_q": float(np.mean([x["measured"]["p_candidate"] for x in nres])),
            "p_cand_noise_q": float(np.mean([x["noise"]["p_candidate"] for x in nres]))}


def _split_info(pt: _Parts, ok_c, ok_p, n_tc: int, n_tp: int, certify, fraction: float,
                seed: int) -> dict:
    """The split as the report states it: images and source groups per part."""
    def n_groups(gs, keep) -> int:
        return len({g for g, k in zip(gs, keep, strict=True) if k})

    ok_paths = {r["path"] for r, _, _ in ok_c + ok_p}
    return {
        "mode": "certify" if certify else "split", "seed": seed,
        "fraction": fraction, "certify_dir": str(certify) if certify else None,
        "clean": [n_tc, len(ok_c) - n_tc], "positives": [n_tp, len(ok_p) - n_tp],
        "clean_groups": [n_groups(pt.groups_tc, [str(p) in ok_paths for p, _, _ in pt.tune_c]),
                         n_groups(pt.groups_cc, [str(p) in ok_paths for p, _, _ in pt.cert_c])],
        "positive_groups": [
            n_groups([g for g, m in zip(pt.pgroups, pt.pmask, strict=True) if not m],
                     [str(p) in ok_paths for p, _, _ in pt.tune_p]),
            n_groups([g for g, m in zip(pt.pgroups, pt.pmask, strict=True) if m],
                     [str(p) in ok_paths for p, _, _ in pt.cert_p])]}
