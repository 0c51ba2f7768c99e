"""Detector settings, input limits and policies, read from and written to one TOML file.

The same file is read by the CLI, the HTTP service and written by calibration (DESIGN.md).
Without ``--config`` the shipped ``lishield_guard/data/default.toml`` applies.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lishield_guard.errors import ConfigError, SpecError
from lishield_guard.spec import PRESETS, BarcodeSpec
from lishield_guard.video.settings import VideoConfig, VideoLimits

__all__ = [
    "AppConfig",
    "DetectorConfig",
    "FitConfig",
    "FoldConfig",
    "LearnedConfig",
    "PaperConfig",
    "ProfileConfig",
    "ScreenConfig",
    "SweepConfig",
    "ToneConfig",
    "Limits",
    "Policy",
    "default_config",
    "dump_config",
    "load_config",
    "merge_tables",
]

DEFAULT_CONFIG_RESOURCE = "default.toml"
FIT_RHO_FLOOR = 0.8  # detector.fit: below this fit rho the look-alike is not fitted (gain 0)
PERIODIC_MIN_PERIODS = 2.0  # pattern periods a frame must hold for the fit's periodic path
FINITE = 1e300  # bounds of a setting that must be finite
PROFILES = ("default", "cascade", "paper")  # detector profiles: learned, pattern search, paper


def _need(ok: bool, what: str, value: Any) -> None:
    """Raise a ConfigError naming ``what`` and the value given unless ``ok``."""
    if not ok:
        raise ConfigError(f"need {what}, got {value!r}")


def _count(value: Any, name: str) -> None:
    """``value`` must be an integer >= 1."""
    _need(isinstance(value, (int, float)) and int(value) == value and value >= 1,
          f"integer {name} >= 1", value)


def _prob(value: Any, name: str) -> None:
    """``value`` must lie strictly between 0 and 1."""
    _need(isinstance(value, (int, float)) and 0 < value < 1, f"0 < {name} < 1", value)


def _number(value: Any, name: str, lo: float = -math.inf, hi: float = math.inf) -> None:
    """``value`` must be a number in [lo, hi] (not nan; finite unless a bound is infinite)."""
    ok = isinstance(value, (int, float)) and lo <= value <= hi
    _need(ok, f"{name} in [{lo:g}, {hi:g}]" if math.isfinite(lo) or math.isfinite(hi)
          else f"a number for {name}", value)


class _Group:
    """Shared behaviour of the detector's per-stage settings."""

    def replace(self, **changes: Any):
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class PaperConfig(_Group):
    """The paper profile: Algorithm 1 (Sec. 5 and 7.3).

    n_block_rows, n_block_cols : int
        n_br x n_bc block grid (paper: n_b = 4).
    nominal_row_rate_hz : float
        f_s used to turn FFT bins into Hz (paper: 30 kHz).
    band_hz : (float, float)
        Peaks are picked in this band (paper: 400 Hz - 15 kHz).
    max_peaks : int
        M_p strongest peaks per block (paper: 2).
    ratio_tol : float
        T_b, absolute tolerance on a ratio, unitless (paper: 0.05).
    gamma : float
        gamma of M_b = ceil(gamma * M_R + M_att) (paper: 2 x 5% = 0.1).
    m_att : int
        M_att, ratios an exposure attack may remove (paper: 2).
    """

    n_block_rows: int = 4
    n_block_cols: int = 4
    nominal_row_rate_hz: float = 30_000.0
    band_hz: tuple[float, float] = (400.0, 15_000.0)
    max_peaks: int = 2
    ratio_tol: float = 0.05
    gamma: float = 0.1
    m_att: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "band_hz", tuple(float(b) for b in self.band_hz))
        for name in ("n_block_rows", "n_block_cols", "max_peaks"):
            _count(getattr(self, name), f"paper.{name}")
        _need(int(self.m_att) == self.m_att and self.m_att >= 0, "integer paper.m_att >= 0",
              self.m_att)
        lo, hi = self.band_hz
        _need(0 < lo < hi, "0 < paper.band_hz[0] < paper.band_hz[1]", self.band_hz)
        for name in ("ratio_tol", "gamma", "nominal_row_rate_hz"):
            v = getattr(self, name)
            _need(math.isfinite(v) and v > 0, f"paper.{name} > 0", v)


@dataclass(frozen=True)
class ProfileConfig(_Group):
    """Decode and row profiles, shared by every stage of the default profile.

    n_col_blocks : int
        Full-height column blocks whose row profiles must agree (the LED is the same in every
        column; scene texture is not).
    min_row_rate_hz, max_row_rate_hz : float
        Plausible sensor row rates; with ``max_downscale`` they bound the band in cycles/row.
    max_downscale : float
        Largest factor by which an upload may have been shrunk (>= 1).
    orientations : {"both", "rows"}
        Also analyse columns, so rotation baked into pixels is still detected.
    fast_decode : bool
        Decode JPEG luma straight to gray with libjpeg-turbo (and colour only when needed);
        False decodes full colour with Pillow first (the reference the fast path is measured
        against).
    max_decode_rows : int
        JPEGs taller than twice this are decoded at 1/2, 1/4 or 1/8 scale in the DCT domain,
        keeping at least this many rows (0 disables). Row frequencies scale with it and the
        matcher accounts for the factor.
    """

    n_col_blocks: int = 8
    min_row_rate_hz: float = 30_000.0
    max_row_rate_hz: float = 120_000.0
    max_downscale: float = 4.0
    orientations: Literal["both", "rows"] = "both"
    fast_decode: bool = True
    max_decode_rows: int = 768

    def __post_init__(self) -> None:
        _count(self.n_col_blocks, "profiles.n_col_blocks")
        _need(0 < self.min_row_rate_hz < self.max_row_rate_hz,
              "0 < profiles.min_row_rate_hz < profiles.max_row_rate_hz",
              (self.min_row_rate_hz, self.max_row_rate_hz))
        _need(self.max_downscale >= 1, "profiles.max_downscale >= 1", self.max_downscale)
        _need(self.orientations in ("both", "rows"), "profiles.orientations 'both' or 'rows'",
              self.orientations)
        _need(int(self.max_decode_rows) == self.max_decode_rows and self.max_decode_rows >= 0,
              "integer profiles.max_decode_rows >= 0", self.max_decode_rows)


@dataclass(frozen=True)
class ScreenConfig(_Group):
    """The first stage (`detector.screen`): a plane goes on to the pattern search only when
    some short-time track holds column-coherent stripes.

    false_prob : float
        A track must have ``min_frames`` frames whose peak passes the significance test at
        this per-frame false-pass probability (looser than ``tones.peak_false_prob``, so every
        frame that the tone tracks count also passes the screen).
    min_frames : int
        Frames a track must hold above the screen's threshold (>= 1).
    partial_false_prob : float or None
        For a light covering part of the frame: a plane that fails the test on all its column
        blocks still passes when one half of its column sub-blocks (left, centre or right)
        has ``partial_min_frames`` frames significant at this per-frame probability, shared
        by the three halves. None: halves are not tested.
    partial_min_frames : int
        Frames a track of one half must hold above the halves' threshold (>= 1).
    """

    false_prob: float = 0.01
    min_frames: int = 2
    partial_false_prob: float | None = 1e-3
    partial_min_frames: int = 3

    def __post_init__(self) -> None:
        _prob(self.false_prob, "screen.false_prob")
        if self.partial_false_prob is not None:
            _prob(self.partial_false_prob, "screen.partial_false_prob (or off)")
        _count(self.min_frames, "screen.min_frames")
        _count(self.partial_min_frames, "screen.partial_min_frames")


@dataclass(frozen=True)
class ToneConfig(_Group):
    """Tone tracks (`detector.tones`): a spec's tones matched on the band tracks.

    peak_false_prob : float
        Probability that one spectral bin of pure noise passes the significance test.
    rel_tol : float
        Relative tolerance between a detected tone and a preset tone at the fitted scale.
    min_tones : int
        Tones a monochrome barcode must show (M - 1 survives the exposure attack).
    min_tones_rgb : int
        Tones an RGB barcode must show over at least two colour channels.
    min_occupancy, max_occupancy : float
        A tone counts when the stripes hold its frequency in this fraction of the rows
        (unitless): enough to be real, little enough to be switched (a barcode shares the frame
        between M tones; mains and PWM flicker hold one frequency all frame long).
    min_purity : float
        Fraction of significant band samples the matched tones must explain (unitless).
    min_fit_gain : float or None
        Tone tracks alone do not decide: a spec whose tones match on an axis is protected by
        them only when one of that spec's exact-model fits on the same axis (rho >= 0.8,
        coherence t >= ``sweep.min_coherence``) explains the rows at least this much better
        than the best steady square wave (the fit's gain). One steady tone whose frequency
        estimate jitters between windows, or a PWM light whose fundamental and harmonic
        dominate different parts of the frame, can look like two alternating tones; the
        look-alike fits those rows as well as the barcode. None: the tones decide alone (also
        when the sweep or the fit is off).
    """

    peak_false_prob: float = 0.001
    rel_tol: float = 0.05
    min_tones: int = 2
    min_tones_rgb: int = 3
    min_occupancy: float = 0.08
    max_occupancy: float = 0.8
    min_purity: float = 0.3
    min_fit_gain: float | None = 0.5

    def __post_init__(self) -> None:
        _prob(self.peak_false_prob, "tones.peak_false_prob")
        _need(math.isfinite(self.rel_tol) and self.rel_tol > 0, "tones.rel_tol > 0",
              self.rel_tol)
        _count(self.min_tones, "tones.min_tones")
        _count(self.min_tones_rgb, "tones.min_tones_rgb")
        _need(0 <= self.min_occupancy < self.max_occupancy <= 1,
              "0 <= tones.min_occupancy < tones.max_occupancy <= 1",
              (self.min_occupancy, self.max_occupancy))
        _number(self.min_purity, "tones.min_purity", 0.0, 1.0)
        if self.min_fit_gain is not None:
            _need(isinstance(self.min_fit_gain, (int, float))
                  and math.isfinite(self.min_fit_gain),
                  "a finite tones.min_fit_gain (or off)", self.min_fit_gain)


@dataclass(frozen=True)
class FoldConfig(_Group):
    """Pattern folding (`detector.fold`).

    min_rho : float
        Smallest normalised correlation between the folded row signal and a spec's template
        that counts as that barcode (unitless, 0-1).
    min_snr : float
        The folded pattern's power over its noise power must exceed this.
    min_margin : float
        The spec's template must beat the best stationary look-alike (k equal square or sine
        cycles per period: PWM, mains, periodic texture) by this much rho.
    """

    min_rho: float = 0.85
    min_snr: float = 30.0
    min_margin: float = 0.05

    def __post_init__(self) -> None:
        _number(self.min_rho, "fold.min_rho", -1.0, 2.0)
        _number(self.min_snr, "fold.min_snr", -FINITE, FINITE)
        _number(self.min_margin, "fold.min_margin", -FINITE, FINITE)


@dataclass(frozen=True)
class SweepConfig(_Group):
    """The period sweep (`detector.sweep`): each spec's template slid over the frame at every
    possible period; catches barcodes whose frame holds under two pattern periods.

    min_rho : float
        Smallest normalised correlation of the tiled template with the rows.
    min_margin : float
        The template must beat the best stationary look-alike by this much rho.
    min_coherence : float
        t statistic of the template's amplitude across column blocks (the LED adds the same
        log contrast to every block; scene structure does not); the exact fit's too.
    """

    min_rho: float = 0.7
    min_margin: float = 0.3
    min_coherence: float = 3.0

    def __post_init__(self) -> None:
        _number(self.min_rho, "sweep.min_rho", -1.0, 2.0)
        _number(self.min_margin, "sweep.min_margin", -1.0, 2.0)
        _number(self.min_coherence, "sweep.min_coherence", -FINITE, FINITE)


@dataclass(frozen=True)
class FitConfig(_Group):
    """The exact-model fit (`detector.fit.refine`) of the sweep's best grid fits: linear
    light, the pattern integrated over each row's exposure, continuous period, c_1, phase and
    exposure; the stationary look-alike is refined the same way. Every path needs the fit's
    coherence t to reach ``sweep.min_coherence``.

    min_rho : float
        Smallest correlation of the template with the linear rows.
    min_gain : float
        Energy explained beyond the refined look-alike over the energy left unexplained,
        (rho^2 - rho_lookalike^2) / (1 - rho^2); inf: this path never passes.
    min_rho_rgb, min_gain_rgb : float
        A second, colour-verified way for a channel of an RGB barcode to pass ...
    max_leak_rgb : float or None
        ... when the fitted template's amplitudes in the R, G, B planes point at its own
        channel (`fit.chroma_leak` <= this; a grey scene's structure shows in all three planes
        alike, leak sqrt 2). None: no colour-verified path.
    min_rho_periodic : float
        A third way to pass when the frame holds at least `PERIODIC_MIN_PERIODS` (2) pattern
        periods: the template then repeats within the rows, so only rows that repeat (a
        periodic light or texture, which the stationary look-alike models) can fit it well,
        and a lower gain suffices. With fewer periods a one-period template bends to fit
        unrepeated scene rows (on natural scenes under steady light, such fits reach gains
        of 4-6 at rho >= 0.94).
    min_gain_periodic : float or None
        The periodic path's gain; None: no periodic path.
    matched_refit : bool
        Refit the best fit on matched-filter block weights (blocks weighted by how much of the
        fitted template they show: a partly lit frame's lit blocks count most).
    """

    min_rho: float = 0.9
    min_gain: float = 8.0
    min_rho_rgb: float = 0.85
    min_gain_rgb: float = 1.0
    max_leak_rgb: float | None = 0.3
    min_rho_periodic: float = 0.85
    min_gain_periodic: float | None = 2.0
    matched_refit: bool = True

    def __post_init__(self) -> None:
        for name in ("min_rho", "min_rho_rgb", "min_rho_periodic"):
            _number(getattr(self, name), f"fit.{name} (look-alikes are only fitted above "
                    f"{FIT_RHO_FLOOR})", FIT_RHO_FLOOR, 1.0)
        _number(self.min_gain, "fit.min_gain (inf: this path off)", -math.inf, math.inf)
        _number(self.min_gain_rgb, "fit.min_gain_rgb", -math.inf, math.inf)
        if self.max_leak_rgb is not None:
            _number(self.max_leak_rgb, "fit.max_leak_rgb (or off)", 0.0, math.inf)
        if self.min_gain_periodic is not None:
            _number(self.min_gain_periodic, "fit.min_gain_periodic (or off)", -math.inf,
                    math.inf)


@dataclass(frozen=True)
class LearnedConfig(_Group):
    """The default profile's decision: the learned score (`detector.learned`) and its threshold.

    threshold_logit : float
        An image is protected when its decision logit (the largest window logit of the
        network) reaches this; chosen by calibration on the tuning part of the clean set and
        certified on the disjoint certification part. Unitless (log-odds).
    model : str or None
        Path of decision weights (``.npz`` with its ``.json`` card beside it); None uses the
        weights shipped in ``lishield_guard/data``.
    min_explain_score : float
        A flagged image's best spec must reach this template score (mean whitened log power
        at its tones, ln units) for the reason to name its tones; below it the reason says the
        network decided without a clear tone match. Unitless.
    """

    threshold_logit: float = 4.491605468030307  # calibrate, 2026-11-26: see default.toml
    model: str | None = None
    min_explain_score: float = 1.0

    def __post_init__(self) -> None:
        _number(self.threshold_logit, "learned.threshold_logit", -FINITE, FINITE)
        _number(self.min_explain_score, "learned.min_explain_score", -FINITE, FINITE)
        _need(self.model is None or (isinstance(self.model, str) and self.model),
              "learned.model a path or false", self.model)


STAGES: dict[str, type] = {"profiles": ProfileConfig, "learned": LearnedConfig,
                           "screen": ScreenConfig, "tones": ToneConfig, "fold": FoldConfig,
                           "sweep": SweepConfig, "fit": FitConfig, "paper": PaperConfig}


def _optional(fields) -> set[str]:
    """Names of the dataclass ``fields`` whose type admits None (None: off)."""
    return {f.name for f in fields if "None" in str(f.type)}


# (stage, field) pairs that None (``false`` in TOML) turns off
OPTIONAL_FIELDS = {(name, f) for name, cls in STAGES.items()
                   for f in _optional(dataclasses.fields(cls))}


@dataclass(frozen=True)
class DetectorConfig:
    """Every tunable number of the detector, grouped by the stage that reads it.

    Profiles: ``"default"`` (the learned decision: ``profiles``, ``learned``), ``"cascade"``
    (the pattern search, stages in order: ``profiles``, ``screen``, ``tones``, ``fold``,
    ``sweep``, ``fit``) and ``"paper"`` (``paper``). A stage set to None is off; so is an
    optional field set to None (in TOML: ``false``). The field defaults are the shipped,
    calibrated ``lishield_guard/data/default.toml`` (``DetectorConfig() ==
    default_config().detector``; a test keeps the two equal). Each group documents its fields.

    Dotted names (``"fit.min_gain"``) address one field (`values`, `with_values`); calibration
    sweeps and its reports use them.
    """

    profile: Literal["default", "cascade", "paper"] = "default"
    profiles: ProfileConfig = field(default_factory=ProfileConfig)
    learned: LearnedConfig = field(default_factory=LearnedConfig)
    screen: ScreenConfig | None = field(default_factory=ScreenConfig)
    tones: ToneConfig = field(default_factory=ToneConfig)
    fold: FoldConfig | None = field(default_factory=FoldConfig)
    sweep: SweepConfig | None = field(default_factory=SweepConfig)
    fit: FitConfig | None = field(default_factory=FitConfig)
    paper: PaperConfig = field(default_factory=PaperConfig)

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ConfigError(f"profile must be one of {', '.join(map(repr, PROFILES))}, got "
                              f"{self.profile!r}")
        for name, cls in STAGES.items():
            group = getattr(self, name)
            if isinstance(group, dict):  # built from a table: validated by the group
                object.__setattr__(self, name, _group_from_table(cls, group, name))
            elif group is None and name not in OPTIONAL_STAGES:
                raise ConfigError(f"the {name} settings cannot be off")
            elif group is not None and not isinstance(group, cls):
                raise ConfigError(f"{name}: need a table of settings, got {group!r}")

    def replace(self, **changes: Any) -> DetectorConfig:
        """A copy with some groups (or the profile) changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def with_values(self, values: dict[str, Any]) -> DetectorConfig:
        """A copy with fields changed by dotted name (``{"fit.min_gain": 5.0}``)."""
        by_group: dict[str, dict[str, Any]] = {}
        top: dict[str, Any] = {}
        for key, value in values.items():
            group, dot, name = key.partition(".")
            if not dot:
                top[key] = value
                continue
            if group not in STAGES:
                raise ConfigError(f"unknown detector setting {key!r}")
            by_group.setdefault(group, {})[name] = value
        for group, changes in by_group.items():
            current = getattr(self, group)
            if current is None:
                raise ConfigError(f"cannot set {sorted(changes)!r} of {group}: the stage is off")
            top[group] = current.replace(**changes)
        return self.replace(**top)

    def values(self) -> dict[str, Any]:
        """Every field by dotted name (a stage that is off: its name -> None)."""
        out: dict[str, Any] = {"profile": self.profile}
        for name in STAGES:
            group = getattr(self, name)
            if group is None:
                out[name] = None
            else:
                out.update({f"{name}.{k}": v for k, v in dataclasses.asdict(group).items()})
        return out


OPTIONAL_STAGES = _optional(dataclasses.fields(DetectorConfig))  # stages that can be off


def _group_from_table(cls: type, table: dict, name: str):
    """One stage's settings from its TOML table (``false`` for an optional field: None)."""
    known = {f.name for f in dataclasses.fields(cls)}
    bad = set(table) - known
    if bad:
        raise ConfigError(f"unknown [detector.{name}] keys {sorted(bad)!r}; known: "
                          f"{', '.join(sorted(known))}")
    kwargs = {}
    for key, value in table.items():
        if value is False and (name, key) in OPTIONAL_FIELDS:
            value = None
        kwargs[key] = value
    return cls(**kwargs)


# flat [detector] keys of config files written before the settings were grouped
LEGACY_KEYS: dict[str, str] = {
    **{k: f"paper.{k}" for k in ("n_block_rows", "n_block_cols", "nominal_row_rate_hz",
                                  "band_hz", "max_peaks", "ratio_tol", "gamma", "m_att")},
    **{k: f"profiles.{k}" for k in ("n_col_blocks", "min_row_rate_hz", "max_row_rate_hz",
                                     "max_downscale", "orientations", "fast_decode",
                                     "max_decode_rows")},
    "peak_false_prob": "tones.peak_false_prob", "tone_rel_tol": "tones.rel_tol",
    "min_tones": "tones.min_tones", "min_tones_rgb": "tones.min_tones_rgb",
    "min_occupancy": "tones.min_occupancy", "max_occupancy": "tones.max_occupancy",
    "min_purity": "tones.min_purity", "tone_min_fit_gain": "tones.min_fit_gain",
    "screen_false_prob": "screen.false_prob", "screen_min_frames": "screen.min_frames",
    "screen_partial_false_prob": "screen.partial_false_prob",
    "screen_partial_min_frames": "screen.partial_min_frames",
    "fold_min_rho": "fold.min_rho", "fold_min_snr": "fold.min_snr",
    "fold_min_margin": "fold.min_margin",
    "sweep_min_rho": "sweep.min_rho", "sweep_min_margin": "sweep.min_margin",
    "sweep_min_coherence": "sweep.min_coherence",
    **{f"fit_{k}": f"fit.{k}" for k in ("min_rho", "min_gain", "min_rho_rgb", "min_gain_rgb",
                                         "max_leak_rgb", "min_rho_periodic",
                                         "min_gain_periodic")},
}


def _is_flat(det: dict) -> bool:
    """Whether a ``[detector]`` table uses the flat keys of an earlier version."""
    return any(k in LEGACY_KEYS or k in ("period_sweep", "model_fit") for k in det)


def _ungroup_legacy(det: dict, source: str) -> dict:
    """A flat ``[detector]`` table of an earlier version as grouped tables; the old ways of
    saying "off" (``period_sweep = false``, ``model_fit = false``, ``tone_min_fit_gain =
    -inf``, ``fit_max_leak_rgb = 0``, ``fit_min_gain_periodic = inf``) become ``false``."""
    out: dict[str, Any] = {}
    for key, value in det.items():
        if key in LEGACY_KEYS:
            group, name = LEGACY_KEYS[key].split(".")
            if (key, value) in (("tone_min_fit_gain", -math.inf), ("fit_max_leak_rgb", 0),
                                ("fit_min_gain_periodic", math.inf)):
                value = False
            if isinstance(out.get(group), dict) or group not in out:
                out.setdefault(group, {})[name] = value
        elif key in ("period_sweep", "model_fit"):
            if value is False:
                out["sweep" if key == "period_sweep" else "fit"] = False
        elif key == "profile":
            out[key] = value
        else:
            raise ConfigError(f"{source}: unknown [detector] key {key!r}")
    return out


@dataclass(frozen=True)
class Limits:
    """Input limits enforced before and during decoding.

    max_pixels : int
        Largest width x height accepted (decompression-bomb guard).
    max_bytes : int
        Largest encoded input accepted, in bytes.
    max_decode_bytes : int
        Memory budget of one detection, in bytes: its peak is estimated from the header
        (pixels actually decoded, after any DCT-domain downscaling, times the measured bytes
        per pixel of the decode path) and checked before any pixel is decoded.
    """

    max_pixels: int = 100_000_000
    max_bytes: int = 64 * 1024 * 1024
    max_decode_bytes: int = 1024 * 1024 * 1024

    def __post_init__(self) -> None:
        for name in ("max_pixels", "max_bytes", "max_decode_bytes"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ConfigError(f"need integer {name} >= 1, got {name}={v!r}")


@dataclass(frozen=True)
class Policy:
    """A policy id (e.g. ``no-distribution``) and the barcodes that signal it."""

    id: str
    specs: tuple[BarcodeSpec, ...]
    description: str = ""

    def __post_init__(self) -> None:
        if not self.id or not isinstance(self.id, str):
            raise ConfigError(f"policy id must be a non-empty string, got {self.id!r}")
        if not self.specs:
            raise ConfigError(f"policy {self.id!r} needs at least one barcode spec")

    def ratio_values(self) -> np.ndarray:
        """S_b: the union of every spec's ratio values, ascending, unitless."""
        return np.unique(np.concatenate([s.ratio_values() for s in self.specs]))

    def to_dict(self) -> dict:
        """JSON-ready description (used by the service's /v1/policies)."""
        return {"id": self.id, "description": self.description,
                "specs": [s.to_dict() for s in self.specs],
                "ratios": [round(float(r), 6) for r in self.ratio_values()]}


@dataclass(frozen=True)
class AppConfig:
    """Everything one TOML config file holds."""

    detector: DetectorConfig = field(default_factory=DetectorConfig)
    limits: Limits = field(default_factory=Limits)
    policies: tuple[Policy, ...] = ()
    source: str = field(default="<built-in>", compare=False)
    video: VideoConfig = field(default_factory=VideoConfig)
    header: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        ids = [p.id for p in self.policies]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"duplicate policy ids in {ids!r}")


def _spec_from_entry(entry: Any, where: str) -> BarcodeSpec:
    if isinstance(entry, str):
        try:
            return PRESETS[entry]
        except KeyError:
            raise ConfigError(f"{where}: unknown preset {entry!r}; known: "
                              f"{', '.join(PRESETS)}") from None
    if isinstance(entry, dict):
        try:
            return BarcodeSpec.from_dict(entry)
        except SpecError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
    raise ConfigError(f"{where}: a spec is a preset name or a table, got {entry!r}")


def _build(table: dict, *, source: str, header: str = "") -> AppConfig:
    try:
        return _build_checked(table, source=source, header=header)
    except ConfigError:
        raise
    except (TypeError, ValueError, AttributeError) as exc:  # wrong value types in the file
        raise ConfigError(f"{source}: invalid value: {exc}") from exc


def _build_checked(table: dict, *, source: str, header: str = "") -> AppConfig:
    known = {"detector", "limits", "policies", "calibration", "video"}
    unknown = set(table) - known
    if unknown:
        raise ConfigError(f"{source}: unknown top-level keys {sorted(unknown)!r}")
    det = _detector_from_table(table.get("detector", {}), source)
    lim = table.get("limits", {})
    bad = set(lim) - {f.name for f in dataclasses.fields(Limits)}
    if bad:
        raise ConfigError(f"{source}: unknown [limits] keys {sorted(bad)!r}")
    policies = []
    for i, p in enumerate(table.get("policies", [])):
        where = f"{source}: policies[{i}]"
        if not isinstance(p, dict) or "id" not in p:
            raise ConfigError(f"{where}: each policy needs an 'id'")
        specs = [_spec_from_entry(e, where) for e in p.get("presets", [])]
        specs += [_spec_from_entry(e, where) for e in p.get("specs", [])]
        policies.append(Policy(id=str(p["id"]), specs=tuple(specs),
                               description=str(p.get("description", ""))))
    try:
        return AppConfig(detector=det, limits=Limits(**lim), policies=tuple(policies),
                         source=source, header=header,
                         video=_video_from_table(table.get("video", {}), source))
    except TypeError as exc:  # wrong value types reach dataclass construction
        raise ConfigError(f"{source}: {exc}") from exc


def _video_from_table(video: Any, source: str) -> VideoConfig:
    """The VideoConfig of a ``[video]`` table (with its ``[video.limits]``)."""
    if not isinstance(video, dict):
        raise ConfigError(f"{source}: [video] must be a table, got {video!r}")
    lim = video.get("limits", {})
    names = {f.name for f in dataclasses.fields(VideoConfig)}
    bad = sorted(set(video) - names) + [f"limits.{k}" for k in sorted(
        set(lim) - {f.name for f in dataclasses.fields(VideoLimits)})]
    if bad:
        raise ConfigError(f"{source}: unknown [video] keys {bad!r}")
    rest = {k: v for k, v in video.items() if k != "limits"}
    return VideoConfig(limits=VideoLimits(**lim), **rest)


def _detector_from_table(det: Any, source: str) -> DetectorConfig:
    """The DetectorConfig of a ``[detector]`` table: grouped tables (a stage or an
    optional field set to ``false`` is off) or the flat keys of an earlier version."""
    if not isinstance(det, dict):
        raise ConfigError(f"{source}: [detector] must be a table, got {det!r}")
    if _is_flat(det):
        det = _ungroup_legacy(det, source)
    known = {"profile", *STAGES}
    bad = set(det) - known
    if bad:
        raise ConfigError(f"{source}: unknown [detector] keys {sorted(bad)!r}; known: "
                          f"{', '.join(sorted(known))}")
    out: dict[str, Any] = {}
    for key, value in det.items():
        if key in OPTIONAL_STAGES and value is False:
            out[key] = None
        elif key in STAGES and not isinstance(value, dict):
            raise ConfigError(f"{source}: [detector.{key}] must be a table"
                              + (" or false (off)" if key in OPTIONAL_STAGES else "")
                              + f", got {value!r}")
        else:
            out[key] = value
    try:
        return DetectorConfig(**out)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _read_table(path: str | Path | None) -> tuple[dict, str, str]:
    """(TOML table, source label, header comment lines) of a config file; None: shipped."""
    if path is None:
        text = resources.files("lishield_guard.data").joinpath(DEFAULT_CONFIG_RESOURCE).read_text()
        source = "default.toml"
    else:
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            why = getattr(exc, "strerror", None) or str(exc)
            raise ConfigError(f"cannot read config file {str(p)!r}: {why}") from exc
        source = str(p)
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from exc
    header = "\n".join(ln for ln in text.splitlines() if ln.startswith("#"))
    return table, source, header


def merge_tables(base: dict, override: dict) -> dict:
    """A user's config table laid over the shipped one.

    ``[limits]``, ``[video]`` (with ``[video.limits]``) and each ``[detector.<stage>]`` table
    are merged key by key (keys left out
    keep the shipped, calibrated values, never the dataclass defaults; a stage set to
    ``false`` is off; flat ``[detector]`` keys of earlier versions are read as their groups'),
    and a ``policies`` key, when present,
    replaces the shipped policies as a whole (``policies = []`` leaves none, which
    `load_config` refuses). Other top-level keys are taken from ``override``.

    Examples
    --------
    >>> merge_tables({"detector": {"fit": {"min_rho": 0.9, "min_gain": 8.0}}, "policies": [1]},
    ...              {"detector": {"fit": {"min_gain": 5.0}}})
    {'detector': {'fit': {'min_rho': 0.9, 'min_gain': 5.0}}, 'policies': [1]}
    """
    out = {k: v for k, v in base.items() if k != "calibration"}
    for key, value in override.items():
        if key == "limits" and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        elif key == "video" and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value, "limits": {**out[key].get("limits", {}),
                                                         **value.get("limits", {})}}
        elif key == "detector" and isinstance(value, dict) \
                and isinstance(out.get(key), dict):
            if _is_flat(value):
                value = _ungroup_legacy(value, "config")
            merged = dict(out[key])
            for k, v in value.items():
                both = isinstance(v, dict) and isinstance(merged.get(k), dict)
                merged[k] = {**merged[k], **v} if both else v
            out[key] = merged
        else:
            out[key] = value
    return out


def load_config(path: str | Path | None = None, *, merge: bool = True) -> AppConfig:
    """Read a TOML config file laid over the shipped default; ``None`` reads the shipped default.

    Parameters
    ----------
    path : str or Path, optional
        A user's config file. It may hold only the keys it changes: the rest, policies
        included, comes from the shipped calibrated ``default.toml`` (see `merge_tables`).
    merge : bool
        False reads the file alone (missing keys take the dataclass defaults); for tools that
        inspect one file as written.

    Raises
    ------
    ConfigError
        If the file is missing, is not valid TOML, holds unknown keys or bad values, or leaves
        no policy to screen for (a screening tool with nothing to look for would call every
        image clean).
    """
    table, source, header = _read_table(path)
    if path is not None and merge:
        table = merge_tables(_read_table(None)[0], table)
    cfg = _build(table, source=source, header=header)
    if not cfg.policies:
        raise ConfigError(f"{source}: no policy defined (policies = [] or none given): every "
                          f"image would be reported clean; add a [[policies]] table or leave "
                          f"'policies' out to keep the shipped ones")
    return cfg


_cached_default: AppConfig | None = None


def default_config() -> AppConfig:
    """The shipped default config, read once."""
    global _cached_default
    if _cached_default is None:
        _cached_default = load_config(None)
    return _cached_default


def dump_config(cfg: AppConfig, *, header: str = "") -> str:
    """Serialise a config to TOML text; ``header`` lines are written as leading comments."""
    import tomli_w

    det: dict[str, Any] = {"profile": cfg.detector.profile}
    for name in STAGES:
        group = getattr(cfg.detector, name)
        det[name] = False if group is None else {
            k: (False if v is None else list(v) if isinstance(v, tuple) else v)
            for k, v in dataclasses.asdict(group).items()}
    table = {
        "detector": det,
        "limits": dataclasses.asdict(cfg.limits),
        "video": dataclasses.asdict(cfg.video),
        "policies": [],
    }
    for p in cfg.policies:
        entry: dict[str, Any] = {"id": p.id, "description": p.description}
        presets = [s.name for s in p.specs if PRESETS.get(s.name) == s]
        custom = [s.to_dict() for s in p.specs if PRESETS.get(s.name) != s]
        if presets:
            entry["presets"] = presets
        if custom:
            entry["specs"] = custom
        table["policies"].append(entry)
    lines = [f"# {ln}" if ln and not ln.startswith("#") else ln for ln in header.splitlines()]
    body = tomli_w.dumps(table)
    return ("\n".join(lines) + "\n\n" if lines else "") + body
