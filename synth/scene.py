"""Scenes as linear reflectance per channel: image files, skimage photos, procedural textures."""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from lishield_guard.errors import ConfigError, ImageDecodeError, InvalidImageError

__all__ = [
    "PHOTO_NAMES",
    "TEXTURE_KINDS",
    "fit_to_sensor",
    "load_scene",
    "photo_scene",
    "random_scene",
    "skimage_photo",
    "srgb_to_linear",
    "texture_scene",
]

# scikit-image's bundled images that need no download, used as ready scenes.
PHOTO_NAMES = ("astronaut", "coffee", "chelsea", "rocket", "camera", "coins", "moon", "clock",
               "hubble_deep_field", "immunohistochemistry", "retina", "motorcycle", "grass",
               "gravel")
TEXTURE_KINDS = ("blinds", "bricks", "fabric")

_SRGB_LUT = None


def srgb_to_linear(image: np.ndarray) -> np.ndarray:
    """Undo the sRGB transfer curve.

    Parameters
    ----------
    image : ndarray of uint8, or float in [0, 1]
        Encoded sRGB values, any shape.

    Returns
    -------
    ndarray of float32, same shape, linear values in [0, 1].
    """
    global _SRGB_LUT
    if image.dtype == np.uint8:
        if _SRGB_LUT is None:
            _SRGB_LUT = srgb_to_linear(np.arange(256, dtype=np.float64) / 255.0)
        return _SRGB_LUT[image]
    x = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return lin.astype(np.float32)


def _to_rgb_uint8(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    elif a.dtype != np.uint8:
        a = np.asarray(a, dtype=np.float64)
        if not np.all(np.isfinite(a)):
            raise InvalidImageError("scene image has non-finite values")
        if a.max(initial=0.0) > 1.0:
            a = a / 255.0
        a = np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) < 2:
        raise InvalidImageError(f"scene must be (n_rows, n_cols[, 3|4]), got shape {a.shape}")
    return np.ascontiguousarray(a[:, :, :3])


def fit_to_sensor(reflectance: np.ndarray, n_rows: int, n_cols: int, *,
                  rng: np.random.Generator | None = None, min_crop: float = 1.0) -> np.ndarray:
    """Crop a scene to the sensor's aspect ratio and resize it to (n_rows, n_cols).

    Parameters
    ----------
    reflectance : ndarray of shape (h, w, 3), uint8 or float32
        Scene image.
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator, optional
        Draws a random crop (position, and size in [min_crop, 1] of the largest crop).
        None gives the centred largest crop.
    min_crop : float
        Smallest crop side as a fraction of the largest one, in (0, 1].

    Returns
    -------
    ndarray of shape (n_rows, n_cols, 3), same dtype as ``reflectance``
    """
    h, w = reflectance.shape[:2]
    aspect = n_cols / n_rows
    ch, cw = (h, int(round(h * aspect))) if w / h >= aspect else (int(round(w / aspect)), w)
    ch, cw = max(min(ch, h), 2), max(min(cw, w), 2)
    if rng is not None:
        s = rng.uniform(min_crop, 1.0)
        ch, cw = max(int(ch * s), 2), max(int(cw * s), 2)
        r0 = int(rng.integers(0, h - ch + 1))
        c0 = int(rng.integers(0, w - cw + 1))
    else:
        r0, c0 = (h - ch) // 2, (w - cw) // 2
    crop = reflectance[r0 : r0 + ch, c0 : c0 + cw]
    interp = cv2.INTER_AREA if ch > n_rows else cv2.INTER_LINEAR
    out = cv2.resize(np.ascontiguousarray(crop), (n_cols, n_rows), interpolation=interp)
    return out.reshape(n_rows, n_cols, 3)


@lru_cache(maxsize=32)
def skimage_photo(name: str) -> np.ndarray:
    """One of scikit-image's bundled photos as sRGB uint8 (h, w, 3); see `PHOTO_NAMES`."""
    import skimage.data

    if name not in PHOTO_NAMES:
        raise ConfigError(f"unknown skimage scene {name!r}; known: {', '.join(PHOTO_NAMES)}")
    img = skimage.data.stereo_motorcycle()[0] if name == "motorcycle" else getattr(
        skimage.data, name)()
    out = _to_rgb_uint8(img)
    out.setflags(write=False)
    return out


def photo_scene(image, n_rows: int, n_cols: int, *, rng: np.random.Generator | None = None,
                min_crop: float = 1.0) -> np.ndarray:
    """Linear reflectance of an sRGB image array fitted to the sensor.

    Parameters
    ----------
    image : ndarray of shape (h, w[, 3|4])
        uint8, bool, or float in [0, 1] (or [0, 255]).
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator, optional
        Random crop; see `fit_to_sensor`.
    min_crop : float
        Smallest crop fraction, in (0, 1].

    Returns
    -------
    ndarray of shape (n_rows, n_cols, 3), float32 in [0, 1]
    """
    # Resize the 8-bit image first, then linearise with a lookup table: far cheaper than
    # resizing a float32 frame, and the difference (resampling in gamma space) is immaterial
    # for a reflectance map.
    return srgb_to_linear(fit_to_sensor(_to_rgb_uint8(image), n_rows, n_cols, rng=rng,
                                        min_crop=min_crop))


def load_scene(source: str | Path | np.ndarray, n_rows: int, n_cols: int, *,
               rng: np.random.Generator | None = None, min_crop: float = 1.0) -> np.ndarray:
    """Scene from an array, an image file, ``skimage:NAME`` or ``texture:KIND``.

    Parameters
    ----------
    source : str, Path or ndarray
        Image array, path to an image file, ``"skimage:astronaut"`` (see `PHOTO_NAMES`) or
        ``"texture:blinds"`` (see `TEXTURE_KINDS`; needs ``rng`` or uses seed 0).
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator, optional
        Random crop / texture parameters.
    min_crop : float
        Smallest crop fraction, in (0, 1].

    Returns
    -------
    ndarray of shape (n_rows, n_cols, 3), float32 linear reflectance in [0, 1]

    Raises
    ------
    ConfigError
        Unknown skimage or texture name.
    ImageDecodeError
        The file cannot be read as an image.
    """
    if isinstance(source, np.ndarray):
        return photo_scene(source, n_rows, n_cols, rng=rng, min_crop=min_crop)
    s = str(source)
    if s.startswith("skimage:"):
        return photo_scene(skimage_photo(s.split(":", 1)[1]), n_rows, n_cols, rng=rng,
                           min_crop=min_crop)
    if s.startswith("texture:"):
        kind = s.split(":", 1)[1]
        return texture_scene(kind, n_rows, n_cols,
                             rng=rng if rng is not None else np.random.default_rng(0))[0]
    from PIL import Image, ImageOps

    try:
        with Image.open(s) as im:
            im = ImageOps.exif_transpose(im).convert("RGB")
            arr = np.asarray(im)
    except FileNotFoundError:
        raise ConfigError(f"scene file not found: {s!r}") from None
    except Exception as exc:  # Pillow raises many types for bad files
        raise ImageDecodeError(f"cannot read scene image {s!r}: {exc}") from None
    return photo_scene(arr, n_rows, n_cols, rng=rng, min_crop=min_crop)


def texture_scene(kind: str, n_rows: int, n_cols: int, *, rng: np.random.Generator,
                  period_px: float | None = None, angle_deg: float | None = None
                  ) -> tuple[np.ndarray, dict]:
    """Procedural periodic texture (a look-alike of LED stripes) as linear reflectance.

    Parameters
    ----------
    kind : {"blinds", "bricks", "fabric"}
        Window blinds (soft square wave), brick courses with staggered joints, or a woven
        fabric (two crossed gratings with fine thread noise).
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator
        Draws the colours, phases and (if not given) period and orientation.
    period_px : float, optional
        Spatial period in pixels; default log-uniform in [8, 120] px (blinds/bricks) or
        [4, 30] px (fabric).
    angle_deg : float, optional
        Orientation of the stripes' normal from the row axis, degrees; 0 gives horizontal
        stripes like an LED's. Default: half the time within 10 degrees of 0, else uniform.

    Returns
    -------
    reflectance : ndarray of shape (n_rows, n_cols, 3), float32 in [0, 1]
    params : dict
        JSON-ready parameters (kind, period_px, angle_deg).
    """
    if kind not in TEXTURE_KINDS:
        raise ConfigError(f"unknown texture {kind!r}; known: {', '.join(TEXTURE_KINDS)}")
    if period_px is None:
        lo, hi = (4.0, 30.0) if kind == "fabric" else (8.0, 120.0)
        period_px = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    if angle_deg is None:
        angle_deg = float(rng.uniform(-10, 10) if rng.random() < 0.5 else rng.uniform(0, 180))
    a = math.radians(angle_deg)
    r = np.arange(n_rows, dtype=np.float32)[:, None]
    c = np.arange(n_cols, dtype=np.float32)[None, :]
    u = (r * math.cos(a) + c * math.sin(a)) / period_px  # across the stripes, in periods
    v = (-r * math.sin(a) + c * math.cos(a)) / period_px  # along the stripes
    u = u + np.float32(rng.uniform(0, 1))
    col_a = rng.uniform(0.15, 0.9, 3).astype(np.float32)
    col_b = (col_a * rng.uniform(0.2, 0.7)).astype(np.float32)
    if kind == "blinds":
        duty = rng.uniform(0.6, 0.9)
        frac = u - np.floor(u)
        mask = np.clip(np.minimum(frac, duty - frac) * period_px + 0.5, 0.0, 1.0)
    elif kind == "bricks":
        course = np.floor(u)
        frac_u = u - course
        brick_len = rng.uniform(2.0, 3.0)
        w = (v + 0.5 * (course % 2)) / brick_len
        frac_v = w - np.floor(w)
        mortar = 0.08
        mask = ((frac_u > mortar) & (frac_v > mortar / brick_len)).astype(np.float32)
        col_b = np.full(3, rng.uniform(0.5, 0.8), dtype=np.float32)  # light mortar
    else:  # fabric
        g1 = 0.5 + 0.5 * np.cos(2 * np.pi * u)
        g2 = 0.5 + 0.5 * np.cos(2 * np.pi * v * rng.uniform(0.8, 1.25))
        mask = (0.6 * g1 + 0.4 * g2).astype(np.float32)
    mask = mask.astype(np.float32)[:, :, None]
    img = col_b + (col_a - col_b) * mask
    # Gentle non-periodic shading so the texture is not a perfect synthetic pattern.
    shade = _smooth_field(n_rows, n_cols, rng=rng, amplitude=0.25)
    out = np.clip(img * shade[:, :, None], 0.0, 1.0).astype(np.float32)
    return out, {"kind": kind, "period_px": round(period_px, 4), "angle_deg": round(angle_deg, 4)}


def _smooth_field(n_rows: int, n_cols: int, *, rng: np.random.Generator,
                  amplitude: float) -> np.ndarray:
    """Smooth random multiplicative field around 1, shape (n_rows, n_cols), float32."""
    small = rng.uniform(1.0 - amplitude, 1.0 + amplitude, (4, 6)).astype(np.float32)
    return cv2.resize(small, (n_cols, n_rows), interpolation=cv2.INTER_CUBIC)


def random_scene(n_rows: int, n_cols: int, *, rng: np.random.Generator,
                 texture_prob: float = 0.0) -> tuple[np.ndarray, dict]:
    """A random skimage photo with a random crop, or (with ``texture_prob``) a texture.

    Parameters
    ----------
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator
        Source of every random choice.
    texture_prob : float
        Probability of a procedural texture instead of a photo, in [0, 1].

    Returns
    -------
    reflectance : ndarray of shape (n_rows, n_cols, 3), float32
    params : dict
        JSON-ready description: ``{"scene": "skimage:NAME", "crop": ...}`` or texture params.
    """
    if rng.random() < texture_prob:
        kind = str(rng.choice(TEXTURE_KINDS))
        refl, p = texture_scene(kind, n_rows, n_cols, rng=rng)
        return refl, {"scene": f"texture:{kind}", **p}
    name = str(rng.choice(PHOTO_NAMES))
    return (photo_scene(skimage_photo(name), n_rows, n_cols, rng=rng, min_crop=0.5),
            {"scene": f"skimage:{name}"})
