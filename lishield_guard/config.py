"""The one TOML config file: policies and every settings group, read, checked and written.

The same file is read by the CLI, the HTTP service and written by calibration (DESIGN.md).
Without ``--config`` the shipped ``lishield_guard/data/default.toml`` applies. The settings
groups themselves live in `lishield_guard.settings` (re-exported here); a config whose
thresholds were calibrated for other decision weights is refused when loaded (`load_config`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lishield_guard import settings
from lishield_guard.data_files import CONFIG_FILE, file_digest, weights_path
from lishield_guard.errors import ConfigError, SpecError
from lishield_guard.settings import *  # noqa: F403 - the settings groups, re-exported here
from lishield_guard.settings import (
    FIT_RHO_FLOOR,
    OPTIONAL_STAGES,
    PERIODIC_MIN_PERIODS,
    STAGES,
    DetectorConfig,
    VideoConfig,
    VideoLimits,
)
from lishield_guard.spec import PRESETS, BarcodeSpec

__all__ = [
    "FIT_RHO_FLOOR",
    "PERIODIC_MIN_PERIODS",
    "AppConfig",
    "Limits",
    "Policy",
    "check_model_binding",
    "default_config",
    "dump_config",
    "load_config",
    "merge_tables",
    *settings.__all__,  # every settings group (`lishield_guard.settings`)
]

DEFAULT_CONFIG_RESOURCE = CONFIG_FILE
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
    rest = {k: None if k == "model_digest" and v is False else v
            for k, v in video.items() if k != "limits"}
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


def check_model_binding(cfg: AppConfig, *, model_mismatch: Literal["error", "warn"] = "error"
                        ) -> None:
    """Refuse (or warn about) thresholds calibrated for weights other than the configured ones.

    Each digest a config records (``learned.model_digest`` beside ``learned.threshold_logit``,
    ``video.model_digest`` beside the clip threshold) must be that of the weights the config
    uses (``learned.model``, or the shipped ones). A digest that is not recorded is not
    checked; weights that cannot be read are left to the model loader to report.

    Raises
    ------
    ConfigError
        On a mismatch, unless ``model_mismatch="warn"`` (then a `UserWarning` says so).
    """
    wanted = {"learned.threshold_logit": cfg.detector.learned.model_digest,
              "video.threshold_logit": cfg.video.model_digest}
    if not any(wanted.values()):
        return
    path = weights_path(cfg.detector.learned.model)
    try:
        have = file_digest(path)
    except OSError:
        return
    for name, want in wanted.items():
        if want is None or want == have:
            continue
        what = "photo calibration (`lishield-guard calibrate`)" if name.startswith("learned") \
            else "clip calibration (`lishield-guard calibrate-videos`)"
        msg = (f"{cfg.source}: {name} was calibrated for decision weights {want[:19]}..., but "
               f"the configured weights {str(path)!r} are {have[:19]}...: its false-alarm rate "
               f"does not hold for them. Run the {what} again on these weights, or set "
               f"learned.model to the weights it was calibrated for")
        if model_mismatch != "warn":
            raise ConfigError(msg)
        warnings.warn(msg + " (loaded anyway: model_mismatch='warn')", UserWarning,
                      stacklevel=3)


def load_config(path: str | Path | None = None, *, merge: bool = True,
                model_mismatch: Literal["error", "warn"] = "error") -> AppConfig:
    """Read a TOML config file laid over the shipped default; ``None`` reads the shipped default.

    Parameters
    ----------
    path : str or Path, optional
        A user's config file. It may hold only the keys it changes: the rest, policies
        included, comes from the shipped calibrated ``default.toml`` (see `merge_tables`).
    merge : bool
        False reads the file alone (missing keys take the dataclass defaults); for tools that
        inspect one file as written.
    model_mismatch : {"error", "warn"}
        What a threshold calibrated for other decision weights than the configured ones does
        (`check_model_binding`): refuse the file (default), or load it with a warning.

    Raises
    ------
    ConfigError
        If the file is missing, is not valid TOML, holds unknown keys or bad values, leaves
        no policy to screen for (a screening tool with nothing to look for would call every
        image clean), or records thresholds of other decision weights.
    """
    table, source, header = _read_table(path)
    if path is not None and merge:
        table = merge_tables(_read_table(None)[0], table)
    cfg = _build(table, source=source, header=header)
    if not cfg.policies:
        raise ConfigError(f"{source}: no policy defined (policies = [] or none given): every "
                          f"image would be reported clean; add a [[policies]] table or leave "
                          f"'policies' out to keep the shipped ones")
    check_model_binding(cfg, model_mismatch=model_mismatch)
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
        "video": {k: False if v is None else v  # model_digest None: written false (not
                  for k, v in dataclasses.asdict(cfg.video).items()},  # recorded)
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
