"""The one orchestration: run the stages in order on an image and turn their results into a Verdict.

The default profile (`_detect_learned`) decides with fixed work per image: block profiles,
window spectra (`spectra`), the learned score (`learned`, `decision`) and, for its reason, the
spec whose tones explain the deciding window best (`explain`). The cascade profile (below) is the
pattern search that came before it, kept as a named profile.

Detection (`detect`, `detect_decoded`) and calibration (`collect_evidence`, `decide`,
`screen_specs`, `fold_fits`, `sweep_fits`) run the same stage sequence per axis, in order:
row profiles and frequency tracks (`analyse_plane`: `profiles`, `tracks`), the first stage
(`screen`), tone tracks (`tones`), folding (`fold`), the period sweep (`sweep`) and its
exact-model refinement (`fit`), each judged by the pass rules of `rules`. The paper profile
(`paper`, Algorithm 1) is dispatched from here too. Stage modules never import this one.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import cache

import numpy as np

from lishield_guard.config import (
    FIT_RHO_FLOOR,
    AppConfig,
    DetectorConfig,
    default_config,
)
from lishield_guard.decode import Decoded, decode
from lishield_guard.detector.decision import (
    DecisionRecord,
    decision_model,
    measure,
    rule,
    window_label,
)
from lishield_guard.detector.emitters import cycles_range, emitter_variants, variant_label
from lishield_guard.detector.explain import match_specs, peak_tones
from lishield_guard.detector.fit import refine
from lishield_guard.detector.fold import candidate_periods, fold_match, refine_period
from lishield_guard.detector.numerics import LOOKALIKE_DOMINANT_RHO, steady_rho
from lishield_guard.detector.paper import run_paper
from lishield_guard.detector.profiles import block_row_profiles, merge_blocks
from lishield_guard.detector.results import FoldResult, SpecMatch, Stage, SweepResult
from lishield_guard.detector.rules import (
    fold_passes,
    grid_passes,
    sweep_passes,
    tone_check_on,
    tone_fit_confirms,
)
from lishield_guard.detector.screen import jpeg_grid_cpr, screen_plane
from lishield_guard.detector.spectra import axis_too_small
from lishield_guard.detector.sweep import sweep_match
from lishield_guard.detector.tones import match_spec, scale_range_cpr_per_hz
from lishield_guard.detector.tracks import PlaneAnalysis, analyse_profiles
from lishield_guard.detector.usable import full_scale_of, unusable_reason
from lishield_guard.spec import BarcodeSpec
from lishield_guard.threads import native_threads
from lishield_guard.verdict import Verdict

__all__ = ["AXIS_NAMES", "Evidence", "analyse_plane", "collect_evidence", "decide",
           "decode_for", "detect", "detect_decoded", "fold_fits", "scaled_detector",
           "screen_specs", "spec_planes", "sweep_fits"]

MIN_ROWS = 64  # shorter profiles cannot hold two cycles of the lowest tone at any scale
MIN_ACROSS = 64  # fewer pixels across the lines cannot fill 8 column blocks of 8 pixels: the
#                  column-coherence tests that tell LED stripes from texture have nothing to use
MAX_CANDIDATES = 6  # (axis, spec) candidates the verdict's evidence lists
FIT_STARTS = 3  # best grid periods per spec channel refined with the exact capture model
FIT_SUB_BLOCKS = 4  # sweep and fit weight n_col_blocks x this many column sub-blocks
MIN_SLOTS_IN_FRAME = 2.0  # sweep/fit periods must leave two slots (two tones) in the frame:
#                           one tone is what a steady light shows
FIT_MIN_GRID_RHO = 0.55  # grid fits below this are not refined (dev set: with quiet-weighted
#                          sub-blocks, true periods started from grid fits of rho 0.6-0.7)


class _Timer:
    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.ms[stage] = self.ms.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3


def _resolve(config) -> AppConfig:
    if config is None:
        return default_config()
    if isinstance(config, AppConfig):
        return config
    if isinstance(config, DetectorConfig):
        base = default_config()
        return AppConfig(detector=config, limits=base.limits, policies=base.policies,
                         source=base.source)
    raise TypeError(f"config must be AppConfig, DetectorConfig or None, not "
                    f"{type(config).__name__}")


def detect(source, config: AppConfig | DetectorConfig | None = None) -> Verdict:
    """Decide whether an image carries a barcode of a configured policy.

    Parameters
    ----------
    source : bytes, str, pathlib.Path or ndarray
        Encoded image bytes, a path, or pixels of shape (n_rows, n_cols[, 3]).
    config : AppConfig or DetectorConfig, optional
        Detector settings, policies and limits; default the shipped config. A bare
        DetectorConfig uses the shipped policies and limits.

    Returns
    -------
    Verdict
        "No barcode" is a verdict, not an error.

    Raises
    ------
    ImageDecodeError, ImageTooLargeError, PayloadTooLargeError, InvalidImageError
        When the input cannot be turned into pixels.

    Notes
    -----
    Runs with one native (BLAS, OpenCV) thread, or the process's own pin, restored after
    the call (`lishield_guard.threads.native_threads`).
    """
    cfg = _resolve(config)
    timer = _Timer()
    with native_threads():
        with timer("decode"):
            decoded = decode_for(source, cfg)
        return detect_decoded(decoded, cfg, _timer=timer)


def decode_for(source, config: AppConfig) -> Decoded:
    """``source`` decoded as the configured profile analyses it (`decode.decode`): the default
    and cascade profiles at reduced JPEG scale (``max_decode_rows``); the default profile
    with its colour planes (the learned stage reads R, G and B), the cascade with them at once
    when an RGB spec is configured (one decode instead of luma first and colour later)."""
    det = config.detector
    reduced = det.profile in ("default", "cascade")
    want_rgb = det.profile == "default" or (
        reduced and any(s.is_rgb for p in config.policies for s in p.specs))
    return decode(source, limits=config.limits, fast=det.profiles.fast_decode,
                  want_rgb=want_rgb, max_rows=det.profiles.max_decode_rows if reduced else 0)


def detect_decoded(decoded: Decoded, config: AppConfig, *, _timer: _Timer | None = None
                   ) -> Verdict:
    """`detect` on an already decoded image."""
    timer = _timer or _Timer()
    det = config.detector
    if det.profile == "paper":
        return _detect_paper(decoded, config, timer)
    if det.profile == "cascade":
        return _detect_cascade(decoded, config, timer)
    return _detect_learned(decoded, config, timer)


def _detect_learned(decoded: Decoded, config: AppConfig, timer: _Timer) -> Verdict:
    """The default profile: fixed work per image, whatever it shows.

    decode -> block profiles of both axes -> window spectra -> the network's logits
    (`decision.measure`) -> the one rule (`decision.rule`) -> which configured spec explains
    the deciding window's tones best (`explain.match_specs`, bounded), for the reason and the
    policy.
    """
    det = config.detector
    specs = [(p.id, s) for p in config.policies for s in p.specs]
    skipped: list[str] = []
    if decoded.row_scale > 1:
        skipped.append(f"full resolution: JPEG decoded at 1/{decoded.row_scale:g} scale in the "
                       f"DCT domain (stripes need rows, not pixels)")
    why, notes = learned_scope(config)
    if why is not None:  # the network cannot look for these barcodes: never "clean"
        return Verdict(False, None, 0, 1, evidence={"reason": why}, skipped=tuple(skipped),
                       timings_ms=timer.ms, profile="default", undetermined=why)
    skipped += notes
    with timer("measure"):
        pixels = decoded.rgb() if decoded.is_color else decoded.luma
        rec = measure(pixels, det)
    skipped += list(rec.spectra.skipped) + [f"usable blocks: {n}" for n in rec.usable_notes]
    if rec.undetermined is not None:
        return Verdict(False, None, 0, 1, evidence={"reason": rec.undetermined},
                       skipped=tuple(skipped), timings_ms=timer.ms, profile="default",
                       undetermined=rec.undetermined)
    with timer("explain"):
        evidence = learned_evidence(rec, specs, det)
    protected = bool(rule(rec.logit, det))
    skipped.append("pattern search and exact capture-model fit: not part of the decision "
                   "(`detect --explain` runs them on a flagged image; profile cascade)")
    return Verdict(protected=protected, policy=evidence["policy"] if protected else None,
                   matches=int(protected), required=1, evidence=evidence,
                   skipped=tuple(skipped), timings_ms=timer.ms, profile="default",
                   score=float(1.0 / (1.0 + math.exp(-min(max(rec.logit, -60.0), 60.0)))))


def learned_scope(config: AppConfig) -> tuple[str | None, list[str]]:
    """Why the learned decision cannot look for the configured specs (None when it can), and
    notes on configured specs it was not trained on (a clean verdict does not cover them)."""
    specs = [s for p in config.policies for s in p.specs]
    model = decision_model(config.detector)
    unknown = [s.name for s in specs if not model.knows(s)]
    if not specs:
        return "no policy configured: nothing to look for", []
    if len(unknown) == len(specs):
        return (f"the decision model was not trained on any configured spec "
                f"({', '.join(unknown)}; it knows "
                f"{', '.join(model.card.get('specs', ())) or 'none'}): use profile cascade, "
                f"or retrain (make train)"), []
    return None, ([f"specs {', '.join(unknown)}: not in the decision model's training (a "
                   f"clean verdict does not cover them; profile cascade does)"] if unknown
                  else [])


def learned_evidence(rec: DecisionRecord, specs: list[tuple[str, BarcodeSpec]],
                     det: DetectorConfig) -> dict:
    """The default verdict's evidence and reason from its record: the decision (logit,
    threshold, deciding window) and the configured spec that best explains the tones of the
    deciding window's column range (its policy is the verdict's policy when flagged)."""
    k = rec.best
    siblings = _row_siblings(rec, k)
    fits = []
    for w in siblings:  # every row window of the deciding column range; the best placement
        fits += [(f, w) for f in match_specs(rec.spectra.x[w], [s for _, s in specs])]
    best_fit, w_best = max(fits, key=lambda fw: fw[0].score) if fits else (None, None)
    policy = next((pid for pid, s in specs if best_fit and s.name == best_fit.spec),
                  specs[0][0])
    thr = det.learned.threshold_logit
    where = window_label(rec.spectra, k)
    flagged = bool(rule(rec.logit, det))
    if flagged and best_fit is not None and best_fit.score >= det.learned.min_explain_score:
        tones = "; ".join(f"{c}: " + ", ".join(f"{v:.4f}" for v in vs)
                          for c, vs in best_fit.tones_cpr.items())
        leak = "" if best_fit.leak is None else (
            f"; the same tones' level in the other colour planes {best_fit.leak:.1f}")
        reason = (f"barcode: decision logit {rec.logit:.2f} >= threshold {thr:.2f} ({where}); "
                  f"best explained by {best_fit.spec} of policy {policy}, tones at {tones} "
                  f"cycles/row (template score {best_fit.score:.1f}){leak}")
    elif flagged:
        reason = (f"barcode: decision logit {rec.logit:.2f} >= threshold {thr:.2f} ({where}); "
                  f"no configured spec's tones stand out clearly (best template score "
                  f"{best_fit.score if best_fit else float('nan'):.1f}); policy {policy}")
    else:
        reason = (f"clean: decision logit {rec.logit:.2f} < threshold {thr:.2f} (highest in "
                  f"{where})")
    order = np.argsort(rec.logits)[::-1][:MAX_CANDIDATES]
    return {"reason": reason, "stage": "learned", "logit": round(rec.logit, 4),
            "threshold_logit": thr, "axis": rec.spectra.axes[k], "where": where,
            "policy": policy, "spec_fit": None if best_fit is None else best_fit.to_dict(),
            "spec_fit_window": None if w_best is None else window_label(rec.spectra, w_best),
            "windows": [{"where": window_label(rec.spectra, int(i)),
                         "logit": round(float(rec.logits[i]), 4)} for i in order],
            "tones_cpr": [[round(f, 5), round(v, 2)] for f, v in peak_tones(rec.spectra.x[k])],
            "model": decision_model(det).card.get("training_commit")}


def _row_siblings(rec: DecisionRecord, window: int) -> list[int]:
    """The windows of the same axis and column range as ``window`` (every row range), the
    window itself first."""
    axis, (c0, c1, _, _) = rec.spectra.axes[window], rec.spectra.windows[window]
    same = [i for i, (a, w) in enumerate(zip(rec.spectra.axes, rec.spectra.windows,
                                             strict=True))
            if a == axis and (w[0], w[1]) == (c0, c1) and i != window]
    return [window, *same]


def _detect_paper(decoded: Decoded, config: AppConfig, timer: _Timer) -> Verdict:
    PAPER_MIN_BLOCK_ROWS = 4  # noqa: N806 - paper.block_peaks_hz skips shorter blocks
    det = config.detector
    skipped: list[str] = []
    with timer("planes"):
        if decoded.is_color:
            rgb = decoded.rgb()
            planes = {c: rgb[:, :, i] for i, c in enumerate("RGB")}
        else:
            planes = {"W": decoded.luma}
    if min(decoded.luma.shape) < 2 * det.paper.n_block_rows:
        skipped.append("image smaller than the block grid")
    n_rows = decoded.luma.shape[0]
    block_rows = np.diff(np.linspace(0, n_rows, det.paper.n_block_rows + 1).round()).max()
    why = None
    if not any(p.specs for p in config.policies):
        why = "no policy configured: nothing to look for"
    elif block_rows < PAPER_MIN_BLOCK_ROWS:  # block_peaks_hz skips every block
        why = (f"image too small: {n_rows} rows give blocks of < {PAPER_MIN_BLOCK_ROWS} rows "
               f"(n_block_rows={det.paper.n_block_rows})")
    if why is not None:
        return Verdict(False, None, 0, 0, evidence={"reason": why}, skipped=tuple(skipped),
                       timings_ms=timer.ms, profile="paper", undetermined=why)
    with timer("algorithm1"):
        out = run_paper(planes, config.policies, det)
    return Verdict(protected=bool(out["protected"]), policy=out["policy"],
                   matches=int(out["matches"]), required=int(out["required"]),
                   evidence=out["evidence"], skipped=tuple(skipped), timings_ms=timer.ms,
                   profile="paper", score=float(out["matches"] >= out["required"]))


def _band_cpr(config: AppConfig, row_scale: float = 1.0) -> tuple[float, float]:
    det = config.detector
    s_lo, s_hi = scale_range_cpr_per_hz(det)
    freqs = [f for p in config.policies for s in p.specs for f in s.all_freqs_hz]
    if not freqs:
        return 0.0, 0.0
    return min(freqs) * s_lo * row_scale, min(0.5, max(freqs) * s_hi * row_scale)


def analyse_plane(plane: np.ndarray, axis: int, config: AppConfig,
                  row_scale: float = 1.0) -> PlaneAnalysis:
    """Row profiles and frequency tracks of one plane along ``axis`` (0: rows, 1: columns),
    over the band the configured policies' tones can fall in at ``row_scale`` stored rows per
    analysed row: the input of every later stage."""
    det = config.detector
    lo, hi = _band_cpr(config, row_scale)
    fine = block_row_profiles(plane, n_col_blocks=det.profiles.n_col_blocks, axis=axis,
                              sub_blocks=FIT_SUB_BLOCKS)
    profiles = merge_blocks(fine, plane.shape[1 - axis], det.profiles.n_col_blocks,
                            FIT_SUB_BLOCKS)
    n_rows = profiles.shape[1]
    sigma = min(0.5 / lo if lo > 0 else n_rows, n_rows / 6.0)
    return analyse_profiles(profiles, full_scale=full_scale_of(plane), band_cpr=(lo, hi),
                            trend_sigma_rows=sigma, false_prob=det.tones.peak_false_prob,
                            fine_profiles=fine)


AXIS_NAMES = {0: "rows", 1: "columns"}


@dataclass(frozen=True)
class Evidence:
    """Everything the default profile decides on, computed once per image.

    Attributes
    ----------
    axes : dict
        ``"rows"``/``"columns"`` -> plane name (``"L"`` luma, ``"R"``, ``"G"``, ``"B"``) ->
        `PlaneAnalysis`. Planes that were not needed may be absent.
    row_scale : float
        Stored rows per analysed row (DCT-domain downscaling of large JPEGs).
    orientation : int
        EXIF orientation tag of the source.
    format : str
        Container format.
    skipped : tuple of str
        Work not done and why.
    """

    axes: dict
    row_scale: float = 1.0
    orientation: int = 1
    format: str = "array"
    skipped: tuple[str, ...] = ()

    @property
    def grid_cpr(self) -> tuple[float, ...]:
        """The source's JPEG block grid in cycles per analysed row (`screen.jpeg_grid_cpr`)."""
        return jpeg_grid_cpr(self.format, self.row_scale)

    def with_false_prob(self, false_prob: float) -> Evidence:
        """The same evidence judged at another per-frame false-pass probability."""
        axes = {a: {k: pa.with_false_prob(false_prob) for k, pa in planes.items()}
                for a, planes in self.axes.items()}
        return Evidence(axes, self.row_scale, self.orientation, self.format, self.skipped)


def scaled_detector(det: DetectorConfig, row_scale: float) -> DetectorConfig:
    """Detector settings whose scale range accounts for decoding at 1/row_scale."""
    if row_scale == 1.0:
        return det
    pr = det.profiles
    return det.replace(profiles=pr.replace(min_row_rate_hz=pr.min_row_rate_hz / row_scale,
                                           max_row_rate_hz=pr.max_row_rate_hz / row_scale))


def spec_planes(spec: BarcodeSpec, planes: dict[str, PlaneAnalysis]
                ) -> dict[str, PlaneAnalysis] | None:
    """The plane analysis carrying each channel of ``spec`` (luma stands in for a colour plane
    that was not analysed); None when luma itself is missing."""
    if spec.is_rgb:
        chans = {c: planes.get(c, planes.get("L")) for c in spec.channel_names}
    else:
        chans = {"W": planes.get("L")}
    return None if any(v is None for v in chans.values()) else chans


def _decide_axis(planes: dict[str, PlaneAnalysis], specs, det: DetectorConfig,
                 grid_cpr: tuple[float, ...] = (), screens: dict | None = None
                 ) -> list[tuple[str, SpecMatch]]:
    """Match every spec whose planes are available on one axis: tone tracks (confirmed by an
    exact fit of the spec when ``tone_min_fit_gain`` is set), then folding, then the period
    sweep (computed once per axis for all specs, when first needed). ``screens``: first-stage
    results already computed for some of the planes (`screen_specs`), filled in place."""
    out = []
    screens, screened = screen_specs(planes, specs, det, grid_cpr, screens)

    @cache
    def periods() -> list[float]:
        return _periods(planes["L"], screened, det)

    @cache
    def sweeps(name: str) -> list[SweepResult]:
        # per spec, when first needed: a verdict reached on one spec spares the others
        return _axis_sweeps(planes, [ps for ps in screened if ps[1].name == name], det,
                            periods(), stop=lambda entry: sweep_passes(entry, det))[name]

    for pid, spec in specs:
        chans = spec_planes(spec, planes)
        if chans is None:
            continue
        if (pid, spec) not in screened:  # the first stage cleared every plane of the spec
            out.append((pid, _cleared_by_screen(spec, chans, screens, det)))
            continue
        m = match_spec(spec, chans, det)  # tone tracks
        if m.protected and tone_check_on(det) and not tone_fit_confirms(sweeps(spec.name),
                                                                          det):
            m = replace(m, protected=False, reason=(
                f"{m.reason}; not confirmed: no exact fit of {spec.name} explains the rows "
                f"{det.tones.min_fit_gain:g}x better than a steady square wave"))
        if not m.protected and det.fold is not None:
            m = _fold_stage(m, spec, _fold_info(spec, chans, periods(), det), det)
        if not m.protected and det.sweep is not None:
            m = _sweep_stage(m, spec, sweeps(spec.name), det)
        out.append((pid, m))
        if m.protected:  # the verdict is certain: later specs are not searched
            break
    return out


def _cleared_by_screen(spec: BarcodeSpec, chans: dict[str, PlaneAnalysis], screens: dict,
                       det: DetectorConfig) -> SpecMatch:
    """``spec`` as the first stage left it: not protected, no tone matched (the tone tracks
    are not searched, as in calibration), with the reason its planes failed."""
    best = max((screens[id(pa)] for pa in chans.values()), key=lambda r: r.frames)
    steady = [r.steady_rho for pa in chans.values()
              if (r := screens[id(pa)]).steady_rho is not None]
    if steady:
        why = (f"the stripes are a steady square wave (look-alike rho="
               f"{min(steady):.3f} >= {LOOKALIKE_DOMINANT_RHO}): a PWM-dimmed or "
               f"mains-flickering light or a regular texture, not a barcode")
    else:
        why = (f"no column-coherent stripes (at most {best.frames} frame(s) of a "
               f"track above the p={best.false_prob:g} noise threshold, "
               f"{det.screen.min_frames} needed"
               + ("" if det.screen.partial_false_prob is None else
                  f"; in any half of the columns, {best.part_frames} at p="
                  f"{det.screen.partial_false_prob:g}, "
                  f"{det.screen.partial_min_frames} needed") + ")")
    need = det.tones.min_tones_rgb if spec.is_rgb else det.tones.min_tones
    return SpecMatch(spec.name, 0.0, {}, {}, 0, need, 0.0, 0, False,
                     f"first stage: {why}; tone tracks and pattern search skipped",
                     stage=Stage.FIRST)


def _fold_stage(m: SpecMatch, spec: BarcodeSpec, fold: FoldResult | None,
                det: DetectorConfig) -> SpecMatch:
    """``m`` after folding: protected when the best fold fit ``fold`` passes `fold_passes`."""
    if fold is None:
        return m
    if not fold_passes(fold, det):
        return replace(m, fold=fold, stage=Stage.FOLD)
    reason = (f"the stripes repeat every {fold.match.period_rows:.1f} rows and the "
              f"folded pattern fits {spec.name} (rho={fold.rho:.2f}, "
              f"{fold.match.cycles_f1:.2f} cycles of f_1 per slot)")
    return replace(m, protected=True, reason=reason, fold=fold, stage=Stage.FOLD)


def _sweep_stage(m: SpecMatch, spec: BarcodeSpec, entries: list[SweepResult],
                 det: DetectorConfig) -> SpecMatch:
    """``m`` after the period sweep and its exact fits (one entry per channel, ``entries``):
    protected when one passes `sweep_passes`; the stage named is the one that passed."""
    passing = [e for e in entries if sweep_passes(e, det)]
    sw = max(passing or entries, key=lambda e: (grid_passes(e, det),
                                                e.rho - e.rho_lookalike),
             default=None)
    if sw is None:
        return m
    if not passing:
        return replace(m, sweep=sw, stage=Stage.SWEEP if sw.fit is None else Stage.EXACT_FIT)
    if not grid_passes(sw, det):
        fit = sw.fit
        reason = (f"{spec.name}'s exact capture model ({sw.channel}: period "
                  f"{fit.period_rows:.1f} rows, {fit.cycles_f1:.2f} "
                  f"cycles of f_1 per slot, exposure {fit.exposure_slots:.2f} slot, "
                  f"{fit.n_periods:.2f} periods in the frame) "
                  f"fits the rows ({fit.domain}, rho={fit.rho:.3f}) {fit.gain:.1f}x "
                  f"better than any steady square wave (look-alike rho="
                  f"{fit.rho_lookalike:.3f}), with the same amplitude in every "
                  f"column block (t={fit.coherence_t:.1f})"
                  + ("" if fit.chroma_leak is None else
                     f" and in its own colour plane only (chroma leak "
                     f"{fit.chroma_leak:.2f})"))
        return replace(m, protected=True, reason=reason, sweep=sw, stage=Stage.EXACT_FIT)
    reason = (f"{spec.name}'s pattern ({sw.channel}), tiled every "
              f"{sw.match.period_rows:.1f} rows ({sw.match.n_periods:.2f} periods in the "
              f"frame), fits the stripes (rho={sw.rho:.2f}, look-alike "
              f"{sw.rho_lookalike:.2f}) with the same amplitude in every column "
              f"block (t={sw.coherence_t:.1f})")
    return replace(m, protected=True, reason=reason, sweep=sw, stage=Stage.SWEEP)


def screen_specs(planes: dict[str, PlaneAnalysis], specs, det: DetectorConfig,
                 grid_cpr: tuple[float, ...] = (), screens: dict | None = None
                 ) -> tuple[dict, list]:
    """The first stage on one axis: `screen.screen_plane` of every plane (by ``id``) and the
    (policy id, spec) pairs with a plane that passed, in order. Detection and calibration
    (`sweep_fits`, `fold_fits`, `calibrate.screened_candidates`) search the same specs with
    the same candidate periods. ``grid_cpr``: the source's JPEG grid (`screen.jpeg_grid_cpr`);
    ``screens``: results of planes screened before (not screened again), filled in place."""
    screens = {} if screens is None else screens
    sc = det.screen
    for name, pa in planes.items():
        if id(pa) not in screens:
            # halves of the columns are tested in luma only: a light covering part of the
            # frame shows there whatever it plays, and colour planes would triple the cost
            screens[id(pa)] = screen_plane(
                pa, false_prob=None if sc is None else sc.false_prob,
                min_frames=1 if sc is None else sc.min_frames, grid_cpr=grid_cpr,
                partial_false_prob=sc.partial_false_prob if sc and name == "L" else None,
                partial_min_frames=1 if sc is None else sc.partial_min_frames)
    return screens, [(pid, spec) for pid, spec in specs
                     if _screen_passes(spec_planes(spec, planes), screens)]


def _screen_passes(chans: dict[str, PlaneAnalysis] | None, screens: dict) -> bool:
    """Whether any plane carrying a spec's channels passed the first stage (`screen`)."""
    return chans is not None and any(screens[id(pa)].passed for pa in chans.values())


def _related_periods(periods) -> tuple[float, ...]:
    """Repetition periods and their simple multiples and fractions (k/j, k, j <= 3): the
    autocorrelation often peaks at a slot (period / M) or at two or three periods."""
    out: list[float] = []
    for p in periods:
        for q in sorted({k / j for k in (1, 2, 3) for j in (1, 2, 3)}):
            v = p * q
            if all(abs(v / w - 1.0) > 0.01 for w in out):
                out.append(v)
    return tuple(out)


def _colour_blocks(planes: dict[str, PlaneAnalysis]) -> dict[str, np.ndarray] | None:
    """Column-block log contrast of the R, G, B planes (sub-blocks where analysed), or None
    unless all three were analysed."""
    out = {}
    for c in "RGB":
        pa = planes.get(c)
        if pa is None or pa.blocks is None:
            return None
        out[c] = pa.fit_blocks
    return out


def _axis_sweeps(planes: dict[str, PlaneAnalysis], specs, det: DetectorConfig,
                 periods: list[float] | None = None, stop=None
                 ) -> dict[str, list[SweepResult]]:
    """Period-sweep fits of every spec on one axis, one per channel plane (spec name -> fits).

    Specs fitted on the same plane share one period grid. Each channel is judged on its own:
    the exposure attack or a long exposure can flatten a colour's tones, and one channel
    fitted the way the spec says is the evidence. With ``stop`` (a predicate on one entry),
    the search ends at the first entry it accepts: the verdict no longer depends on the rest.
    """
    by_plane: dict[int, tuple[PlaneAnalysis, list]] = {}
    for _, spec in specs:
        chans = spec_planes(spec, planes)
        for c, pa in (chans or {}).items():
            if pa.blocks is not None:
                by_plane.setdefault(id(pa), (pa, []))[1].extend(
                    (v, c) for v in emitter_variants(spec))
    scale = scale_range_cpr_per_hz(det)
    out: dict[str, list[SweepResult]] = {spec.name: [] for _, spec in specs}
    for pa, targets in by_plane.values():
        ranges = [_frame_period_range(s, det, pa.n_rows) for s, _ in targets]
        blocks = pa.fit_blocks
        fits = sweep_match(blocks, targets, scale_range_cpr_per_hz=scale,
                           period_range_rows=ranges,
                           n_starts=0 if det.fit is None else FIT_STARTS,
                           start_periods=_related_periods(periods or ()), weighted=True)
        # one steady look-alike per plane, at its best grid period: rows a steady square wave
        # already explains are not refined for any target
        top = max((st for sm in fits if sm is not None for st in sm.starts), default=None)
        steady = (steady_rho(blocks, top[1])
                  if det.fit is not None and top is not None and top[0] >= FIT_MIN_GRID_RHO
                  else 0.0)
        for (spec, c), sm, rng in zip(targets, fits, ranges, strict=True):
            if sm is None:
                continue
            entry = SweepResult(sm, c, variant_label(spec))
            if steady >= LOOKALIKE_DOMINANT_RHO:
                entry = replace(entry, steady_rho=steady)
            elif det.fit is not None:
                starts = [st for st in sm.starts if st[0] >= FIT_MIN_GRID_RHO]
                mf = refine(blocks, spec, c, starts, period_range_rows=rng,
                            scale_range_cpr_per_hz=scale,
                            colour_blocks=_colour_blocks(planes) if spec.is_rgb else None,
                            matched_refit=det.fit.matched_refit)
                entry = replace(entry, fit=mf)
            out[spec.name].append(entry)
            if stop is not None and stop(entry):
                return {name: _best_variants(infos) for name, infos in out.items()}
    return {name: _best_variants(infos) for name, infos in out.items()}


def _variant_rank(entry: SweepResult) -> tuple:
    """How well an emitter variant's sweep entry explains the rows: an exact fit's gain over
    the steady look-alike first (when it reached `config.FIT_RHO_FLOOR`), then the grid's
    margin over the look-alike."""
    fit = entry.fit
    good = fit is not None and fit.rho >= FIT_RHO_FLOOR
    return (good, fit.gain if good else -math.inf, entry.rho - entry.rho_lookalike)


def _best_variants(entries: list[SweepResult]) -> list[SweepResult]:
    """One sweep entry per channel: the emitter variant that explains the rows best."""
    best: dict[str, SweepResult] = {}
    for entry in entries:
        c = entry.channel
        if c not in best or _variant_rank(entry) > _variant_rank(best[c]):
            best[c] = entry
    return list(best.values())


def _screened_axes(evidence: Evidence, config: AppConfig):
    """Per axis of ``evidence`` with luma: (axis name, planes, detector settings, the (policy
    id, spec) pairs the first stage passes, their candidate periods), as `decide` sees them."""
    det = scaled_detector(config.detector, evidence.row_scale)
    all_specs = [(p.id, s) for p in config.policies for s in p.specs]
    for axis_name, planes in evidence.axes.items():
        if "L" not in planes:
            continue
        _, specs = screen_specs(planes, all_specs, det, evidence.grid_cpr)
        yield axis_name, planes, det, specs, _periods(planes["L"], specs, det)


def sweep_fits(evidence: Evidence, config: AppConfig) -> list[tuple[str, str, SweepResult]]:
    """Unthresholded period-sweep fits of every spec the first stage passes, on every axis, as
    (axis name, policy id, entry) (for calibration sweeps; the specs and candidate periods
    `decide` searches)."""
    out = []
    for axis_name, planes, det, specs, periods in _screened_axes(evidence, config):
        sweeps = _axis_sweeps(planes, specs, det, periods)
        for pid, spec in specs:
            out += [(axis_name, pid, entry) for entry in sweeps[spec.name]]
    return out


def fold_fits(evidence: Evidence, config: AppConfig) -> list[tuple[str, str, FoldResult]]:
    """Unthresholded fold fits of every spec the first stage passes, on every axis, as (axis
    name, policy id, fit) (for calibration sweeps; the specs and candidate periods `decide`
    searches)."""
    out = []
    for axis_name, planes, det, specs, periods in _screened_axes(evidence, config):
        for pid, spec in specs:
            chans = spec_planes(spec, planes)
            fold = _fold_info(spec, chans, periods, det) if chans else None
            if fold is not None:
                out.append((axis_name, pid, fold))
    return out


def _period_range_rows(spec: BarcodeSpec, det: DetectorConfig) -> tuple[float, float]:
    """Pattern periods M/f_B in rows that the scale range and f_B range allow."""
    s_lo, s_hi = scale_range_cpr_per_hz(det)
    c_lo, c_hi = cycles_range(spec.f1_hz)
    return spec.n_tones * c_lo / (spec.f1_hz * s_hi), spec.n_tones * c_hi / (spec.f1_hz * s_lo)


def _frame_period_range(spec: BarcodeSpec, det: DetectorConfig, n_rows: int
                        ) -> tuple[float, float]:
    """`_period_range_rows` capped so that the frame holds at least MIN_SLOTS_IN_FRAME slots
    (a quarter of a pattern in a small crop is a smooth curve, which anything can fit)."""
    lo, hi = _period_range_rows(spec, det)
    return lo, min(hi, n_rows * spec.n_tones / MIN_SLOTS_IN_FRAME)


def _periods(luma: PlaneAnalysis, specs, det: DetectorConfig) -> list[float]:
    if luma.common is None or not specs:
        return []
    ranges = [_period_range_rows(s, det) for _, s in specs]
    lo = min(r[0] for r in ranges)
    hi = max(r[1] for r in ranges)
    x = luma.common.astype(np.float64)
    coarse = candidate_periods(x, min_rows=max(lo, 4.0), max_rows=hi)
    return [refine_period(x, p) for p in coarse]


def _fold_info(spec: BarcodeSpec, chans: dict[str, PlaneAnalysis], periods: list[float],
               det: DetectorConfig) -> FoldResult | None:
    """Best fold fit of ``spec`` over its channels' planes (mean rho over channels)."""
    if not periods or any(pa.common is None for pa in chans.values()):
        return None
    best = None
    for variant in emitter_variants(spec):
        fits = []
        for c, pa in chans.items():
            fm = fold_match(pa.common.astype(np.float64), variant, c,
                            period_range_rows=_period_range_rows(spec, det), periods=periods,
                            refine=False, scale_range_cpr_per_hz=scale_range_cpr_per_hz(det))
            if fm is None:
                return None
            fits.append(fm)
        fold = FoldResult(fits[0], float(np.mean([f.rho for f in fits])),
                          float(np.mean([f.rho_lookalike for f in fits])),
                          float(min(f.fold_snr for f in fits)), len(fits),
                          variant_label(variant))
        if best is None or fold.rho - fold.rho_lookalike > best.rho - best.rho_lookalike:
            best = fold
    return best


def _too_small(shape: tuple[int, ...], axis: int) -> str | None:
    """Why the luma plane of ``shape`` cannot be analysed along ``axis`` (None: it can); the
    same size rule as the default profile's (`spectra.axis_too_small`)."""
    return axis_too_small(shape, axis)


def _analysed_axes(decoded: Decoded, config: AppConfig, timer: _Timer, skipped: list[str]):
    """Per configured axis (rows, then columns), analysed on first use: (axis name, planes
    holding luma ``"L"``, ``colour()`` adding the R, G, B planes when the image has colour and
    returning the planes). Axes too small to analyse are named in ``skipped`` instead."""
    for axis in (0, 1) if config.detector.profiles.orientations == "both" else (0,):
        name = AXIS_NAMES[axis]
        if (why := _too_small(decoded.luma.shape, axis)) is not None:
            skipped.append(f"{name}: {why}")
            continue
        with timer("profile_luma"):
            planes = {"L": analyse_plane(decoded.luma, axis, config, decoded.row_scale)}

        def colour(axis=axis, planes=planes) -> dict[str, PlaneAnalysis]:
            if decoded.is_color:
                with timer("profile_color"):
                    planes.update({c: analyse_plane(p, axis, config, decoded.row_scale)
                                   for c, p in zip("RGB", decoded.colour_planes(),
                                                   strict=True)})
            return planes

        yield name, planes, colour


def collect_evidence(decoded: Decoded, config: AppConfig) -> Evidence:
    """Every plane on every configured axis, analysed up front (for calibration sweeps;
    `detect` analyses lazily, with the same `analyse_plane`)."""
    skipped: list[str] = []
    has_rgb = any(s.is_rgb for p in config.policies for s in p.specs)
    axes = {name: colour() if has_rgb else planes
            for name, planes, colour in _analysed_axes(decoded, config, _Timer(), skipped)}
    return Evidence(axes, decoded.row_scale, decoded.orientation, decoded.format,
                    tuple(skipped))


def decide(evidence: Evidence, config: AppConfig) -> Verdict:
    """The default profile's verdict from precomputed evidence (no decoding, no profiling):
    `_run_stages` over every plane of every axis, every spec at once."""
    axes = ((name, planes, None) for name, planes in evidence.axes.items())
    return _run_stages(axes, config, row_scale=evidence.row_scale, fmt=evidence.format,
                       orientation=evidence.orientation, skipped=list(evidence.skipped),
                       timer=_Timer(), lazy=False)


def _run_stages(axes, config: AppConfig, *, row_scale: float, fmt: str, orientation: int,
                skipped: list[str], timer: _Timer, lazy: bool) -> Verdict:
    """The default profile's stages on each axis in turn (`_decide_axis`), and the Verdict:
    the one orchestration of detection (`detect`, lazy) and of `decide` (calibration).

    ``axes`` yields (axis name, planes, colour) as `_analysed_axes` does. Lazy: the mono specs
    are matched on luma first, the RGB specs (with the colour planes, ``colour()``) only when
    luma is not decisive, and the columns only when the rows found no barcode. Otherwise every
    spec is matched at once on the planes given, on every axis.
    """
    det = scaled_detector(config.detector, row_scale)
    specs = [(p.id, s) for p in config.policies for s in p.specs]
    first = [(pid, s) for pid, s in specs if not (lazy and s.is_rgb)]
    rgb = [(pid, s) for pid, s in specs if lazy and s.is_rgb]
    grid = jpeg_grid_cpr(fmt, row_scale)
    candidates: list[tuple[str, str, SpecMatch]] = []
    for name, planes, colour in axes:
        skipped.extend(f"{name}: {s}" for s in planes["L"].skipped)
        with timer("match"):
            screens: dict = {}  # luma is screened once, for the mono and the RGB specs
            found = _decide_axis(planes, first, det, grid, screens)
        if rgb and not any(m.protected for _, m in found):
            # Colour planes whenever luma is not decisive: an RGB barcode's channels can
            # cancel in luma (measured: gating them on luma stripes lost 27/400 positives).
            planes = colour()
            with timer("match"):
                found += _decide_axis(planes, rgb, det, grid, screens)
        elif rgb:
            skipped.append(f"{name}: colour planes (luma verdict certain)")
        candidates += [(name, pid, m) for pid, m in found]
        if lazy and any(m.protected for _, m in found):
            if name == AXIS_NAMES[0] and det.profiles.orientations == "both":
                skipped.append("columns: verdict certain from rows")
            break
    return _verdict(candidates, config, skipped, timer.ms, orientation, fmt)


def _verdict(candidates, config: AppConfig, skipped: list[str], timings: dict,
             orientation: int, fmt: str) -> Verdict:
    if not candidates:  # the detector could not look: undetermined, never clean
        if not any(p.specs for p in config.policies):
            why = "no policy configured: nothing to look for"
        else:
            why = (f"image too small: fewer than {MIN_ROWS} lines of at least {MIN_ACROSS} "
                   f"pixels on every analysed axis ("
                   + "; ".join(skipped) + ")" if skipped else "nothing analysable")
        return Verdict(False, None, 0, config.detector.tones.min_tones,
                       evidence={"reason": why, "candidates": []},
                       skipped=tuple(skipped), timings_ms=timings, profile="cascade",
                       undetermined=why)
    axis, pid, m = max(candidates, key=lambda c: (c[2].protected, c[2].score, c[2].n_matched))
    # the evidence lists MAX_CANDIDATES: most tones first, then those the search looked at
    tried = sorted(({"axis": a, "policy": p, **c.to_dict()} for a, p, c in candidates),
                   key=lambda d: (-d["n_matched"], d["stage"] == Stage.FIRST, -d["purity"]))
    evidence = {"reason": m.reason, "axis": axis, "stage": m.stage, "best": m.to_dict(),
                "candidates": tried[:MAX_CANDIDATES], "orientation_exif": orientation,
                "format": fmt}
    # matches / required count the deciding stage's evidence: tones for the tone tracks, one
    # pattern fit of one needed for folding, the sweep and the exact fit
    pattern = m.protected and m.stage != Stage.TONES
    return Verdict(protected=m.protected, policy=pid if m.protected else None,
                   matches=1 if pattern else m.n_matched, required=1 if pattern else m.required,
                   evidence=evidence,
                   skipped=tuple(skipped), timings_ms=timings, profile="cascade",
                   score=m.score)


def _detect_cascade(decoded: Decoded, config: AppConfig, timer: _Timer) -> Verdict:
    """The cascade profile: `_run_stages`, lazily, on the planes of a decoded image analysed as
    they are needed."""
    det = config.detector
    with timer("profile_luma"):  # a frame the test cannot run on is undetermined, never clean
        why = unusable_reason(decoded.luma, n_col_blocks=det.profiles.n_col_blocks,
                              axes=(0, 1) if det.profiles.orientations == "both" else (0,),
                              min_lines=MIN_ROWS, min_across=MIN_ACROSS,
                              colour_planes=decoded.colour_planes if decoded.is_color else None)
    if why is not None:
        return Verdict(False, None, 0, det.tones.min_tones,
                       evidence={"reason": why, "candidates": []}, timings_ms=timer.ms,
                       profile="cascade", undetermined=why)
    skipped: list[str] = []
    if decoded.row_scale > 1:
        skipped.append(f"full resolution: JPEG decoded at 1/{decoded.row_scale:g} scale in the "
                       f"DCT domain (stripes need rows, not pixels)")
    if decoded.orientation in (5, 6, 7, 8) and config.detector.profiles.orientations == "both":
        skipped.append(f"EXIF orientation {decoded.orientation}: stored rows are sensor rows, "
                       f"analysed first")
    return _run_stages(_analysed_axes(decoded, config, timer, skipped), config,
                       row_scale=decoded.row_scale, fmt=decoded.format,
                       orientation=decoded.orientation, skipped=skipped, timer=timer, lazy=True)
