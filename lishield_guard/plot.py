"""A figure a person can check: what decided one verdict, drawn from its evidence.

`verdict_figure` redraws, for the decision that was taken, the rows the deciding stage fitted
(linear light, high-passed, quiet-weighted column sub-blocks) with the fitted barcode template
over them and the best steady square wave (the look-alike) beside it; the decision's numbers
against their thresholds; and the rows' spectrum in Hz at the fitted row rate with the spec's
tones labelled. The title states the verdict in words.

Everything is rebuilt from ``Verdict.evidence`` plus the image, and every evidence key is read
defensively: a key that is missing (another profile, an older or newer detector) leaves its
part of the figure out instead of failing. matplotlib is imported lazily and only through its
object-oriented API (``Figure`` + Agg canvas, no pyplot), so the service can draw in worker
threads.
"""

from __future__ import annotations

import dataclasses
import io
import math
import re
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["figure_caption", "plot_verdict", "verdict_figure", "verdict_png", "verdict_title"]

CHANNEL_COLOURS = {"W": "tab:purple", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}
FIGSIZE_IN = (11.0, 9.5)
DPI = 100


def _get(d: Any, *keys: str, default: Any = None) -> Any:
    """``d[k0][k1]...`` for nested dicts, ``default`` as soon as one level is missing."""
    for k in keys:
        if not isinstance(d, dict) or d.get(k) is None:
            return default
        d = d[k]
    return d


def _status(verdict) -> str:
    status = getattr(verdict, "status", None)
    if status:
        return str(status)
    return "protected" if verdict.protected else "clean"


def _stage(best: dict) -> tuple[str, dict | None]:
    """(name of the stage whose fit is drawn, its evidence dict)."""
    fit = _get(best, "sweep", "fit")
    if isinstance(fit, dict) and fit.get("period_rows"):
        return "exact capture-model fit", fit
    sweep = _get(best, "sweep")
    if isinstance(sweep, dict) and sweep.get("period_rows"):
        return "period-sweep grid fit", sweep
    fold = _get(best, "fold")
    if isinstance(fold, dict) and fold.get("period_rows"):
        return "pattern folding", fold
    if _get(best, "n_matched", default=0):
        return "tone tracks", None
    return "no fit", None


def verdict_title(verdict) -> str:
    """The verdict in words, e.g. ``"PROTECTED: policy 'no-distribution' (table1-seq1)"``."""
    status = _status(verdict)
    ev = verdict.evidence or {}
    spec = _get(ev, "best", "spec") or _get(ev, "best_spec") or _get(ev, "spec_fit", "spec")
    if status == "protected":
        return (f"PROTECTED: carries a barcode of policy {verdict.policy!r}"
                + (f" ({spec})" if spec else ""))
    if status == "undetermined":
        return "UNDETERMINED: the detector could not look at this image"
    return "CLEAN: no policy barcode found"


def figure_caption(verdict) -> str:
    """What `verdict_figure` shows for this verdict, in words: the caption follows the stage
    that decided (a pattern fit, the tone tracks, the first stage) and the status.

    Examples
    --------
    >>> from lishield_guard.verdict import Verdict
    >>> figure_caption(Verdict(False, None, 0, 2, undetermined="blank")).split(":")[0]
    'Left'
    """
    status = _status(verdict)
    if "video" in (verdict.evidence or {}):
        from lishield_guard.video.figure import video_caption

        return video_caption(verdict)
    if status == "undetermined":
        return ("Left: the image as the detector decoded it. Right: why it could not look at "
                "it; the image is not clean, and nothing was fitted.")
    ev = verdict.evidence or {}
    if ev.get("stage") == "learned":
        from lishield_guard.figure_learned import learned_caption

        return learned_caption(verdict)
    best = ev.get("best") if isinstance(ev.get("best"), dict) else {}
    stage, info = _stage(best)
    numbers = "Middle: the reason and the decision's numbers against their thresholds."
    if verdict.profile == "paper":
        return ("Top: the rows of the image, high-passed (Algorithm 1 fits no template). "
                f"{numbers} Bottom: their spectrum, with the peak frequencies it matched.")
    if info is not None:  # a pattern stage fitted a template
        lead = ("the rows the " + stage + " fitted" if status == "protected"
                else "the closest candidate's rows and its rejected " + stage)
        return (f"Top: {lead}, with the fitted barcode template and the best steady square "
                f"wave (the look-alike it had to beat). {numbers} Bottom: the rows' spectrum, "
                f"with the barcode's tones.")
    if stage == "tone tracks":
        return ("Top: the analysed rows (tone tracks decide on their spectrum; no template was "
                f"fitted). {numbers} Bottom: the rows' spectrum, with the barcode's tones; "
                "solid lines mark the tones the tracks matched.")
    first = str(ev.get("stage") or best.get("stage") or "") == "first stage" or str(
        ev.get("reason", "")).startswith("first stage")
    why = ("the first stage cleared it (no column-coherent stripes), so nothing was fitted"
           if first else "no candidate came close enough to be fitted")
    return (f"Top: the analysed rows; {why}. {numbers} Bottom: the rows' spectrum, with the "
            "nearest policy's tones for reference.")


def _highpass(n_rows: int, sigma_rows: float):
    """x minus its Gaussian trend of ``sigma_rows`` (mirror-extended), as the fit does."""
    from lishield_guard.detector.numerics import highpass_gain, mirror_rfft

    gain = highpass_gain(n_rows, sigma_rows)

    def hp(x: np.ndarray) -> np.ndarray:
        out = np.fft.irfft(mirror_rfft(x) * gain, n=2 * n_rows, axis=-1)[..., :n_rows]
        return out - out.mean(axis=-1, keepdims=True)

    hp.sigma_rows = sigma_rows  # type: ignore[attr-defined]
    return hp


def _spec_named(config, name: str | None):
    for p in getattr(config, "policies", ()):
        for s in p.specs:
            if s.name == name:
                return s
    return None


def _emitter_spec(spec, *infos: dict | None):
    """The spec as the fit saw it: slot order and phase mode from the evidence when given
    (keys ``slot_order`` / ``phase_mode``, or an ``emitter`` label like "order 0-2-1, restart"),
    looked up in each of ``infos`` in turn."""
    changes: dict[str, Any] = {}
    for info in infos:
        if not isinstance(info, dict):
            continue
        label = info.get("emitter")
        if isinstance(label, str):
            m = re.search(r"order\s+(\d+(?:-\d+)*)", label)
            if m and "order" not in changes:
                changes["order"] = tuple(int(i) for i in m.group(1).split("-"))
            m = re.search(r"\b(restart|continuous)\b", label)
            if m and "phase" not in changes:
                changes["phase"] = m.group(1)
        order = info.get("slot_order")
        if isinstance(order, list | tuple) and order and "order" not in changes:
            changes["order"] = tuple(int(i) for i in order)
        phase = info.get("phase_mode")
        if isinstance(phase, str) and "phase" not in changes:
            changes["phase"] = phase
    for key, value in changes.items():  # one at a time: a field this spec lacks is skipped
        try:
            spec = dataclasses.replace(spec, **{key: value})
        except Exception:  # noqa: BLE001 - a variant this spec cannot take is drawn as specified
            continue
    return spec


def _plane_rows(source, verdict, config, axis: int, channel: str) -> tuple[np.ndarray, float]:
    """Per-sub-block log contrast (n_blocks, n_rows) of the plane a fit was made on, computed
    as the detector does, and the decoded image's row scale."""
    from lishield_guard import detect as _detect
    from lishield_guard.detector.pipeline import decode_for

    decoded = decode_for(source, config)
    plane = decoded.luma
    if channel in ("R", "G", "B") and decoded.is_color:
        plane = decoded.colour_planes()["RGB".index(channel)]
    analyse = getattr(_detect, "_analyse", None)
    if analyse is not None:
        try:
            pa = analyse(plane, axis, config, decoded.row_scale)
            blocks = pa.fit_blocks
            if blocks is not None:
                return np.asarray(blocks, dtype=np.float64), decoded.row_scale
        except (TypeError, ValueError, AttributeError):
            pass
    from lishield_guard.detector.profiles import block_row_profiles, detrend_profiles

    prof = block_row_profiles(plane, n_col_blocks=config.detector.profiles.n_col_blocks,
                              axis=axis)
    prof = np.log(np.maximum(np.asarray(prof, dtype=np.float64), 1e-3))
    contrast, _ = detrend_profiles(prof, sigma_rows=prof.shape[1] / 6.0)
    return contrast, decoded.row_scale


def _lookalike(y: np.ndarray, hp, fit: dict) -> tuple[np.ndarray, dict] | None:
    """Rows of the best steady square wave for high-passed rows ``y`` and its parameters
    (frequency in cycles per row, duty, phase and exposure in cycles, rho), from the evidence
    when it carries them, else searched the way `detector.numerics.lookalike_rho` searches."""
    from lishield_guard.detector import numerics as fit_mod

    n = y.size
    rows = np.arange(n, dtype=np.float64)
    yy = float(y @ y)
    if n < 8 or not yy > 0:
        return None

    def corr(params) -> float:
        f, d, ph, e = params
        t = hp(fit_mod.square_rows(f * rows + ph, d, e))
        tt = float(t @ t)
        return float(t @ y) / math.sqrt(tt * yy) if tt > 0 else 0.0

    given = fit.get("lookalike") if isinstance(fit.get("lookalike"), dict) else None
    if given:
        f = given.get("freq_cpr", given.get("frequency_cpr"))
        if f:
            th = (float(f), float(given.get("duty", 0.5)),
                  float(given.get("phase_cycles", given.get("phase", 0.0))),
                  float(given.get("exposure_cycles", given.get("exposure", 0.0))))
            return (hp(fit_mod.square_rows(th[0] * rows + th[2], th[1], th[3])),
                    {"freq_cpr": th[0], "duty": th[1], "rho": corr(th)})
    square_start = getattr(fit_mod, "_square_start", None)
    nelder_mead = getattr(fit_mod, "_nelder_mead", None)
    if square_start is None or nelder_mead is None:
        return None
    cands = fit_mod.square_candidates(y)
    if not cands:
        return None
    try:
        starts = sorted((square_start(y, yy, f0, getattr(hp, "gain_at", None)) for f0 in cands),
                        key=lambda s: -s[0])
    except (TypeError, ValueError):
        return None

    def loss(th):
        f, d, _, e = th
        if not (f > 0 and 0.02 <= d <= 0.98 and 0.0 <= e <= 3.0):
            return 1.0
        return -corr(th)

    best = None
    for _, x0 in starts[:4]:
        val, th = nelder_mead(loss, np.asarray(x0, dtype=np.float64),
                              np.array([0.01 * x0[0], 0.05, 0.05, 0.05]))
        if best is None or val < best[0]:
            best = (val, th)
    f, d, ph, e = best[1]
    return (hp(fit_mod.square_rows(f * rows + ph, d, e)),
            {"freq_cpr": float(f), "duty": float(d), "rho": -best[0]})


def _scaled(template: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``template`` times its least-squares amplitude on ``y``."""
    tt = float(template @ template)
    return template * (float(template @ y) / tt) if tt > 0 else template


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


def _num(value, fmt: str = ".3f") -> str:
    """A number as printed in the figure (None or a non-number as given)."""
    return format(value, fmt) if isinstance(value, int | float) else str(value)


def _ok(value, need) -> str:
    try:
        return "[pass]" if float(value) >= float(need) else "[FAIL]"
    except (TypeError, ValueError):
        return "[ ?  ]"


def _threshold_lines(stage: str, info: dict | None, det, verdict) -> list[str]:
    """The decision's numbers next to the thresholds they were held against."""
    lines: list[str] = []
    values = det.values()  # dotted names; a stage that is off has none of its fields
    g = lambda name, default=None: values.get(name, default)  # noqa: E731
    if info is None:
        best = _get(verdict.evidence, "best") or {}
        if best:
            lines.append(f"tones matched {best.get('n_matched', 0)}/{best.get('required', '?')}"
                         f"  purity {best.get('purity')}  switches {best.get('switches')}")
        return lines
    rho, alt = info.get("rho"), info.get("rho_lookalike")
    n_periods = info.get("n_periods")
    if stage == "exact capture-model fit":
        periodic = (n_periods is not None and n_periods >= 2.0
                    and g("fit.min_gain_periodic") is not None)
        leak = info.get("chroma_leak")
        rgb = leak is not None and g("fit.max_leak_rgb") is not None and \
            leak <= g("fit.max_leak_rgb")
        need_rho, need_gain = g("fit.min_rho"), g("fit.min_gain")
        path = "general"
        if rgb:
            need_rho = min(need_rho, g("fit.min_rho_rgb", need_rho))
            need_gain = min(need_gain, g("fit.min_gain_rgb", need_gain))
            path = "colour-verified"
        if periodic:
            need_rho = min(need_rho, g("fit.min_rho_periodic", need_rho))
            need_gain = min(need_gain, g("fit.min_gain_periodic", need_gain))
            path += ", >= 2 periods"
        lines.append(f"{_ok(rho, need_rho)} correlation rho {rho:.3f}   (needs >= {need_rho:g};"
                     f" {path} path)" if rho is not None and need_rho is not None
                     else f"rho {_num(rho)}")
        gain = info.get("gain")
        if gain is not None and need_gain is not None:
            lines.append(f"{_ok(gain, need_gain)} gain over the look-alike {gain:.2f}   (needs >= "
                         f"{need_gain:g}); look-alike rho {_num(alt)}")
        t = info.get("coherence_t")
        need_t = g("sweep.min_coherence")
        if t is not None and need_t is not None:
            lines.append(f"{_ok(t, need_t)} same amplitude in every column block: t = {t:.1f}"
                         f"   (needs >= {need_t:g})")
        max_leak = g("fit.max_leak_rgb")
        if leak is not None:
            lines.append(f"chroma leak {leak:.2f}   (colour path " + (
                "off)" if max_leak is None else f"needs <= {max_leak:g})"))
    elif stage == "period-sweep grid fit":
        lines.append(f"grid rho {_num(rho)}  (needs >= {g('sweep.min_rho')}); look-alike rho "
                     f"{_num(alt)} (margin needs >= {g('sweep.min_margin')}); coherence t "
                     f"{_num(info.get('coherence_t'), '.1f')} (needs >= "
                     f"{g('sweep.min_coherence')})")
    elif stage == "pattern folding":
        lines.append(f"folded rho {_num(rho)}  (needs >= {g('fold.min_rho')}); look-alike rho "
                     f"{_num(alt)}; fold SNR {_num(info.get('fold_snr'), '.1f')} (needs >= "
                     f"{g('fold.min_snr')})")
    extras = [f"{k} {info[k]}" for k in ("phase_mode", "slot_order", "switching_hz")
              if info.get(k) is not None]
    geom = [f"period {info['period_rows']:.1f} rows" if info.get("period_rows") else None,
            f"{n_periods:.2f} periods in the frame" if n_periods is not None else None,
            f"c_1 {info['cycles_per_slot_f1']:.2f} cycles/slot"
            if info.get("cycles_per_slot_f1") is not None else None,
            f"exposure {info['exposure_slots']:.2f} slot"
            if isinstance(info.get("exposure_slots"), int | float) else None]
    lines.append(", ".join([x for x in geom if x] + extras))
    return lines


def _label_levels(xs: list[float], span: float, min_gap_frac: float = 0.06) -> list[int]:
    """Stagger label heights so that labels closer than ``min_gap_frac`` of the axis span never
    share a height (greedy: the lowest level whose last label is far enough)."""
    last: list[float] = []
    levels = []
    for x in xs:
        for i, prev in enumerate(last):
            if x - prev >= min_gap_frac * span:
                last[i] = x
                levels.append(i)
                break
        else:
            last.append(x)
            levels.append(len(last) - 1)
    return levels


def verdict_figure(source, verdict, config):
    """Build the figure of one verdict.

    Parameters
    ----------
    source : bytes, str, Path or ndarray
        The image the verdict was computed on.
    verdict : Verdict
        Its verdict; ``evidence`` says which stage decided and with which parameters.
    config : AppConfig
        The config of the detection (policies, decode limits, thresholds).

    Returns
    -------
    matplotlib.figure.Figure
        Three panels: fitted rows with template and look-alike; the decision's numbers
        against their thresholds; the spectrum with the spec's tones labelled.
    """
    from matplotlib.figure import Figure

    from lishield_guard.video import is_video

    if is_video(source):  # a clip: the deciding frame and the per-frame scores
        from lishield_guard.video.figure import video_figure

        return video_figure(source, verdict, config)
    if _status(verdict) == "undetermined":
        return _undetermined_figure(source, verdict, config)
    if (verdict.evidence or {}).get("stage") == "learned":  # the default profile
        from lishield_guard.figure_learned import learned_figure

        return learned_figure(source, verdict, config)
    ev = verdict.evidence or {}
    best = ev.get("best") if isinstance(ev.get("best"), dict) else {}
    det = config.detector
    stage, info = _stage(best)
    if verdict.profile == "paper":
        stage, info = "paper Algorithm 1", None
    axis = 1 if ev.get("axis") == "columns" else 0
    channel = (info or {}).get("channel") or "W"
    blocks, row_scale = _plane_rows(source, verdict, config, axis,
                                    "L" if channel == "W" else channel)
    from lishield_guard.detector.fit import pattern_knots, render_rows
    from lishield_guard.detector.numerics import HIGHPASS_CYCLES, linear_common

    x, _, _ = linear_common(blocks)
    n = x.size
    period = float((info or {}).get("period_rows") or 0.0)
    sigma = (period if period > 0 else n / 4.0) / (2 * math.pi * HIGHPASS_CYCLES)
    hp = _highpass(n, sigma)
    y = hp(x)
    rows = np.arange(n, dtype=np.float64)

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    gs = fig.add_gridspec(3, 1, height_ratios=[3.0, 1.25, 2.4])
    ax_rows, ax_text, ax_spec = (fig.add_subplot(gs[i]) for i in range(3))
    fig.suptitle(verdict_title(verdict), fontsize=14, fontweight="bold",
                 color={"protected": "darkred", "clean": "darkgreen"}.get(_status(verdict),
                                                                          "darkorange"))

    # --- panel 1: the rows that were fitted, the fitted template, the look-alike
    ax_rows.plot(rows, y, color="0.25", lw=0.8, label="rows (linear light, high-passed)")
    spec = _spec_named(config, (info or {}).get("spec") or best.get("spec"))
    sigma_cpr_per_hz = None
    if spec is not None and info and period > 0 and info.get("cycles_per_slot_f1"):
        c1 = float(info["cycles_per_slot_f1"])
        sigma_cpr_per_hz = c1 * spec.n_tones / (period * spec.f1_hz)
        if info.get("phase_slots") is not None:  # grid and fold fits carry no phase
            try:
                espec = _emitter_spec(spec, info, best.get("sweep"), best)
                knots = pattern_knots(espec, channel if channel in dict(espec.channels)
                                      else espec.channel_names[0], c1)
                exp_slots = info.get("exposure_slots")
                exp_slots = float(exp_slots) if isinstance(exp_slots, int | float) else 0.0
                u = spec.n_tones * rows / period + float(info.get("phase_slots") or 0.0)
                tpl = hp(render_rows(*knots, u, exp_slots))
                order = "-".join(str(i) for i in espec.slot_order())
                ax_rows.plot(rows, _scaled(tpl, y), color="tab:red", lw=1.3,
                             label=f"fitted {spec.name} template ({channel}, slot order {order}, "
                                   f"{getattr(espec, 'phase', 'restart')} phase): rho "
                                   f"{_corr(tpl, y):.3f} here, {_num(info.get('rho'))} reported")
            except (ValueError, TypeError, KeyError, IndexError):
                pass
        try:
            alt = _lookalike(y, hp, info)
        except (ValueError, TypeError, FloatingPointError):
            alt = None
        if alt is not None:
            alt_rows, p = alt
            ax_rows.plot(rows, _scaled(alt_rows, y), color="tab:blue", lw=1.0, ls="--",
                         label=f"best steady square wave (look-alike): {1 / p['freq_cpr']:.1f} "
                               f"rows/cycle, duty {p['duty']:.2f}, rho {p['rho']:.3f} here, "
                               f"{_num(info.get('rho_lookalike'))} reported")
    line_name = "sensor row" if axis == 0 else "sensor row (stored image columns)"
    if row_scale != 1.0:
        line_name += f", decoded at 1/{row_scale:g}"
    ax_rows.set_xlabel(line_name)
    ax_rows.set_ylabel("relative light (a.u.)")
    ax_rows.set_xlim(0, max(n - 1, 1))  # one row: a unit-wide axis, not a singular one
    lead = "What decided" if _status(verdict) == "protected" else "Closest candidate (rejected)"
    ax_rows.set_title(f"{lead}: {stage}"
                      + (f" of {spec.name} on channel {channel}" if spec is not None and info
                         else ""), loc="left", fontsize=11)
    ax_rows.legend(loc="upper right", fontsize=8, framealpha=0.85)

    # --- panel 2: the reason and the numbers against their thresholds
    ax_text.axis("off")
    reason = ev.get("reason") or getattr(verdict, "undetermined", None) or "(no reason given)"
    text = ["Reason: " + reason]
    text += _threshold_lines(stage, info, det, verdict)
    text.append(f"profile {verdict.profile}, score {verdict.score:.3f}, matches "
                f"{verdict.matches}/{verdict.required}")
    wrapped = "\n".join(textwrap.fill(t, 125, subsequent_indent="    ") for t in text)
    ax_text.text(0.0, 1.0, wrapped, va="top", ha="left", fontsize=8.5, family="monospace",
                 transform=ax_text.transAxes)

    # --- panel 3: spectrum of the fitted rows, tones labelled
    n_fft = 1 << int(math.ceil(math.log2(max(n, 2)))) + 2
    power = np.abs(np.fft.rfft(y * np.hanning(n), n=n_fft)) ** 2
    f_cpr = np.fft.rfftfreq(n_fft)
    db = 10 * np.log10(power / max(float(power.max()), 1e-30) + 1e-12)
    if sigma_cpr_per_hz is None:
        sigma_cpr_per_hz = best.get("sigma_cpr_per_hz") or None
    if sigma_cpr_per_hz is None and verdict.profile == "paper":
        sigma_cpr_per_hz = 1.0 / float(det.paper.nominal_row_rate_hz)
    marks: list[tuple[str, float]] = []
    matched = {(c, float(f)) for c, fs in (best.get("matched_hz") or {}).items() for f in fs}
    if spec is None and best.get("spec"):
        spec = _spec_named(config, best.get("spec"))
    if spec is not None:
        marks = [(c, f) for c, fs in spec.channels for f in fs
                 if channel == "W" or c == channel]
    elif verdict.profile == "paper":
        marks = [("W", f) for f in ev.get("frequencies_hz", [])]
    if sigma_cpr_per_hz:
        f_hz = f_cpr / sigma_cpr_per_hz
        top_hz = max([f for _, f in marks] + [1.0]) * 2.5
        keep = f_hz <= top_hz
        ax_spec.plot(f_hz[keep], db[keep], color="0.2", lw=0.8)
        ax_spec.set_xlim(0, top_hz)
        ax_spec.set_xlabel("frequency (Hz at the fitted row rate "
                           f"{1 / sigma_cpr_per_hz * row_scale:,.0f} rows/s)"
                           if info else "frequency (Hz at the matched tones' scale)"
                           if best.get("sigma_cpr_per_hz") else
                           "frequency (Hz at the nominal row rate)")
        sec = ax_spec.secondary_xaxis("top", functions=(lambda h: h * sigma_cpr_per_hz,
                                                        lambda c: c / sigma_cpr_per_hz))
        sec.set_xlabel("cycles per row", fontsize=8)
        xs = sorted(marks, key=lambda m: m[1])
        levels = _label_levels([f for _, f in xs], top_hz)
        seen: set[tuple[str, bool]] = set()
        for (ch, f), lev in zip(xs, levels, strict=True):
            colour = CHANNEL_COLOURS.get(ch, "tab:orange")
            hit = (ch, float(f)) in matched
            ax_spec.axvline(f, color=colour, ls="-" if hit else "--", lw=1.6 if hit else 1.0,
                            label=None if (ch, hit) in seen else
                            f"{ch} tones of the spec" + (", matched by tone tracks" if hit else ""))
            seen.add((ch, hit))
            ax_spec.annotate(f"{f:g} Hz", (f, 0.97 - 0.09 * lev),
                             xycoords=("data", "axes fraction"),
                             ha="center", va="top", fontsize=8, color=colour,
                             bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none",
                                   "alpha": 0.8})
        if seen:
            ax_spec.legend(loc="lower right", fontsize=8)
    else:
        keep = f_cpr <= 0.5
        ax_spec.plot(f_cpr[keep], db[keep], color="0.2", lw=0.8)
        ax_spec.set_xlim(0, min(0.5, 40.0 / max(period, n / 8.0) if period else 0.1))
        ax_spec.set_xlabel("frequency (cycles per row; no fit gives a row rate)")
    ax_spec.set_ylim(max(float(db.min()), -60.0), 3)
    ax_spec.set_ylabel("power (dB re max)")
    ax_spec.set_title("Spectrum of the " + ("fitted" if info else "analysed") + " rows",
                      loc="left", fontsize=11)
    return fig


def _undetermined_figure(source, verdict, config):
    """The figure of a verdict the detector could not decide: the image as decoded (when it
    decodes) and the reason, instead of empty axes (a 1x1 image, a blank frame)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIGSIZE_IN[0], 5.0), dpi=DPI, layout="constrained")
    ax_img, ax_text = fig.subplots(1, 2, width_ratios=[1.0, 1.6])
    fig.suptitle(verdict_title(verdict), fontsize=14, fontweight="bold", color="darkorange")
    try:
        from lishield_guard.detector.pipeline import decode_for

        luma = decode_for(source, config).luma
        ax_img.imshow(luma, cmap="gray", vmin=0, vmax=255 if luma.dtype == np.uint8 else None,
                      interpolation="nearest", aspect="auto")
        ax_img.set_title(f"the image as analysed: {luma.shape[0]} x {luma.shape[1]} pixels, "
                         f"values {float(luma.min()):g}-{float(luma.max()):g}",
                         loc="left", fontsize=9)
    except Exception as exc:  # noqa: BLE001 - the figure must not fail on what it explains
        ax_img.text(0.5, 0.5, f"not decodable: {exc}", ha="center", va="center", wrap=True)
    ax_img.set_xticks([])
    ax_img.set_yticks([])
    reason = getattr(verdict, "undetermined", None) or (verdict.evidence or {}).get("reason")
    text = ["The detector could not look at this image; it is not clean.",
            "", "Reason: " + str(reason or "(no reason given)")]
    if verdict.skipped:
        text += ["", "Skipped: " + "; ".join(verdict.skipped)]
    ax_text.axis("off")
    ax_text.text(0.0, 1.0, "\n".join(textwrap.fill(t, 70) for t in text), va="top",
                 ha="left", fontsize=10, family="monospace", transform=ax_text.transAxes)
    return fig


def verdict_png(source, verdict, config) -> bytes:
    """`verdict_figure` rendered as PNG bytes (Agg)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = verdict_figure(source, verdict, config)
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def plot_verdict(source, verdict, config, out_png: str | Path) -> Path:
    """Write `verdict_figure` of one verdict to ``out_png``; returns the path.

    Raises
    ------
    OSError
        If the file cannot be written.
    """
    out = Path(out_png)
    out.write_bytes(verdict_png(source, verdict, config))
    return out
