"""Rolling-shutter capture: light + scene + CameraModel -> noisy sRGB frame, resized, JPEG."""

from __future__ import annotations

import io
import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from lishield_guard.camera import CameraModel
from lishield_guard.errors import ConfigError, InvalidImageError
from synth.light import LightSource, light_to_rgb, mean_rgb, row_means

__all__ = [
    "EXIF_ORIENTATION",
    "SensorModel",
    "auto_exposure_s",
    "encode_jpeg",
    "led_row_contrast",
    "led_rows_rgb",
    "linear_to_srgb8",
    "postprocess",
    "render_linear",
    "row_start_times_s",
    "simulate_frame",
    "simulate_video",
]

# Clockwise display rotation (degrees) -> EXIF orientation tag (0x0112) value.
EXIF_ORIENTATION = {0: 1, 90: 6, 180: 3, 270: 8}
EXIF_ORIENTATION_TAG = 0x0112
_LUT_BITS = 14  # linear values are quantised to 14 bits before the sRGB lookup table
_SRGB8_LUT: np.ndarray | None = None
_METER_STRIDE = 4  # auto gain meters every 4th row and column


@dataclass(frozen=True)
class SensorModel:
    """Photometric response of the sensor: sensitivity, full well, read noise, gain range.

    Parameters
    ----------
    light_e_per_s : float
        Electrons per second a pixel of reflectance 1 collects under unit light (the LED's time
        average is normalised to 1). Default 1.5e6: 1/250 s fills the well.
    full_well_e : float
        Electrons at saturation at base gain (ISO 100). Default 6000.
    read_noise_e : float
        Read noise in electrons RMS. Default 2.5.
    min_gain, max_gain : float
        Range of the ISO-like analog gain (1 = ISO 100), unitless. Defaults 1 and 64.
    """

    light_e_per_s: float = 1.5e6
    full_well_e: float = 6000.0
    read_noise_e: float = 2.5
    min_gain: float = 1.0
    max_gain: float = 64.0

    def __post_init__(self) -> None:
        for name in ("light_e_per_s", "full_well_e", "min_gain", "max_gain"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"need {name} > 0, got {name}={v!r}")
        if not self.read_noise_e >= 0:
            raise ConfigError(f"need read_noise_e >= 0, got {self.read_noise_e!r}")
        if self.min_gain > self.max_gain:
            raise ConfigError(f"need min_gain={self.min_gain} <= max_gain={self.max_gain}")


def auto_exposure_s(scene: np.ndarray, *, ambient_ratio: float = 0.0,
                    coverage: np.ndarray | None = None, sensor: SensorModel | None = None,
                    target_mean: float = 0.18,
                    range_s: tuple[float, float] = (1 / 8000, 1 / 30)) -> float:
    """Exposure a phone's auto exposure would pick: reach ``target_mean`` at base gain.

    Parameters
    ----------
    scene : ndarray of shape (n_rows, n_cols, 3)
        Linear reflectance.
    ambient_ratio : float
        Ambient light / LED average, unitless.
    coverage : ndarray of shape (n_rows, n_cols), optional
        LED illumination map in [0, 1].
    sensor : SensorModel, optional
        Sensitivity; default `SensorModel()`.
    target_mean : float
        Target mean linear value in (0, 1).
    range_s : (float, float)
        Shortest and longest exposure the camera allows, in seconds.

    Returns
    -------
    float
        Exposure t_e in seconds, clipped to ``range_s``.
    """
    sensor = sensor or SensorModel()
    sub = np.asarray(scene, dtype=np.float32)[::_METER_STRIDE, ::_METER_STRIDE]
    lit = 1.0 if coverage is None else float(
        np.asarray(coverage)[::_METER_STRIDE, ::_METER_STRIDE].mean())
    mean_irr = float(sub.mean(dtype=np.float64)) * (ambient_ratio + lit)
    t_e = target_mean * sensor.full_well_e / (max(mean_irr, 1e-9) * sensor.light_e_per_s)
    return float(np.clip(t_e, *range_s))


def row_start_times_s(camera: CameraModel, *, start_s: float = 0.0) -> np.ndarray:
    """Exposure start t_i = start_s + i * t_s of every row, shape (n_rows,), float64."""
    return start_s + np.arange(camera.n_rows, dtype=np.float64) * camera.row_time_s


def led_rows_rgb(light: LightSource, camera: CameraModel, *, start_s: float = 0.0,
                 normalize: bool = True) -> np.ndarray:
    """Mean light each row sees during its exposure, in image R, G, B (the O(rows) step).

    Parameters
    ----------
    light : LightSource
        Light queried through its exact cumulative integral.
    camera : CameraModel
        Row time t_s, row count and exposure t_e.
    start_s : float
        Exposure start of row 0, in seconds.
    normalize : bool
        Divide by the light's time average (mean over R, G, B), so a steady light of the same
        average gives 1. Default True.

    Returns
    -------
    ndarray of shape (n_rows, 3), float64
    """
    vals = row_means(light, row_start_times_s(camera, start_s=start_s), camera.exposure_s)
    rgb = light_to_rgb(vals, tuple(light.channels))
    if normalize:
        avg = float(mean_rgb(light).mean())
        if avg <= 0:
            raise ConfigError("the light's time-averaged intensity is 0; cannot normalise")
        rgb = rgb / avg
    return rgb


def led_row_contrast(light: LightSource, camera: CameraModel, *, start_s: float = 0.0,
                     ambient_ratio: float = 0.0, lit_fraction: float = 1.0) -> float:
    """How strongly a light stripes a capture: std / mean of the luma-weighted light each row
    sees (`led_rows_rgb`), the mean including the ambient light, times the lit fraction of the
    frame (a light on a quarter of the frame dilutes the stripes of the whole image fourfold).
    Unitless; 0.1 and above are stripes anyone sees."""
    rows = led_rows_rgb(light, camera, start_s=start_s) @ np.array([0.299, 0.587, 0.114])
    return float(rows.std() / (rows.mean() + ambient_ratio) * lit_fraction)


def _check_scene(scene: np.ndarray, camera: CameraModel) -> np.ndarray:
    s = np.asarray(scene)
    if s.ndim == 2:
        s = s[:, :, None]
    if s.ndim != 3 or s.shape[2] not in (1, 3) or s.shape[0] != camera.n_rows:
        raise InvalidImageError(f"scene must have shape (n_rows={camera.n_rows}, n_cols, 3), "
                                f"got {np.shape(scene)}")
    if s.dtype != np.float32:
        s = s.astype(np.float32)
    return s


def render_linear(light: LightSource, scene: np.ndarray, camera: CameraModel, *,
                  start_s: float = 0.0, ambient_ratio: float = 0.0,
                  coverage: np.ndarray | None = None, normalize: bool = True) -> np.ndarray:
    """Linear irradiance per pixel averaged over each row's exposure (no noise, no gain).

    ``scene * (ambient_ratio + coverage * led_row[row])``, where ``led_row`` is
    `led_rows_rgb`: each row integrates the light exactly over [t_i, t_i + t_e] (Eq. 1).

    Parameters
    ----------
    light : LightSource
        The flickering (or steady) light.
    scene : ndarray of shape (n_rows, n_cols, 3) or (n_rows, n_cols, 1)
        Linear reflectance.
    camera : CameraModel
        Sensor timing.
    start_s : float
        Exposure start of row 0, in seconds.
    ambient_ratio : float
        Steady white ambient light as a ratio of the LED's time average, unitless, >= 0.
    coverage : ndarray of shape (n_rows, n_cols), optional
        Where the LED reaches, in [0, 1]; None lights the whole frame.
    normalize : bool
        See `led_rows_rgb`. With False the LED rows are in the light's own units.

    Returns
    -------
    ndarray of shape (n_rows, n_cols, 3), float32
    """
    s = _check_scene(scene, camera)
    if not (math.isfinite(ambient_ratio) and ambient_ratio >= 0):
        raise ConfigError(f"need ambient_ratio >= 0, got ambient_ratio={ambient_ratio!r}")
    led = led_rows_rgb(light, camera, start_s=start_s, normalize=normalize).astype(np.float32)
    amb = np.float32(ambient_ratio)
    if coverage is None:
        return s * (amb + led[:, None, :])
    cov = np.asarray(coverage, dtype=np.float32)
    if cov.shape != s.shape[:2]:
        raise ConfigError(f"coverage must have shape {s.shape[:2]}, got {cov.shape}")
    out = cov[:, :, None] * led[:, None, :]
    out += amb
    out *= s
    return out


def _srgb8_lut() -> np.ndarray:
    global _SRGB8_LUT
    if _SRGB8_LUT is None:
        x = np.arange(2**_LUT_BITS, dtype=np.float64) / (2**_LUT_BITS - 1)
        enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
        _SRGB8_LUT = np.round(np.clip(enc, 0, 1) * 255).astype(np.uint8)
    return _SRGB8_LUT


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Clip linear values to [0, 1] (saturation), apply the sRGB curve, quantise to uint8.

    Works in place on float32 input to avoid full-frame copies.

    Parameters
    ----------
    linear : ndarray of float32, any shape
        Linear values; 1 is the saturation level.

    Returns
    -------
    ndarray of uint8, same shape
    """
    x = linear if linear.dtype == np.float32 else linear.astype(np.float32)
    x *= np.float32(2**_LUT_BITS - 1)
    x += np.float32(0.5)
    np.clip(x, 0, 2**_LUT_BITS - 1, out=x)
    return _srgb8_lut()[x.astype(np.uint16)]


def simulate_frame(
    light: LightSource,
    scene: np.ndarray,
    camera: CameraModel,
    *,
    rng: np.random.Generator,
    start_s: float | None = None,
    ambient_ratio: float = 0.0,
    coverage: np.ndarray | None = None,
    gain: float | None = None,
    target_mean: float = 0.18,
    sensor: SensorModel | None = None,
    noise: bool = True,
    output: str = "srgb8",
) -> np.ndarray:
    """Capture one rolling-shutter frame.

    Parameters
    ----------
    light : LightSource
        Light (LED sequence, steady, mains, PWM) with an exact cumulative integral.
    scene : ndarray of shape (n_rows, n_cols, 3)
        Linear reflectance in [0, 1] (see `synth.scene`).
    camera : CameraModel
        Row time t_s, rows, exposure t_e. Rows run down the image height.
    rng : numpy.random.Generator
        Frame start (when ``start_s`` is None) and noise.
    start_s : float, optional
        Exposure start of row 0 in seconds; default uniform in [0, 1) s.
    ambient_ratio : float
        Steady ambient light as a ratio of the LED's time average, unitless, >= 0.
    coverage : ndarray of shape (n_rows, n_cols), optional
        LED illumination map in [0, 1] (see `synth.light.coverage_map`).
    gain : float, optional
        Manual ISO-like gain (1 = base ISO). None meters the frame so its mean linear value
        is ``target_mean`` (auto gain, clipped to the sensor's gain range).
    target_mean : float
        Metering target, linear, in (0, 1). Default 0.18.
    sensor : SensorModel, optional
        Sensitivity and noise; default `SensorModel()`.
    noise : bool
        Add shot and read noise. Default True.
    output : {"srgb8", "linear"}
        ``"srgb8"`` gives sRGB uint8; ``"linear"`` the float32 value before clipping and gamma.

    Returns
    -------
    ndarray of shape (n_rows, n_cols, 3), uint8 (or float32 for ``output="linear"``)

    Notes
    -----
    Electrons per pixel are ``render_linear * t_e * light_e_per_s``; the digital value is
    ``electrons * gain / full_well_e`` (1 = saturation). Shot and read noise are one Gaussian
    draw of variance ``electrons + read_noise_e**2``.
    """
    sensor = sensor or SensorModel()
    if output not in ("srgb8", "linear"):
        raise ConfigError(f"output must be 'srgb8' or 'linear', got {output!r}")
    if start_s is None:
        start_s = float(rng.uniform(0.0, 1.0))
    s = _check_scene(scene, camera)
    e_scale = camera.exposure_s * sensor.light_e_per_s  # electrons per unit irradiance
    led = led_rows_rgb(light, camera, start_s=start_s)
    amb = float(ambient_ratio)
    if gain is None:
        # Meter on a 1-in-16 pixel grid (every 4th row and column): a cheap, deterministic
        # estimate of the frame mean, like a phone's metering on a low-resolution preview.
        sub = s[::_METER_STRIDE, ::_METER_STRIDE]
        s_rows = sub.mean(axis=1, dtype=np.float64)
        led_sub = led[::_METER_STRIDE]
        if coverage is None:
            lit = s_rows * led_sub
        else:
            cov = np.asarray(coverage, dtype=np.float32)[::_METER_STRIDE, ::_METER_STRIDE]
            lit = (sub * cov[:, :, None]).mean(axis=1, dtype=np.float64) * led_sub
        mean_e = float((amb * s_rows + lit).mean()) * e_scale
        gain = target_mean * sensor.full_well_e / max(mean_e, 1e-12)
        gain = float(np.clip(gain, sensor.min_gain, sensor.max_gain))
    elif not (math.isfinite(gain) and gain > 0):
        raise ConfigError(f"need gain > 0, got gain={gain!r}")
    dn_per_e = gain / sensor.full_well_e
    led_c = (led * (e_scale * dn_per_e)).astype(np.float32)
    amb_c = np.float32(amb * e_scale * dn_per_e)
    if coverage is None:
        sig = s * (amb_c + led_c[:, None, :])
    else:
        sig = np.asarray(coverage, dtype=np.float32)[:, :, None] * led_c[:, None, :]
        sig += amb_c
        sig *= s
    if noise:
        # variance in DN^2: electrons * dn^2 + read^2 * dn^2 = sig * dn + (read * dn)^2
        std = sig * np.float32(dn_per_e)
        std += np.float32((sensor.read_noise_e * dn_per_e) ** 2)
        np.sqrt(std, out=std)
        std *= rng.standard_normal(sig.shape, dtype=np.float32)
        sig += std
        del std
    if output == "linear":
        return sig
    return linear_to_srgb8(sig)


def simulate_video(light: LightSource, scene: np.ndarray, camera: CameraModel, *,
                   rng: np.random.Generator, n_frames: int, frame_rate_hz: float = 30.0,
                   start_s: float | None = None, **kwargs) -> Iterator[np.ndarray]:
    """Successive frames at ``frame_rate_hz``: frame k starts at start_s + k / frame_rate_hz.

    Parameters
    ----------
    light, scene, camera, rng
        As for `simulate_frame`.
    n_frames : int
        Frames to yield (>= 1).
    frame_rate_hz : float
        Frames per second; one frame's readout must fit in a frame interval.
    start_s : float, optional
        Start of the first frame; default uniform in [0, 1) s.
    **kwargs
        Passed to `simulate_frame` (ambient_ratio, coverage, gain, noise, ...).

    Yields
    ------
    ndarray of shape (n_rows, n_cols, 3)
    """
    if int(n_frames) != n_frames or n_frames < 1:
        raise ConfigError(f"need n_frames >= 1, got n_frames={n_frames!r}")
    if not (frame_rate_hz > 0 and camera.readout_s < 1.0 / frame_rate_hz):
        raise ConfigError(f"frame_rate_hz={frame_rate_hz!r} leaves less than the readout of "
                          f"{camera.readout_s:.4g} s per frame")
    if start_s is None:
        start_s = float(rng.uniform(0.0, 1.0))
    for k in range(int(n_frames)):
        yield simulate_frame(light, scene, camera, rng=rng, start_s=start_s + k / frame_rate_hz,
                             **kwargs)


def postprocess(image: np.ndarray, *, downscale: float = 1.0, rotation_deg: int = 0,
                rotation_mode: str = "bake") -> tuple[np.ndarray, int]:
    """Downscale (area interpolation) and rotate a captured frame.

    Parameters
    ----------
    image : ndarray of shape (n_rows, n_cols, 3), uint8
        Sensor-oriented frame.
    downscale : float
        Factor >= 1 dividing both sides (``cv2.INTER_AREA``). 1 keeps the size.
    rotation_deg : {0, 90, 180, 270}
        Clockwise rotation needed to display the photo upright.
    rotation_mode : {"bake", "exif"}
        ``"bake"`` rotates the pixels; ``"exif"`` keeps sensor pixels and returns the EXIF
        orientation tag a viewer applies.

    Returns
    -------
    image : ndarray, uint8
    exif_orientation : int
        EXIF tag 0x0112 value to store (1 when baked or not rotated).
    """
    if not (math.isfinite(downscale) and downscale >= 1.0):
        raise ConfigError(f"need downscale >= 1, got downscale={downscale!r}")
    if rotation_deg not in EXIF_ORIENTATION:
        raise ConfigError(f"rotation_deg must be 0, 90, 180 or 270, got {rotation_deg!r}")
    if rotation_mode not in ("bake", "exif"):
        raise ConfigError(f"rotation_mode must be 'bake' or 'exif', got {rotation_mode!r}")
    out = image
    if downscale > 1.0:
        h, w = image.shape[:2]
        size = (max(int(round(w / downscale)), 1), max(int(round(h / downscale)), 1))
        out = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    if rotation_deg == 0:
        return out, 1
    if rotation_mode == "exif":
        return out, EXIF_ORIENTATION[rotation_deg]
    return np.ascontiguousarray(np.rot90(out, k=-(rotation_deg // 90))), 1


def encode_jpeg(image: np.ndarray, *, quality: int = 90, subsampling: str = "4:2:0",
                exif_orientation: int = 1) -> bytes:
    """Encode a uint8 RGB image as JPEG with Pillow.

    Parameters
    ----------
    image : ndarray of shape (n_rows, n_cols, 3), uint8
    quality : int
        JPEG quality, 1..100.
    subsampling : {"4:2:0", "4:2:2", "4:4:4"}
        Chroma subsampling.
    exif_orientation : int
        EXIF orientation tag (1..8); 1 writes no EXIF block.

    Returns
    -------
    bytes
    """
    from PIL import Image

    if not 1 <= int(quality) <= 100:
        raise ConfigError(f"need 1 <= quality <= 100, got quality={quality!r}")
    sub = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}.get(subsampling)
    if sub is None:
        raise ConfigError(f"subsampling must be 4:4:4, 4:2:2 or 4:2:0, got {subsampling!r}")
    im = Image.fromarray(np.ascontiguousarray(image))
    kw: dict = {"quality": int(quality), "subsampling": sub}
    if exif_orientation != 1:
        exif = Image.Exif()
        exif[EXIF_ORIENTATION_TAG] = int(exif_orientation)
        kw["exif"] = exif.tobytes()
    buf = io.BytesIO()
    im.save(buf, format="JPEG", **kw)
    return buf.getvalue()
