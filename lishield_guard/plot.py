"""A figure a person can check: what decided one verdict, drawn from its typed evidence.

`verdict_figure` draws the figure the verdict's evidence defines (`verdict.Evidence.figure`):
the learned profile's (`figure_learned`), a clip's (`video.figure`), an undetermined
verdict's (`figure_text`), and here the cascade's and the paper profile's. The cascade's
figure draws, for the candidate that decided, the rows the deciding stage fitted (linear
light, high-passed, from the analysed planes the verdict kept) with the fitted barcode
template and the best steady square wave the fit found (the look-alike); the numbers against
the thresholds of each way to pass (`rules.fit_paths`); and the rows' spectrum in Hz at the
fitted row rate with the spec's tones labelled. Nothing is decoded, measured or judged again.
matplotlib is imported lazily and only through its object-oriented API (``Figure`` + Agg
canvas, no pyplot), so the service can draw in worker threads.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from lishield_guard.figure_text import DPI, FIGSIZE_IN, STATUS_COLOURS, text_panel
from lishield_guard.verdict import verdict_title

__all__ = ["cascade_caption", "cascade_figure", "figure_caption", "paper_caption",
           "paper_figure", "plot_verdict", "verdict_figure", "verdict_png", "verdict_title"]

CHANNEL_COLOURS = {"W": "tab:purple", "R": "tab:red", "G": "tab:green", "B": "tab:blue"}


def verdict_figure(source, verdict, config):
    """Build the figure of one verdict (its evidence's ``figure``).

    Parameters
    ----------
    source : bytes, str, Path or ndarray
        The image or clip the verdict was computed on (not read again: the evidence keeps
        what the figure draws; kept for callers).
    verdict : Verdict
        Its verdict, with typed evidence (`lishield_guard.verdict.Evidence`).
    config : AppConfig
        The config of the detection (policies, thresholds).

    Returns
    -------
    matplotlib.figure.Figure

    """
    return verdict.evidence.figure(verdict, config)


def figure_caption(verdict) -> str:
    """What `verdict_figure` shows for this verdict, in words (its evidence's ``caption``:
    it follows the stage that decided and the status).

    Examples
    --------
    >>> from lishield_guard.verdict import undetermined
    >>> figure_caption(undetermined("blank", looked_at="1 x 1 pixels", profile="default",
    ...                             required=1)).split(":")[0]
    'Left'
    """
    return verdict.evidence.caption(verdict)


def _highpass(n_rows: int, sigma_rows: float):
    """x minus its Gaussian trend of ``sigma_rows`` (mirror-extended), as the fit does."""
    from lishield_guard.detector.numerics import highpass_gain, mirror_rfft

    gain = highpass_gain(n_rows, sigma_rows)

    def hp(x: np.ndarray) -> np.ndarray:
        out = np.fft.irfft(mirror_rfft(x) * gain, n=2 * n_rows, axis=-1)[..., :n_rows]
        return out - out.mean(axis=-1, keepdims=True)

    return hp


def _spec_named(config, name: str | None):
    return next((s for p in getattr(config, "policies", ()) for s in p.specs
                 if s.name == name), None)


def _scaled(template: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``template`` times its least-squares amplitude on ``y``."""
    tt = float(template @ template)
    return template * (float(template @ y) / tt) if tt > 0 else template


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


def _ok(passed) -> str:
    return "[pass]" if passed else "[FAIL]"


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


def _deciding_fit(best):
    """(the deciding stage in words, its fit: `ModelFit`, `SweepResult`, `FoldResult` or
    None) of a cascade candidate (`SpecMatch`)."""
    sweep, fold = best.sweep, best.fold
    if sweep is not None and sweep.fit is not None and sweep.fit.period_rows:
        return "exact capture-model fit", sweep.fit
    if sweep is not None and sweep.match.period_rows:
        return "period-sweep grid fit", sweep
    if fold is not None and fold.match.period_rows:
        return "pattern folding", fold
    if best.n_matched:
        return "tone tracks", None
    return "no fit", None


def cascade_caption(ev, status: str) -> str:
    """What `cascade_figure` shows for ``ev`` (`CascadeEvidence`) at ``status``, in words."""
    stage, info = _deciding_fit(ev.best)
    numbers = "Middle: the reason and the decision's numbers against their thresholds."
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
    why = ("the first stage cleared it (no column-coherent stripes), so nothing was fitted"
           if ev.stage == "first stage" else "no candidate came close enough to be fitted")
    return (f"Top: the analysed rows; {why}. {numbers} Bottom: the rows' spectrum, with the "
            "nearest policy's tones for reference.")


def paper_caption() -> str:
    """What `paper_figure` shows, in words."""
    return ("Top: the rows of the image, high-passed (Algorithm 1 fits no template). "
            "Middle: the reason and the decision's numbers against their thresholds. Bottom: "
            "their spectrum, with the peak frequencies it matched.")


def _threshold_lines(stage: str, info, det) -> list[str]:
    """The decision's numbers next to the thresholds of each way to pass (`rules.fit_paths`
    for the exact fit: the rule itself, not a copy of it)."""
    from lishield_guard.detector.rules import fit_paths, fold_passes, grid_passes

    lines: list[str] = []
    if stage == "exact capture-model fit":
        leak = math.inf if info.chroma_leak is None else info.chroma_leak
        alt = "-" if info.rho_lookalike is None else f"{info.rho_lookalike:.3f}"
        if det.fit is not None and det.sweep is not None:
            for path in fit_paths(det):
                if not path.applies(info.n_periods, leak):
                    continue
                lines.append(f"{_ok(info.rho >= path.min_rho and info.gain >= path.min_gain)} "
                             f"{path.name} path: rho {info.rho:.3f} (needs >= "
                             f"{path.min_rho:g}), gain over the look-alike {info.gain:.2f} "
                             f"(needs >= {path.min_gain:g}); look-alike rho {alt}")
            need_t = det.sweep.min_coherence
            lines.append(f"{_ok(info.coherence_t >= need_t)} same amplitude in every column "
                         f"block: t = {info.coherence_t:.1f}   (needs >= {need_t:g})")
        if info.chroma_leak is not None:
            max_leak = None if det.fit is None else det.fit.max_leak_rgb
            lines.append(f"chroma leak {info.chroma_leak:.2f}   (colour path " + (
                "off)" if max_leak is None else f"needs <= {max_leak:g})"))
    elif stage == "period-sweep grid fit" and det.sweep is not None:
        lines.append(f"{_ok(grid_passes(info, det))} grid rho {info.rho:.3f}  (needs >= "
                     f"{det.sweep.min_rho:g}); look-alike rho {info.rho_lookalike:.3f} "
                     f"(margin needs >= {det.sweep.min_margin:g}); coherence t "
                     f"{info.coherence_t:.1f} (needs >= {det.sweep.min_coherence:g})")
    elif stage == "pattern folding" and det.fold is not None:
        lines.append(f"{_ok(fold_passes(info, det))} folded rho {info.rho:.3f}  (needs >= "
                     f"{det.fold.min_rho:g}); look-alike rho {info.rho_lookalike:.3f}; fold "
                     f"SNR {info.fold_snr:.1f} (needs >= {det.fold.min_snr:g})")
    match = getattr(info, "match", info)
    exposure = getattr(match, "exposure_slots", None)
    geom = [f"period {match.period_rows:.1f} rows",
            f"{match.n_periods:.2f} periods in the frame",
            f"c_1 {match.cycles_f1:.2f} cycles/slot",
            None if exposure is None else f"exposure {exposure:.2f} slot"]
    emitter = getattr(info, "emitter", None)
    lines.append(", ".join([g for g in geom if g] + ([f"emitter {emitter}"] if emitter else [])))
    return lines


def _fitted_variant(spec, entry):
    """The emitter variant of ``spec`` a sweep entry fitted (slot order, phase mode), found
    by its label among `emitters.emitter_variants`; ``spec`` itself when none matches."""
    from lishield_guard.detector.emitters import emitter_variants, variant_label

    label = getattr(entry, "emitter", None)
    return next((v for v in emitter_variants(spec) if variant_label(v) == label), spec)


def _rows_panel(ax, y, hp, info, spec, entry, channel: str):
    """The fitted template and the fit's look-alike over the high-passed rows ``y``; the
    spec's scale in cycles per row per Hz (None when no fit gives it)."""
    from lishield_guard.detector.fit import pattern_knots, render_rows
    from lishield_guard.detector.numerics import square_rows

    rows = np.arange(y.size, dtype=np.float64)
    period = float(getattr(getattr(info, "match", info), "period_rows", 0.0) or 0.0)
    c1 = getattr(getattr(info, "match", info), "cycles_f1", None)
    if spec is None or info is None or period <= 0 or not c1:
        return None
    if hasattr(info, "phase_slots"):  # the exact fit: its template and its look-alike
        variant = _fitted_variant(spec, entry)
        knots = pattern_knots(variant, channel if channel in dict(variant.channels)
                              else variant.channel_names[0], c1)
        u = spec.n_tones * rows / period + info.phase_slots
        tpl = hp(render_rows(*knots, u, info.exposure_slots))
        order = "-".join(str(i) for i in variant.slot_order())
        ax.plot(rows, _scaled(tpl, y), color="tab:red", lw=1.3,
                label=f"fitted {spec.name} template ({channel}, slot order {order}, "
                      f"{getattr(variant, 'phase', 'restart')} phase): rho {_corr(tpl, y):.3f} "
                      f"here, {info.rho:.3f} reported")
        if info.lookalike is not None:
            f, d, ph, e = info.lookalike
            alt = hp(square_rows(f * rows + ph, d, e))
            ax.plot(rows, _scaled(alt, y), color="tab:blue", lw=1.0, ls="--",
                    label=f"best steady square wave (look-alike): {1 / f:.1f} rows/cycle, "
                          f"duty {d:.2f}, rho {_corr(alt, y):.3f} here, "
                          f"{info.rho_lookalike:.3f} reported")
    return c1 * spec.n_tones / (period * spec.f1_hz)


def _spectrum_panel(ax, y, sigma, marks, matched: set, xlabel: str, period: float,
                    fitted: bool) -> None:
    """The rows' spectrum (dB re max), in Hz at scale ``sigma`` (cycles per row per Hz) with
    the ``marks`` (channel, Hz) labelled, or in cycles per row when no scale is known."""
    n = y.size
    n_fft = 1 << int(math.ceil(math.log2(max(n, 2)))) + 2
    power = np.abs(np.fft.rfft(y * np.hanning(n), n=n_fft)) ** 2
    f_cpr = np.fft.rfftfreq(n_fft)
    db = 10 * np.log10(power / max(float(power.max()), 1e-30) + 1e-12)
    if sigma:
        f_hz = f_cpr / sigma
        top_hz = max([f for _, f in marks] + [1.0]) * 2.5
        keep = f_hz <= top_hz
        ax.plot(f_hz[keep], db[keep], color="0.2", lw=0.8)
        ax.set_xlim(0, top_hz)
        ax.set_xlabel(xlabel)
        sec = ax.secondary_xaxis("top", functions=(lambda h: h * sigma, lambda c: c / sigma))
        sec.set_xlabel("cycles per row", fontsize=8)
        xs = sorted(marks, key=lambda m: m[1])
        levels = _label_levels([f for _, f in xs], top_hz)
        seen: set[tuple[str, bool]] = set()
        for (ch, f), lev in zip(xs, levels, strict=True):
            colour = CHANNEL_COLOURS.get(ch, "tab:orange")
            hit = (ch, float(f)) in matched
            ax.axvline(f, color=colour, ls="-" if hit else "--", lw=1.6 if hit else 1.0,
                       label=None if (ch, hit) in seen else
                       f"{ch} tones of the spec" + (", matched by tone tracks" if hit else ""))
            seen.add((ch, hit))
            ax.annotate(f"{f:g} Hz", (f, 0.97 - 0.09 * lev), xycoords=("data", "axes fraction"),
                        ha="center", va="top", fontsize=8, color=colour,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none",
                              "alpha": 0.8})
        if seen:
            ax.legend(loc="lower right", fontsize=8)
    else:
        keep = f_cpr <= 0.5
        ax.plot(f_cpr[keep], db[keep], color="0.2", lw=0.8)
        ax.set_xlim(0, min(0.5, 40.0 / max(period, n / 8.0) if period else 0.1))
        ax.set_xlabel("frequency (cycles per row; no fit gives a row rate)")
    ax.set_ylim(max(float(db.min()), -60.0), 3)
    ax.set_ylabel("power (dB re max)")
    ax.set_title("Spectrum of the " + ("fitted" if fitted else "analysed") + " rows",
                 loc="left", fontsize=11)


def _three_panels(verdict):
    from matplotlib.figure import Figure

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    gs = fig.add_gridspec(3, 1, height_ratios=[3.0, 1.25, 2.4])
    axes = [fig.add_subplot(gs[i]) for i in range(3)]
    fig.suptitle(verdict_title(verdict), fontsize=14, fontweight="bold",
                 color=STATUS_COLOURS.get(verdict.status, "darkorange"))
    return fig, axes


def _rows_of(blocks: np.ndarray, period: float):
    """Linear-light rows of the analysed sub-blocks, high-passed as the fit does."""
    from lishield_guard.detector.numerics import HIGHPASS_CYCLES, linear_common

    x, _, _ = linear_common(np.asarray(blocks, dtype=np.float64))
    n = x.size
    hp = _highpass(n, (period if period > 0 else n / 4.0) / (2 * math.pi * HIGHPASS_CYCLES))
    return hp(x), hp


def cascade_figure(verdict, ev, config):
    """Three panels for a cascade verdict, from its evidence (`CascadeEvidence`): the rows of
    the deciding plane with the fitted template and look-alike; the numbers against their
    thresholds; the rows' spectrum with the spec's tones."""
    best = ev.best
    stage, info = _deciding_fit(best)
    channel = getattr(info, "channel", None) or "W"
    plane = ev.planes.get("L" if channel == "W" else channel) or ev.planes["L"]
    period = float(getattr(getattr(info, "match", info), "period_rows", 0.0) or 0.0)
    y, hp = _rows_of(plane.fit_blocks, period)
    fig, (ax_rows, ax_text, ax_spec) = _three_panels(verdict)
    rows = np.arange(y.size, dtype=np.float64)
    ax_rows.plot(rows, y, color="0.25", lw=0.8, label="rows (linear light, high-passed)")
    spec = _spec_named(config, getattr(info, "spec", None) or best.spec)
    sigma = _rows_panel(ax_rows, y, hp, info, spec, best.sweep, channel)
    line_name = "sensor row" if ev.axis == "rows" else "sensor row (stored image columns)"
    if ev.row_scale != 1.0:
        line_name += f", decoded at 1/{ev.row_scale:g}"
    ax_rows.set_xlabel(line_name)
    ax_rows.set_ylabel("relative light (a.u.)")
    ax_rows.set_xlim(0, max(y.size - 1, 1))  # one row: a unit-wide axis, not a singular one
    lead = "What decided" if verdict.status == "protected" else "Closest candidate (rejected)"
    ax_rows.set_title(f"{lead}: {stage}" + (f" of {spec.name} on channel {channel}"
                                           if spec is not None and info is not None else ""),
                      loc="left", fontsize=11)
    ax_rows.legend(loc="upper right", fontsize=8, framealpha=0.85)
    lines = (_threshold_lines(stage, info, ev.detector) if info is not None else
             [f"tones matched {best.n_matched}/{best.required}  purity {best.purity:.3g}  "
              f"switches {best.switches}"])
    text_panel(ax_text, ev.reason, lines, verdict.numbers)
    if sigma is None and best.sigma_cpr_per_hz:
        sigma = best.sigma_cpr_per_hz
    spec = spec or _spec_named(config, best.spec)
    marks = [] if spec is None else [(c, f) for c, fs in spec.channels for f in fs
                                     if channel == "W" or c == channel]
    matched = {(c, float(f)) for c, fs in best.matched.items() for f in fs}
    xlabel = (f"frequency (Hz at the fitted row rate {1 / sigma * ev.row_scale:,.0f} rows/s)"
              if info is not None and sigma else "frequency (Hz at the matched tones' scale)")
    _spectrum_panel(ax_spec, y, sigma, marks, matched, xlabel, period, info is not None)
    return fig


def paper_figure(verdict, ev, config):
    """Three panels for a paper-profile verdict, from its evidence (`PaperEvidence`): the row
    means Algorithm 1 read, high-passed; the reason and numbers; their spectrum at the
    nominal row rate with the peak frequencies it pooled."""
    from lishield_guard.detector.profiles import detrend_profiles

    contrast, _ = detrend_profiles(ev.rows[None, :], sigma_rows=max(ev.rows.size / 6.0, 1.0))
    y = contrast[0] - contrast[0].mean()
    fig, (ax_rows, ax_text, ax_spec) = _three_panels(verdict)
    ax_rows.plot(np.arange(y.size), y, color="0.25", lw=0.8,
                 label="row means (mean of the planes' column blocks), high-passed")
    ax_rows.set_xlabel("sensor row")
    ax_rows.set_ylabel("log contrast")
    ax_rows.set_xlim(0, max(y.size - 1, 1))
    ax_rows.set_title("What Algorithm 1 read: the rows (it fits no template)", loc="left",
                      fontsize=11)
    ax_rows.legend(loc="upper right", fontsize=8)
    text_panel(ax_text, ev.reason,
               [f"spec tested best: {ev.best_spec}; {len(ev.frequencies_hz)} peak "
                f"frequencies pooled over {', '.join(ev.planes)} and {ev.blocks} blocks"],
               verdict.numbers)
    _spectrum_panel(ax_spec, y, 1.0 / ev.nominal_row_rate_hz,
                    [("W", f) for f in ev.frequencies_hz], set(),
                    "frequency (Hz at the nominal row rate)", 0.0, False)
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
