"""Training data for the learned decision stage: a wide mix of captures -> decision inputs.

Every example is drawn from its own seed (``SeedSequence([seed, index])``) by `sample_example`:
a JSON-ready description of the scene, the lights, the camera, the processing and the upload
path. Two renderers turn a description into the block line profiles the detector reduces an
image to (`lishield_guard.detector.spectra.analysable`):

- `render` (the reference): the full frame through `synth.camera.simulate_frame` (lights
  compiled by `firmware.sequence`), processing, JPEG encoding with Pillow and the detector's
  own decoder;
- `render_profiles` (the one training uses): the same description in the profile domain
  (`synth.fastrender`), tens of times cheaper; ``tests/training/test_fastrender_agreement.py``
  checks that the two agree.

The mix is deliberately wider than any evaluation (DESIGN.md, "Notes for the learned decision"):

- barcodes: the shipped policy's presets (table1-seq1/2/3 white, table2-rgb), f_B = 200 Hz,
  f_B = f_1 or anywhere from 120 Hz to 1.3 f_1; restart or continuous phase; any slot order;
  duty 0.3-0.7; rise 0-10 % of the shortest half-period; a second light beside the LED;
- cameras: frames of 300-2400 lines, aspect 0.45-2.3, effective row rate 12-170 kHz (standing
  for the sensor, the resizing and the decoder's scale), exposure 1/8000-1/25 s with a fifth
  k/f attacks, auto gain, shot and read noise, a larger sensor resized down;
- light: ambient 0-25x the LED; the LED on part of the frame (a disc or a soft rectangle,
  4-85 %);
- look-alikes, each a kind: steady, mains, PWM (60 Hz-25 kHz, duty 0.03-0.97; a third at the
  barcodes' own frequencies: multiples of 200 Hz and the tones), two or three PWM lights at
  harmonically related frequencies (the tones of a spec at once), a dimmer that changes duty or
  frequency mid-frame, mains beside PWM, textures (blinds, bricks, fabric, screens) under
  steady or PWM light; flickering ones on part of the frame a quarter of the time;
- scenes: photos of the scene bank (random crops, flips, white balance and contrast), and
  procedural scenes;
- processing: tone curves, sharpening, denoising, rotation by 90/270 degrees, JPEG 40-98
  (4:2:0 or 4:4:4), borders, 2x2 collages and frames.
"""

from __future__ import annotations

import functools
import io
import math
from pathlib import Path

import cv2
import numpy as np

from lishield_guard.camera import CameraModel
from lishield_guard.spec import get_preset

__all__ = ["DEFAULT_BANK", "MAX_DECODE_ROWS", "MONO_PRESETS", "NEG_KINDS", "RGB_PRESETS",
           "example", "example_profiles", "render", "render_profiles", "sample_example",
           "scene_bank"]

MONO_PRESETS = ("table1-seq1", "table1-seq2", "table1-seq3")
RGB_PRESETS = ("table2-rgb",)
DEFAULT_BANK = Path("out/scenebank")
NEG_KINDS = ("steady", "mains", "pwm", "pwm-tones", "multi-pwm", "dimmer", "mains+pwm",
             "texture")
NEG_PROBS = (0.12, 0.11, 0.2, 0.12, 0.12, 0.08, 0.05, 0.2)
MAX_DECODE_ROWS = 768  # the shipped detector's profiles.max_decode_rows
MONO_PROB = 0.55  # share of white-LED barcodes among positives


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


@functools.cache
def scene_bank(folder: str = str(DEFAULT_BANK)) -> tuple[str, ...]:
    """JPEG files of the scene bank (`training.scenes.build_bank`), sorted; () when absent."""
    p = Path(folder)
    return tuple(sorted(str(f) for f in p.glob("*.jpg"))) if p.is_dir() else ()


@functools.lru_cache(maxsize=1024)
def _bank_image(path: str) -> np.ndarray:
    """A scene-bank photo as sRGB uint8 (kept: the bank is small)."""
    from PIL import Image

    with Image.open(path) as im:
        arr = np.asarray(im.convert("RGB"))
    arr.setflags(write=False)
    return arr


# -- the description --------------------------------------------------------------------------

@functools.cache
def bank_weights(folder: str = str(DEFAULT_BANK)) -> tuple[float, ...]:
    """Draw probability of every scene-bank photo (`scene_bank` order): 1/sqrt(photos of its
    package), normalised, so that one large package (a planetarium's sky textures) does not
    make up most scenes; () when the bank is absent."""
    import collections
    import json

    names = [Path(f).name for f in scene_bank(folder)]
    man = Path(folder) / "manifest.jsonl"
    pkg = {}
    if man.exists():
        pkg = {r["bank"]: r.get("package") for r in map(json.loads, man.read_text().split("\n")
                                                        [:-1])}
    keys = [pkg.get(n, n) for n in names]
    size = collections.Counter(keys)
    w = np.array([1.0 / math.sqrt(size[k]) for k in keys])
    return tuple((w / w.sum()).tolist()) if len(w) else ()


def _scene_desc(rng: np.random.Generator, weights: tuple[float, ...],
                kind: str | None = None, texture: str | None = None) -> dict:
    """A scene: a bank photo (crop, flip, white balance, contrast), a procedural scene or a
    periodic texture (``texture``: that one, else any of `synth.scene.ALL_TEXTURE_KINDS`)."""
    from synth.scene import ALL_TEXTURE_KINDS

    d: dict = {"seed": int(rng.integers(2**63))}
    if kind == "texture":
        d.update(kind="texture", texture=texture or str(rng.choice(ALL_TEXTURE_KINDS)))
    elif weights and rng.random() < 0.88:
        d.update(kind="bank", bank_index=int(rng.choice(len(weights), p=np.asarray(weights))),
                 crop=[float(rng.uniform(0.3, 1.0)), float(rng.random()), float(rng.random())],
                 flip=bool(rng.random() < 0.5))
    else:
        d["kind"] = "procedural"
    d["balance"] = [float(v) for v in rng.uniform(0.75, 1.3, 3)]
    d["contrast"] = _log_uniform(rng, 0.7, 1.5)
    d["rot90"] = bool(rng.random() < 0.25)  # vertical structure along the rows
    return d


def _pwm(rng: np.random.Generator, freq_hz: float | None = None, duty=None) -> dict:
    f = _log_uniform(rng, 60.0, 25_000.0) if freq_hz is None else float(freq_hz)
    return {"kind": "pwm", "freq_hz": f,
            "duty": float(rng.uniform(0.03, 0.97)) if duty is None else float(duty),
            "depth": float(rng.uniform(0.1, 1.0)), "phase_s": float(rng.uniform(0, 1 / f))}


def _mains(rng: np.random.Generator) -> dict:
    return {"kind": "mains", "supply_hz": float(rng.choice([50.0, 60.0])),
            "depth": float(rng.uniform(0.05, 1.0)), "phase_s": float(rng.uniform(0, 0.02))}


def _spec_tones(rng: np.random.Generator) -> list[float]:
    """The tones of a random preset (white ones flattened), for look-alikes at them."""
    spec = get_preset(str(rng.choice(MONO_PRESETS + RGB_PRESETS)))
    return sorted({float(f) for _, fs in spec.channels for f in fs})


def _negative_lights(rng: np.random.Generator, kind: str) -> list[dict]:
    jitter = float(rng.uniform(0.97, 1.03))
    if kind == "mains":
        return [_mains(rng)]
    if kind == "pwm":
        return [_pwm(rng)]
    if kind == "pwm-tones":  # at f_B's multiples, a tone, or the tones' common fundamental
        tones = _spec_tones(rng)
        f = float(rng.choice([200.0, 400.0, 600.0, *tones, tones[0] / 2])) * jitter
        return [_pwm(rng, f, 0.5 if rng.random() < 0.4 else None)]
    if kind == "multi-pwm":  # two or three lights at a spec's tones or harmonic ratios
        tones = _spec_tones(rng)
        k = int(rng.integers(2, 4))
        if rng.random() < 0.6:
            freqs = list(rng.choice(tones, size=min(k, len(tones)), replace=False))
        else:
            base = _log_uniform(rng, 80.0, 3000.0)
            freqs = [base * float(m) for m in rng.choice([1, 1.5, 2, 2.5, 3, 4], size=k,
                                                          replace=False)]
        return [_pwm(rng, float(f) * jitter) for f in freqs]
    if kind == "dimmer":  # duty or frequency changes mid-frame
        a = _pwm(rng)
        b = dict(a, duty=float(rng.uniform(0.03, 0.97))) if rng.random() < 0.5 else \
            _pwm(rng, a["freq_hz"] * float(rng.choice([1.5, 2.0, 0.5, 0.75, 4 / 3]))
                 if rng.random() < 0.6 else None)
        return [{"kind": "switched", "before": a, "after": b,
                 "switch_frac": float(rng.uniform(0.1, 0.9))}]
    if kind == "mains+pwm":
        return [_mains(rng), _pwm(rng)]
    return [{"kind": "steady"}]


def sample_example(index: int, seed: int, weights: tuple[float, ...] = (),
                   texture: str | None = None) -> dict:
    """Every parameter of example ``index`` of the dataset drawn with ``seed`` (no rendering).

    ``weights``: draw probability of each scene-bank photo (`bank_weights`); empty for
    procedural scenes only. ``texture``: a supplement whose every scene is that texture
    (`synth.scene.texture_scene`), barcodes and look-alikes alike (its look-alikes are steady
    or PWM light on it): the hard look-alikes that a fresh evaluation found, as a kind.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))
    label = int(rng.random() < 0.5)
    p: dict = {"index": int(index), "label": label, "noise_seed": int(rng.integers(2**63))}
    n_rows = int(round(_log_uniform(rng, 300, 1600 if rng.random() < 0.9 else 2400)))
    p["size"] = [n_rows, max(96, int(round(n_rows * _log_uniform(rng, 0.45, 2.3))))]
    p["oversample"] = _log_uniform(rng, 1.2, 2.5) if rng.random() < 0.3 else 1.0
    p["row_rate_hz"] = _log_uniform(rng, 12_000, 170_000)
    exposure = _log_uniform(rng, 1 / 8000, 1 / 25)
    p["attack"] = None
    lights: list[dict] = []
    if label:
        mono = rng.random() < MONO_PROB
        spec = get_preset(str(rng.choice(MONO_PRESETS if mono else RGB_PRESETS)))
        f1 = spec.f1_hz
        u = rng.random()
        f_b = 200.0 if u < 0.3 else f1 if u < 0.5 else _log_uniform(rng, 120, 1.3 * f1)
        m = spec.n_tones
        phase = "continuous" if rng.random() < 0.5 else "restart"
        duty = float(rng.uniform(0.3, 0.7))
        half = min(duty, 1 - duty) / spec.all_freqs_hz[-1]
        lights.append({"kind": "led", "preset": spec.name, "switching_hz": round(f_b, 2),
                       "order": [int(i) for i in rng.permutation(m)], "phase": phase,
                       "duty": duty, "rise_s": float(rng.uniform(0, 0.1)) * half,
                       "loop_patterns": max(1, math.ceil(0.05 * f_b / m))
                       if phase == "continuous" else 1})
        p["kind"], p["preset"] = "barcode", spec.name
        if rng.random() < 0.2:
            chan = spec.channels[int(rng.integers(len(spec.channels)))][1]
            f = float(chan[int(rng.integers(len(chan)))])
            ks = [k for k in (1, 2, 3) if 1 / 8000 <= k / f <= 1 / 25]
            exposure = ks[int(rng.integers(len(ks)))] / f
            p["attack"] = {"hz": f, "k": int(round(exposure * f))}
        if rng.random() < 0.15:
            lights += _negative_lights(rng, str(rng.choice(["pwm", "mains", "pwm-tones"])))
    else:
        kind = "texture" if texture else \
            NEG_KINDS[int(rng.choice(len(NEG_KINDS), p=np.asarray(NEG_PROBS)))]
        p["kind"], p["preset"] = kind, None
        if kind == "texture":
            lights = [_pwm(rng)] if rng.random() < 0.4 else [{"kind": "steady"}]
        else:
            lights = _negative_lights(rng, kind)
    p["lights"] = lights
    p["exposure_s"] = exposure
    p["ambient_ratio"] = 0.0 if rng.random() < 0.2 else _log_uniform(rng, 0.05, 25.0)
    p["start_s"] = float(rng.uniform(0, 1))
    flickers = any(lt["kind"] != "steady" for lt in lights)
    p["coverage"] = None
    if flickers and rng.random() < (0.4 if label else 0.25):
        p["coverage"] = {"shape": str(rng.choice(["disc", "rect"])),
                         "fraction": float(rng.uniform(0.04, 0.85)),
                         "centre_rc": [float(rng.uniform(0.05, 0.95)),
                                       float(rng.uniform(0.05, 0.95))],
                         "aspect": _log_uniform(rng, 0.4, 2.5),
                         "softness": float(rng.uniform(0.02, 0.25))}
    textured = p["kind"] == "texture" or (label and rng.random() < 0.1) or bool(texture)
    p["scene"] = _scene_desc(rng, weights, "texture" if textured else None, texture)
    p["tone"] = None
    if rng.random() < 0.4:
        p["tone"] = {"gamma": _log_uniform(rng, 0.6, 1.6), "s_curve": float(rng.uniform(0, 0.6))}
    p["sharpen"] = float(rng.uniform(0.3, 1.5)) if rng.random() < 0.25 else 0.0
    p["denoise"] = None
    if rng.random() < 0.2:
        p["denoise"] = [str(rng.choice(["gauss", "bilateral"])), float(rng.uniform(0.5, 1.2))]
    p["rotate"] = int(rng.choice([90, 270])) if rng.random() < 0.2 else 0
    p["composite"] = None
    if rng.random() < 0.25:
        ck = str(rng.choice(["border", "collage", "frame"]))
        p["composite"] = {
            "kind": ck, "area": float(rng.uniform(1.2, 3.0)), "tall": bool(rng.random() < 0.5),
            "colour": [int(v) for v in rng.integers(0, 256, 3)] if rng.random() < 0.5
            else [255, 255, 255],
            "where": [float(rng.random()), float(rng.random())],
            "shrink": float(rng.uniform(0.4, 0.8)), "slot": int(rng.integers(4)),
            "frame_photo": bool(rng.random() < 0.4),
            "tiles": [_scene_desc(rng, weights) for _ in range(3)]}
    p["jpeg_quality"] = int(rng.integers(40, 99))
    p["subsampling"] = "4:2:0" if rng.random() < 0.75 else "4:4:4"
    return p


# -- shared pieces of both renderers ----------------------------------------------------------

def _make_light(d: dict):
    """The light of one description (a barcode LED plays the firmware's sequence, compiled
    without the accuracy report: at 16 MHz every tone is kept)."""
    from synth.dataset import _make_light as make

    if d["kind"] == "switched":
        raise ValueError("a switched light needs the frame's timing (`_lights`)")
    if d["kind"] != "led":
        return make({"light": d})
    return _led_light(d["preset"], d["switching_hz"], d["phase"], tuple(d["order"]),
                      d["duty"], d["loop_patterns"], d["rise_s"])


def _led_light(preset: str, f_b: float, phase: str, order: tuple, duty: float, loops: int,
               rise_s: float):
    import dataclasses
    import warnings

    from firmware.sequence import compile_spec
    from lishield_guard.spec import SpecWarning
    from synth.dataset import EMITTER_ALLOW, LED_CLOCK_HZ
    from synth.light import SequenceLight

    spec = dataclasses.replace(get_preset(preset), switching_hz=f_b, phase=phase,
                               order=order, duty=duty)
    with warnings.catch_warnings():  # f_B = 200 Hz breaks our flicker rule, on purpose
        warnings.simplefilter("ignore", SpecWarning)
        seq = compile_spec(spec, clock_hz=LED_CLOCK_HZ, allow=EMITTER_ALLOW, n_patterns=loops,
                           verify=False)
    return SequenceLight(seq, rise_s=rise_s)


def _lights(p: dict, readout_s: float):
    from synth.light import SumLight, SwitchedLight

    parts = []
    for d in p["lights"]:
        if d["kind"] == "switched":
            t = p["start_s"] + d["switch_frac"] * readout_s
            parts.append(SwitchedLight(_make_light(d["before"]), _make_light(d["after"]), t))
        else:
            parts.append(_make_light(d))
    return parts[0] if len(parts) == 1 else SumLight(tuple(parts))


def _camera(p: dict) -> CameraModel:
    over = p["oversample"]
    n_rows = int(round(p["size"][0] * over))
    return CameraModel(row_time_s=1.0 / (p["row_rate_hz"] * over), n_rows=n_rows,
                       exposure_s=p["exposure_s"])


def _crop(d: dict, bank: tuple[str, ...], n_rows: int, n_cols: int) -> np.ndarray:
    """The bank photo's crop for a frame of (n_rows, n_cols), linear, balanced (any size)."""
    from synth.scene import srgb_to_linear

    img = _bank_image(bank[d["bank_index"] % len(bank)])
    if d.get("rot90"):
        img = np.rot90(img)
    h, w = img.shape[:2]
    aspect = n_cols / n_rows
    ch, cw = (h, int(round(h * aspect))) if w / h >= aspect else (int(round(w / aspect)), w)
    s = d["crop"][0]
    ch, cw = max(min(int(ch * s), h), 4), max(min(int(cw * s), w), 4)
    r0, c0 = int((h - ch) * d["crop"][1]), int((w - cw) * d["crop"][2])
    crop = img[r0:r0 + ch, c0:c0 + cw]
    if d.get("flip"):
        crop = crop[:, ::-1]
    # linearise, contrast and white balance in one lookup per channel (what `_balance` does)
    lut = _balance(np.repeat(srgb_to_linear(np.arange(256, dtype=np.uint8))[:, None], 3,
                             axis=1).astype(np.float32), d)
    return np.stack([lut[crop[..., c], c] for c in range(3)], axis=-1)


def _balance(refl: np.ndarray, d: dict) -> np.ndarray:
    out = np.power(np.clip(refl, 1e-4, 1.0), np.float32(d["contrast"]), dtype=np.float32)
    out *= np.asarray(d["balance"], np.float32)
    return np.clip(out, 0.0, 1.0)


def _full_scene(d: dict, bank: tuple[str, ...], n_rows: int, n_cols: int) -> np.ndarray:
    """Reflectance of a scene description at (n_rows, n_cols): procedural and texture scenes
    are drawn at this size (both renderers), photos are resized from their crop."""
    from synth.fastrender import _resize
    from synth.scene import texture_scene

    rng = np.random.default_rng(d["seed"])
    if d["kind"] == "bank" and bank:
        return _resize(np.ascontiguousarray(_crop(d, bank, n_rows, n_cols)), n_rows, n_cols)
    rows, cols = (n_cols, n_rows) if d.get("rot90") else (n_rows, n_cols)
    half = max(rows // 2, 2), max(cols // 2, 2)  # drawn at half size, enlarged: a texture's
    #                                              period and a grain of two pixels or more
    if d["kind"] == "texture":
        refl = _resize(texture_scene(d["texture"], *half, rng=rng)[0], rows, cols)
    else:
        refl = _resize(_procedural(rng, *half), rows, cols)
    if d.get("rot90"):
        refl = np.ascontiguousarray(np.rot90(refl))
    return _balance(refl, d)


def _procedural(rng: np.random.Generator, n_rows: int, n_cols: int) -> np.ndarray:
    """A synthetic non-periodic scene: smooth colour field, random rectangles, fine grain."""
    small = rng.uniform(0.1, 0.9, (int(rng.integers(2, 8)), int(rng.integers(2, 8)), 3))
    img = cv2.resize(small.astype(np.float32), (n_cols, n_rows), interpolation=cv2.INTER_CUBIC)
    for _ in range(int(rng.integers(0, 12))):
        r0, c0 = int(rng.integers(n_rows)), int(rng.integers(n_cols))
        h, w = int(rng.integers(8, max(9, n_rows // 2))), int(rng.integers(8, max(9, n_cols // 2)))
        img[r0:r0 + h, c0:c0 + w] = rng.uniform(0.05, 0.95, 3)
    grain = rng.standard_normal((n_rows, n_cols, 1), dtype=np.float32)
    grain *= np.float32(rng.uniform(0, 0.08))
    grain += np.float32(1.0)
    return np.clip(img * grain, 0.01, 1.0).astype(np.float32)


def _coverage_at(c: dict | None, rows_frac: np.ndarray, cols_frac: np.ndarray,
                 n_rows: int, n_cols: int) -> np.ndarray | None:
    """The LED's coverage at the given row and column positions (fractions of the frame of
    n_rows x n_cols pixels): a disc with a raised-cosine edge or a soft rectangle."""
    if c is None:
        return None
    r = np.asarray(rows_frac, np.float32)[:, None]
    q = np.asarray(cols_frac, np.float32)[None, :]
    if c["shape"] == "disc":
        radius, edge = _disc_radius(c["fraction"], tuple(c["centre_rc"]), c["softness"],
                                    n_rows, n_cols)
        d = np.sqrt(((r - c["centre_rc"][0]) * n_rows) ** 2
                    + ((q - c["centre_rc"][1]) * n_cols) ** 2)
        x = np.clip((d - radius) / edge, 0.0, 1.0)
        return (0.5 + 0.5 * np.cos(np.pi * x)).astype(np.float32)
    h = min(1.0, math.sqrt(c["fraction"] / c["aspect"]))
    w = min(1.0, c["fraction"] / h)
    e = max(c["softness"] * 0.5, 1e-3)

    def ramp(x, lo, hi):
        return np.clip(np.minimum(x - lo, hi - x) / e + 0.5, 0.0, 1.0)

    r0, c0 = c["centre_rc"][0] - h / 2, c["centre_rc"][1] - w / 2
    return (ramp(r, r0, r0 + h) * ramp(q, c0, c0 + w)).astype(np.float32)


@functools.lru_cache(maxsize=256)
def _disc_radius(fraction: float, centre_rc: tuple, softness: float, n_rows: int,
                 n_cols: int) -> tuple[float, float]:
    """Radius (pixels) whose disc has mean ``fraction`` over the frame, and the edge width."""
    diag = math.hypot(n_rows, n_cols)
    edge = max(softness * diag, 1.0)
    g = (np.arange(64, dtype=np.float32) + 0.5) / 64
    d = np.sqrt(((g[:, None] - centre_rc[0]) * n_rows) ** 2
                + ((g[None, :] - centre_rc[1]) * n_cols) ** 2)
    lo, hi = -edge, 2.0 * diag
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        x = np.clip((d - mid) / edge, 0.0, 1.0)
        if (0.5 + 0.5 * np.cos(np.pi * x)).mean() < fraction:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi), edge


def _centres(n: int) -> np.ndarray:
    return (np.arange(n, dtype=np.float32) + 0.5) / n


def _contrast(light, camera: CameraModel, p: dict) -> float:
    from synth.camera import led_row_contrast

    cov = p["coverage"]
    lit = 1.0 if cov is None else float(_coverage_at(cov, _centres(48), _centres(48),
                                                     *p["size"]).mean())
    return led_row_contrast(light, camera, start_s=p["start_s"],
                            ambient_ratio=p["ambient_ratio"], lit_fraction=lit)


# -- the reference renderer -------------------------------------------------------------------

def _clean_tile(d: dict, bank: tuple[str, ...], h: int, w: int) -> np.ndarray:
    from synth.camera import linear_to_srgb8

    refl = _full_scene(d, bank, h, w)
    gain = 0.18 / max(float(refl.mean()), 1e-3)
    return linear_to_srgb8(np.clip(refl * gain, 0, 1))


def _compose(img: np.ndarray, c: dict, bank: tuple[str, ...]) -> np.ndarray:
    h, w = img.shape[:2]
    colour = np.array(c["colour"], np.uint8)
    if c["kind"] == "border":
        hh, ww = _border_size(h, w, c)
        out = np.empty((hh, ww, 3), np.uint8)
        out[:] = colour
        r0, c0 = int((hh - h) * c["where"][0]), int((ww - w) * c["where"][1])
        out[r0:r0 + h, c0:c0 + w] = img
        return out
    if c["kind"] == "collage":
        tiles = [_clean_tile(d, bank, h, w) for d in c["tiles"]]
        tiles.insert(c["slot"], img)
        return np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])])
    sh, sw = max(8, int(h * c["shrink"])), max(8, int(w * c["shrink"]))
    small = cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA)
    out = _clean_tile(c["tiles"][0], bank, h, w) if c["frame_photo"] else \
        np.full_like(img, colour)
    r0, c0 = int((h - sh) * c["where"][0]), int((w - sw) * c["where"][1])
    out[r0:r0 + sh, c0:c0 + sw] = small
    return out


def stripe_lines_per_row(p: dict) -> float:
    """Lines of the decoded image's stripe axis per frame row of example ``p``: the frame's
    shrink inside a frame composite, over the decoder's DCT-domain scale."""
    from lishield_guard.decode import jpeg_scale

    h, w = p["size"][::-1] if p["rotate"] else p["size"]
    c = p["composite"] or {}
    if c.get("kind") == "border":
        h, w = _border_size(h, w, c)
    elif c.get("kind") == "collage":
        h, w = 2 * h, 2 * w
    shrink = c["shrink"] if c.get("kind") == "frame" else 1.0
    scale = jpeg_scale(h, MAX_DECODE_ROWS if h >= 2 * MAX_DECODE_ROWS else 0)
    return shrink / scale


def _border_size(h: int, w: int, c: dict) -> tuple[int, int]:
    scale = math.sqrt(c["area"])
    return max(int(h * (scale if c["tall"] else 1.0)), h), max(int(w * scale), w)


def render(p: dict, bank: tuple[str, ...] = ()) -> tuple[bytes, dict]:
    """Render example ``p`` (`sample_example`) in full: the JPEG bytes an upload would carry,
    and what rendering measured (``led_contrast``, ``gain``)."""
    from synth.camera import encode_jpeg, simulate_frame

    n_rows, n_cols = p["size"]
    camera = _camera(p)
    rs, cs = camera.n_rows, int(round(n_cols * p["oversample"]))
    if p["scene"]["kind"] == "bank" and bank:
        refl = _full_scene(p["scene"], bank, rs, cs)
    else:  # drawn at the frame's size, as the profile renderer draws it
        from synth.fastrender import _resize

        refl = _resize(_full_scene(p["scene"], bank, n_rows, n_cols), rs, cs)
    light = _lights(p, camera.readout_s)
    cov = _coverage_at(p["coverage"], _centres(rs), _centres(cs), *p["size"])
    frame = simulate_frame(light, refl, camera, rng=np.random.default_rng(p["noise_seed"]),
                           start_s=p["start_s"], ambient_ratio=p["ambient_ratio"],
                           coverage=cov)
    if (rs, cs) != (n_rows, n_cols):
        frame = cv2.resize(frame, (n_cols, n_rows), interpolation=cv2.INTER_AREA)
    if p["tone"]:
        from synth.fastrender import _tone

        frame = np.round(_tone(frame.astype(np.float32), p["tone"])).astype(np.uint8)
    if p["denoise"]:
        kind, sigma = p["denoise"]
        frame = cv2.GaussianBlur(frame, (0, 0), sigma) if kind == "gauss" else \
            cv2.bilateralFilter(frame, 5, 25.0 * sigma, 3)
    if p["sharpen"]:
        blur = cv2.GaussianBlur(frame, (0, 0), 1.5)
        frame = cv2.addWeighted(frame, 1 + p["sharpen"], blur, -p["sharpen"], 0)
    if p["rotate"]:
        frame = np.ascontiguousarray(np.rot90(frame, k=-(p["rotate"] // 90)))
    if p["composite"]:
        frame = _compose(frame, p["composite"], bank)
    data = encode_jpeg(frame, quality=p["jpeg_quality"], subsampling=p["subsampling"])
    return data, {"led_contrast": _contrast(light, camera, p)}


def profiles_of_jpeg(data: bytes) -> dict:
    """What the detector's decision reduces an upload to: `spectra.analysable` of the
    detector's own decode (colour planes, DCT-domain scaling of large JPEGs)."""
    from lishield_guard.decode import decode
    from lishield_guard.detector.spectra import analysable

    decoded = decode(data, want_rgb=True, max_rows=MAX_DECODE_ROWS)
    return analysable(decoded.rgb())


# -- the profile-domain renderer --------------------------------------------------------------

def _scene_cells(d: dict, bank: tuple[str, ...], n_rows: int, n_cols: int, *, rows: bool,
                 cols: bool):
    """`synth.fastrender.SceneGrids` of a scene description at (n_rows, n_cols): from the
    photo's crop directly, or from the procedural scene drawn at that size."""
    from synth.fastrender import scene_grids

    src = _crop(d, bank, n_rows, n_cols) if d["kind"] == "bank" and bank else \
        _full_scene(d, bank, n_rows, n_cols)
    return scene_grids(src, n_rows, n_cols, rows=rows, cols=cols)


def _clean_grids(d: dict, bank: tuple[str, ...], h: int, w: int, like):
    from synth.fastrender import still_grids

    sg = _scene_cells(d, bank, h, w, rows=like.rows is not None, cols=like.cols is not None)
    mean = sg.rows_mean if sg.rows_mean is not None else sg.cols_mean
    return still_grids(sg, 0.18 / max(float(mean.mean()), 1e-3))


def _compose_grids(g, c: dict, bank: tuple[str, ...]):
    from synth import fastrender as fr

    h, w = g.height, g.width
    if c["kind"] == "border":
        hh, ww = _border_size(h, w, c)
        return fr.compose_border(g, height=hh, width=ww, r0=int((hh - h) * c["where"][0]),
                                 c0=int((ww - w) * c["where"][1]), colour=c["colour"])
    if c["kind"] == "collage":
        tiles = [_clean_grids(d, bank, h, w, g) for d in c["tiles"]]
        tiles.insert(c["slot"], g)
        return fr.compose_collage(tiles)
    bg = _clean_grids(c["tiles"][0], bank, h, w, g) if c["frame_photo"] else \
        fr.blank_grids(h, w, c["colour"], rows=g.rows is not None, cols=g.cols is not None)
    return fr.compose_frame(g, bg, shrink=c["shrink"], where=tuple(c["where"]))


def render_profiles(p: dict, bank: tuple[str, ...] = (), *, both_axes: bool = False
                    ) -> tuple[dict, dict]:
    """Render example ``p`` in the profile domain (`synth.fastrender`): the block profiles
    `profiles_of_jpeg` would give for `render`'s bytes, and the same measurements.

    Only the axis the stripes run along (the stored rows, or the columns of a rotated capture)
    is rendered unless ``both_axes``: training reads every instance of one axis with the same
    network, and the other axis of a capture is a scene seen across (`_scene_desc` rotates a
    scene now and then so that training sees that too).
    """
    from lishield_guard.decode import jpeg_scale
    from synth import fastrender as fr
    from synth.camera import led_rows_rgb

    n_rows, n_cols = p["size"]
    camera = _camera(p)
    scene = _scene_cells(p["scene"], bank, n_rows, n_cols, rows=True, cols=both_axes)
    light = _lights(p, camera.readout_s)
    led = led_rows_rgb(light, camera, start_s=p["start_s"]).astype(np.float32)
    led = fr._resize2(led[:, None, :], n_rows, 0)[:, 0, :]  # frame rows: sensor rows' mean
    cov = None if p["coverage"] is None else (
        lambda r, c: _coverage_at(p["coverage"], r, c, n_rows, n_cols))
    g, gain = fr.capture_grids(scene, led, ambient=p["ambient_ratio"], coverage=cov,
                               exposure_s=p["exposure_s"],
                               pixels_per_cell=8 * p["oversample"] ** 2,
                               rng=np.random.default_rng(p["noise_seed"]), tone=p["tone"])
    g = fr.postprocess_grids(g, denoise=p["denoise"], sharpen=p["sharpen"])
    g = fr.rotate_grids(g, p["rotate"])
    if p["composite"]:
        g = _compose_grids(g, p["composite"], bank)
    min_rows = MAX_DECODE_ROWS if g.height >= 2 * MAX_DECODE_ROWS else 0
    g = fr.jpeg_roundtrip(g, quality=p["jpeg_quality"], subsampling=p["subsampling"],
                          scale=jpeg_scale(g.height, min_rows))
    return fr.block_profiles(g), {"led_contrast": _contrast(light, camera, p), "gain": gain}


# -- examples ---------------------------------------------------------------------------------

def _record(p: dict, meas: dict) -> dict:
    led = next((d for d in p["lights"] if d["kind"] == "led"), {})
    return {"index": p["index"], "label": p["label"], "kind": p["kind"], "preset": p["preset"],
            "f_b_hz": led.get("switching_hz"), "attack": p["attack"] is not None,
            "ambient": p["ambient_ratio"],
            "coverage": (p["coverage"] or {}).get("fraction", 1.0),
            "composite": (p["composite"] or {}).get("kind"), "rotate": p["rotate"],
            "led_contrast": meas["led_contrast"]}


def example_profiles(index: int, seed: int, bank_dir: str = str(DEFAULT_BANK), *,
                     fast: bool = True, texture: str | None = None) -> tuple[dict, dict]:
    """Block profiles (axis -> (3, 32, n_lines)) and record of one example, by the profile
    renderer (``fast``) or the full one (``texture``: see `sample_example`)."""
    bank = scene_bank(bank_dir)
    p = sample_example(index, seed, bank_weights(bank_dir), texture)
    if fast:
        profiles, meas = render_profiles(p, bank)
    else:
        data, meas = render(p, bank)
        profiles = profiles_of_jpeg(data)["profiles"]
    return profiles, _record(p, meas)


def example(index: int, seed: int, bank_dir: str = str(DEFAULT_BANK), *, fast: bool = True
            ) -> tuple[np.ndarray, dict]:
    """The decision input of one example (`lishield_guard.detector.tfinput`) and its record."""
    from lishield_guard.detector.tfinput import profiles_input

    profiles, rec = example_profiles(index, seed, bank_dir, fast=fast)
    return profiles_input(profiles, full_scale=255.0), rec


def encode_npz(arrays: dict) -> bytes:
    """``np.savez_compressed`` into bytes."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()

