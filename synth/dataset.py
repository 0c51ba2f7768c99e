"""Labelled synthetic datasets: barcode captures and look-alike negatives, with a JSONL manifest.

Every item is drawn from a `Mix` of distributions using its own seed, derived from
``np.random.SeedSequence([seed, index])``, so output is byte-identical for a seed whatever the
number of worker processes.

The default mix (``MIXES["default"]``)
--------------------------------------
Positives (label 1, kind ``"barcode"``):

- preset: 50% monochrome (``table1-seq1/2/3`` uniformly), 50% RGB (``table2-rgb``);
- the emitter (`sample_emitter`; DESIGN.md, "What the detector may assume about an emitter"),
  an LED built by others, so our firmware's flicker and switching rules are allowed (compiled
  with a filtered `SpecWarning`): switching rate f_B in band ``"200"`` (f_B = 200 Hz, paper
  Sec. 7.3; 31%), ``"f1"`` (f_B = f_1, Sec. 3.3.1; 31%), ``"between"`` (log-uniform in
  (200 Hz, f_1); 31%) or ``"beyond"`` (7%: half log-uniform in [170, 200) Hz, half
  f_1 * uniform(1, 1.2]); tone phase at a slot start ``restart`` or ``continuous`` (50/50);
  slot order ascending, descending or another fixed permutation (1/3 each); LED rise/fall
  time uniform in 0-5% of the shortest half-period; a continuous-phase emitter's firmware
  loop holds 0.1 s of patterns (its tones run on across patterns, as a free-running LED's
  would). Manifest fields ``switching_hz``, ``f_b_band``, ``phase_mode``, ``slot_order``,
  ``slot_order_kind``, ``rise_frac``, ``rise_s``, ``loop_patterns``; ``nominal`` is true for
  no attack, full coverage, ambient <= 1 and t_e < half a slot;
- exposure log-uniform in [1/8000, 1/30] s (DESIGN.md, "Camera settings in the wild"); 20%
  manual-exposure attack: t_e = k / f with f one random tone of one channel and k uniform
  among 1..3 keeping t_e within [1/8000, 1/200] s;
- ambient ratio (steady white light / LED average): 30% zero, else log-uniform in [0.1, 10];
- coverage: 25% partial (lit fraction uniform 0.3-0.8, raised-cosine radial falloff centred
  uniformly in the frame), else the LED lights the whole frame;
- row rate uniform in 30-120 kHz; random frame start; auto gain; shot and read noise;
- JPEG quality uniform 60-95, chroma 4:2:0 (80%) or 4:4:4;
- 50% downscaled (``cv2.INTER_AREA``) to a long side uniform in 1080-2048 px (capped at the
  sensor's long side);
- 20% rotated by 90 or 270 degrees, half as an EXIF orientation tag only, half baked into pixels;
- scene: a procedural texture (20%) or a photo with a random crop: a real photograph of the
  ``out/photos`` corpus (80% of photos, through the `real_photo_scenes` hook, when
  `synth.scene` lists that corpus; each photo weighted 1/sqrt(photos of its package);
  packages reserved for independent evaluation left out) or a scikit-image photo.

Negatives (label 0): 30% steady light (kind ``"steady"``), 25% mains flicker (``"mains"``:
100 or 120 Hz, depth uniform 0.05-1), 25% PWM dimming (``"pwm"``: frequency log-uniform
90 Hz-20 kHz, duty 0.1-0.9, depth 0.2-1), 20% periodic texture (blinds, bricks, fabric) under
steady light (``"texture"``); the same camera, ambient, JPEG, downscale and rotation mix as
positives (no attack; no coverage map, since there is no LED).

Other mixes: ``mono`` and ``rgb`` (positives of one kind only), ``negatives-only`` (no
positives allowed), ``easy`` (no attack, no ambient light, full coverage, no downscale or
rotation), ``nominal`` (every positive in the nominal sub-mix: no attack, full coverage,
ambient <= 1, exposure log-uniform below half a slot; ``exposure_max_slot_frac``). Any field
can be overridden with `Mix.with_overrides` (CLI ``--set key=value``).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
import math
import os
import warnings
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lishield_guard.camera import CameraModel
from lishield_guard.errors import ConfigError
from lishield_guard.spec import get_preset
from lishield_guard.threads import one_thread_per_worker

__all__ = [
    "EMITTER_ALLOW",
    "EMITTER_FIELDS",
    "MIXES",
    "EVAL_PHOTO_PACKAGES",
    "RESERVED_PHOTO_PACKAGES",
    "SIZES",
    "Mix",
    "demo_images",
    "f_b_band",
    "item_seed",
    "parse_size",
    "real_photo_scenes",
    "render_item",
    "sample_emitter",
    "sample_item",
    "slot_order_kind",
    "write_dataset",
]

SIZES = {"1080p": (1080, 1920), "720p": (720, 1280), "12mp": (3024, 4032),
         "8mp": (2448, 3264)}  # name -> (n_rows, n_cols); sensor rows run down the height
NEGATIVE_KINDS = ("steady", "mains", "pwm", "texture")
# A 16 MHz timer (a common MCU clock) keeps every tone ratio within 1e-4 for any f_B drawn;
# at 1 MHz, slots of a non-integer f_B lose up to 1e-3 of a ratio to tick rounding.
LED_CLOCK_HZ = 16_000_000
# Rules an emitter built by others may break (paper Sec. 7.3: f_B = 200 Hz, f_B / M = 66.7 Hz);
# synthetic captures compile such specs with a SpecWarning (filtered), not an error.
EMITTER_ALLOW = ("flicker", "switching")


@dataclass(frozen=True)
class Mix:
    """Distributions a dataset's items are drawn from (see the module docstring).

    Probabilities are unitless in [0, 1]; ranges are (low, high) tuples.
    """

    name: str = "default"
    allow_positives: bool = True
    rgb_prob: float = 0.5
    mono_presets: tuple[str, ...] = ("table1-seq1", "table1-seq2", "table1-seq3")
    rgb_presets: tuple[str, ...] = ("table2-rgb",)
    switching_min_hz: float = 200.0
    switching_band_probs: tuple[float, float, float, float] = (0.31, 0.31, 0.31, 0.07)
    beyond_low_range_hz: tuple[float, float] = (170.0, 200.0)
    beyond_high_factor_range: tuple[float, float] = (1.0, 1.2)
    continuous_phase_prob: float = 0.5
    order_probs: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)
    rise_frac_range: tuple[float, float] = (0.0, 0.05)
    continuous_loop_s: float = 0.1
    exposure_range_s: tuple[float, float] = (1 / 8000, 1 / 30)
    exposure_max_slot_frac: float = 0.0
    attack_prob: float = 0.2
    attack_max_k: int = 3
    attack_range_s: tuple[float, float] = (1 / 8000, 1 / 200)
    ambient_zero_prob: float = 0.3
    ambient_range: tuple[float, float] = (0.1, 10.0)
    partial_coverage_prob: float = 0.25
    coverage_range: tuple[float, float] = (0.3, 0.8)
    row_rate_range_hz: tuple[float, float] = (30_000.0, 120_000.0)
    jpeg_quality_range: tuple[int, int] = (60, 95)
    subsampling_420_prob: float = 0.8
    downscale_prob: float = 0.5
    downscale_range: tuple[float, float] = (1.0, 4.0)
    downscale_long_side_range_px: tuple[int, int] = (1080, 2048)
    rotate_prob: float = 0.2
    rotate_exif_prob: float = 0.5
    positive_texture_prob: float = 0.2
    real_photo_prob: float = 0.8
    negative_probs: tuple[float, float, float, float] = (0.30, 0.25, 0.25, 0.20)
    mains_depth_range: tuple[float, float] = (0.05, 1.0)
    pwm_freq_range_hz: tuple[float, float] = (90.0, 20_000.0)
    pwm_duty_range: tuple[float, float] = (0.1, 0.9)
    pwm_depth_range: tuple[float, float] = (0.2, 1.0)
    noise: bool = True
    photo_packages: tuple[str, ...] = ()  # real-photo scenes only from these (empty: any)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name.endswith("_prob") and not 0.0 <= v <= 1.0:
                raise ConfigError(f"need 0 <= {f.name} <= 1, got {f.name}={v!r}")
            if f.name.endswith("_range") or f.name.endswith("_range_s") or \
                    f.name.endswith("_range_hz"):
                if len(v) != 2 or not v[0] <= v[1]:
                    raise ConfigError(f"{f.name} must be (low, high) with low <= high, got {v!r}")
        for name, n, what in (("negative_probs", 4, "steady, mains, pwm, texture"),
                              ("switching_band_probs", 4, "200, between, f1, beyond"),
                              ("order_probs", 3, "ascending, descending, other")):
            v = getattr(self, name)
            if len(v) != n or abs(sum(v) - 1) > 1e-6 or min(v) < 0:
                raise ConfigError(f"{name} ({what}) must be >= 0 and sum to 1, got {v!r}")
        if not (0.0 <= self.rise_frac_range[0] and self.rise_frac_range[1] < 0.5):
            raise ConfigError(f"rise_frac_range must lie in [0, 0.5), got "
                              f"{self.rise_frac_range!r}")
        if self.beyond_low_range_hz[0] <= 0 or self.beyond_high_factor_range[0] < 1.0:
            raise ConfigError("beyond_low_range_hz must be > 0 and beyond_high_factor_range "
                              ">= 1")
        for p in self.mono_presets + self.rgb_presets:
            get_preset(p)
        if self.exposure_range_s[0] <= 0:
            raise ConfigError(f"exposure_range_s must be > 0, got {self.exposure_range_s!r}")
        if self.downscale_range[0] < 1.0:
            raise ConfigError(f"downscale_range must be >= 1, got {self.downscale_range!r}")

    def with_overrides(self, overrides: dict[str, str]) -> Mix:
        """Copy with fields replaced from strings (``"0.5"``, ``"60,95"``, ``"true"``).

        Raises
        ------
        ConfigError
            For an unknown field or a value that does not parse.
        """
        fields = {f.name: f for f in dataclasses.fields(self)}
        kw: dict = {}
        for key, text in overrides.items():
            k = key.strip().replace("-", "_")
            if k not in fields or k == "name":
                raise ConfigError(f"unknown mix field {key!r}; known: "
                                  f"{', '.join(n for n in fields if n != 'name')}")
            cur = getattr(self, k)
            try:
                if isinstance(cur, bool):
                    if text.lower() not in ("true", "false", "1", "0"):
                        raise ValueError(text)
                    kw[k] = text.lower() in ("true", "1")
                elif isinstance(cur, tuple):
                    parts = [p.strip() for p in text.split(",") if p.strip()]
                    kw[k] = tuple(type(cur[0])(p) if not isinstance(cur[0], str) else p
                                  for p in parts) if cur else tuple(parts)
                else:
                    kw[k] = type(cur)(text)
            except ValueError:
                raise ConfigError(f"cannot parse mix field {key}={text!r}") from None
        return dataclasses.replace(self, **kw)


MIXES: dict[str, Mix] = {
    "default": Mix(),
    "mono": Mix(name="mono", rgb_prob=0.0),
    "rgb": Mix(name="rgb", rgb_prob=1.0),
    "negatives-only": Mix(name="negatives-only", allow_positives=False),
    "easy": Mix(name="easy", attack_prob=0.0, ambient_zero_prob=1.0, partial_coverage_prob=0.0,
                downscale_prob=0.0, rotate_prob=0.0),
    "nominal": Mix(name="nominal", attack_prob=0.0, partial_coverage_prob=0.0,
                   ambient_range=(0.1, 1.0), exposure_max_slot_frac=0.5),
}


def parse_size(size: str) -> tuple[int, int]:
    """``"1080p"``, ``"12mp"`` or ``"WxH"`` -> (n_rows, n_cols) of a landscape sensor.

    Raises
    ------
    ConfigError
        If the text is not a known name or ``WxH`` with both sides >= 16.
    """
    s = size.strip().lower()
    if s in SIZES:
        return SIZES[s]
    try:
        w, h = (int(p) for p in s.split("x"))
    except ValueError:
        raise ConfigError(f"size must be one of {', '.join(SIZES)} or WxH, got {size!r}") from None
    if w < 16 or h < 16:
        raise ConfigError(f"need width and height >= 16, got size={size!r}")
    return h, w


def item_seed(seed: int, index: int) -> int:
    """64-bit seed of item ``index`` of a dataset seeded with ``seed`` (order independent)."""
    state = np.random.SeedSequence([int(seed), int(index)]).generate_state(2, np.uint32)
    return int(state[0]) << 32 | int(state[1])


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sample_item(label: int, *, seed: int, mix: Mix, size: tuple[int, int]) -> dict:
    """Draw every parameter of one item (no rendering).

    Parameters
    ----------
    label : {0, 1}
        1 for a barcode capture, 0 for a negative.
    seed : int
        The item's own seed (see `item_seed`).
    mix : Mix
        Distributions to draw from.
    size : (int, int)
        Sensor (n_rows, n_cols).

    Returns
    -------
    dict
        JSON-ready parameters; `render_item` turns them into an image. Parameters that the
        renderer uses exactly are stored unrounded.
    """
    rng = np.random.default_rng(seed)
    n_rows, n_cols = size
    p: dict = {"label": int(label), "item_seed": int(seed), "sensor_rows": n_rows,
               "sensor_cols": n_cols, "mix": mix.name}
    row_rate_hz = float(rng.uniform(*mix.row_rate_range_hz))
    exposure_s = _log_uniform(rng, *mix.exposure_range_s)
    p["row_rate_hz"] = row_rate_hz
    p["attack"] = False
    p["attacked_tone"] = None
    if label:
        rgb = rng.random() < mix.rgb_prob
        presets = mix.rgb_presets if rgb else mix.mono_presets
        spec = get_preset(str(rng.choice(presets)))
        emitter = sample_emitter(spec, rng=rng, mix=mix)
        f_b = emitter["switching_hz"]
        p.update(kind="barcode", preset=spec.name, channels=list(spec.channel_names),
                 tones_hz={c: list(fs) for c, fs in spec.channels}, **emitter)
        if rng.random() < mix.attack_prob:
            c_idx = int(rng.integers(len(spec.channels)))
            ch, tones = spec.channels[c_idx]
            f = float(tones[int(rng.integers(len(tones)))])
            ks = [k for k in range(1, mix.attack_max_k + 1)
                  if mix.attack_range_s[0] <= k / f <= mix.attack_range_s[1]]
            if ks:
                k = int(ks[int(rng.integers(len(ks)))])
                exposure_s = k / f
                p["attack"] = True
                p["attacked_tone"] = {"channel": ch, "hz": f, "k": k}
        if mix.exposure_max_slot_frac > 0 and not p["attack"]:
            # a capture mix limited to short exposures (e.g. the nominal sub-mix): t_e below
            # the given fraction of a slot; drawn only then, so other mixes keep their draws
            hi = min(mix.exposure_range_s[1], mix.exposure_max_slot_frac / f_b) * (1 - 1e-9)
            exposure_s = _log_uniform(rng, min(mix.exposure_range_s[0], hi), hi)
        p["light"] = {"kind": "led", "preset": spec.name, "switching_hz": f_b,
                      "phase": emitter["phase_mode"], "order": emitter["slot_order"],
                      "rise_s": emitter["rise_s"], "loop_patterns": emitter["loop_patterns"]}
    else:
        kind = NEGATIVE_KINDS[int(rng.choice(4, p=np.asarray(mix.negative_probs)))]
        p.update(kind=kind, preset=None, channels=["W"], switching_hz=None, tones_hz=None,
                 **{k: None for k in EMITTER_FIELDS if k != "switching_hz"})
        if kind == "mains":
            p["light"] = {"kind": "mains", "supply_hz": float(rng.choice([50.0, 60.0])),
                          "depth": float(rng.uniform(*mix.mains_depth_range)),
                          "phase_s": float(rng.uniform(0, 0.02))}
        elif kind == "pwm":
            freq = _log_uniform(rng, *mix.pwm_freq_range_hz)
            p["light"] = {"kind": "pwm", "freq_hz": freq,
                          "duty": float(rng.uniform(*mix.pwm_duty_range)),
                          "depth": float(rng.uniform(*mix.pwm_depth_range)),
                          "phase_s": float(rng.uniform(0, 1 / freq))}
        else:
            p["light"] = {"kind": "steady"}
    p["exposure_s"] = exposure_s
    p["ambient_ratio"] = 0.0 if rng.random() < mix.ambient_zero_prob else _log_uniform(
        rng, *mix.ambient_range)
    if label and rng.random() < mix.partial_coverage_prob:
        p["coverage"] = {"fraction": float(rng.uniform(*mix.coverage_range)),
                         "centre_rc": [float(rng.uniform()), float(rng.uniform())],
                         "softness": float(rng.uniform(0.1, 0.3))}
    else:
        p["coverage"] = {"fraction": 1.0, "centre_rc": None, "softness": None}
    p["jpeg_quality"] = int(rng.integers(mix.jpeg_quality_range[0],
                                         mix.jpeg_quality_range[1] + 1))
    p["chroma_subsampling"] = "4:2:0" if rng.random() < mix.subsampling_420_prob else "4:4:4"
    p["downscale"] = 1.0
    if rng.random() < mix.downscale_prob:
        long_side = max(n_rows, n_cols)
        lo_px, hi_px = mix.downscale_long_side_range_px
        target = float(rng.uniform(min(lo_px, long_side), min(hi_px, long_side)))
        p["downscale"] = float(np.clip(long_side / target, *mix.downscale_range))
    if rng.random() < mix.rotate_prob:
        p["rotation_deg"] = int(rng.choice([90, 270]))
        p["rotation_mode"] = "exif" if rng.random() < mix.rotate_exif_prob else "bake"
    else:
        p["rotation_deg"], p["rotation_mode"] = 0, "none"
    p["frame_start_s"] = float(rng.uniform(0.0, 1.0))
    p["scene_seed"] = int(rng.integers(2**63))
    p["noise_seed"] = int(rng.integers(2**63))
    if p["kind"] == "texture":
        p["scene_kind"] = "texture"
    else:
        p["scene_kind"] = "texture" if (label and rng.random() < mix.positive_texture_prob) \
            else "photo"
    p["scene_photo"] = None
    photos = real_photo_scenes() if mix.real_photo_prob > 0 else ()
    if mix.photo_packages:
        photos = packaged_photos(photos, tuple(mix.photo_packages))
    if p["scene_kind"] == "photo" and photos and rng.random() < mix.real_photo_prob:
        p["scene_kind"] = "real-photo"
        p["scene_photo"] = str(photos[int(rng.choice(len(photos), p=_photo_probs(photos)))])
    p["noise"] = bool(mix.noise)
    if label:
        p["nominal"] = bool(not p["attack"] and p["coverage"]["fraction"] >= 1.0
                            and p["ambient_ratio"] <= 1.0
                            and p["exposure_s"] < 0.5 / p["switching_hz"])
    else:
        p["nominal"] = None
    return p


def f_b_band(switching_hz: float, f1_hz: float, *, low_hz: float = 200.0) -> str:
    """Name of the switching-rate band of f_B (Hz) for a barcode whose lowest tone is f1_hz.

    ``"200"`` (f_B = 200 Hz, paper Sec. 7.3), ``"f1"`` (f_B = f_1, Sec. 3.3.1), ``"between"``
    (strictly between), ``"beyond"`` (below 200 Hz or above f_1). Equality is to 1e-6
    relative.
    """
    if abs(switching_hz - low_hz) <= 1e-6 * low_hz:
        return "200"
    if abs(switching_hz - f1_hz) <= 1e-6 * f1_hz:
        return "f1"
    return "between" if low_hz < switching_hz < f1_hz else "beyond"


def slot_order_kind(order) -> str:
    """``"ascending"``, ``"descending"`` or ``"other"`` for a slot order (tone indices)."""
    order = tuple(order)
    m = len(order)
    if order == tuple(range(m)):
        return "ascending"
    if order == tuple(range(m - 1, -1, -1)):
        return "descending"
    return "other"


EMITTER_FIELDS = ("switching_hz", "f_b_band", "phase_mode", "slot_order", "slot_order_kind",
                  "rise_frac", "rise_s", "loop_patterns")


def sample_emitter(spec, *, rng: np.random.Generator, mix: Mix) -> dict:
    """Draw how an LED built by others plays ``spec`` (DESIGN.md, "What the detector may assume").

    Parameters
    ----------
    spec : BarcodeSpec
        The barcode (its tones and M).
    rng : numpy.random.Generator
        Source of every draw.
    mix : Mix
        ``switching_band_probs`` over (200 Hz, between, f_1, beyond), ``beyond_low_range_hz``,
        ``beyond_high_factor_range``, ``continuous_phase_prob``, ``order_probs`` over
        (ascending, descending, another fixed permutation) and ``rise_frac_range``.

    Returns
    -------
    dict
        JSON-ready: ``switching_hz`` (f_B, Hz, rounded to 0.01 Hz), ``f_b_band``, ``phase_mode``
        ("restart"/"continuous"), ``slot_order`` (list of tone indices), ``slot_order_kind``,
        ``rise_frac`` (of the shortest half-period, unitless), ``rise_s`` (seconds) and
        ``loop_patterns``: patterns in one firmware loop. A continuous-phase emitter's timers
        run on for ``mix.continuous_loop_s`` (so within any frame consecutive patterns need not
        repeat each other's phases, as with a free-running LED); restart emitters loop one
        pattern.
    """
    f1 = spec.f1_hz
    low = mix.switching_min_hz
    band = ("200", "between", "f1", "beyond")[int(rng.choice(4, p=np.asarray(
        mix.switching_band_probs)))]
    if band == "200" or f1 <= low:
        f_b = low
    elif band == "f1":
        f_b = f1
    elif band == "between":
        f_b = _log_uniform(rng, low, f1)
    elif rng.random() < 0.5:
        f_b = _log_uniform(rng, *mix.beyond_low_range_hz)
    else:
        f_b = f1 * float(rng.uniform(*mix.beyond_high_factor_range))
    f_b = round(float(f_b), 2)
    phase = "continuous" if rng.random() < mix.continuous_phase_prob else "restart"
    m = spec.n_tones
    kind = ("ascending", "descending", "other")[int(rng.choice(3, p=np.asarray(
        mix.order_probs)))]
    if kind == "ascending" or m == 1:
        order = list(range(m))
    elif kind == "descending":
        order = list(range(m - 1, -1, -1))
    else:
        others = [o for o in itertools.permutations(range(m))
                  if slot_order_kind(o) == "other"] if m <= 6 else None
        if others:
            order = list(others[int(rng.integers(len(others)))])
        elif m > 6:
            while slot_order_kind(order := [int(i) for i in rng.permutation(m)]) != "other":
                pass
        else:  # M = 2: only ascending and descending exist
            order = list(range(m - 1, -1, -1))
    rise_frac = float(rng.uniform(*mix.rise_frac_range))
    half_period_s = min(spec.duty, 1.0 - spec.duty) / spec.all_freqs_hz[-1]
    return {"switching_hz": f_b, "f_b_band": f_b_band(f_b, f1, low_hz=low),
            "phase_mode": phase, "slot_order": order, "slot_order_kind": slot_order_kind(order),
            "rise_frac": rise_frac, "rise_s": rise_frac * half_period_s,
            "loop_patterns": max(1, math.ceil(mix.continuous_loop_s * f_b / m))
            if phase == "continuous" else 1}


# Photo packages the issue (#21) reserves for an independent evaluation: never used as scenes.
RESERVED_PHOTO_PACKAGES = (
    "gcompris-qt-data", "opencv-doc", "mypaint-data-extras", "lomiri-wallpapers-16.04",
    "lomiri-wallpapers-20.04", "budgie-backgrounds", "mate-backgrounds",
    "plasma-workspace-wallpapers", "palapeli-data", "scikit-learn", "pywavelets", "mahotas",
    "imgaug")


# Photo packages held out of the training scene bank (`training.scenes`): fresh evaluation
# sets draw their scenes from these only (``--set photo_packages=...``), so the learned stage
# is judged on photographs it never saw.
EVAL_PHOTO_PACKAGES = ("hugin-data", "kphotoalbum", "forensics-samples-files", "libjxl-testdata")


def packaged_photos(names: tuple[str, ...], packages: tuple[str, ...]) -> tuple[str, ...]:
    """The real-photo scenes of ``names`` whose corpus package is one of ``packages``."""
    from synth import scene

    rows = _corpus_rows(names[0]) if names else None
    if rows is None:
        return ()
    return tuple(n for n in names
                 if str(rows[scene.parse_photo_scene(n)[1]].get("package")) in packages)


def _reserved_photo(row: dict) -> bool:
    name = str(row.get("package", "")).lower().replace("_", "-")
    full = f"{name}-{str(row.get('version', '')).split(':')[-1]}"
    return any(name == r or full.startswith(r + ".") or full == r
               for r in RESERVED_PHOTO_PACKAGES)


def real_photo_scenes() -> tuple[str, ...]:
    """Hook: names of the real-photo scenes (``out/photos`` corpus) the default mix may use.

    Uses ``synth.scene.photo_scene_names()`` (``"photos:DIR#INDEX"``, DIR relative to the
    working directory) or, failing that, ``synth.scene.list_photo_scenes()``; returns ``()``
    when neither exists or the corpus is absent (the mix then keeps scikit-image photos and
    textures). Photos of the packages in `RESERVED_PHOTO_PACKAGES` are left out. The order is
    the corpus manifest's, so a dataset seed picks the same photos from the same corpus;
    `render_item` records each photo's package and sha256.
    """
    from synth import scene

    lister = getattr(scene, "photo_scene_names", None) or getattr(scene, "list_photo_scenes",
                                                                  None)
    return () if lister is None else _listed_photos(lister)


@functools.lru_cache(maxsize=4)
def _listed_photos(lister) -> tuple[str, ...]:
    """The lister's photos minus reserved packages; listed once per process."""
    from synth import scene

    try:
        names = [str(x) for x in lister()]
    except (OSError, LookupError, ConfigError):
        return ()
    rows = _corpus_rows(names[0]) if names else None
    if rows is not None and len(rows) == len(names):
        names = [n for n, r in zip(names, rows, strict=True) if not _reserved_photo(r)]
    elif any(n.startswith("photos:") for n in names) and hasattr(scene, "corpus_manifest"):
        return ()  # cannot check the packages: use no real photo rather than a reserved one
    return tuple(names)


@functools.lru_cache(maxsize=4)
def _photo_probs(names: tuple[str, ...]) -> np.ndarray:
    """Draw probability of each real-photo scene: 1/sqrt(photos of its package), normalised,
    so one large package (e.g. a planetarium's textures) does not make up most scenes."""
    rows = _corpus_rows(names[0]) if names else None
    if rows is None:
        return np.full(len(names), 1.0 / max(len(names), 1))
    from synth import scene

    pkgs = [str(rows[scene.parse_photo_scene(n)[1]].get("package", n)) for n in names]
    size = Counter(pkgs)
    w = np.array([1.0 / math.sqrt(size[k]) for k in pkgs])
    return w / w.sum()


def _corpus_rows(name: str):
    """Manifest rows of the corpus holding scene ``name`` (``photos:DIR#INDEX``), or None."""
    from synth import scene

    if not name.startswith("photos:") or not hasattr(scene, "corpus_manifest"):
        return None
    try:
        folder, _ = scene.parse_photo_scene(name)
        return scene.corpus_manifest(folder)
    except (OSError, LookupError, ConfigError):
        return None


def _real_photo(name: str, n_rows: int, n_cols: int, rng: np.random.Generator):
    """Reflectance and manifest description of real-photo scene ``name`` (random crop)."""
    from synth import scene

    rows = _corpus_rows(name)
    if rows is not None:
        folder, index = scene.parse_photo_scene(name)
        arr = scene.corpus_photo(folder, index, min_side_px=max(n_rows, n_cols))
        row = rows[index]
        desc = {"scene": name, **{k: row[k] for k in ("package", "version", "path", "sha256")
                                  if k in row}}
        return scene.photo_scene(arr, n_rows, n_cols, rng=rng, min_crop=0.5), desc
    return scene.load_scene(name, n_rows, n_cols, rng=rng, min_crop=0.5), {"scene": name}


def _make_light(p: dict):
    from synth.light import MainsFlicker, PwmLight, SequenceLight, SteadyLight

    lt = p["light"]
    if lt["kind"] == "led":
        from firmware.sequence import compile_spec
        from lishield_guard.spec import SpecWarning

        spec = dataclasses.replace(get_preset(lt["preset"]), switching_hz=lt["switching_hz"],
                                   phase=lt.get("phase", "restart"),
                                   order=tuple(lt.get("order") or ()) or "cyclic",
                                   **({"duty": lt["duty"]} if "duty" in lt else {}))
        with warnings.catch_warnings():  # f_B = 200 Hz breaks our flicker rule, on purpose
            warnings.simplefilter("ignore", SpecWarning)
            seq = compile_spec(spec, clock_hz=LED_CLOCK_HZ, allow=EMITTER_ALLOW,
                               n_patterns=int(lt.get("loop_patterns") or 1))
        return SequenceLight(seq, rise_s=float(lt.get("rise_s") or 0.0))
    if lt["kind"] == "mains":
        return MainsFlicker(supply_hz=lt["supply_hz"], depth=lt["depth"], phase_s=lt["phase_s"])
    if lt["kind"] == "pwm":
        return PwmLight(freq_hz=lt["freq_hz"], duty=lt["duty"], depth=lt["depth"],
                        phase_s=lt["phase_s"])
    return SteadyLight()


def _render_scene(p: dict, n_rows: int, n_cols: int) -> tuple[np.ndarray, dict]:
    """Reflectance (n_rows, n_cols, 3) and description of the scene `sample_item` drew.

    ``n_rows, n_cols`` may exceed the sensor (a video's panning camera crops a larger scene).
    """
    from synth.scene import load_scene, random_scene, texture_scene

    scene_rng = np.random.default_rng(p["scene_seed"])
    if p.get("scene_name"):
        return load_scene(p["scene_name"], n_rows, n_cols), {"scene": p["scene_name"]}
    if p.get("scene_photo"):
        return _real_photo(p["scene_photo"], n_rows, n_cols, scene_rng)
    if p["scene_kind"] == "texture":
        kind = str(scene_rng.choice(("blinds", "bricks", "fabric")))
        scene, sp = texture_scene(kind, n_rows, n_cols, rng=scene_rng)
        return scene, {"scene": f"texture:{kind}", **sp}
    return random_scene(n_rows, n_cols, rng=scene_rng)


def _coverage(p: dict, n_rows: int, n_cols: int) -> np.ndarray | None:
    """The LED's coverage map of shape (n_rows, n_cols) that `sample_item` drew, or None."""
    from synth.light import coverage_map

    cov = p["coverage"]
    if cov["fraction"] >= 1.0:
        return None
    return coverage_map(n_rows, n_cols, fraction=cov["fraction"],
                        centre_rc=tuple(cov["centre_rc"]), softness=cov["softness"])


def render_item(p: dict) -> tuple[bytes, dict]:
    """Render the item described by `sample_item` parameters.

    Parameters
    ----------
    p : dict
        Output of `sample_item`.

    Returns
    -------
    jpeg : bytes
        The encoded capture.
    record : dict
        ``p`` plus what rendering decided: ``scene`` (description), ``width``, ``height``
        (stored pixels), ``exif_orientation`` and ``gain``.
    """
    from synth.camera import encode_jpeg, postprocess, simulate_frame

    n_rows, n_cols = p["sensor_rows"], p["sensor_cols"]
    scene, scene_desc = _render_scene(p, n_rows, n_cols)
    cmap = _coverage(p, n_rows, n_cols)
    camera = CameraModel(row_time_s=1.0 / p["row_rate_hz"], n_rows=n_rows,
                         exposure_s=p["exposure_s"])
    frame = simulate_frame(_make_light(p), scene, camera,
                           rng=np.random.default_rng(p["noise_seed"]),
                           start_s=p["frame_start_s"], ambient_ratio=p["ambient_ratio"],
                           coverage=cmap, noise=p["noise"])
    rot_mode = "bake" if p["rotation_mode"] == "none" else p["rotation_mode"]
    img, orient = postprocess(frame, downscale=p["downscale"], rotation_deg=p["rotation_deg"],
                              rotation_mode=rot_mode)
    data = encode_jpeg(img, quality=p["jpeg_quality"], subsampling=p["chroma_subsampling"],
                       exif_orientation=orient)
    rec = dict(p)
    rec.update(scene=scene_desc, height=int(img.shape[0]), width=int(img.shape[1]),
               exif_orientation=orient)
    return data, rec


def _work(args: tuple) -> dict:
    index, label, seed, mix, size, out_dir = args
    s = item_seed(seed, index)
    p = sample_item(label, seed=s, mix=mix, size=size)
    data, rec = render_item(p)
    name = f"{index:06d}.jpg"
    (Path(out_dir) / name).write_bytes(data)
    return {"file": name, "index": index, **rec}


def write_dataset(out_dir: str | Path, *, n_pos: int, n_neg: int, seed: int,
                  mix: Mix | str = "default", size: str | tuple[int, int] = "1080p",
                  jobs: int = 1, progress: bool | Callable = True) -> Path:
    """Render a labelled dataset: ``out_dir/NNNNNN.jpg`` plus ``out_dir/manifest.jsonl``.

    Parameters
    ----------
    out_dir : str or Path
        Output folder, created if missing.
    n_pos, n_neg : int
        Number of barcode captures and of negatives (>= 0, total >= 1).
    seed : int
        Dataset seed; the label order and every item derive from it.
    mix : Mix or str
        Distributions, or a key of `MIXES`.
    size : str or (int, int)
        ``"1080p"``, ``"12mp"``, ``"WxH"`` or (n_rows, n_cols).
    jobs : int
        Worker processes (>= 1). The output does not depend on it.
    progress : bool
        Show a tqdm progress bar on stderr.

    Returns
    -------
    Path
        The manifest path. Each line: ``file``, ``label`` (1/0), ``kind`` and every parameter
        (see `sample_item` and `render_item`), in index order.

    Raises
    ------
    ConfigError
        Bad counts, mix, size or jobs.
    """
    mix = resolve_mix(mix)
    size_rc = parse_size(size) if isinstance(size, str) else (int(size[0]), int(size[1]))
    labels = label_order(n_pos, n_neg, seed=seed, mix=mix, jobs=jobs)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(i, int(labels[i]), int(seed), mix, size_rc, str(out)) for i in range(len(labels))]
    records = run_tasks(_work, tasks, jobs=jobs, progress=progress, unit="img")
    return write_manifest(out, records)


def resolve_mix(mix: Mix | str) -> Mix:
    """A `Mix`, or the `MIXES` entry named ``mix``; ConfigError for an unknown name."""
    if isinstance(mix, str):
        if mix not in MIXES:
            raise ConfigError(f"unknown mix {mix!r}; known: {', '.join(MIXES)}")
        return MIXES[mix]
    return mix


def label_order(n_pos: int, n_neg: int, *, seed: int, mix: Mix, jobs: int = 1) -> np.ndarray:
    """Labels (1/0) of a dataset's items in index order, shuffled by ``seed``; checks counts.

    Raises
    ------
    ConfigError
        Negative counts, no item, positives from a negatives-only mix, or jobs < 1.
    """
    if n_pos < 0 or n_neg < 0 or n_pos + n_neg < 1:
        raise ConfigError(f"need n_pos, n_neg >= 0 and n_pos + n_neg >= 1, got n_pos={n_pos}, "
                          f"n_neg={n_neg}")
    if n_pos and not mix.allow_positives:
        raise ConfigError(f"mix {mix.name!r} makes negatives only; got n_pos={n_pos} (use 0)")
    if jobs < 1:
        raise ConfigError(f"need jobs >= 1, got jobs={jobs!r}")
    labels = np.zeros(n_pos + n_neg, dtype=int)
    labels[:n_pos] = 1
    return np.random.default_rng(np.random.SeedSequence([int(seed), 2**31])).permutation(labels)


def run_tasks(work: Callable[[tuple], dict], tasks: list[tuple], *, jobs: int,
              progress: bool | Callable, unit: str = "img", chunksize: int | None = None
              ) -> list[dict]:
    """``[work(t) for t in tasks]`` on ``jobs`` spawned processes (one thread each), in order.

    ``work`` must be a module-level function (picklable); a tqdm bar on stderr shows progress.
    ``chunksize`` (tasks sent to a worker at once) defaults to ``min(8, n / (4 * jobs))``.
    """
    from tqdm import tqdm

    n = len(tasks)
    bar = tqdm(total=n, desc="synth", unit=unit, disable=not progress, file=None)
    records: list[dict] = []
    try:
        if jobs == 1:
            for t in tasks:
                records.append(work(t))
                bar.update()
        else:
            import multiprocessing as mp

            ctx = mp.get_context("spawn")
            with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx,
                                     initializer=one_thread_per_worker) as ex:
                chunk = chunksize or max(1, min(8, n // (4 * jobs)))
                for rec in ex.map(work, tasks, chunksize=chunk):
                    records.append(rec)
                    bar.update()
    finally:
        bar.close()
    return records


def write_manifest(out: Path, records: list[dict]) -> Path:
    """Write ``out/manifest.jsonl`` (one sorted-key JSON object per record) atomically."""
    manifest = out / "manifest.jsonl"
    tmp = manifest.with_suffix(".jsonl.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        for rec in records:
            fh.write(json.dumps(rec, sort_keys=True) + "\n")
    os.replace(tmp, manifest)
    return manifest


def demo_images(out_dir: str | Path, *, seed: int = 0) -> tuple[Path, Path]:
    """Write one protected and one clean 1080p JPEG of the same scene (for ``make run``).

    The protected capture is ``table2-rgb`` (an RGB LED: 400/600/800 Hz red, 1000/1200/1400 Hz
    green, 1600/1800/2000 Hz blue) switched at f_B = 200 Hz, the paper's evaluation setting
    (Sec. 7.3), at 60 kHz row rate and 1/2000 s exposure, full coverage, no ambient light, JPEG
    quality 90; the clean one is the same camera under steady light.

    Parameters
    ----------
    out_dir : str or Path
        Output folder, created if missing.
    seed : int
        Noise and frame-start seed.

    Returns
    -------
    (Path, Path)
        ``(protected_path, clean_path)``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    base = {"label": 1, "item_seed": int(seed), "sensor_rows": 1080, "sensor_cols": 1920,
            "mix": "demo", "row_rate_hz": 60_000.0, "exposure_s": 1 / 2000, "attack": False,
            "attacked_tone": None, "ambient_ratio": 0.0,
            "coverage": {"fraction": 1.0, "centre_rc": None, "softness": None},
            "jpeg_quality": 90, "chroma_subsampling": "4:2:0", "downscale": 1.0,
            "rotation_deg": 0, "rotation_mode": "none", "frame_start_s": 0.0123,
            "scene_seed": int(seed), "noise_seed": int(seed) + 1, "scene_kind": "photo",
            "scene_name": "skimage:astronaut", "noise": True}
    pos = dict(base, kind="barcode", preset="table2-rgb",
               light={"kind": "led", "preset": "table2-rgb", "switching_hz": 200.0})
    neg = dict(base, label=0, kind="steady", light={"kind": "steady"})
    paths = []
    for name, p in (("protected.jpg", pos), ("clean.jpg", neg)):
        data, _ = render_item(p)
        path = out / name
        path.write_bytes(data)
        paths.append(path)
    return paths[0], paths[1]
