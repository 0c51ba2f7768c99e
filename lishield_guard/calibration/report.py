"""The calibration report: the config header, the console lines, summary.md and the figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

from lishield_guard.calibration.bounds import claim
from lishield_guard.calibration.evidence import PROFILES
from lishield_guard.calibration.split import stratum_key
from lishield_guard.profiles import cascade, paper

__all__ = ["config_header", "console_report", "plan_text", "split_line", "write_report"]


def plan_text(items, cert_paths: set[str], groups_t: int, groups_c: int, n_tp: int, n_cp: int,
          certify, fraction: float, seed: int, target_far: float) -> str:
    """--dry-run's text: images per stratum and part, and what the certification part can show
    if it holds no false alarm."""
    counts: dict[str, list[int]] = {}
    for p, m, origin in items:
        counts.setdefault(stratum_key(m, origin), [0, 0])[str(p) in cert_paths] += 1
    n_t = sum(v[0] for v in counts.values())
    n_c = sum(v[1] for v in counts.values())
    split = {"mode": "certify" if certify else "split", "seed": seed, "fraction": fraction,
             "certify_dir": str(certify) if certify else None, "clean": [n_t, n_c],
             "clean_groups": [groups_t, groups_c], "positives": [n_tp, n_cp]}
    width = max(len(k) for k in counts)
    lines = [split_line(split), f"{'clean stratum'.ljust(width)}  tuning  certification"]
    lines += [f"{k.ljust(width)}  {v[0]:>6}  {v[1]:>13}" for k, v in sorted(counts.items())]
    best = claim(0, n_c, target_far)
    lines.append(f"with no false alarm the certification part shows FAR <= {best.far_upper:.3g}: "
                 + (f"enough for the target {target_far:g}" if best.met else
                    f"NOT enough for the target {target_far:g} (needs >= "
                    f"{best.images_needed} clean certification images)"))
    return "\n".join(lines)


def _fmt_part(p: dict) -> tuple[str, str, str]:
    lo, hi = p["detection_ci"]
    return (f"{p['false_alarms']}/{p['n_clean']}", f"{p['far_upper']:.3g}",
            f"{p['detected']}/{p['n_pos']} = {p['detection']:.3f} [{lo:.3f}, {hi:.3f}]")


def split_line(split: dict) -> str:
    how = (f"certification on the independent folder {split['certify_dir']}"
           if split["mode"] == "certify" else
           f"seed {split['seed']}, certification fraction {split['fraction']:g}")
    (tc, cc), (tg, cg) = split["clean"], split["clean_groups"]
    (tp, cp) = split["positives"]
    return (f"split ({how}): clean {tc} tuning / {cc} certification "
            f"({tg} / {cg} source groups); positives {tp} / {cp}")


def config_header(*, date, clean, positives, base, best, split, parts, target_far, met, quick,
            cert_claim) -> str:
    t, c = parts["tuning"], parts["certification"]
    lines = [
        "lishield-guard calibrated config (written by `lishield-guard calibrate`).",
        f"date: {date}",
        *(["QUICK MODE: built-in demonstration sets, not a calibration for real uploads."]
          if quick else []),
        f"clean: {', '.join(str(d) for d in clean)}; positives: {positives}",
        split_line(split),
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


def console_report(info: dict, best, n_settings: int, summary_path: Path) -> str:
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
        split_line(info["split"]), *table,
        f"chosen (on the tuning part): {best.setting.label()}",
        f"target FAR {tf:g}: {'met' if info['met'] else 'NOT MET'} on the certification part "
        f"({c['reason']})",
        f"the tuning part alone would call it {'met' if info['tune_met'] else 'not met'}",
        f"showing FAR <= {tf:g} needs >= {need[0]} certification images with no false alarm "
        f"({need[1]} with one, {need[2]} with two)",
        *([info["first_look"]["line"]] if info.get("first_look") else []),
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


def write_report(report: Path, summaries, best, cert, info: dict) -> dict:
    """summary.md, settings.jsonl and PNG plots into ``report``; returns their paths.

    ``summaries`` are every setting's figures on the tuning part (what selection saw); ``cert``
    is the chosen setting's on the certification part.
    """
    paths = {}
    with open(report / "settings.jsonl", "w", encoding="utf-8") as fh:
        for s in summaries:
            fh.write(json.dumps(s.to_dict()) + "\n")
    paths["settings"] = report / "settings.jsonl"
    paths |= _figures(report, summaries, best, cert, info)
    (report / "summary.md").write_text(_summary_md(summaries, best, cert, info, paths),
                                       encoding="utf-8")
    paths["summary"] = report / "summary.md"
    return paths


def _figures(report: Path, summaries, best, cert, info: dict) -> dict:
    """heatmaps.png, roc.png and detection_by_kind.png (those that have data); their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    # heatmaps (paper Figs. 21-22 analogues), tuning part
    fixed_d = best.setting.as_dict if best.setting.profile == cascade.NAME else next(
        (s.setting.as_dict for s in summaries if s.setting.profile == cascade.NAME), {})
    paper_best = max((s for s in summaries if s.setting.profile == paper.NAME),
                     key=lambda s: (s.far_upper <= info["target_far"], s.detection), default=None)
    panels = []
    if fixed_d:
        tol, fp = "tones.rel_tol", "tones.peak_false_prob"
        panels += [(cascade.NAME, fixed_d, tol, fp, "false_match_fraction",
                    "cascade: false candidate matches (>= min_tones) on clean"),
                   (cascade.NAME, fixed_d, tol, fp, "far_upper", "cascade: FAR 95% upper bound"),
                   (cascade.NAME, fixed_d, tol, fp, "detection", "cascade: detection rate"),
                   (cascade.NAME, fixed_d, "tones.min_purity", "tones.min_occupancy",
                    "detection", "cascade: detection rate")]
    if paper_best is not None:
        pd_ = paper_best.setting.as_dict
        tol = "paper.ratio_tol"
        panels += [(paper.NAME, pd_, tol, "paper.n_b", "false_match_fraction",
                    "paper: fraction of false ratio matches (Fig. 21)"),
                   (paper.NAME, pd_, tol, "paper.gamma", "far", "paper: clean FAR (Fig. 22)"),
                   (paper.NAME, pd_, tol, "paper.gamma", "detection", "paper: detection"),
                   (paper.NAME, pd_, tol, "paper.max_peaks", "detection", "paper: detection")]
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
    for prof, marker in zip(PROFILES, "o^s", strict=True):
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
    return paths


def _summary_md(summaries, best, cert, info: dict, paths: dict) -> str:
    """The text of summary.md."""
    sp = info["split"]
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
        f"- {split_line(sp)}",
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
    if info.get("first_look"):
        fl = info["first_look"]
        lines += ["", "## First look (docs/first_look.md)", "", fl["line"] + ".", "",
                  f"Margin {fl['margin_ln']:.4f} ln below the smallest first-look peak among "
                  f"the {fl['n_flagged']} images the chosen decision flags (clean and positives,"
                  f" both parts); {fl['n_flagged_cleared']} of them cleared."]
    nm = info.get("null_model")
    lines += ["", "## Null model vs measurement (default profile, chosen setting, tuning part)",
              ""]
    if nm:
        lines += [
            "Chance matches of random significant peaks, uniform in log frequency (derivation "
            "in `lishield_guard/calibration/__init__.py`), averaged over "
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
    for prof in PROFILES:
        cand = [s for s in summaries if s.setting.profile == prof]
        if cand:
            top = max(cand, key=lambda s: (s.far_upper <= tf, s.detection))
            lines.append(f"\nBest {prof}-profile setting on the tuning part: "
                         f"`{top.setting.label()}`: FA {top.false_alarms}/{top.n_clean}, bound "
                         f"{top.far_upper:.3g}, detection {top.detection:.3f}.")
    lines += ["", "## Plots", ""]
    lines += [f"- `{p.name}`" for k, p in paths.items() if k != "settings"]
    lines += [f"\n![{k}]({p.name})" for k, p in paths.items() if str(p).endswith(".png")]
    return "\n".join(lines) + "\n"
