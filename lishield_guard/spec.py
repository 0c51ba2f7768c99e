"""Barcode spec: which frequencies a LiShield LED plays, how it switches, and the ratios it encodes.

A barcode (paper Sec. 3.3.1 and 5) cycles each colour channel through M on-off-keyed tones
f_1 < f_2 < ... < f_M, holding each for one slot of 1/f_B seconds (f_B is the switching rate).
The whole pattern repeats every M/f_B seconds. Ratios between tones do not depend on the
camera's row rate, so the set of ratios (larger/smaller for every pair) is what a detector
looks for.

Slot semantics used project-wide (firmware and synth agree on it): in slot k of a pattern every
channel plays tone ``slot_order()[k]`` of its ascending tone list, as an on-off square wave of
duty ``duty``. ``phase`` says where that wave starts:

- ``"restart"`` (default): each slot restarts its tone at the start of an ON half-period;
- ``"continuous"``: each tone's timer runs on through the slots where it is silent, so at a slot
  start s (seconds from the loop start) the tone's phase is f_n * s mod 1 (ON while the phase is
  below ``duty``).

Either way the emitted loop starts over after M/f_B seconds (times ``n_patterns`` in the
firmware), so the light is exactly periodic.

What the firmware emits versus what a detector may assume
--------------------------------------------------------
`check_spec` holds the rules *our firmware* follows for a flicker-free light: f_B <= f_1
(``switching``) and f_B / M above ~80 Hz (``flicker``, paper Sec. 3.3.1). LEDs built by others
need not: the paper's own detection experiments (Sec. 7.3) switch three Table 1 tones at
f_B = 200 Hz (f_B / M = 66.7 Hz). Such specs are representable and compilable: pass
``allow=("flicker",)`` (and ``"switching"`` for f_B > f_1) to `check_spec`, `require_valid` or
`firmware.sequence.compile_spec`, and the rule is reported as a warning (a `SpecWarning` is
issued) instead of an error. A policy names only the ratio sets, M and on-off keying; switching
rate, phase mode, slot order and the LED's rise and fall times are properties of an emitter,
not of the policy.
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

from lishield_guard.errors import SpecError

if TYPE_CHECKING:  # numpy is imported where it is used: `spec list` and --help start fast
    import numpy as np

__all__ = [
    "EMITTER_RULES",
    "NOTE_RULES",
    "POLICY_RULES",
    "BarcodeSpec",
    "PRESETS",
    "Ratio",
    "SpecReport",
    "SpecWarning",
    "Violation",
    "check_spec",
    "get_preset",
    "require_valid",
]

CHANNEL_NAMES = ("W", "R", "G", "B")
DEFAULT_FLICKER_THRESHOLD_HZ = 80.0  # paper Sec. 3.3.1: f_th ~ 80 Hz
DEFAULT_MAX_FREQ_HZ = 15_000.0  # paper Sec. 5: Nyquist at the slowest (30 kHz) row rate
DEFAULT_RATIO_TOL = 0.05  # paper Sec. 7.3: T_b = 0.05 (absolute, unitless)
DEFAULT_MIN_READOUT_S = 0.010  # DESIGN.md: phones read a frame in roughly 10-35 ms
ORDER_NAMES = ("cyclic", "random")
PHASE_MODES = ("restart", "continuous")


class SpecWarning(UserWarning):
    """A spec breaks a rule that the caller allowed (e.g. ``flicker`` at f_B = 200 Hz)."""


@dataclass(frozen=True)
class Ratio:
    """One value of a barcode's ratio set and the tone pairs that produce it.

    Attributes
    ----------
    value : float
        larger / smaller, unitless, >= 1.
    pairs : tuple of ((channel, hz), (channel, hz))
        Each pair is (numerator tone, denominator tone).
    """

    value: float
    pairs: tuple[tuple[tuple[str, float], tuple[str, float]], ...]


@dataclass(frozen=True)
class BarcodeSpec:
    """A LiShield barcode: per-channel tone lists plus switching, duty and randomization.

    Parameters
    ----------
    name : str
        Identifier, e.g. ``"table1-seq1"``.
    channels : tuple of (channel, tuple of float)
        ``("W", (400.0, 600.0, 800.0))`` for monochrome, or one entry per ``R``/``G``/``B``.
        Frequencies in Hz, listed in any order; stored ascending. Every channel holds the same
        number M of tones.
    switching_hz : float or None
        Slot rate f_B in Hz. None means f_B = f_1, the lowest tone of all channels (paper default).
    duty : float
        ON fraction of each tone's period, in (0, 1). Default 0.5.
    intensity_levels : int
        K >= 1 ON levels for intensity randomization (paper Sec. 3.3.2); 1 disables it.
    order : {"cyclic", "random"} or tuple of int
        Slot order: ascending tones (``"cyclic"``), a permutation drawn from ``order_seed``
        (``"random"``), or an explicit permutation of ``range(M)``: tone indices into each
        channel's ascending tone list, one per slot, e.g. ``(2, 1, 0)`` for descending.
    order_seed : int or None
        Seed of the random slot order; required when ``order="random"``.
    phase : {"restart", "continuous"}
        Tone phase at a slot start: restart each tone ON at the slot start (default), or let
        each tone's timer run on from the loop start (phase f_n * t mod 1 at slot start t).
    """

    name: str
    channels: tuple[tuple[str, tuple[float, ...]], ...]
    switching_hz: float | None = None
    duty: float = 0.5
    intensity_levels: int = 1
    order: Literal["cyclic", "random"] | tuple[int, ...] = "cyclic"
    order_seed: int | None = None
    description: str = field(default="", compare=False)
    phase: Literal["restart", "continuous"] = "restart"

    def __post_init__(self) -> None:
        chans = tuple((str(c), tuple(sorted(float(f) for f in fs))) for c, fs in self.channels)
        object.__setattr__(self, "channels", chans)
        if not chans:
            raise SpecError("a spec needs at least one channel", rule="structure")
        names = [c for c, _ in chans]
        if len(set(names)) != len(names):
            raise SpecError(f"duplicate channel in {names!r}", rule="structure")
        bad = [c for c in names if c not in CHANNEL_NAMES]
        if bad:
            raise SpecError(f"unknown channel {bad!r}; use W, R, G or B", rule="structure")
        if "W" in names and len(names) > 1:
            raise SpecError("channel W (monochrome) cannot be mixed with R/G/B", rule="structure")
        counts = {len(fs) for _, fs in chans}
        if len(counts) != 1 or min(counts) < 1:
            raise SpecError(f"every channel needs the same number (>= 1) of tones, got "
                            f"{ {c: len(fs) for c, fs in chans} }", rule="structure")
        for c, fs in chans:
            if not all(math.isfinite(f) and f > 0 for f in fs):
                raise SpecError(f"channel {c} frequencies must be finite and > 0 Hz, got {fs!r}",
                                rule="structure")
        if self.switching_hz is not None and not (
            math.isfinite(self.switching_hz) and self.switching_hz > 0
        ):
            raise SpecError(f"need switching_hz > 0, got {self.switching_hz!r}", rule="structure")
        if not 0.0 < self.duty < 1.0:
            raise SpecError(f"need 0 < duty < 1, got duty={self.duty!r}", rule="structure")
        if int(self.intensity_levels) != self.intensity_levels or self.intensity_levels < 1:
            raise SpecError(f"need intensity_levels >= 1, got {self.intensity_levels!r}",
                            rule="structure")
        if isinstance(self.order, list | tuple):
            try:
                perm = tuple(int(i) for i in self.order)
            except (TypeError, ValueError):
                perm = None
            if perm is None or any(isinstance(i, bool) or int(i) != i for i in self.order) or \
                    sorted(perm) != list(range(len(chans[0][1]))):
                raise SpecError(f"an explicit order must be a permutation of range(M)="
                                f"range({len(chans[0][1])}), got order={self.order!r}",
                                rule="structure")
            object.__setattr__(self, "order", perm)
        elif self.order not in ORDER_NAMES:
            raise SpecError(f"order must be 'cyclic', 'random' or a permutation of tone "
                            f"indices, got {self.order!r}", rule="structure")
        if self.order == "random" and self.order_seed is None:
            raise SpecError("order='random' needs order_seed", rule="structure")
        if self.phase not in PHASE_MODES:
            raise SpecError(f"phase must be 'restart' or 'continuous', got {self.phase!r}",
                            rule="structure")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def mono(cls, name: str, freqs_hz, **kw) -> BarcodeSpec:
        """Monochrome spec (channel ``W``) with the given tones in Hz."""
        return cls(name=name, channels=(("W", tuple(freqs_hz)),), **kw)

    @classmethod
    def rgb(cls, name: str, red_hz, green_hz, blue_hz, **kw) -> BarcodeSpec:
        """RGB spec with one tone list per colour channel, in Hz."""
        return cls(name=name, channels=(("R", tuple(red_hz)), ("G", tuple(green_hz)),
                                        ("B", tuple(blue_hz))), **kw)

    # ------------------------------------------------------------------ derived values
    @property
    def channel_names(self) -> tuple[str, ...]:
        """Channel names in spec order."""
        return tuple(c for c, _ in self.channels)

    @property
    def is_rgb(self) -> bool:
        """True when the spec drives separate colour channels."""
        return self.channel_names != ("W",)

    @property
    def n_tones(self) -> int:
        """M, the number of tones (slots) per channel."""
        return len(self.channels[0][1])

    @property
    def all_freqs_hz(self) -> tuple[float, ...]:
        """Every tone of every channel, ascending, in Hz."""
        return tuple(sorted(f for _, fs in self.channels for f in fs))

    @property
    def f1_hz(self) -> float:
        """The lowest tone over all channels, in Hz."""
        return self.all_freqs_hz[0]

    @property
    def f_b_hz(self) -> float:
        """Switching rate f_B in Hz (slots per second)."""
        return float(self.switching_hz) if self.switching_hz is not None else self.f1_hz

    @property
    def slot_s(self) -> float:
        """Duration of one slot, 1/f_B, in seconds."""
        return 1.0 / self.f_b_hz

    @property
    def pattern_period_s(self) -> float:
        """Duration of the whole pattern, M/f_B, in seconds."""
        return self.n_tones / self.f_b_hz

    @property
    def lowest_side_lobe_hz(self) -> float:
        """Lowest non-DC side lobe f_B/M of the switching modulation, in Hz (Sec. 3.3.1)."""
        return self.f_b_hz / self.n_tones

    def slot_order(self) -> tuple[int, ...]:
        """Tone index (into each channel's ascending list) played in each slot of one pattern."""
        m = self.n_tones
        if isinstance(self.order, tuple):
            return self.order
        if self.order == "cyclic":
            return tuple(range(m))
        import numpy as np

        rng = np.random.default_rng(self.order_seed)
        return tuple(int(i) for i in rng.permutation(m))

    def ratios(self) -> tuple[Ratio, ...]:
        """The ratio set S_b: larger/smaller for every tone pair, within and across channels.

        Equal values (to 1e-9 relative) are merged into one `Ratio` listing every pair.
        """
        tones = [(c, f) for c, fs in self.channels for f in fs]
        raw: list[tuple[float, tuple[tuple[str, float], tuple[str, float]]]] = []
        for a, b in itertools.combinations(tones, 2):
            hi, lo = (a, b) if a[1] >= b[1] else (b, a)
            if lo[1] == hi[1]:
                continue
            raw.append((hi[1] / lo[1], (hi, lo)))
        raw.sort(key=lambda r: r[0])
        merged: list[Ratio] = []
        for value, pair in raw:
            if merged and abs(merged[-1].value - value) <= 1e-9 * value:
                merged[-1] = Ratio(merged[-1].value, merged[-1].pairs + (pair,))
            else:
                merged.append(Ratio(value, (pair,)))
        return tuple(merged)

    def ratio_values(self) -> np.ndarray:
        """Distinct ratio values of `ratios`, ascending, unitless."""
        import numpy as np

        return np.array([r.value for r in self.ratios()], dtype=float)

    def to_dict(self) -> dict:
        """JSON/TOML-ready description."""
        d: dict = {"name": self.name, "channels": {c: list(fs) for c, fs in self.channels},
                   "duty": self.duty, "intensity_levels": self.intensity_levels,
                   "order": list(self.order) if isinstance(self.order, tuple) else self.order}
        if self.phase != "restart":
            d["phase"] = self.phase
        if self.switching_hz is not None:
            d["switching_hz"] = self.switching_hz
        if self.order_seed is not None:
            d["order_seed"] = self.order_seed
        if self.description:
            d["description"] = self.description
        return d

    @classmethod
    def from_dict(cls, d: dict) -> BarcodeSpec:
        """Inverse of `to_dict`; raises SpecError naming a missing or unknown key."""
        known = {"name", "channels", "switching_hz", "duty", "intensity_levels", "order",
                 "order_seed", "description", "phase"}
        unknown = set(d) - known
        if unknown:
            raise SpecError(f"unknown spec keys {sorted(unknown)!r}", rule="structure")
        if "name" not in d or "channels" not in d:
            raise SpecError("a spec needs 'name' and 'channels'", rule="structure")
        chans = d["channels"]
        if not isinstance(chans, dict):
            raise SpecError("'channels' must map channel name to a list of Hz", rule="structure")
        kw = {k: d[k] for k in known - {"name", "channels"} if k in d}
        if isinstance(kw.get("order"), list):
            kw["order"] = tuple(kw["order"])
        spec = cls(name=str(d["name"]), channels=tuple((c, tuple(fs)) for c, fs in chans.items()),
                   **kw)
        # a spec read from a file is a barcode or nothing: the policy rules hold for every
        # reader (config loader, spec show, firmware), which therefore agree
        return require_valid(spec, rules=POLICY_RULES)


# ---------------------------------------------------------------------- validation
@dataclass(frozen=True)
class Violation:
    """One validation rule a spec breaks (``severity`` "error") or should note ("warning").

    ``allowed`` is True for an error-level rule demoted to a warning by ``check_spec(allow=...)``.
    """

    rule: str
    message: str
    severity: Literal["error", "warning"] = "error"
    allowed: bool = False


@dataclass(frozen=True)
class SpecReport:
    """Result of `check_spec`: every rule broken, plus warnings."""

    spec: BarcodeSpec
    violations: tuple[Violation, ...]

    @property
    def ok(self) -> bool:
        """True when no rule of severity "error" is broken: our firmware plays the spec (with
        the ``allow`` it was checked with), and so does every other tool."""
        return not any(v.severity == "error" for v in self.violations)

    @property
    def ok_as_policy(self) -> bool:
        """True when no `POLICY_RULES` rule is broken: the config loader accepts the spec as
        a policy's barcode (emitter rules do not bind LEDs built by others)."""
        return not any(v.severity == "error" and v.rule in POLICY_RULES
                       for v in self.violations)


RULES = ("switching", "flicker", "max_freq", "distinct_freqs", "ratios_distinct", "readout")
#: Rules without which a spec is no barcode at all: broken, it is refused everywhere (as a
#: policy by the config loader, by ``spec show`` and by the firmware compiler).
POLICY_RULES = ("max_freq", "distinct_freqs")
#: Rules of a flicker-free emitter, ours: the firmware compiler and ``spec show`` refuse a spec
#: that breaks them unless ``allow``-ed; a *policy* may name such a spec (the detector searches
#: emitters built by others, e.g. the paper's 200 Hz switching).
EMITTER_RULES = ("switching", "flicker")
#: Notes that never make a spec invalid: ``ratios_distinct`` (two of the spec's own ratios are
#: closer than the paper's T_b window; both belong to the same spec, so the policy is still
#: decided: 7 of the paper's 9 presets have such pairs) and ``readout``.
NOTE_RULES = ("ratios_distinct", "readout")


def check_spec(
    spec: BarcodeSpec,
    *,
    ratio_tol: float = DEFAULT_RATIO_TOL,
    flicker_threshold_hz: float = DEFAULT_FLICKER_THRESHOLD_HZ,
    max_freq_hz: float = DEFAULT_MAX_FREQ_HZ,
    min_readout_s: float = DEFAULT_MIN_READOUT_S,
    allow=(),
) -> SpecReport:
    """Check a spec against the paper's rules and report every one it breaks.

    Rules (names used in `Violation.rule` and `SpecError.rule`):

    - ``switching``: f_B <= f_1 (a slot must hold at least one period of its lowest tone).
    - ``flicker``: lowest side lobe f_B / M > ``flicker_threshold_hz`` (Hz).
    - ``max_freq``: highest tone <= ``max_freq_hz`` (Hz).
    - ``distinct_freqs``: no tone appears twice in one channel.
    - ``ratios_distinct`` (warning): two different ratio values differ by more than
      2 * ``ratio_tol`` (absolute, unitless; the paper's T_b window) so a measured ratio names
      one of them. Both ratios belong to this spec, so the policy is decided either way: a
      note, not an error (7 of the paper's 9 presets, among them the default policy's
      ``table2-rgb``, have such pairs at T_b = 0.05).
    - ``readout`` (warning): the pattern period M / f_B fits in ``min_readout_s`` seconds, so even
      a fast-readout frame holds every tone.

    ``switching`` and ``flicker`` are the rules of a flicker-free emitter (ours); an LED built
    by others may break them (the paper's Sec. 7.3 switches at f_B = 200 Hz, f_B / M = 66.7 Hz).
    Name them in ``allow`` (iterable of rule names) to report them with severity "warning".
    Rules that make a spec unplayable or undetectable (``max_freq``, ``distinct_freqs``) cannot
    be allowed.
    """
    allow = _check_allow(allow)
    out: list[Violation] = []
    if spec.f_b_hz > spec.f1_hz * (1 + 1e-12):
        out.append(Violation("switching", f"need f_B <= f_1, got f_B={spec.f_b_hz:g} Hz > "
                                          f"f_1={spec.f1_hz:g} Hz"))
    if spec.lowest_side_lobe_hz <= flicker_threshold_hz:
        out.append(Violation("flicker", f"lowest side lobe f_B/M={spec.lowest_side_lobe_hz:.1f} "
                                        f"Hz is not above flicker_threshold_hz="
                                        f"{flicker_threshold_hz:g} Hz"))
    top = spec.all_freqs_hz[-1]
    if top > max_freq_hz:
        out.append(Violation("max_freq", f"highest tone {top:g} Hz exceeds max_freq_hz="
                                         f"{max_freq_hz:g} Hz"))
    for c, fs in spec.channels:
        if len(set(fs)) != len(fs):
            out.append(Violation("distinct_freqs", f"channel {c} repeats a tone: {fs!r}"))
    values = spec.ratio_values()
    if values.size > 1:
        import numpy as np

        gaps = np.diff(values)
        i = int(np.argmin(gaps))
        if gaps[i] <= 2 * ratio_tol:
            out.append(Violation("ratios_distinct",
                                 f"ratios {values[i]:.4f} and {values[i + 1]:.4f} differ by "
                                 f"{gaps[i]:.4f} <= 2*ratio_tol={2 * ratio_tol:g}; a measured "
                                 f"ratio cannot tell them apart (both are this spec's, so the "
                                 f"policy is still decided)", "warning"))
    if spec.pattern_period_s > min_readout_s:
        out.append(Violation("readout", f"pattern period M/f_B={spec.pattern_period_s * 1e3:.2f} "
                                        f"ms exceeds a fast frame readout of "
                                        f"{min_readout_s * 1e3:g} ms; such a photo holds only "
                                        f"part of the cycle and may miss a tone", "warning"))
    out = [Violation(v.rule, v.message + " (allowed)", "warning", allowed=True)
           if v.rule in allow and v.severity == "error" else v for v in out]
    return SpecReport(spec, tuple(out))


ALLOWABLE_RULES = ("switching", "flicker", "ratios_distinct")


def _check_allow(allow) -> frozenset[str]:
    if isinstance(allow, str):
        allow = (allow,)
    allow = frozenset(str(a) for a in allow)
    bad = sorted(allow - set(ALLOWABLE_RULES))
    if bad:
        raise SpecError(f"allow names rules {bad!r} that cannot be allowed; allowable: "
                        f"{', '.join(ALLOWABLE_RULES)}", rule="allow")
    return allow


def require_valid(spec: BarcodeSpec, *, rules=EMITTER_RULES + POLICY_RULES, allow=(),
                  **kw) -> BarcodeSpec:
    """Raise SpecError for the first broken rule among ``rules``; return the spec otherwise.

    A broken rule named in ``allow`` (see `check_spec`) does not raise: it issues a
    `SpecWarning` instead, e.g. ``require_valid(spec_200hz, allow=("flicker",))``.
    """
    for v in check_spec(spec, allow=allow, **kw).violations:
        if v.rule in rules and v.severity == "error":
            raise SpecError(v.message, rule=v.rule)
        if v.rule in rules and v.allowed:
            warnings.warn(f"spec {spec.name!r} [{v.rule}] {v.message}", SpecWarning,
                          stacklevel=2)
    return spec


# ---------------------------------------------------------------------- presets
def _table3(m: int) -> BarcodeSpec:
    f_b = {  # Table 3: f_B = f_1 = 200, 300, ..., 600 Hz for M = 2..6
        2: 200.0, 3: 300.0, 4: 400.0, 5: 500.0, 6: 600.0}[m]
    return BarcodeSpec.mono(f"table3-m{m}", [f_b + 50.0 * n for n in range(m)],
                            description=f"Paper Table 3, frequency randomization with M={m}: "
                                        f"f_B = f_1 = {f_b:g} Hz, delta f = 50 Hz.")


PRESETS: dict[str, BarcodeSpec] = {
    "table1-seq1": BarcodeSpec.mono("table1-seq1", [400, 600, 800],
                                    description="Paper Table 1, monochrome sequence 1."),
    "table1-seq2": BarcodeSpec.mono("table1-seq2", [1000, 1200, 1400],
                                    description="Paper Table 1, monochrome sequence 2."),
    "table1-seq3": BarcodeSpec.mono("table1-seq3", [1600, 1800, 2000],
                                    description="Paper Table 1, monochrome sequence 3."),
    "table2-rgb": BarcodeSpec.rgb("table2-rgb", [400, 600, 800], [1000, 1200, 1400],
                                  [1600, 1800, 2000],
                                  description="Paper Table 2, RGB barcode (f_B = 400 Hz)."),
    **{f"table3-m{m}": _table3(m) for m in range(2, 7)},
}


def get_preset(name: str) -> BarcodeSpec:
    """Look up a preset by name; raises SpecError listing the known names."""
    try:
        return PRESETS[name]
    except KeyError:
        raise SpecError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}",
                        rule="preset") from None
