"""The cascade's search on one axis: first stage, tone tracks, folding, period sweep, exact fit.

`decide_axis` runs the pattern stages in order on the analysed planes of one axis
(`analyse_plane`: row profiles and frequency tracks), every spec the first stage passes
(`screen_specs`), each judged by the pass rules of `rules`; calibration sweeps the same
candidates unthresholded (`axis_sweeps`, `fold_info`, `candidate_periods`). The cascade profile
(`lishield_guard.profiles.cascade`) runs it per axis and turns its matches into a Verdict.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache

import numpy as np

from lishield_guard.config import FIT_RHO_FLOOR, AppConfig, DetectorConfig
from lishield_guard.detector.emitters import cycles_range, emitter_variants, variant_label
from lishield_guard.detector.fit import refine
from lishield_guard.detector.fold import candidate_periods, fold_match, refine_period
from lishield_guard.detector.numerics import LOOKALIKE_DOMINANT_RHO, steady_rho
from lishield_guard.detector.profiles import block_row_profiles, merge_blocks
from lishield_guard.detector.results import FoldResult, SpecMatch, Stage, SweepResult
from lishield_guard.detector.rules import (
    fold_passes,
    grid_passes,
    sweep_passes,
    tone_check_on,
    tone_fit_confirms,
)
from lishield_guard.detector.screen import screen_plane
from lishield_guard.detector.sweep import sweep_match
from lishield_guard.detector.tones import match_spec, scale_range_cpr_per_hz
from lishield_guard.detector.tracks import PlaneAnalysis, analyse_profiles
from lishield_guard.detector.usable import full_scale_of
from lishield_guard.spec import BarcodeSpec

__all__ = ["WHITE_LIGHT_LEAK", "analyse_plane", "axis_sweeps", "decide_axis", "fold_info",
           "scaled_detector", "screen_specs", "search_periods", "spec_planes", "white_twin"]

FIT_STARTS = 3  # best grid periods per spec channel refined with the exact capture model
FIT_SUB_BLOCKS = 4  # sweep and fit weight n_col_blocks x this many column sub-blocks
MIN_SLOTS_IN_FRAME = 2.0  # sweep/fit periods must leave two slots (two tones) in the frame:
#                           one tone is what a steady light shows
FIT_MIN_GRID_RHO = 0.55  # grid fits below this are not refined (dev set: with quiet-weighted
#                          sub-blocks, true periods started from grid fits of rho 0.6-0.7)
WHITE_LIGHT_LEAK = 1.0  # an exact fit's chroma leak from here up is a white light: stripes alike
#                         in every colour plane leak sqrt 2 (`fit.chroma_leak`), an RGB light's
#                         own-plane stripes about 0



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


def decide_axis(planes: dict[str, PlaneAnalysis], specs, det: DetectorConfig,
                grid_cpr: tuple[float, ...] = (), screens: dict | None = None,
                all_specs=()) -> list[tuple[str, SpecMatch]]:
    """Match every spec whose planes are available on one axis: tone tracks (confirmed by an
    exact fit of the spec when ``tone_min_fit_gain`` is set), then folding, then the period
    sweep (computed once per axis for all specs, when first needed). ``screens``: first-stage
    results already computed for some of the planes (`screen_specs`), filled in place.
    ``all_specs``: every configured (policy id, spec); a white light matched by one channel
    of an RGB spec is named for the mono spec among them with that channel's tones
    (`white_twin`)."""
    out = []
    screens, screened = screen_specs(planes, specs, det, grid_cpr, screens)

    @cache
    def periods() -> list[float]:
        return search_periods(planes["L"], screened, det)

    @cache
    def sweeps(name: str) -> list[SweepResult]:
        # per spec, when first needed: a verdict reached on one spec spares the others
        return axis_sweeps(planes, [ps for ps in screened if ps[1].name == name], det,
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
            m = _fold_stage(m, spec, fold_info(spec, chans, periods(), det), det)
        if not m.protected and det.sweep is not None:
            m = _sweep_stage(m, spec, sweeps(spec.name), det)
            if m.protected and (twin := white_twin(m, spec, all_specs)) is not None:
                pid, mono = twin
                m = _sweep_stage(m, spec, sweeps(spec.name), det, name=mono.name)
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


def white_twin(m: SpecMatch, spec: BarcodeSpec, specs) -> tuple[str, BarcodeSpec] | None:
    """The (policy id, mono spec) a match of RGB ``spec`` is really evidence of: when its
    exact fit of one channel shows the same stripes in every colour plane (chroma leak at
    least `WHITE_LIGHT_LEAK`), a white light played that channel's tones, and the configured
    mono spec with those tones (the same ratios) is the one to name. None otherwise."""
    fit = None if m.sweep is None else m.sweep.fit
    if not spec.is_rgb or fit is None or fit.chroma_leak is None \
            or fit.chroma_leak < WHITE_LIGHT_LEAK:
        return None
    tones = np.sort(np.asarray(dict(spec.channels)[m.sweep.channel], dtype=float))
    for pid, other in specs:
        mono = np.sort(np.asarray(other.all_freqs_hz, dtype=float))
        if not other.is_rgb and mono.size == tones.size \
                and np.allclose(mono / mono[0], tones / tones[0], rtol=1e-6):
            return pid, other
    return None


def _sweep_stage(m: SpecMatch, spec: BarcodeSpec, entries: list[SweepResult],
                 det: DetectorConfig, name: str | None = None) -> SpecMatch:
    """``m`` after the period sweep and its exact fits (one entry per channel, ``entries``):
    protected when one passes `sweep_passes`; the stage named is the one that passed. A
    protected match is named ``name`` when given (`white_twin`), else ``spec``."""
    passing = [e for e in entries if sweep_passes(e, det)]
    sw = max(passing or entries, key=lambda e: (grid_passes(e, det),
                                                e.rho - e.rho_lookalike),
             default=None)
    if sw is None:
        return m
    if not passing:
        return replace(m, sweep=sw, stage=Stage.SWEEP if sw.fit is None else Stage.EXACT_FIT)
    name = name or spec.name
    if not grid_passes(sw, det):
        fit = sw.fit
        leak = fit.chroma_leak
        reason = (f"{name}'s exact capture model ({sw.channel}: period "
                  f"{fit.period_rows:.1f} rows, {fit.cycles_f1:.2f} "
                  f"cycles of f_1 per slot, exposure {fit.exposure_slots:.2f} slot, "
                  f"{fit.n_periods:.2f} periods in the frame) "
                  f"fits the rows ({fit.domain}, rho={fit.rho:.3f}) {fit.gain:.1f}x "
                  f"better than any steady square wave (look-alike rho="
                  f"{fit.rho_lookalike:.3f}), with the same amplitude in every "
                  f"column block (t={fit.coherence_t:.1f})"
                  + ("" if leak is None else
                     f" and in its own colour plane only (chroma leak {leak:.2f})"
                     if leak < WHITE_LIGHT_LEAK else
                     f" and alike in every colour plane (chroma leak {leak:.2f}: a white "
                     f"light)"))
        return replace(m, spec=name, protected=True, reason=reason, sweep=sw,
                       stage=Stage.EXACT_FIT)
    reason = (f"{name}'s pattern ({sw.channel}), tiled every "
              f"{sw.match.period_rows:.1f} rows ({sw.match.n_periods:.2f} periods in the "
              f"frame), fits the stripes (rho={sw.rho:.2f}, look-alike "
              f"{sw.rho_lookalike:.2f}) with the same amplitude in every column "
              f"block (t={sw.coherence_t:.1f})")
    return replace(m, spec=name, protected=True, reason=reason, sweep=sw, stage=Stage.SWEEP)


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


def axis_sweeps(planes: dict[str, PlaneAnalysis], specs, det: DetectorConfig,
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


def search_periods(luma: PlaneAnalysis, specs, det: DetectorConfig) -> list[float]:
    if luma.common is None or not specs:
        return []
    ranges = [_period_range_rows(s, det) for _, s in specs]
    lo = min(r[0] for r in ranges)
    hi = max(r[1] for r in ranges)
    x = luma.common.astype(np.float64)
    coarse = candidate_periods(x, min_rows=max(lo, 4.0), max_rows=hi)
    return [refine_period(x, p) for p in coarse]


def fold_info(spec: BarcodeSpec, chans: dict[str, PlaneAnalysis], periods: list[float],
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


