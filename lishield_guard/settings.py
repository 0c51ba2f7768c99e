"""The settings groups of the one config file: the detector's stages and video screening.

`lishield_guard.config` reads and writes them as TOML (and re-exports every name here); the
groups themselves only validate their own values.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from lishield_guard.errors import ConfigError
from lishield_guard.profiles import DEFAULT as DEFAULT_PROFILE
from lishield_guard.profiles import REGISTRY as PROFILES

__all__ = [
    "DetectorConfig",
    "FitConfig",
    "FoldConfig",
    "LearnedConfig",
    "PaperConfig",
    "ProfileConfig",
    "ScreenConfig",
    "SweepConfig",
    "ToneConfig",
    "VideoConfig",
    "VideoLimits",
]


FIT_RHO_FLOOR = 0.8  # detector.fit: below this fit rho the look-alike is not fitted (gain 0)
PERIODIC_MIN_PERIODS = 2.0  # pattern periods a frame must hold for the fit's periodic path
FINITE = 1e300  # bounds of a setting that must be finite


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


def _digest_ok(value: Any, name: str) -> None:
    """``value`` must be None or a ``sha256:<64 hex digits>`` model digest."""
    _need(value is None or (isinstance(value, str) and value.startswith("sha256:")
                            and len(value) == 71), f"{name} 'sha256:<hex>' or false", value)


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
    model_digest : str or None
        Digest (``sha256:<hex>``) of the weights ``threshold_logit`` was calibrated for;
        calibration writes it beside the threshold. A config whose digest is not that of the
        configured weights is refused when loaded (`lishield_guard.config.load_config`).
        None: not recorded (a config written before thresholds were bound to their model).
    first_look_ln : float or None
        The first look's threshold (`detector.firstlook`): an image whose largest whitened
        coherent luma power stays below this is clean without the full decision; the others
        go on to it. ln units over the noise floor. Set by calibration for the weights of
        ``model_digest``, below the smallest first-look peak of every image the full decision
        flags there, with a margin (`calibration.firstlook`). None (``false`` in TOML): no
        first look, every image goes on to the full decision (the safe value for weights it
        was not calibrated with).
    """

    threshold_logit: float = 4.386050705801313  # calibrate, 2026-11-27: see default.toml
    model: str | None = None
    min_explain_score: float = 1.0
    # the shipped weights' (data/decision_model.json), as default.toml records it
    model_digest: str | None = \
        "sha256:44eb5832a051b1b3fbfc27cc431176c014f91dd0780cdfaa45aa7cc22a46f6b2"
    first_look_ln: float | None = None

    def __post_init__(self) -> None:
        _number(self.threshold_logit, "learned.threshold_logit", -FINITE, FINITE)
        _number(self.min_explain_score, "learned.min_explain_score", -FINITE, FINITE)
        _need(self.model is None or (isinstance(self.model, str) and self.model),
              "learned.model a path or false", self.model)
        _digest_ok(self.model_digest, "learned.model_digest")
        if self.first_look_ln is not None:
            _need(not isinstance(self.first_look_ln, bool), "a number for learned."
                  "first_look_ln (or false: off)", self.first_look_ln)
            _number(self.first_look_ln, "learned.first_look_ln (or false: off)", -FINITE,
                    FINITE)


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

    ``profile`` names an entry of the profile registry (`lishield_guard.profiles`): the
    learned decision reads ``profiles`` and ``learned``; the cascade (the pattern search)
    ``profiles``, ``screen``, ``tones``, ``fold``, ``sweep`` and ``fit``, in that order; the
    paper's Algorithm 1 ``paper``. A stage set to None is off; so is an
    optional field set to None (in TOML: ``false``). The field defaults are the shipped,
    calibrated ``lishield_guard/data/default.toml`` (``DetectorConfig() ==
    default_config().detector``; a test keeps the two equal). Each group documents its fields.

    Dotted names (``"fit.min_gain"``) address one field (`values`, `with_values`); calibration
    sweeps and its reports use them.
    """

    profile: str = DEFAULT_PROFILE
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




@dataclass(frozen=True)
class VideoLimits:
    """Limits checked on a video's header before any frame is decoded, and on the decoding.

    max_bytes : int
        Largest encoded video accepted, in bytes.
    max_duration_s : float
        Longest video accepted, in seconds.
    max_frames : int
        Most frames a video may declare.
    max_frame_pixels : int
        Largest frame (width x height) accepted.
    max_decoded_frames : int
        Most frames decoded for one screen (the work bound: a frame between a keyframe and a
        screened frame counts too); the screen stops with what it has when it is reached.
    max_decoded_bytes : int
        Most bytes of decoded frames (YUV 4:2:0, 1.5 bytes per pixel) for one screen: for
        frames over 4K this bounds the decoding before `max_decoded_frames` does.
    """

    max_bytes: int = 512 * 1024 * 1024
    max_duration_s: float = 600.0
    max_frames: int = 36_000
    max_frame_pixels: int = 7680 * 4320
    max_decoded_frames: int = 240
    max_decoded_bytes: int = 1024 * 1024 * 1024

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            _need(v > 0 and (f.name.endswith("_s") or int(v) == v),
                  f"{f.name} > 0" + ("" if f.name.endswith("_s") else " (integer)"), v)


@dataclass(frozen=True)
class VideoConfig:
    """How a video is screened (see `lishield_guard.video.screen`).

    limits : VideoLimits
        Input limits.
    first_frames : int
        Frames screened first, spread over the clip.
    max_frames : int
        Most frames screened; the screen adds `first_frames` at a time (checkpoints) until the
        verdict is certain or this many were screened.
    min_frames : int
        Fewer screened frames than this make the verdict undetermined.
    threshold_logit : float
        The clip is protected when some window's logit, averaged over the screened frames,
        reaches this (checked at every checkpoint; calibrated: ``calibrate --videos``).
    clear_logit : float
        After a run, the clip is clean at once when its clip logit is below this (more frames
        would rarely change the verdict; calibrated with the threshold).
    frame_stride_s : float
        Runs started between keyframes (a clip with few keyframes) are at least this far
        apart, in seconds.
    max_rows : int
        Frames taller than twice this are scaled down by powers of two, keeping at least
        this many rows (0 keeps full size).
    model_digest : str or None
        Digest of the decision weights ``threshold_logit`` was calibrated for (written by
        ``calibrate-videos``; see `LearnedConfig.model_digest`). None: not recorded.
    """

    limits: VideoLimits = field(default_factory=VideoLimits)
    first_frames: int = 4
    max_frames: int = 16
    min_frames: int = 2
    threshold_logit: float = 2.5397  # the shipped calibration (data/default.toml)
    clear_logit: float = 1.0
    frame_stride_s: float = 0.1
    max_rows: int = 540
    model_digest: str | None = LearnedConfig.model_digest  # the shipped weights'

    def __post_init__(self) -> None:
        _need(1 <= self.min_frames <= self.first_frames <= self.max_frames,
              "1 <= min_frames <= first_frames <= max_frames",
              (self.min_frames, self.first_frames, self.max_frames))
        _need(self.clear_logit <= self.threshold_logit, "clear_logit <= threshold_logit",
              (self.clear_logit, self.threshold_logit))
        _need(self.frame_stride_s > 0, "frame_stride_s > 0", self.frame_stride_s)
        _need(int(self.max_rows) == self.max_rows and self.max_rows >= 0,
              "integer max_rows >= 0", self.max_rows)
        _digest_ok(self.model_digest, "video.model_digest")
