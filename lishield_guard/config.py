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

__all__ = [
    "AppConfig",
    "DetectorConfig",
    "Limits",
    "Policy",
    "default_config",
    "dump_config",
    "load_config",
    "merge_tables",
]

DEFAULT_CONFIG_RESOURCE = "default.toml"
FIT_RHO_FLOOR = 0.8  # detector.fit: below this fit rho the look-alike is not fitted (gain 0)
PERIODIC_MIN_PERIODS = 2.0  # pattern periods a frame must hold for the fit_*_periodic path


@dataclass(frozen=True)
class DetectorConfig:
    """Every tunable number of the detector. Profiles: ``"default"`` and ``"paper"``.

    The field defaults are the shipped, calibrated ``lishield_guard/data/default.toml``
    (``DetectorConfig() == default_config().detector``; a test keeps the two equal).

    Paper profile (Algorithm 1, Sec. 5 and 7.3)
    -------------------------------------------
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

    Default profile
    ---------------
    n_col_blocks : int
        Full-height column blocks whose row profiles must agree (the LED is the same in every
        column; scene texture is not).
    min_row_rate_hz, max_row_rate_hz : float
        Plausible sensor row rates; with ``max_downscale`` they bound the band in cycles/row.
    max_downscale : float
        Largest factor by which an upload may have been shrunk (>= 1).
    peak_false_prob : float
        Probability that one spectral bin of pure noise passes the significance test.
    tone_rel_tol : float
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
    orientations : {"both", "rows"}
        Also analyse columns, so rotation baked into pixels is still detected.
    fold_min_rho : float
        Pattern folding (detector/fold.py): smallest normalised correlation between the folded row
        signal and a spec's template that counts as that barcode (unitless, 0-1).
    fold_min_snr : float
        Pattern folding: the folded pattern's power over its noise power must exceed this.
    fold_min_margin : float
        Pattern folding: the spec's template must beat the best stationary look-alike (k equal
        square or sine cycles per period: PWM, mains, periodic texture) by this much rho.
    period_sweep : bool
        When folding finds nothing, slide each spec's template over the frame at every
        possible period (fold.sweep_match): catches barcodes whose frame holds under two
        pattern periods, at some cost in time.
    sweep_min_rho : float
        Period sweep: smallest normalised correlation of the tiled template with the rows.
    sweep_min_margin : float
        Period sweep: the template must beat the best stationary look-alike by this much rho.
    model_fit : bool
        Refine the sweep's best grid fits with the exact capture model (`fit.refine`):
        linear light, the pattern integrated over each row's exposure, continuous period,
        c_1, phase and exposure; the stationary look-alike is refined the same way.
    fit_min_rho : float
        Exact-model fit: smallest correlation of the template with the linear rows.
    fit_min_gain : float
        Exact-model fit: energy explained beyond the refined look-alike over the energy left
        unexplained, (rho^2 - rho_lookalike^2) / (1 - rho^2). The fit's coherence t must also
        reach ``sweep_min_coherence``.
    fit_min_rho_rgb, fit_min_gain_rgb, fit_max_leak_rgb : float
        A second, colour-verified way for a channel of an RGB barcode to pass: its fit needs
        only these rho and gain when the fitted template's amplitudes in the R, G, B planes
        point at its own channel (`fit.chroma_leak` <= ``fit_max_leak_rgb``; a grey
        scene's structure shows in all three planes alike, leak sqrt 2). 0 leak turns this
        path off.
    fit_min_rho_periodic, fit_min_gain_periodic : float
        A second way for an exact fit to pass when the frame holds at least
        `PERIODIC_MIN_PERIODS` (2) pattern periods: the template then repeats within the rows,
        so only rows that repeat (a periodic light or texture, which the stationary
        look-alike models) can fit it well, and a lower gain suffices. With fewer periods a
        one-period template bends to fit unrepeated scene rows (on natural scenes under
        steady light, such fits reach gains of 4-6 at rho >= 0.94). Gain inf turns this path
        off.
    sweep_min_coherence : float
        Period sweep: t statistic of the template's amplitude across column blocks (the LED
        adds the same log contrast to every block; scene structure does not).
    tone_min_fit_gain : float
        Tone tracks alone do not decide: a spec whose tones match on an axis is protected by
        them only when one of that spec's exact-model fits on the same axis (rho >= 0.8,
        coherence t >= ``sweep_min_coherence``) explains the rows at least this much better
        than the best steady square wave (the fit's gain). One steady tone whose frequency
        estimate jitters between windows, or a PWM light whose fundamental and harmonic
        dominate different parts of the frame, can look like two alternating tones; the
        look-alike fits those rows as well as the barcode. -inf turns the check off.
    screen_false_prob : float or None
        First stage: a plane goes on to the pattern search only when some short-time track
        has ``screen_min_frames`` frames whose peak passes the significance test at this
        per-frame false-pass probability (looser than ``peak_false_prob``, so every frame
        that the tone tracks count also passes the screen). None turns the screen off.
    screen_min_frames : int
        Frames a track must hold above the screen's threshold (>= 1).
    screen_partial_false_prob : float or None
        First stage, for a light covering part of the frame: a plane that fails the test on
        all its column blocks still passes when one half of its column sub-blocks (left,
        centre or right) has ``screen_partial_min_frames`` frames significant at this
        per-frame probability, shared by the three halves. None: halves are not tested.
    screen_partial_min_frames : int
        Frames a track of one half must hold above the halves' threshold (>= 1).
    fast_decode : bool
        Decode JPEG luma straight to gray with libjpeg-turbo (and colour only when needed);
        False decodes full colour with Pillow first (the reference the fast path is measured
        against).
    max_decode_rows : int
        JPEGs taller than twice this are decoded at 1/2, 1/4 or 1/8 scale in the DCT domain,
        keeping at least this many rows (0 disables). Row frequencies scale with it and the
        matcher accounts for the factor.
    """

    profile: Literal["default", "paper"] = "default"
    # --- paper profile
    n_block_rows: int = 4
    n_block_cols: int = 4
    nominal_row_rate_hz: float = 30_000.0
    band_hz: tuple[float, float] = (400.0, 15_000.0)
    max_peaks: int = 2
    ratio_tol: float = 0.05
    gamma: float = 0.1
    m_att: int = 2
    # --- default profile
    n_col_blocks: int = 8
    min_row_rate_hz: float = 30_000.0
    max_row_rate_hz: float = 120_000.0
    max_downscale: float = 4.0
    peak_false_prob: float = 0.001
    tone_rel_tol: float = 0.05
    min_tones: int = 2
    min_tones_rgb: int = 3
    min_occupancy: float = 0.08
    max_occupancy: float = 0.8
    min_purity: float = 0.3
    orientations: Literal["both", "rows"] = "both"
    fold_min_rho: float = 0.85
    fold_min_snr: float = 30.0
    fold_min_margin: float = 0.05
    period_sweep: bool = True
    sweep_min_rho: float = 0.7
    sweep_min_margin: float = 0.3
    sweep_min_coherence: float = 3.0
    model_fit: bool = True
    fit_min_rho: float = 0.9
    fit_min_gain: float = 8.0
    fit_min_rho_rgb: float = 0.85
    fit_min_gain_rgb: float = 1.0
    fit_max_leak_rgb: float = 0.3
    fit_min_rho_periodic: float = 0.85
    fit_min_gain_periodic: float = 2.0
    tone_min_fit_gain: float = 0.5
    screen_false_prob: float | None = 0.01
    screen_min_frames: int = 2
    screen_partial_false_prob: float | None = 1e-3
    screen_partial_min_frames: int = 3
    fast_decode: bool = True
    max_decode_rows: int = 768

    def __post_init__(self) -> None:
        if self.profile not in ("default", "paper"):
            raise ConfigError(f"profile must be 'default' or 'paper', got {self.profile!r}")
        object.__setattr__(self, "band_hz", tuple(float(b) for b in self.band_hz))
        for name in ("n_block_rows", "n_block_cols", "max_peaks", "n_col_blocks", "min_tones",
                     "min_tones_rgb"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ConfigError(f"need integer {name} >= 1, got {name}={v!r}")
        if self.m_att < 0:
            raise ConfigError(f"need m_att >= 0, got m_att={self.m_att!r}")
        lo, hi = self.band_hz
        if not 0 < lo < hi:
            raise ConfigError(f"need 0 < band_hz[0] < band_hz[1], got band_hz={self.band_hz!r}")
        if not 0 < self.min_row_rate_hz < self.max_row_rate_hz:
            raise ConfigError(f"need 0 < min_row_rate_hz={self.min_row_rate_hz!r} < "
                              f"max_row_rate_hz={self.max_row_rate_hz!r}")
        if self.max_downscale < 1:
            raise ConfigError(f"need max_downscale >= 1, got {self.max_downscale!r}")
        if not 0 < self.peak_false_prob < 1:
            raise ConfigError(f"need 0 < peak_false_prob < 1, got {self.peak_false_prob!r}")
        if not 0 <= self.min_occupancy < self.max_occupancy <= 1:
            raise ConfigError(f"need 0 <= min_occupancy={self.min_occupancy!r} < "
                              f"max_occupancy={self.max_occupancy!r} <= 1")
        for name in ("fold_min_rho", "sweep_min_rho", "sweep_min_margin"):
            v = getattr(self, name)
            if not (math.isfinite(v) and -1 <= v <= 2):
                raise ConfigError(f"need {name} in [-1, 2], got {name}={v!r}")
        if not (math.isfinite(self.fit_min_rho) and FIT_RHO_FLOOR <= self.fit_min_rho <= 1):
            raise ConfigError(f"need {FIT_RHO_FLOOR} <= fit_min_rho <= 1 (look-alikes are only "
                              f"fitted above {FIT_RHO_FLOOR}), got {self.fit_min_rho!r}")
        for name in ("fit_min_rho_rgb", "fit_min_rho_periodic"):
            v = getattr(self, name)
            if not (math.isfinite(v) and FIT_RHO_FLOOR <= v <= 1):
                raise ConfigError(f"need {FIT_RHO_FLOOR} <= {name} <= 1, got {v!r}")
        for name in ("fit_min_gain", "fit_min_gain_rgb", "fit_min_gain_periodic"):
            if math.isnan(getattr(self, name)):
                raise ConfigError(f"need a number (or inf: no exact-model verdicts) for {name}, "
                                  f"got nan")
        if math.isnan(self.tone_min_fit_gain) or self.tone_min_fit_gain == math.inf:
            raise ConfigError(f"need tone_min_fit_gain < inf (-inf: off), got "
                              f"{self.tone_min_fit_gain!r}")
        if self.screen_false_prob is not None and not 0 < self.screen_false_prob < 1:
            raise ConfigError(f"need 0 < screen_false_prob < 1 (or None: no screen), got "
                              f"screen_false_prob={self.screen_false_prob!r}")
        if (self.screen_partial_false_prob is not None
                and not 0 < self.screen_partial_false_prob < 1):
            raise ConfigError(f"need 0 < screen_partial_false_prob < 1 (or None: halves not "
                              f"tested), got screen_partial_false_prob="
                              f"{self.screen_partial_false_prob!r}")
        for name in ("screen_min_frames", "screen_partial_min_frames"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ConfigError(f"need integer {name} >= 1, got {name}={v!r}")
        if not self.fit_max_leak_rgb >= 0:
            raise ConfigError(f"need fit_max_leak_rgb >= 0 (0: off), got "
                              f"{self.fit_max_leak_rgb!r}")
        for name in ("fold_min_snr", "sweep_min_coherence"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ConfigError(f"need a finite {name}, got {name}={v!r}")
        if not 0 <= self.min_purity <= 1:
            raise ConfigError(f"need 0 <= min_purity <= 1, got {self.min_purity!r}")
        for name in ("ratio_tol", "tone_rel_tol", "gamma", "nominal_row_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"need {name} > 0, got {name}={v!r}")
        if int(self.max_decode_rows) != self.max_decode_rows or self.max_decode_rows < 0:
            raise ConfigError(f"need integer max_decode_rows >= 0, got {self.max_decode_rows!r}")
        if self.orientations not in ("both", "rows"):
            raise ConfigError(f"orientations must be 'both' or 'rows', got {self.orientations!r}")

    def replace(self, **changes: Any) -> DetectorConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


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
    known = {"detector", "limits", "policies", "calibration"}
    unknown = set(table) - known
    if unknown:
        raise ConfigError(f"{source}: unknown top-level keys {sorted(unknown)!r}")
    det_fields = {f.name for f in dataclasses.fields(DetectorConfig)}
    det = table.get("detector", {})
    bad = set(det) - det_fields
    if bad:
        raise ConfigError(f"{source}: unknown [detector] keys {sorted(bad)!r}")
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
        return AppConfig(detector=DetectorConfig(**det), limits=Limits(**lim),
                         policies=tuple(policies), source=source, header=header)
    except TypeError as exc:  # wrong value types reach dataclass construction
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

    ``[detector]`` and ``[limits]`` are merged key by key (keys left out keep the shipped,
    calibrated values, never the dataclass defaults); a ``policies`` key, when present,
    replaces the shipped policies as a whole (``policies = []`` leaves none, which
    `load_config` refuses). Other top-level keys are taken from ``override``.

    Examples
    --------
    >>> merge_tables({"detector": {"a": 1, "b": 2}, "policies": [1]},
    ...              {"detector": {"b": 3}})
    {'detector': {'a': 1, 'b': 3}, 'policies': [1]}
    """
    out = {k: v for k, v in base.items() if k != "calibration"}
    for key, value in override.items():
        if key in ("detector", "limits") and isinstance(value, dict) \
                and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
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

    det = dataclasses.asdict(cfg.detector)
    det["band_hz"] = list(det["band_hz"])
    table = {
        "detector": det,
        "limits": dataclasses.asdict(cfg.limits),
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
