"""Synthetic video clips: consecutive rolling-shutter frames of one light, encoded with PyAV.

A clip is the photo dataset's capture (`synth.dataset.sample_item`: light, emitter, scene,
ambient light, coverage, exposure, look-alike kinds) filmed for 2-10 s. Frame k starts at
``frame_start_s + k / fps`` and goes through the same camera model as a photo
(`synth.camera.simulate_frame`), so the LED runs on between frames and its phase moves from
frame to frame exactly as the firmware sequence says.

What a video adds (`VideoMix`, defaults in brackets)
-----------------------------------------------------
- frame rate drawn from 24/25/30/50/60 fps [probabilities 0.1/0.1/0.6/0.05/0.15];
- duration uniform in [2, 10] s; ``n_frames = round(duration * fps)``;
- readout: the whole frame is read in ``readout_s`` uniform in [10, 35] ms (DESIGN.md,
  "Readout duration"), capped at 95 % of the frame interval; the row rate is
  ``n_rows / readout_s`` (a downscaled 540p stream is read as fast as a 1080p one, so its
  rows are further apart in time);
- exposure: the photo mix's draw, capped at the frame interval, is where auto exposure
  starts; it then follows the scene (the metered brightness of the moving crop) with a time
  constant ``ae_tau_range_s`` [0.3-1.5 s] plus a slow random walk (``ae_walk_range``
  [0-0.15] log units per sqrt(s)); a manual-exposure attack clip keeps its exposure locked.
  The gain is metered in every frame by `simulate_frame`'s auto gain;
- camera motion on ``motion_prob`` [0.5] of the clips: the scene (and the LED's coverage
  map, fixed in the room) is rendered ``1 + margin`` times larger [margin 0.1-0.3] and a
  sensor-sized window pans linearly between two random positions, plus hand shake (an
  AR(1) jitter of ``shake_range_px`` [0-0.8 %] of the frame height, time constant 0.1 s);
  over a blinds texture this is "camera motion across blinds";
- encoding: H.264 (libx264, preset ``veryfast``, yuv420p, one thread, so output is
  byte-identical per seed) in MP4 at ``bits_per_pixel_range`` [0.025-0.25 bit per pixel and
  frame: 1.5-16 Mbit/s at 1080p30, 0.4-3.9 Mbit/s at 540p30], VBV max rate 1.5x and buffer
  2x the bitrate, a keyframe every 1-2 s; ``codec`` may be ``hevc`` (libx265, MP4) or
  ``vp9``/``vp8`` (WebM);
- rotation: the photo mix's 20 % rotated clips keep their draw; ``"exif"`` becomes a display
  matrix tag (``rotation_mode="tag"``, what a phone writes for a portrait video), ``"bake"``
  rotates the pixels;
- size: ``"mixed"`` (default) draws 540p (80 %), 720p (15 %) or 1080p (5 %) per clip;
  any name of `VIDEO_SIZES` or ``WxH`` fixes it. The photo mix's downscale and JPEG draws do
  not apply to a video and are dropped from its record.

Rendering cost per frame, one core (simulate_frame about 3/4, libx264 veryfast about 1/4):
about 31 / 55 / 145 ms at 540p / 720p / 1080p on an idle core, 42 / 73 / 160 ms on a busy
shared one. A default clip averages 6 s at 34 fps (about 206 frames), so a 400-clip set is
about 400 * 206 * 41 ms / 2 jobs = 28 min on two idle cores (see docs/synth_video.md).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from lishield_guard.camera import CameraModel
from lishield_guard.errors import ConfigError
from synth.dataset import (
    NEGATIVE_KINDS,
    Mix,
    _coverage,
    _make_light,
    _render_scene,
    f_b_band,
    item_seed,
    label_order,
    resolve_mix,
    run_tasks,
    sample_item,
    write_manifest,
)

__all__ = [
    "CODECS",
    "SIZE_MIXES",
    "VIDEO_MIXES",
    "VIDEO_SIZES",
    "VideoMix",
    "clip_params",
    "render_video_item",
    "sample_video_item",
    "write_video_dataset",
]

VIDEO_SIZES = {"360p": (360, 640), "540p": (540, 960), "720p": (720, 1280),
               "1080p": (1080, 1920)}  # name -> (n_rows, n_cols), landscape
# Per-clip size draw; 540p-heavy so that 400 clips render in about 30 min on 2 cores.
SIZE_MIXES = {"mixed": (("540p", 0.8), ("720p", 0.15), ("1080p", 0.05))}
# codec name -> (encoder, container format, file suffix)
CODECS = {"h264": ("libx264", "mp4", ".mp4"), "hevc": ("libx265", "mp4", ".mp4"),
          "vp9": ("libvpx-vp9", "webm", ".webm"), "vp8": ("libvpx", "webm", ".webm")}
_PHOTO_ONLY = ("jpeg_quality", "chroma_subsampling", "downscale")
MIN_EXPOSURE_S = 1 / 8000  # shortest exposure auto exposure picks
_METER_STRIDE = 8  # auto exposure meters every 8th row and column of the crop


@dataclass(frozen=True)
class VideoMix:
    """Distributions of the video-only parameters (see the module docstring).

    Probabilities are unitless; ranges are (low, high) tuples.
    """

    name: str = "default"
    fps_choices: tuple[float, ...] = (24.0, 25.0, 30.0, 50.0, 60.0)
    fps_probs: tuple[float, ...] = (0.1, 0.1, 0.6, 0.05, 0.15)
    duration_range_s: tuple[float, float] = (2.0, 10.0)
    readout_range_s: tuple[float, float] = (0.010, 0.035)
    readout_max_frame_frac: float = 0.95
    ae_tau_range_s: tuple[float, float] = (0.3, 1.5)
    ae_walk_range: tuple[float, float] = (0.0, 0.15)
    motion_prob: float = 0.5
    margin_range: tuple[float, float] = (0.1, 0.3)
    shake_range_px: tuple[float, float] = (0.0, 0.008)  # std, as a fraction of n_rows
    shake_tau_s: float = 0.1
    codec: str = "h264"
    bits_per_pixel_range: tuple[float, float] = (0.025, 0.25)
    min_bitrate: int = 200_000
    gop_range_s: tuple[float, float] = (1.0, 2.0)
    x264_preset: str = "veryfast"

    def __post_init__(self) -> None:
        if len(self.fps_choices) != len(self.fps_probs) or not self.fps_choices or \
                abs(sum(self.fps_probs) - 1) > 1e-6 or min(self.fps_probs) < 0:
            raise ConfigError(f"fps_probs must match fps_choices and sum to 1, got "
                              f"{self.fps_choices!r} / {self.fps_probs!r}")
        for name in ("duration_range_s", "readout_range_s", "ae_tau_range_s", "ae_walk_range",
                     "margin_range", "shake_range_px", "bits_per_pixel_range", "gop_range_s"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ConfigError(f"{name} must be (low, high) with 0 <= low <= high, got "
                                  f"{(lo, hi)!r}")
        if not 0.0 <= self.motion_prob <= 1.0:
            raise ConfigError(f"need 0 <= motion_prob <= 1, got {self.motion_prob!r}")
        if self.codec not in CODECS:
            raise ConfigError(f"unknown codec {self.codec!r}; known: {', '.join(CODECS)}")
        if self.duration_range_s[0] <= 0 or self.readout_range_s[0] <= 0:
            raise ConfigError("duration_range_s and readout_range_s must be > 0")


VIDEO_MIXES: dict[str, VideoMix] = {
    "default": VideoMix(),
    "static": VideoMix(name="static", motion_prob=0.0),
    "motion": VideoMix(name="motion", motion_prob=1.0),
}


def parse_video_size(size: str | tuple[int, int]) -> tuple[int, int] | str:
    """(n_rows, n_cols), or the name of a `SIZE_MIXES` entry, for a size argument.

    Accepts a `VIDEO_SIZES` name, a `SIZE_MIXES` name, ``"WxH"`` (both even, >= 16) or a
    tuple; ConfigError otherwise.
    """
    if not isinstance(size, str):
        n_rows, n_cols = int(size[0]), int(size[1])
    else:
        s = size.strip().lower()
        if s in SIZE_MIXES:
            return s
        if s in VIDEO_SIZES:
            return VIDEO_SIZES[s]
        try:
            w, h = (int(v) for v in s.split("x"))
        except ValueError:
            raise ConfigError(f"size must be one of {', '.join([*VIDEO_SIZES, *SIZE_MIXES])} "
                              f"or WxH, got {size!r}") from None
        n_rows, n_cols = h, w
    if n_rows < 16 or n_cols < 16 or n_rows % 2 or n_cols % 2:
        raise ConfigError(f"video sides must be even and >= 16 (yuv420p), got "
                          f"{n_cols}x{n_rows}")
    return n_rows, n_cols


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sample_video_item(label: int, *, seed: int, mix: Mix | str = "default",
                      size: str | tuple[int, int] = "mixed",
                      video_mix: VideoMix | str = "default") -> dict:
    """Draw every parameter of one clip (no rendering).

    Parameters
    ----------
    label : {0, 1}
        1 for a barcode clip, 0 for a look-alike (steady, mains, PWM, texture).
    seed : int
        The clip's own seed (see `synth.dataset.item_seed`).
    mix : Mix or str
        Photo mix: light, emitter, scene, ambient, coverage, exposure and rotation draws
        (`synth.dataset.sample_item` with this seed, so they match the photo dataset's).
    size : str or (int, int)
        ``"mixed"`` (default: 540p/720p/1080p), a `VIDEO_SIZES` name, ``"WxH"`` or
        (n_rows, n_cols); sides even.
    video_mix : VideoMix or str
        Video-only distributions (frame rate, duration, readout, auto exposure, motion,
        encoding), or a key of `VIDEO_MIXES`.

    Returns
    -------
    dict
        JSON-ready parameters for `render_video_item`: the photo item's (minus JPEG and
        downscale) plus ``size``, ``fps``, ``n_frames``, ``duration_s``, ``readout_s``,
        ``row_rate_hz``, ``exposure_s`` (first frame), ``ae`` (``locked``, ``tau_s``,
        ``walk``, ``seed``), ``motion`` (``enabled``, ``margin``, ``pan_start_rc``,
        ``pan_end_rc`` as fractions of the margin, ``shake_px``, ``shake_tau_s``,
        ``seed``), ``codec``, ``encoder``, ``container``, ``bitrate`` (bit/s), ``gop_frames``,
        ``encoder_preset``, ``rotation_deg`` and ``rotation_mode`` (none/tag/bake).
    """
    mix = resolve_mix(mix)
    vmix = _resolve_video_mix(video_mix)
    vrng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))  # video-only draws
    size_rc = parse_video_size(size)
    size_name = size if isinstance(size, str) else f"{size_rc[1]}x{size_rc[0]}"
    if isinstance(size_rc, str):
        names, probs = zip(*SIZE_MIXES[size_rc], strict=True)
        size_name = str(names[int(vrng.choice(len(names), p=np.asarray(probs)))])
        size_rc = VIDEO_SIZES[size_name]
    n_rows, n_cols = size_rc
    p = sample_item(label, seed=seed, mix=mix, size=size_rc)
    for k in _PHOTO_ONLY:
        p.pop(k, None)
    fps = float(vmix.fps_choices[int(vrng.choice(len(vmix.fps_choices),
                                                 p=np.asarray(vmix.fps_probs)))])
    n_frames = max(1, int(round(vrng.uniform(*vmix.duration_range_s) * fps)))
    hi = min(vmix.readout_range_s[1], vmix.readout_max_frame_frac / fps)
    readout_s = float(vrng.uniform(min(vmix.readout_range_s[0], hi), hi))
    exposure_s = min(p["exposure_s"], 1.0 / fps)
    p.update(size=str(size_name), fps=fps, n_frames=n_frames, duration_s=n_frames / fps,
             readout_s=readout_s, row_rate_hz=n_rows / readout_s, exposure_s=exposure_s)
    p["ae"] = {"locked": bool(p["attack"]),
               "tau_s": float(vrng.uniform(*vmix.ae_tau_range_s)),
               "walk": float(vrng.uniform(*vmix.ae_walk_range)),
               "seed": int(vrng.integers(2**63))}
    moving = bool(vrng.random() < vmix.motion_prob)
    p["motion"] = {"enabled": moving, "margin": float(vrng.uniform(*vmix.margin_range)),
                   "pan_start_rc": [float(v) for v in vrng.uniform(0, 1, 2)],
                   "pan_end_rc": [float(v) for v in vrng.uniform(0, 1, 2)],
                   "shake_px": float(vrng.uniform(*vmix.shake_range_px) * n_rows),
                   "shake_tau_s": vmix.shake_tau_s, "seed": int(vrng.integers(2**63))} \
        if moving else {"enabled": False}
    encoder, container, _ = CODECS[vmix.codec]
    bpp = _log_uniform(vrng, *vmix.bits_per_pixel_range)
    p.update(codec=vmix.codec, encoder=encoder, container=container,
             bitrate=max(vmix.min_bitrate, int(round(bpp * n_rows * n_cols * fps, -3))),
             gop_frames=max(1, int(round(vrng.uniform(*vmix.gop_range_s) * fps))),
             encoder_preset=vmix.x264_preset, video_mix=vmix.name)
    p["rotation_mode"] = {"exif": "tag"}.get(p["rotation_mode"], p["rotation_mode"])
    if label:
        p["nominal"] = bool(not p["attack"] and p["coverage"]["fraction"] >= 1.0
                            and p["ambient_ratio"] <= 1.0
                            and exposure_s < 0.5 / p["switching_hz"])
    return p


def _resolve_video_mix(video_mix: VideoMix | str) -> VideoMix:
    if isinstance(video_mix, str):
        if video_mix not in VIDEO_MIXES:
            raise ConfigError(f"unknown video mix {video_mix!r}; known: "
                              f"{', '.join(VIDEO_MIXES)}")
        return VIDEO_MIXES[video_mix]
    return video_mix


def clip_params(*, label: int = 1, seed: int = 0, size: str | tuple[int, int] = "540p",
                preset: str | None = None, switching_hz: float | None = None,
                negative: str | None = None, fps: float | None = None,
                duration_s: float | None = None, ambient_ratio: float | None = None,
                coverage: float | None = None, exposure_s: float | None = None,
                motion: bool | None = None, codec: str = "h264", bitrate: int | None = None,
                rotation_deg: int | None = None, rotation_mode: str = "tag",
                scene: str | None = None) -> dict:
    """Parameters of one clip: drawn from the default mixes with ``seed``, then overridden.

    Every argument left None keeps its random draw. ``negative`` (steady, mains, pwm or
    texture) makes a look-alike clip; ``preset``/``switching_hz`` fix the barcode (f_B in Hz).
    ``coverage`` < 1 lights that fraction of the frame around its centre; ``exposure_s``
    locks the exposure; ``rotation_deg`` (clockwise, to display upright) is stored as a
    display-matrix tag (``rotation_mode="tag"``) or baked into the pixels (``"bake"``);
    ``scene`` is anything `synth.scene.load_scene` reads. ConfigError for bad values.
    """
    overrides: dict = {"attack_prob": 0.0, "rotate_prob": 0.0}
    if negative is not None:
        if negative not in NEGATIVE_KINDS:
            raise ConfigError(f"unknown negative kind {negative!r}; known: "
                              f"{', '.join(NEGATIVE_KINDS)}")
        label = 0
        overrides["negative_probs"] = tuple(float(k == negative) for k in NEGATIVE_KINDS)
    if preset is not None:
        overrides.update(mono_presets=(preset,), rgb_presets=(preset,))
    if switching_hz is not None:
        overrides.update(switching_min_hz=float(switching_hz),
                         switching_band_probs=(1.0, 0.0, 0.0, 0.0))
    mix = dataclasses.replace(resolve_mix("default"), name="clip", **overrides)
    vkw: dict = {"name": "clip", "codec": codec}
    if fps is not None:
        vkw.update(fps_choices=(float(fps),), fps_probs=(1.0,))
    if duration_s is not None:
        vkw["duration_range_s"] = (float(duration_s), float(duration_s))
    if motion is not None:
        vkw["motion_prob"] = float(bool(motion))
    p = sample_video_item(label, seed=seed, mix=mix, size=size,
                          video_mix=dataclasses.replace(VIDEO_MIXES["default"], **vkw))
    if p["label"] and switching_hz is not None:
        f1 = min(min(fs) for fs in p["tones_hz"].values())
        p["f_b_band"] = f_b_band(p["switching_hz"], f1)
    if ambient_ratio is not None:
        if not ambient_ratio >= 0:
            raise ConfigError(f"need ambient_ratio >= 0, got {ambient_ratio!r}")
        p["ambient_ratio"] = float(ambient_ratio)
    if coverage is not None and p["label"]:
        if not 0.0 < coverage <= 1.0:
            raise ConfigError(f"need 0 < coverage <= 1, got coverage={coverage!r}")
        p["coverage"] = {"fraction": float(coverage), "centre_rc": [0.5, 0.5], "softness": 0.25} \
            if coverage < 1.0 else {"fraction": 1.0, "centre_rc": None, "softness": None}
    if exposure_s is not None:
        if not 0 < exposure_s <= 1.0 / p["fps"]:
            raise ConfigError(f"need 0 < exposure_s <= 1/fps = {1 / p['fps']:.4g} s, got "
                              f"{exposure_s!r}")
        p["exposure_s"] = float(exposure_s)
        p["ae"] = dict(p["ae"], locked=True)
    if bitrate is not None:
        if not bitrate > 0:
            raise ConfigError(f"need bitrate > 0, got {bitrate!r}")
        p["bitrate"] = int(bitrate)
    if rotation_deg is not None:
        if rotation_deg not in (0, 90, 180, 270) or rotation_mode not in ("tag", "bake"):
            raise ConfigError(f"need rotation_deg in 0/90/180/270 and rotation_mode tag or "
                              f"bake, got {rotation_deg!r}, {rotation_mode!r}")
        p["rotation_deg"] = int(rotation_deg)
        p["rotation_mode"] = rotation_mode if rotation_deg else "none"
    if scene is not None:
        p.update(scene_name=scene, scene_photo=None)
    return p


def _pan_offsets(p: dict, n_rows: int, n_cols: int, big: tuple[int, int]) -> np.ndarray:
    """Top-left corner (row, col) of the sensor window in the big scene per frame, int."""
    n = p["n_frames"]
    m = p["motion"]
    if not m["enabled"]:
        return np.zeros((n, 2), dtype=int)
    span = np.array([big[0] - n_rows, big[1] - n_cols], dtype=np.float64)
    t = np.linspace(0.0, 1.0, n)[:, None] if n > 1 else np.zeros((1, 1))
    pos = (np.asarray(m["pan_start_rc"]) * (1 - t) + np.asarray(m["pan_end_rc"]) * t) * span
    rng = np.random.default_rng(m["seed"])
    a = math.exp(-1.0 / (p["fps"] * m["shake_tau_s"]))  # AR(1) with unit stationary std
    z = rng.standard_normal((n, 2))
    shake = np.empty((n, 2))
    shake[0] = z[0]
    for k in range(1, n):
        shake[k] = a * shake[k - 1] + math.sqrt(1 - a * a) * z[k]
    pos += shake * m["shake_px"]
    return np.clip(np.rint(pos), 0, span).astype(int)


def _meter(scene: np.ndarray, cmap: np.ndarray | None, ambient_ratio: float) -> float:
    """Mean light of a frame window, as auto exposure sees it (coarse grid), unitless."""
    sub = scene[::_METER_STRIDE, ::_METER_STRIDE]
    lum = sub.mean(axis=2, dtype=np.float64)
    lit = 1.0 if cmap is None else cmap[::_METER_STRIDE, ::_METER_STRIDE]
    return float((lum * (ambient_ratio + lit)).mean())


def _exposures(p: dict, meters: list[float]) -> np.ndarray:
    """Per-frame exposure (s): locked, or a first-order follow of the metered scene plus a
    random walk in log exposure, clipped to [1/8000 s, frame interval]."""
    n = p["n_frames"]
    t0 = p["exposure_s"]
    ae = p["ae"]
    if ae["locked"]:
        return np.full(n, t0)
    dt = 1.0 / p["fps"]
    lo, hi = min(MIN_EXPOSURE_S, t0), 1.0 / p["fps"]
    alpha = 1.0 - math.exp(-dt / ae["tau_s"])
    z = np.random.default_rng(ae["seed"]).standard_normal(n) * (ae["walk"] * math.sqrt(dt))
    m0 = max(meters[0], 1e-9)
    x = math.log(t0)
    walk = 0.0
    out = np.empty(n)
    for k in range(n):
        walk += z[k]
        target = math.log(t0 * m0 / max(meters[k], 1e-9)) + walk
        if k:
            x += alpha * (target - x)
        x = min(max(x, math.log(lo)), math.log(hi))
        out[k] = math.exp(x)
    return out


def render_frames(p: dict, *, frame_fn: Callable | None = None):
    """Yield the clip's frames (sensor orientation, uint8 RGB) and fill in per-frame data.

    Returns a generator; after exhaustion, ``info`` (the generator's return value) holds
    ``scene`` (description), ``exposures_s`` and, for barcode clips, ``led_contrast`` per
    frame. ``frame_fn`` defaults to `synth.camera.simulate_frame`.
    """
    from synth.camera import led_row_contrast, simulate_frame

    frame_fn = frame_fn or simulate_frame
    n_rows, n_cols = p["sensor_rows"], p["sensor_cols"]
    margin = p["motion"]["margin"] if p["motion"]["enabled"] else 0.0
    big = (2 * math.ceil(n_rows * (1 + margin) / 2), 2 * math.ceil(n_cols * (1 + margin) / 2))
    scene, scene_desc = _render_scene(p, *big)
    cmap = _coverage(p, *big)
    offs = _pan_offsets(p, n_rows, n_cols, big)
    windows = [(slice(r, r + n_rows), slice(c, c + n_cols)) for r, c in offs]
    amb = p["ambient_ratio"]
    meters = [_meter(scene[w], None if cmap is None else cmap[w], amb) for w in windows]
    exposures = _exposures(p, meters)
    light = _make_light(p)
    rng = np.random.default_rng(p["noise_seed"])
    row_time_s = p["readout_s"] / n_rows
    contrast: list[float] = []
    for k, w in enumerate(windows):
        camera = CameraModel(row_time_s=row_time_s, n_rows=n_rows, exposure_s=float(exposures[k]))
        start_s = p["frame_start_s"] + k / p["fps"]
        cw = None if cmap is None else cmap[w]
        if p["label"]:
            lit = 1.0 if cw is None else float(cw[::_METER_STRIDE, ::_METER_STRIDE].mean())
            contrast.append(round(led_row_contrast(light, camera, start_s=start_s,
                                                   ambient_ratio=amb, lit_fraction=lit), 6))
        yield frame_fn(light, scene[w], camera, rng=rng, start_s=start_s, ambient_ratio=amb,
                       coverage=cw, noise=p["noise"])
    return {"scene": scene_desc, "exposures_s": [float(f"{e:.6g}") for e in exposures],
            **({"led_contrast": contrast} if p["label"] else {})}


def encode_frames(frames, *, width: int, height: int, fps: float, codec: str = "h264",
                  bitrate: int, gop_frames: int, preset: str = "veryfast",
                  rotation_deg: int = 0, container: str | None = None) -> bytes:
    """Encode uint8 RGB frames of shape (height, width, 3) into a video file's bytes.

    Parameters
    ----------
    frames : iterable of ndarray
        Frames in display order (already rotated when the rotation is baked).
    width, height : int
        Frame size in pixels, both even.
    fps : float
        Frame rate (an integer or 24000/1001-style rational).
    codec : {"h264", "hevc", "vp9", "vp8"}
        See `CODECS`.
    bitrate : int
        Target bit rate in bit/s (VBV max rate 1.5x, buffer 2x).
    gop_frames : int
        Keyframe interval, frames.
    preset : str
        libx264/libx265 speed preset. VP8/VP9 use ``deadline=realtime``, ``cpu-used=8``.
    rotation_deg : {0, 90, 180, 270}
        Clockwise rotation a player applies, stored as the stream's display matrix.
    container : str, optional
        Format (``mp4``, ``mov``, ``webm``); default the codec's.

    Returns
    -------
    bytes
    """
    import av

    if codec not in CODECS:
        raise ConfigError(f"unknown codec {codec!r}; known: {', '.join(CODECS)}")
    encoder, default_fmt, _ = CODECS[codec]
    opts = {"g": str(int(gop_frames)), "maxrate": str(int(bitrate * 1.5)),
            "bufsize": str(int(bitrate * 2))}
    if codec == "h264":
        opts.update(preset=preset, threads="1")
    elif codec == "hevc":
        opts.update(preset=preset, **{"x265-params": "pools=none:frame-threads=1:log-level=error"})
    else:
        opts.update({"deadline": "realtime", "cpu-used": "8", "threads": "1"})
    buf = io.BytesIO()
    rate = Fraction(fps).limit_denominator(1001)
    with av.open(buf, "w", format=container or default_fmt) as out:
        st = out.add_stream(encoder, rate=rate, options=opts)
        st.width, st.height, st.pix_fmt = int(width), int(height), "yuv420p"
        st.bit_rate = int(bitrate)
        st.codec_context.thread_count = 1
        if codec == "hevc":
            st.codec_context.codec_tag = "hvc1"
        if rotation_deg:
            st.set_display_rotation(-float(rotation_deg))  # PyAV: counter-clockwise degrees
        for img in frames:
            frame = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format="yuv420p")
            out.mux(st.encode(frame))
        out.mux(st.encode())
    return buf.getvalue()


def render_video_item(p: dict, *, frame_fn: Callable | None = None) -> tuple[bytes, dict]:
    """Render and encode the clip described by `sample_video_item` (or `clip_params`).

    Parameters
    ----------
    p : dict
        Clip parameters.
    frame_fn : callable, optional
        Replaces `synth.camera.simulate_frame` (same signature), e.g. in tests.

    Returns
    -------
    data : bytes
        The encoded file (MP4 or WebM).
    record : dict
        ``p`` plus ``scene`` (description), ``width`` and ``height`` (stored pixels),
        ``exposures_s`` (per frame) and for barcode clips ``led_contrast`` (per frame:
        `synth.camera.led_row_contrast` of the lit window, unitless) and its median
        ``led_contrast_median``.
    """
    rot, mode = int(p["rotation_deg"]), p["rotation_mode"]
    gen = render_frames(p, frame_fn=frame_fn)
    info: dict = {}

    def frames():
        try:
            while True:
                img = next(gen)
                yield np.ascontiguousarray(np.rot90(img, k=-(rot // 90))) \
                    if mode == "bake" and rot else img
        except StopIteration as stop:
            info.update(stop.value)

    h, w = p["sensor_rows"], p["sensor_cols"]
    if mode == "bake" and rot in (90, 270):
        h, w = w, h
    data = encode_frames(frames(), width=w, height=h, fps=p["fps"], codec=p["codec"],
                         bitrate=p["bitrate"], gop_frames=p["gop_frames"],
                         preset=p.get("encoder_preset", "veryfast"),
                         rotation_deg=rot if mode == "tag" else 0,
                         container=p.get("container"))
    rec = dict(p, width=int(w), height=int(h), bytes=len(data), **info)
    if p["label"]:
        rec["led_contrast_median"] = float(np.median(info["led_contrast"]))
    return data, rec


PARTS_DIR = ".parts"  # per-clip records of an unfinished set (a rerun resumes from them)


def _work(args: tuple) -> dict:
    index, label, seed, mix, size, vmix, out_dir = args
    part = Path(out_dir) / PARTS_DIR / f"{index:06d}.json"
    if part.exists():
        return json.loads(part.read_text(encoding="utf-8"))
    p = sample_video_item(label, seed=item_seed(seed, index), mix=mix, size=size,
                          video_mix=vmix)
    data, rec = render_video_item(p)
    name = f"{index:06d}{CODECS[p['codec']][2]}"
    (Path(out_dir) / name).write_bytes(data)
    record = {"file": name, "index": index, **rec}
    tmp = part.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, sort_keys=True), encoding="utf-8")
    os.replace(tmp, part)
    return record


def write_video_dataset(out_dir: str | Path, *, n_pos: int, n_neg: int, seed: int,
                        mix: Mix | str = "default", size: str | tuple[int, int] = "mixed",
                        video_mix: VideoMix | str = "default", jobs: int = 1,
                        progress: bool | Callable = True) -> Path:
    """Render a labelled video set: ``out_dir/NNNNNN.mp4`` plus ``out_dir/manifest.jsonl``.

    Same shape as `synth.dataset.write_dataset`: the label order and every clip derive from
    ``seed`` (clip i uses ``item_seed(seed, i)``), so the files are byte-identical for any
    ``jobs``. Resumable: each finished clip leaves its record in ``out_dir/.parts``, which a
    rerun with the same arguments reads instead of rendering again (the folder is removed
    once the manifest is written).

    Parameters
    ----------
    out_dir : str or Path
        Output folder, created if missing.
    n_pos, n_neg : int
        Barcode clips and look-alike clips (>= 0, total >= 1).
    seed : int
        Dataset seed.
    mix : Mix or str
        Photo mix (light, emitter, scene, ambient, coverage, exposure, rotation).
    size : str or (int, int)
        ``"mixed"`` (540p/720p/1080p per clip), a `VIDEO_SIZES` name, ``"WxH"`` or a tuple.
    video_mix : VideoMix or str
        Video-only distributions (`VIDEO_MIXES`: default, static, motion).
    jobs : int
        Worker processes (>= 1).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    Path
        The manifest: one line per clip in index order with ``file``, ``index``, ``label``,
        ``kind`` and every parameter of `sample_video_item` and `render_video_item`.
    """
    mix = resolve_mix(mix)
    vmix = _resolve_video_mix(video_mix)
    parse_video_size(size)
    labels = label_order(n_pos, n_neg, seed=seed, mix=mix, jobs=jobs)
    out = Path(out_dir)
    (out / PARTS_DIR).mkdir(parents=True, exist_ok=True)
    tasks = [(i, int(labels[i]), int(seed), mix, size, vmix, str(out))
             for i in range(len(labels))]
    records = run_tasks(_work, tasks, jobs=jobs, progress=progress, unit="clip", chunksize=1)
    manifest = write_manifest(out, records)
    shutil.rmtree(out / PARTS_DIR, ignore_errors=True)
    return manifest
