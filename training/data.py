"""Training data for the learned decision stage: wide-mix synthetic captures -> decision inputs.

Every example is drawn from its own seed (``SeedSequence([seed, index])``) by `sample_example`,
rendered through the project's rolling-shutter model (`synth.camera.simulate_frame`, lights
from `firmware.sequence.compile_spec`), post-processed like a phone and an upload app would
(tone curve, sharpening, denoising, resizing, rotation, borders, collages, frames, JPEG),
decoded by the detector's own decoder and reduced by the detector's own
`lishield_guard.detector.spectra.image_input`. Output is byte-identical for a seed whatever
the number of workers.

The mix is deliberately wider than any evaluation (issue 32, "Trained on the physics"):

- emitters: the shipped policy's presets (table1-seq1/2/3 mono, table2-rgb), f_B from 150 Hz to
  1.25 f_1 (a quarter at 200 Hz, a fifth at f_1), restart or continuous phase, any slot order,
  duty 0.3-0.7, rise 0-10 % of the shortest half-period;
- camera: row rate 15-150 kHz (frames are rendered at their final size, so this also stands for
  downscaling), exposure 1/8000-1/30 s with a fifth k/f attacks, auto gain, noise;
- light: ambient 0-20x the LED, the LED on part of the frame (disc or rectangle, 5-80 %),
  a second flickering light (PWM or mains) beside the LED;
- look-alikes: steady, mains (100/120 Hz), PWM (60 Hz-25 kHz, duty 0.05-0.95), two lights,
  periodic textures (blinds, bricks, fabric) under steady or PWM light, any of them on part
  of the frame;
- scenes: real photos (88 %: the scene bank built from the ``out/photos`` corpus, reserved
  packages left out) and procedural scenes;
- processing: tone curves, unsharp masking, denoising, 30 % rendered larger and resized,
  rotation by 90/270 degrees, JPEG 50-98 (4:2:0 or 4:4:4), and a quarter of all images
  composed (uniform border of any colour, 2x2 collage with clean photos, shrunk in a frame).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import math
from pathlib import Path

import cv2
import numpy as np

from lishield_guard.camera import CameraModel
from lishield_guard.decode import decode
from lishield_guard.detector.spectra import image_input
from lishield_guard.spec import get_preset

__all__ = ["DEFAULT_BANK", "MONO_PRESETS", "RGB_PRESETS", "example", "sample_example",
           "scene_bank"]

MONO_PRESETS = ("table1-seq1", "table1-seq2", "table1-seq3")
RGB_PRESETS = ("table2-rgb",)
DEFAULT_BANK = Path("out/scenebank")
NEG_KINDS = ("steady", "mains", "pwm", "two-lights", "texture")
NEG_PROBS = (0.22, 0.2, 0.3, 0.1, 0.18)
MAX_DECODE_ROWS = 768  # the shipped detector's profiles.max_decode_rows


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


@functools.cache
def scene_bank(folder: str = str(DEFAULT_BANK)) -> tuple[str, ...]:
    """JPEG files of the scene bank (`training.scenes.build_bank`), sorted; () when absent."""
    p = Path(folder)
    return tuple(sorted(str(f) for f in p.glob("*.jpg"))) if p.is_dir() else ()


@functools.lru_cache(maxsize=48)
def _bank_image(path: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _scene(rng: np.random.Generator, n_rows: int, n_cols: int, bank: tuple[str, ...],
           kind: str | None = None) -> tuple[np.ndarray, str]:
    """Linear reflectance (n_rows, n_cols, 3) and its description."""
    from synth import scene as sc

    u = rng.random()
    if kind == "texture":
        tk = str(rng.choice(sc.TEXTURE_KINDS))
        refl, _ = sc.texture_scene(tk, n_rows, n_cols, rng=rng)
        return refl, f"texture:{tk}"
    if bank and u < 0.88:
        path = bank[int(rng.integers(len(bank)))]
        return sc.photo_scene(_bank_image(path), n_rows, n_cols, rng=rng, min_crop=0.35), \
            f"bank:{Path(path).name}"
    return _procedural(rng, n_rows, n_cols), "procedural"


def _procedural(rng: np.random.Generator, n_rows: int, n_cols: int) -> np.ndarray:
    """A synthetic non-periodic scene: smooth colour field, random rectangles, fine grain."""
    small = rng.uniform(0.1, 0.9, (int(rng.integers(2, 8)), int(rng.integers(2, 8)), 3))
    img = cv2.resize(small.astype(np.float32), (n_cols, n_rows), interpolation=cv2.INTER_CUBIC)
    for _ in range(int(rng.integers(0, 12))):
        r0, c0 = int(rng.integers(n_rows)), int(rng.integers(n_cols))
        h, w = int(rng.integers(8, max(9, n_rows // 2))), int(rng.integers(8, max(9, n_cols // 2)))
        img[r0:r0 + h, c0:c0 + w] = rng.uniform(0.05, 0.95, 3)
    grain = rng.normal(1.0, float(rng.uniform(0, 0.08)), (n_rows, n_cols, 1))
    return np.clip(img * grain.astype(np.float32), 0.01, 1.0).astype(np.float32)


def sample_example(index: int, seed: int) -> dict:
    """Every parameter of example ``index`` of the dataset drawn with ``seed`` (no rendering)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))
    label = int(rng.random() < 0.5)
    p: dict = {"index": int(index), "label": label, "render_seed": int(rng.integers(2**63))}
    n_rows = int(round(_log_uniform(rng, 400, 1600)))
    aspect = _log_uniform(rng, 0.5, 2.2)
    p["size"] = [n_rows, max(96, int(round(n_rows * aspect)))]
    p["oversample"] = _log_uniform(rng, 1.2, 2.5) if rng.random() < 0.3 else 1.0
    p["row_rate_hz"] = _log_uniform(rng, 15_000, 150_000)
    exposure = _log_uniform(rng, 1 / 8000, 1 / 30)
    p["attack"] = None
    lights: list[dict] = []
    if label:
        spec = get_preset(str(rng.choice(RGB_PRESETS if rng.random() < 0.5 else MONO_PRESETS)))
        f1 = spec.f1_hz
        u = rng.random()
        f_b = 200.0 if u < 0.25 else f1 if u < 0.45 else _log_uniform(rng, 150, 1.25 * f1)
        m = spec.n_tones
        order = [int(i) for i in rng.permutation(m)]
        phase = "continuous" if rng.random() < 0.5 else "restart"
        duty = float(rng.uniform(0.3, 0.7))
        half = min(duty, 1 - duty) / spec.all_freqs_hz[-1]
        lights.append({"kind": "led", "preset": spec.name, "switching_hz": round(f_b, 2),
                       "order": order, "phase": phase, "duty": duty,
                       "rise_s": float(rng.uniform(0, 0.1)) * half,
                       "loop_patterns": max(1, math.ceil(0.1 * f_b / m))
                       if phase == "continuous" else 1})
        p["kind"], p["preset"] = "barcode", spec.name
        if rng.random() < 0.2:
            chan = spec.channels[int(rng.integers(len(spec.channels)))][1]
            f = float(chan[int(rng.integers(len(chan)))])
            ks = [k for k in (1, 2, 3) if 1 / 8000 <= k / f <= 1 / 30]
            k = ks[int(rng.integers(len(ks)))]
            exposure = k / f
            p["attack"] = {"hz": f, "k": k}
        if rng.random() < 0.15:
            lights.append(_lookalike_light(rng, str(rng.choice(["pwm", "mains"]))))
    else:
        kind = NEG_KINDS[int(rng.choice(len(NEG_KINDS), p=np.asarray(NEG_PROBS)))]
        p["kind"], p["preset"] = kind, None
        if kind in ("mains", "pwm"):
            lights.append(_lookalike_light(rng, kind))
        elif kind == "two-lights":
            lights += [_lookalike_light(rng, "pwm"),
                       _lookalike_light(rng, str(rng.choice(["pwm", "mains"])))]
        elif kind == "texture" and rng.random() < 0.4:
            lights.append(_lookalike_light(rng, "pwm"))
        if not lights:
            lights.append({"kind": "steady"})
    p["lights"] = lights
    p["exposure_s"] = exposure
    p["ambient_ratio"] = 0.0 if rng.random() < 0.25 else _log_uniform(rng, 0.05, 20.0)
    flickers = p["kind"] != "steady" and not (p["kind"] == "texture" and len(lights) == 1
                                               and lights[0]["kind"] == "steady")
    p["coverage"] = None
    if flickers and rng.random() < (0.4 if label else 0.25):
        p["coverage"] = {"shape": str(rng.choice(["disc", "rect"])),
                         "fraction": float(rng.uniform(0.05, 0.8)),
                         "centre_rc": [float(rng.uniform(0.1, 0.9)), float(rng.uniform(0.1,
                                                                                       0.9))],
                         "aspect": _log_uniform(rng, 0.4, 2.5),
                         "softness": float(rng.uniform(0.02, 0.25))}
    p["scene_kind"] = "texture" if p["kind"] == "texture" or (label and rng.random() < 0.1) \
        else None
    p["tone"] = None
    if rng.random() < 0.4:
        p["tone"] = {"gamma": _log_uniform(rng, 0.6, 1.6), "s_curve": float(rng.uniform(0, 0.6))}
    p["sharpen"] = float(rng.uniform(0.3, 1.5)) if rng.random() < 0.25 else 0.0
    p["denoise"] = str(rng.choice(["gauss", "bilateral"])) if rng.random() < 0.2 else None
    p["rotate"] = int(rng.choice([90, 270])) if rng.random() < 0.2 else 0
    p["composite"] = None
    if rng.random() < 0.25:
        ck = str(rng.choice(["border", "collage", "frame"]))
        p["composite"] = {"kind": ck, "area": float(rng.uniform(1.2, 3.0)),
                          "colour": [int(v) for v in rng.integers(0, 256, 3)]
                          if rng.random() < 0.5 else [255, 255, 255],
                          "where": [float(rng.random()), float(rng.random())],
                          "shrink": float(rng.uniform(0.4, 0.8)),
                          "seed": int(rng.integers(2**63))}
    p["jpeg_quality"] = int(rng.integers(50, 99))
    p["subsampling"] = "4:2:0" if rng.random() < 0.75 else "4:4:4"
    return p


def _lookalike_light(rng: np.random.Generator, kind: str) -> dict:
    if kind == "mains":
        return {"kind": "mains", "supply_hz": float(rng.choice([50.0, 60.0])),
                "depth": float(rng.uniform(0.05, 1.0)), "phase_s": float(rng.uniform(0, 0.02))}
    freq = _log_uniform(rng, 60.0, 25_000.0)
    return {"kind": "pwm", "freq_hz": freq, "duty": float(rng.uniform(0.05, 0.95)),
            "depth": float(rng.uniform(0.1, 1.0)), "phase_s": float(rng.uniform(0, 1 / freq))}


@dataclasses.dataclass(frozen=True)
class SumLight:
    """Several lights at once: intensities (and so cumulative integrals) add."""

    parts: tuple
    channels: tuple[str, ...] = ("R", "G", "B")

    def cumulative(self, t_s):
        """Sum of the parts' cumulative integrals, in R, G, B."""
        from synth.light import light_to_rgb

        return sum(light_to_rgb(p.cumulative(t_s), tuple(p.channels)) for p in self.parts)

    def mean_level(self) -> np.ndarray:
        """Sum of the parts' mean levels, in R, G, B."""
        from synth.light import mean_rgb

        return sum(mean_rgb(p) for p in self.parts)


def _make_light(d: dict):
    """The light of one description (`synth.dataset`'s, which also takes ``duty``)."""
    from synth.dataset import _make_light as make

    return make({"light": d})


def _coverage(c: dict | None, n_rows: int, n_cols: int) -> np.ndarray | None:
    if c is None:
        return None
    if c["shape"] == "disc":
        from synth.light import coverage_map

        return coverage_map(n_rows, n_cols, fraction=c["fraction"],
                            centre_rc=tuple(c["centre_rc"]), softness=c["softness"])
    h = min(1.0, math.sqrt(c["fraction"] / c["aspect"]))
    w = min(1.0, c["fraction"] / h)
    r = (np.arange(n_rows, dtype=np.float32) + 0.5) / n_rows
    q = (np.arange(n_cols, dtype=np.float32) + 0.5) / n_cols
    edge = max(c["softness"] * 0.5, 1e-3)

    def ramp(x, lo, hi):
        return np.clip(np.minimum(x - lo, hi - x) / edge + 0.5, 0.0, 1.0)

    r0 = c["centre_rc"][0] - h / 2
    c0 = c["centre_rc"][1] - w / 2
    return (ramp(r, r0, r0 + h)[:, None] * ramp(q, c0, c0 + w)[None, :]).astype(np.float32)


def _tone(img: np.ndarray, t: dict) -> np.ndarray:
    x = np.linspace(0.0, 1.0, 256)
    y = x ** t["gamma"]
    y = y + t["s_curve"] * (y - 0.5) * y * (1 - y) * 2
    lut = np.clip(np.round(y * 255), 0, 255).astype(np.uint8)
    return cv2.LUT(img, lut)


def _compose(img: np.ndarray, c: dict, bank: tuple[str, ...]) -> np.ndarray:
    """The capture as an upload app might present it: inside a border, in a 2x2 collage with
    clean photos, or shrunk inside a frame."""
    rng = np.random.default_rng(c["seed"])
    h, w = img.shape[:2]
    colour = np.array(c["colour"], np.uint8)
    if c["kind"] == "border":
        scale = math.sqrt(c["area"])
        hh, ww = int(h * (scale if rng.random() < 0.5 else 1.0)), int(w * scale)
        out = np.empty((max(hh, h), max(ww, w), 3), np.uint8)
        out[:] = colour
        r0 = int((out.shape[0] - h) * c["where"][0])
        c0 = int((out.shape[1] - w) * c["where"][1])
        out[r0:r0 + h, c0:c0 + w] = img
        return out
    if c["kind"] == "collage":
        tiles = [img]
        for _ in range(3):
            tiles.append(_clean_tile(rng, h, w, bank))
        k = int(rng.integers(4))
        tiles[0], tiles[k] = tiles[k], tiles[0]
        return np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])])
    small = cv2.resize(img, (max(8, int(w * c["shrink"])), max(8, int(h * c["shrink"]))),
                       interpolation=cv2.INTER_AREA)
    out = _clean_tile(rng, h, w, bank) if rng.random() < 0.4 else np.full_like(img, colour)
    r0 = int((h - small.shape[0]) * c["where"][0])
    c0 = int((w - small.shape[1]) * c["where"][1])
    out[r0:r0 + small.shape[0], c0:c0 + small.shape[1]] = small
    return out


def _clean_tile(rng: np.random.Generator, h: int, w: int, bank: tuple[str, ...]) -> np.ndarray:
    from synth.camera import linear_to_srgb8

    refl, _ = _scene(rng, h, w, bank)
    gain = 0.18 / max(float(refl.mean()), 1e-3)
    return linear_to_srgb8(np.clip(refl * gain, 0, 1))


def render(p: dict, bank: tuple[str, ...] = ()) -> tuple[bytes, dict]:
    """Render example ``p`` (`sample_example`) to JPEG bytes; also returns what rendering
    measured (``led_contrast``, ``scene``)."""
    from synth.camera import encode_jpeg, led_row_contrast, simulate_frame

    rng = np.random.default_rng(p["render_seed"])
    over = p["oversample"]
    n_rows, n_cols = (int(round(v * over)) for v in p["size"])
    refl, scene_desc = _scene(rng, n_rows, n_cols, bank, p["scene_kind"])
    parts = [_make_light(d) for d in p["lights"]]
    light = parts[0] if len(parts) == 1 else SumLight(tuple(parts))
    camera = CameraModel(row_time_s=1.0 / (p["row_rate_hz"] * over), n_rows=n_rows,
                         exposure_s=p["exposure_s"])
    cov = _coverage(p["coverage"], n_rows, n_cols)
    start = float(rng.uniform(0, 1))
    frame = simulate_frame(light, refl, camera, rng=rng, start_s=start,
                           ambient_ratio=p["ambient_ratio"], coverage=cov)
    contrast = led_row_contrast(light, camera, start_s=start, ambient_ratio=p["ambient_ratio"],
                                lit_fraction=1.0 if cov is None else float(cov.mean()))
    if over > 1.0:
        frame = cv2.resize(frame, (p["size"][1], p["size"][0]), interpolation=cv2.INTER_AREA)
    if p["tone"]:
        frame = _tone(frame, p["tone"])
    if p["denoise"] == "gauss":
        frame = cv2.GaussianBlur(frame, (0, 0), float(rng.uniform(0.5, 1.2)))
    elif p["denoise"] == "bilateral":
        frame = cv2.bilateralFilter(frame, 5, float(rng.uniform(10, 40)), 3)
    if p["sharpen"]:
        blur = cv2.GaussianBlur(frame, (0, 0), 1.5)
        frame = cv2.addWeighted(frame, 1 + p["sharpen"], blur, -p["sharpen"], 0)
    if p["rotate"]:
        frame = np.ascontiguousarray(np.rot90(frame, k=-(p["rotate"] // 90)))
    if p["composite"]:
        frame = _compose(frame, p["composite"], bank)
    data = encode_jpeg(frame, quality=p["jpeg_quality"], subsampling=p["subsampling"])
    return data, {"led_contrast": contrast, "scene": scene_desc}


def example(index: int, seed: int, bank_dir: str = str(DEFAULT_BANK)
            ) -> tuple[np.ndarray, dict]:
    """Decision input (float16, shape (n_windows, channels, frequencies)) and record of one
    example, through the detector's own decode and `spectra.image_input`."""
    p = sample_example(index, seed)
    data, meas = render(p, scene_bank(bank_dir))
    decoded = decode(data, want_rgb=True, max_rows=MAX_DECODE_ROWS)
    x = image_input(decoded.rgb()).x
    rec = {"index": p["index"], "label": p["label"], "kind": p["kind"], "preset": p["preset"],
           "f_b_hz": p["lights"][0].get("switching_hz"), "attack": p["attack"] is not None,
           "ambient": p["ambient_ratio"], "coverage": (p["coverage"] or {}).get("fraction", 1.0),
           "composite": (p["composite"] or {}).get("kind"), "rotate": p["rotate"],
           "bytes": len(data), **meas}
    return x.astype(np.float16), rec


def encode_npz(arrays: dict) -> bytes:
    """``np.savez_compressed`` into bytes."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()
