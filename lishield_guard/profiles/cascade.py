"""The cascade profile: the pattern search the learned decision replaced, kept as a named profile.

Per axis (rows, then columns), the planes are analysed on first use (`search.analyse_plane`:
row profiles and frequency tracks) and `search.decide_axis` runs the stages in order: the
first stage, tone tracks, folding, the period sweep and its exact fit, each judged by the pass
rules of `rules`. Detection (`measure`, `decide`) analyses lazily: mono specs on luma first,
RGB specs with the colour planes only when luma is not decisive, the columns only when the rows
found no barcode. Calibration measures every plane up front (`collect_record`) and decides on
that record (`decide_record`, `sweep_fits`, `fold_fits`), with the same stages.
"""

from __future__ import annotations

from dataclasses import dataclass

from lishield_guard.config import AppConfig
from lishield_guard.decode import Decoded
from lishield_guard.decode import decode as decode_source
from lishield_guard.detector.results import FoldResult, SpecMatch, Stage, SweepResult
from lishield_guard.detector.screen import jpeg_grid_cpr
from lishield_guard.detector.search import (
    analyse_plane,
    axis_sweeps,
    decide_axis,
    fold_info,
    scaled_detector,
    screen_specs,
    search_periods,
    spec_planes,
)
from lishield_guard.detector.spectra import AXIS_NAMES, axis_too_small
from lishield_guard.detector.tracks import PlaneAnalysis
from lishield_guard.detector.usable import unusable_reason
from lishield_guard.profiles import name_of
from lishield_guard.verdict import (
    Evidence,
    Looked,
    Timer,
    Verdict,
    looked_at_image,
    undetermined,
)

__all__ = ["MAX_CANDIDATES", "NAME", "UNIT", "CascadeEvidence", "CascadeRecord",
           "collect_record", "decide", "decide_record", "decode", "fold_fits", "measure",
           "required", "sweep_fits"]

NAME = name_of(__name__)
UNIT = "tones"  # what `Verdict.matches` counts when no pattern stage decided
MIN_ROWS = 64  # shorter profiles cannot hold two cycles of the lowest tone at any scale
MIN_ACROSS = 64  # fewer pixels across the lines cannot fill 8 column blocks of 8 pixels: the
#                  column-coherence tests that tell LED stripes from texture have nothing to use
MAX_CANDIDATES = 6  # (axis, spec) candidates the verdict's evidence lists


def required(config: AppConfig) -> int:
    """Tones a monochrome barcode must show (``tones.min_tones``)."""
    return config.detector.tones.min_tones


def decode(source, config: AppConfig) -> Decoded:
    """``source`` decoded at reduced JPEG scale (``profiles.max_decode_rows``), with its colour
    planes at once when an RGB spec is configured (one decode instead of luma, then colour)."""
    det = config.detector
    return decode_source(source, limits=config.limits, fast=det.profiles.fast_decode,
                         want_rgb=any(s.is_rgb for p in config.policies for s in p.specs),
                         max_rows=det.profiles.max_decode_rows)


@dataclass(frozen=True)
class CascadeRecord:
    """Every plane the cascade decides on, analysed up front (calibration's record).

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

    def with_false_prob(self, false_prob: float) -> CascadeRecord:
        """The same record judged at another per-frame false-pass probability."""
        axes = {a: {k: pa.with_false_prob(false_prob) for k, pa in planes.items()}
                for a, planes in self.axes.items()}
        return CascadeRecord(axes, self.row_scale, self.orientation, self.format, self.skipped)


@dataclass(frozen=True)
class _Lazy(Looked):
    """What `measure` leaves for `decide` in detection: the decoded image, analysed by the
    stages as they need it (as `Looked`: why it cannot be analysed at all)."""

    decoded: Decoded | None = None


def measure(decoded: Decoded, config: AppConfig, timer: Timer) -> _Lazy:
    """The usable-frame check; the planes themselves are analysed as `decide` needs them."""
    det = config.detector
    with timer("profile_luma"):  # a frame the test cannot run on is undetermined, never clean
        why = unusable_reason(decoded.luma, n_col_blocks=det.profiles.n_col_blocks,
                              axes=(0, 1) if det.profiles.orientations == "both" else (0,),
                              min_lines=MIN_ROWS, min_across=MIN_ACROSS,
                              colour_planes=decoded.colour_planes if decoded.is_color else None)
    return _Lazy(looked_at_image(decoded), (), why, decoded.luma, decoded)


def decide(record: _Lazy, config: AppConfig, timer: Timer) -> Verdict:
    """The stages, lazily, on the planes of the decoded image as they are needed."""
    decoded = record.decoded
    if record.why is not None:
        return record.undetermined(profile=NAME, required=required(config), timings_ms=timer.ms)
    skipped: list[str] = []
    if decoded.row_scale > 1:
        skipped.append(f"full resolution: JPEG decoded at 1/{decoded.row_scale:g} scale in the "
                       f"DCT domain (stripes need rows, not pixels)")
    if decoded.orientation in (5, 6, 7, 8) and config.detector.profiles.orientations == "both":
        skipped.append(f"EXIF orientation {decoded.orientation}: stored rows are sensor rows, "
                       f"analysed first")
    return _run_stages(_analysed_axes(decoded, config, timer, skipped), config,
                       row_scale=decoded.row_scale, fmt=decoded.format,
                       orientation=decoded.orientation, skipped=skipped, timer=timer,
                       lazy=True, looked_at=record.looked_at)


def _analysed_axes(decoded: Decoded, config: AppConfig, timer: Timer, skipped: list[str]):
    """Per configured axis (rows, then columns), analysed on first use: (axis name, planes
    holding luma ``"L"``, ``colour()`` adding the R, G, B planes when the image has colour and
    returning the planes). Axes too small to analyse (`spectra.axis_too_small`, the learned
    profile's size rule) are named in ``skipped`` instead."""
    for axis in (0, 1) if config.detector.profiles.orientations == "both" else (0,):
        name = AXIS_NAMES[axis]
        if (why := axis_too_small(decoded.luma.shape, axis)) is not None:
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


def collect_record(decoded: Decoded, config: AppConfig) -> CascadeRecord:
    """Every plane on every configured axis, analysed up front (for calibration sweeps;
    detection analyses lazily, with the same `search.analyse_plane`)."""
    skipped: list[str] = []
    has_rgb = any(s.is_rgb for p in config.policies for s in p.specs)
    axes = {name: colour() if has_rgb else planes
            for name, planes, colour in _analysed_axes(decoded, config, Timer(), skipped)}
    return CascadeRecord(axes, decoded.row_scale, decoded.orientation, decoded.format,
                         tuple(skipped))


def decide_record(record: CascadeRecord, config: AppConfig) -> Verdict:
    """The cascade's verdict from a precomputed record (no decoding, no profiling):
    `_run_stages` over every plane of every axis, every spec at once."""
    axes = ((name, planes, None) for name, planes in record.axes.items())
    return _run_stages(axes, config, row_scale=record.row_scale, fmt=record.format,
                       orientation=record.orientation, skipped=list(record.skipped),
                       timer=Timer(), lazy=False, looked_at="a precomputed record")


def _screened_axes(record: CascadeRecord, config: AppConfig):
    """Per axis of ``record`` with luma: (axis name, planes, detector settings, the (policy
    id, spec) pairs the first stage passes, their candidate periods), as `decide_record`
    sees them."""
    det = scaled_detector(config.detector, record.row_scale)
    all_specs = [(p.id, s) for p in config.policies for s in p.specs]
    for axis_name, planes in record.axes.items():
        if "L" not in planes:
            continue
        _, specs = screen_specs(planes, all_specs, det, record.grid_cpr)
        yield axis_name, planes, det, specs, search_periods(planes["L"], specs, det)


def sweep_fits(record: CascadeRecord, config: AppConfig
               ) -> list[tuple[str, str, SweepResult]]:
    """Unthresholded period-sweep fits of every spec the first stage passes, on every axis, as
    (axis name, policy id, entry) (for calibration sweeps; the specs and candidate periods
    `decide_record` searches)."""
    out = []
    for axis_name, planes, det, specs, periods in _screened_axes(record, config):
        sweeps = axis_sweeps(planes, specs, det, periods)
        for pid, spec in specs:
            out += [(axis_name, pid, entry) for entry in sweeps[spec.name]]
    return out


def fold_fits(record: CascadeRecord, config: AppConfig) -> list[tuple[str, str, FoldResult]]:
    """Unthresholded fold fits of every spec the first stage passes, on every axis, as (axis
    name, policy id, fit) (for calibration sweeps; the specs and candidate periods
    `decide_record` searches)."""
    out = []
    for axis_name, planes, det, specs, periods in _screened_axes(record, config):
        for pid, spec in specs:
            chans = spec_planes(spec, planes)
            fold = fold_info(spec, chans, periods, det) if chans else None
            if fold is not None:
                out.append((axis_name, pid, fold))
    return out


def _run_stages(axes, config: AppConfig, *, row_scale: float, fmt: str, orientation: int,
                skipped: list[str], timer: Timer, lazy: bool, looked_at: str) -> Verdict:
    """The stages on each axis in turn (`search.decide_axis`), and the Verdict: the one
    orchestration of detection (`decide`, lazy) and of `decide_record` (calibration).

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
    analysed: dict[str, dict] = {}
    for name, planes, colour in axes:
        skipped.extend(f"{name}: {s}" for s in planes["L"].skipped)
        with timer("match"):
            screens: dict = {}  # luma is screened once, for the mono and the RGB specs
            found = decide_axis(planes, first, det, grid, screens, all_specs=specs)
        if rgb and not any(m.protected for _, m in found):
            # Colour planes whenever luma is not decisive: an RGB barcode's channels can
            # cancel in luma (measured: gating them on luma stripes lost 27/400 positives).
            planes = colour()
            with timer("match"):
                found += decide_axis(planes, rgb, det, grid, screens, all_specs=specs)
        elif rgb:
            skipped.append(f"{name}: colour planes (luma verdict certain)")
        analysed[name] = planes
        candidates += [(name, pid, m) for pid, m in found]
        if lazy and any(m.protected for _, m in found):
            if name == AXIS_NAMES[0] and det.profiles.orientations == "both":
                skipped.append("columns: verdict certain from rows")
            break
    return _verdict(candidates, analysed, config, skipped, timer.ms, orientation, fmt,
                    looked_at, row_scale)


def _verdict(candidates, analysed: dict, config: AppConfig, skipped: list[str],
             timings: dict, orientation: int, fmt: str, looked_at: str,
             row_scale: float) -> Verdict:
    if not candidates:  # the detector could not look: undetermined, never clean
        why = (f"image too small: fewer than {MIN_ROWS} lines of at least {MIN_ACROSS} "
               f"pixels on every analysed axis (" + "; ".join(skipped) + ")" if skipped
               else "nothing analysable")
        return undetermined(why, looked_at=looked_at, profile=NAME, required=required(config),
                            skipped=skipped, timings_ms=timings)
    axis, pid, m = max(candidates, key=lambda c: (c[2].protected, c[2].score, c[2].n_matched))
    # the evidence lists MAX_CANDIDATES: most tones first, then those the search looked at
    tried = sorted(({"axis": a, "policy": p, **c.to_dict()} for a, p, c in candidates),
                   key=lambda d: (-d["n_matched"], d["stage"] == Stage.FIRST, -d["purity"]))
    ev = CascadeEvidence(m.reason, axis, m, tuple(tried[:MAX_CANDIDATES]), orientation, fmt,
                         analysed[axis], config.detector, row_scale)
    # matches / required count the deciding stage's evidence: tones for the tone tracks, one
    # pattern fit of one needed for folding, the sweep and the exact fit
    pattern = m.protected and m.stage != Stage.TONES
    return Verdict(protected=m.protected, policy=pid if m.protected else None,
                   matches=1 if pattern else m.n_matched, required=1 if pattern else m.required,
                   evidence=ev, skipped=tuple(skipped), timings_ms=timings, profile=NAME,
                   score=m.score)


@dataclass(frozen=True, eq=False)
class CascadeEvidence(Evidence):
    """The cascade's evidence: the candidate that decided, those it tried, and its planes.

    Attributes
    ----------
    reason : str
        The deciding stage's reason.
    axis : str
        ``"rows"`` or ``"columns"``: where the deciding candidate was found.
    best : SpecMatch
        The deciding candidate (or the closest one): its tone match and pattern fits.
    candidates : tuple of dict
        The candidates the search looked at (JSON-ready), most tones first.
    orientation : int
        The source's EXIF orientation.
    format : str
        The source's container format.
    planes : dict
        Plane name -> `PlaneAnalysis` of the deciding axis: the record the figure draws.
    detector : DetectorConfig
        The settings the pass rules held the fits against (for the figure's thresholds).
    row_scale : float
        Stored rows per analysed row.
    """

    reason: str
    axis: str
    best: SpecMatch
    candidates: tuple
    orientation: int
    format: str
    planes: dict
    detector: object
    row_scale: float = 1.0

    @property
    def stage(self) -> Stage:
        """The stage that decided (or looked last)."""
        return self.best.stage

    @property
    def spec(self) -> str:
        """The named spec: the deciding candidate's (`search.white_twin` names a white
        light's mono spec)."""
        return self.best.spec

    def to_dict(self) -> dict:
        """The JSON of the evidence (``best`` and ``candidates`` as `SpecMatch.to_dict`)."""
        return {"reason": self.reason, "axis": self.axis, "stage": self.best.stage,
                "best": self.best.to_dict(), "candidates": list(self.candidates),
                "orientation_exif": self.orientation, "format": self.format}

    def counts(self, verdict: Verdict) -> str:
        """``1/1 pattern fit (stage)`` when a pattern stage flagged it, else the tones."""
        if verdict.protected and self.stage != Stage.TONES:
            return f"{verdict.matches}/{verdict.required} pattern fit ({self.stage})"
        return f"{verdict.matches}/{verdict.required} {UNIT} required"

    def caption(self, verdict: Verdict) -> str:
        """`plot.cascade_caption`."""
        from lishield_guard.plot import cascade_caption

        return cascade_caption(self, verdict.status)

    def figure(self, verdict: Verdict, config):
        """`plot.cascade_figure`, from the deciding axis' planes."""
        from lishield_guard.plot import cascade_figure

        return cascade_figure(verdict, self, config)

