"""Scenes as linear reflectance per channel: image files, skimage photos, the real-photo
corpus (``photos:DIR#INDEX``), procedural textures."""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from lishield_guard.errors import ConfigError, ImageDecodeError, InvalidImageError

__all__ = [
    "DEFAULT_PHOTO_DIR",
    "PHOTO_NAMES",
    "ALL_TEXTURE_KINDS",
    "HARD_TEXTURE_KINDS",
    "TEXTURE_KINDS",
    "corpus_manifest",
    "corpus_photo",
    "fit_to_sensor",
    "load_scene",
    "parse_photo_scene",
    "photo_scene",
    "photo_scene_names",
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
#: Every kind `texture_scene` draws; ``"screen"`` (a display's fine scan lines) is left out of
#: `TEXTURE_KINDS` so that datasets drawn from that tuple stay as they were.
ALL_TEXTURE_KINDS = (*TEXTURE_KINDS, "screen")
#: Kinds drawn only where asked for by name (training's hard look-alikes): a building's windows
#: in perspective, a grid whose pitch changes across the frame.
HARD_TEXTURE_KINDS = ("facade",)
# Real-photo corpus written by scripts/fetch_photos.py (manifest.jsonl + images/).
DEFAULT_PHOTO_DIR = Path("out/photos")
PHOTOS_PREFIX = "photos:"

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


# -- real-photo corpus ---------------------------------------------------------------------

def _manifest_path(photo_dir: str | Path) -> Path:
    return Path(photo_dir) / "manifest.jsonl"


@lru_cache(maxsize=8)
def _read_manifest(path: str, mtime_ns: int) -> tuple[dict, ...]:
    rows = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                row["file"]  # noqa: B018 - every row must name its copy
            except (ValueError, KeyError, TypeError):
                raise ConfigError(f"{path}:{lineno}: not a photo manifest line") from None
            rows.append(row)
    return tuple(rows)


def corpus_manifest(photo_dir: str | Path = DEFAULT_PHOTO_DIR) -> tuple[dict, ...]:
    """Rows of the real-photo corpus manifest, in manifest order.

    Parameters
    ----------
    photo_dir : str or Path
        Corpus directory written by ``scripts/fetch_photos.py`` (``manifest.jsonl`` and
        ``images/``). Default ``out/photos``.

    Returns
    -------
    tuple of dict
        One dict per photo with at least ``file`` (relative to ``photo_dir``); the fetcher also
        writes ``package``, ``version``, ``source``, ``path``, ``n_rows``, ``n_cols``,
        ``file_bytes`` and ``sha256``. Re-read when the manifest file changes.

    Raises
    ------
    ConfigError
        No manifest in ``photo_dir``, or a line that is not a manifest row.
    """
    path = _manifest_path(photo_dir)
    try:
        mtime_ns = path.stat().st_mtime_ns
    except FileNotFoundError:
        raise ConfigError(f"no photo corpus manifest at {str(path)!r}; "
                          "run scripts/fetch_photos.py") from None
    return _read_manifest(str(path.resolve()), mtime_ns)


def photo_scene_names(photo_dir: str | Path = DEFAULT_PHOTO_DIR) -> list[str]:
    """Scene names ``"photos:DIR#INDEX"`` of every corpus photo, for `load_scene`.

    Parameters
    ----------
    photo_dir : str or Path
        Corpus directory (see `corpus_manifest`); DIR in the names is spelled as given.

    Returns
    -------
    list of str
        ``[f"photos:{photo_dir}#{i}" for i in range(n_photos)]``; INDEX is the manifest line
        (0-based), so a name is stable for one manifest. Record the photo's ``sha256`` (from
        `corpus_manifest`) next to it where reproducibility across corpus versions matters.

    Raises
    ------
    ConfigError
        No manifest in ``photo_dir``.

    Examples
    --------
    >>> names = photo_scene_names("out/photos")           # doctest: +SKIP
    >>> load_scene(names[0], 480, 640, rng=np.random.default_rng(0)).shape  # doctest: +SKIP
    (480, 640, 3)
    """
    n = len(corpus_manifest(photo_dir))
    return [f"{PHOTOS_PREFIX}{photo_dir}#{i}" for i in range(n)]


def parse_photo_scene(name: str) -> tuple[Path, int]:
    """Split ``"photos:DIR#INDEX"`` into (DIR, INDEX); ``"photos:DIR"`` alone is an error.

    Raises
    ------
    ConfigError
        Not of that form, or INDEX is not a non-negative integer.
    """
    if not name.startswith(PHOTOS_PREFIX) or "#" not in name:
        raise ConfigError(f"photo scene must be 'photos:DIR#INDEX', got {name!r}")
    folder, _, idx = name[len(PHOTOS_PREFIX):].rpartition("#")
    if not idx.isdigit():
        raise ConfigError(f"photo scene index must be an integer >= 0, got {idx!r} in {name!r}")
    return Path(folder or "."), int(idx)


def corpus_photo(photo_dir: str | Path, index: int, *, min_side_px: int | None = None
                 ) -> np.ndarray:
    """Corpus photo number ``index`` as read-only sRGB uint8 of shape (n_rows, n_cols, 3).

    Parameters
    ----------
    photo_dir : str or Path
        Corpus directory (see `corpus_manifest`).
    index : int
        Manifest line, 0-based.
    min_side_px : int, optional
        JPEGs larger than needed are decoded at 1/2, 1/4 or 1/8 scale (libjpeg's draft mode),
        keeping both sides >= this many pixels when the file allows. None decodes full size.

    Returns
    -------
    ndarray of uint8, shape (n_rows, n_cols, 3)
        EXIF orientation applied; grey and 16-bit images expanded to 8-bit RGB.

    Raises
    ------
    ConfigError
        No manifest, index out of range, or the listed file is missing.
    ImageDecodeError
        The file cannot be decoded.
    """
    rows = corpus_manifest(photo_dir)
    if not 0 <= index < len(rows):
        raise ConfigError(f"photo index {index} out of range: the corpus in {str(photo_dir)!r} "
                          f"has {len(rows)} photos")
    path = (Path(photo_dir) / rows[index]["file"]).resolve()
    return _decode_photo(str(path), min_side_px)


@lru_cache(maxsize=8)
def _decode_photo(path: str, min_side_px: int | None) -> np.ndarray:
    from PIL import Image, ImageOps

    try:
        with Image.open(path) as im:
            if min_side_px is not None and im.format == "JPEG":
                n_cols, n_rows = im.size
                frac = min_side_px / max(1, min(n_rows, n_cols))
                if frac < 1.0:  # draft keeps the decoded size >= the requested one
                    im.draft("RGB", (math.ceil(n_cols * frac), math.ceil(n_rows * frac)))
            im = ImageOps.exif_transpose(im)
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                top = 65535.0 if a.max(initial=0.0) > 255 else 255.0
                arr = _to_rgb_uint8(a / top)
            else:
                arr = np.asarray(im.convert("RGB"))
    except FileNotFoundError:
        raise ConfigError(f"corpus photo missing: {path!r}; re-run scripts/fetch_photos.py"
                          ) from None
    except Exception as exc:  # Pillow raises many types for bad files
        raise ImageDecodeError(f"cannot read corpus photo {path!r}: {exc}") from None
    out = np.ascontiguousarray(arr)
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
    """Scene from an array, an image file, ``skimage:NAME``, ``photos:DIR#INDEX`` or
    ``texture:KIND``.

    Parameters
    ----------
    source : str, Path or ndarray
        Image array, path to an image file, ``"skimage:astronaut"`` (see `PHOTO_NAMES`),
        ``"photos:out/photos#12"`` (photo 12 of the real-photo corpus; see
        `photo_scene_names`) or ``"texture:blinds"`` (see `TEXTURE_KINDS`; needs ``rng`` or
        uses seed 0).
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
        Unknown skimage or texture name; bad ``photos:`` name, index or missing corpus.
    ImageDecodeError
        The file cannot be read as an image.
    """
    if isinstance(source, np.ndarray):
        return photo_scene(source, n_rows, n_cols, rng=rng, min_crop=min_crop)
    s = str(source)
    if s.startswith("skimage:"):
        return photo_scene(skimage_photo(s.split(":", 1)[1]), n_rows, n_cols, rng=rng,
                           min_crop=min_crop)
    if s.startswith(PHOTOS_PREFIX):
        folder, index = parse_photo_scene(s)
        if not 0.0 < min_crop <= 1.0:
            raise ConfigError(f"need 0 < min_crop={min_crop!r} <= 1")
        # Decode big JPEGs at reduced scale, never below what the smallest crop needs.
        need_px = math.ceil(max(n_rows, n_cols) / min_crop)
        return photo_scene(corpus_photo(folder, index, min_side_px=need_px), n_rows, n_cols,
                           rng=rng, min_crop=min_crop)
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
    kind : {"blinds", "bricks", "fabric", "screen", "facade"}
        Window blinds (soft square wave), brick courses with staggered joints, a woven
        fabric (two crossed gratings with fine thread noise), a display's scan lines, or a
        facade's windows in perspective (a grid whose pitch changes by up to 2x across the
        frame, each window its own shade: successive pitches look like tones taking turns).
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator
        Draws the colours, phases and (if not given) period and orientation.
    period_px : float, optional
        Spatial period in pixels; default log-uniform in [8, 120] px (blinds/bricks),
        [4, 30] px (fabric) or [2, 6] px (screen).
    angle_deg : float, optional
        Orientation of the stripes' normal from the row axis, degrees; 0 gives horizontal
        stripes like an LED's. Default: half the time within 10 degrees of 0, else uniform.

    Returns
    -------
    reflectance : ndarray of shape (n_rows, n_cols, 3), float32 in [0, 1]
    params : dict
        JSON-ready parameters (kind, period_px, angle_deg).
    """
    known = (*ALL_TEXTURE_KINDS, *HARD_TEXTURE_KINDS)
    if kind not in known:
        raise ConfigError(f"unknown texture {kind!r}; known: {', '.join(known)}")
    if period_px is None:
        lo, hi = {"fabric": (4.0, 30.0), "screen": (2.0, 6.0),
                  "facade": (4.0, 60.0)}.get(kind, (8.0, 120.0))
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
    elif kind == "facade":  # pitch p (1 + g x / span) along each direction: perspective
        span = float(max(n_rows, n_cols))
        uu, vv = (_chirp(w * period_px, float(rng.uniform(-0.6, 0.6)), span, period_px)
                  for w in (u, v))
        uu = uu + np.float32(rng.uniform(0, 1))
        fu, fv = uu - np.floor(uu), vv - np.floor(vv)
        wu, wv = rng.uniform(0.5, 0.85), rng.uniform(0.5, 0.85)
        window = ((fu > 1 - wu) & (fv > 1 - wv)).astype(np.float32)
        shades = rng.uniform(0.0, 0.7, (61, 67)).astype(np.float32)  # each window its own
        cell = shades[np.floor(uu).astype(np.int64) % 61, np.floor(vv).astype(np.int64) % 67]
        mask = 1.0 - window * (1.0 - cell)
    elif kind == "screen":  # scan lines: bright rows, thin dark gaps, a slow image on top
        frac = u - np.floor(u)
        mask = np.clip((frac - 0.15) * period_px * 2, 0.0, 1.0) * (
            0.6 + 0.4 * np.cos(2 * np.pi * v / rng.uniform(20, 80)) ** 2)
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


def _chirp(x_px: np.ndarray, g: float, span: float, period_px: float) -> np.ndarray:
    """Phase in periods at position ``x_px`` of a grating whose local period is
    ``period_px * (1 + g x / span)`` (a plane seen in perspective)."""
    if abs(g) < 1e-6:
        return x_px / period_px
    return np.log(np.maximum(1.0 + g * x_px / span, 0.05)) * (span / (g * period_px))


def _smooth_field(n_rows: int, n_cols: int, *, rng: np.random.Generator,
                  amplitude: float) -> np.ndarray:
    """Smooth random multiplicative field around 1, shape (n_rows, n_cols), float32."""
    small = rng.uniform(1.0 - amplitude, 1.0 + amplitude, (4, 6)).astype(np.float32)
    return cv2.resize(small, (n_cols, n_rows), interpolation=cv2.INTER_CUBIC)


def random_scene(n_rows: int, n_cols: int, *, rng: np.random.Generator,
                 texture_prob: float = 0.0, photo_dir: str | Path | None = None
                 ) -> tuple[np.ndarray, dict]:
    """A random photo with a random crop, or (with ``texture_prob``) a texture.

    Photos are scikit-image's bundled ones, or with ``photo_dir`` the real-photo corpus.

    Parameters
    ----------
    n_rows, n_cols : int
        Sensor size in pixels.
    rng : numpy.random.Generator
        Source of every random choice.
    texture_prob : float
        Probability of a procedural texture instead of a photo, in [0, 1].
    photo_dir : str or Path, optional
        Corpus directory (``scripts/fetch_photos.py``): draw a corpus photo, uniformly over
        the manifest, instead of a scikit-image one. None (default) keeps the scikit-image
        photos and the exact random draws of earlier versions.

    Returns
    -------
    reflectance : ndarray of shape (n_rows, n_cols, 3), float32
    params : dict
        JSON-ready description: ``{"scene": "skimage:NAME"}``, ``{"scene":
        "photos:DIR#INDEX", "package": ..., "sha256": ...}`` or texture params.
    """
    if rng.random() < texture_prob:
        kind = str(rng.choice(TEXTURE_KINDS))
        refl, p = texture_scene(kind, n_rows, n_cols, rng=rng)
        return refl, {"scene": f"texture:{kind}", **p}
    if photo_dir is not None:
        rows = corpus_manifest(photo_dir)
        index = int(rng.integers(len(rows)))
        name = f"{PHOTOS_PREFIX}{photo_dir}#{index}"
        return (load_scene(name, n_rows, n_cols, rng=rng, min_crop=0.5),
                {"scene": name, "package": rows[index].get("package"),
                 "sha256": rows[index].get("sha256")})
    name = str(rng.choice(PHOTO_NAMES))
    return (photo_scene(skimage_photo(name), n_rows, n_cols, rng=rng, min_crop=0.5),
            {"scene": f"skimage:{name}"})
