"""Profile-domain renderer: a capture's block line profiles without rendering every pixel.

The learned decision sees an image only through per-block line means (`spectra.analysable`:
three colour planes, 32 blocks across, every line). This module produces those means for a
capture described like `training.data.sample_example` describes one, many times cheaper than
rendering, encoding and decoding the full frame (`training.data.render`), so that training
can see hundreds of thousands of captures.

A canvas is kept as *cell grids* (`Grids`), lines first: ``rows`` holds, for every row, the
means of its runs of 8 pixels (the JPEG block width), and ``cols`` the same for every column.
Block means of either axis follow from them exactly, and training needs only the grid of the
stripes' axis. What breaks the separation of scene and light is modelled where it happens:

- **Camera.** Reflectance x (ambient + coverage x the exact row light of `synth.camera`) x
  auto gain. Each cell's stored value is the mean over its pixels of clipping, the sRGB curve
  (linear toe included), a tone curve and 8-bit rounding, taken from tables of a pixel's
  statistics given the cell's mean signal, its shot and read noise and the scene's spread
  within the cell (`_pixel_stats`); the cell then gets the noise of a mean of its pixels.
- **Processing.** Resizing from a larger sensor, sharpening and denoising act along the lines
  (they are linear); rotation swaps the grids; borders, collages and frames are composed cell
  by cell (exact area resampling).
- **JPEG.** The mean of a decoded 8x8 block over its 8 columns depends only on its quantised
  DCT coefficients of horizontal frequency 0, the 1-D DCT of the cell column: the quantisation
  of faint stripes is reproduced exactly for luma, and for chroma after the encoder's 2x2
  averaging (4:2:0) and the decoder's triangular upsampling. A decode at 1/2, 1/4 or 1/8 scale
  in the DCT domain keeps the low coefficients and averages lines.

Approximations, measured by ``tests/synth/test_fastrender.py`` against the full render: the
spread within a cell is Gaussian or log-normal; a tone curve acts to second order; bilateral
denoising is a Gaussian blur; the decoder's horizontal chroma upsampling and per-pixel
clipping act on cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cache

import cv2
import numpy as np

__all__ = ["CELL_PX", "Grids", "SceneGrids", "blank_grids", "block_profiles", "capture_grids",
           "compose_border", "compose_collage", "compose_frame", "grids_of_pixels", "jpeg_roundtrip",
           "postprocess_grids", "resize_lines", "rotate_grids", "scene_grids", "still_grids"]

CELL_PX = 8  # pixels per cell: the JPEG block side
_N_BLOCKS = 32
# JPEG Annex K tables: first column (vertical frequency u, horizontal 0) and first row.
_LUMA_COL = np.array([16, 12, 14, 14, 18, 24, 49, 72], np.float32)
_LUMA_ROW = np.array([16, 11, 10, 16, 24, 40, 51, 61], np.float32)
_CHROMA = np.array([17, 18, 24, 47, 99, 99, 99, 99], np.float32)
_YCC = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5],
                 [0.5, -0.418688, -0.081312]], np.float32)
_RGB = np.linalg.inv(_YCC.astype(np.float64)).astype(np.float32)


@dataclass(frozen=True)
class Grids:
    """A canvas as cell grids, lines first (values 0..255 once stored, float32).

    Attributes
    ----------
    rows : ndarray of shape (height, ceil(width / 8), 3) or None
        Every row's means over runs of 8 columns.
    cols : ndarray of shape (width, ceil(height / 8), 3) or None
        Every column's means over runs of 8 rows.
    height, width : int
        Canvas size in pixels (decoded pixels after a scaled decode).
    cell_px : float
        Pixels per cell (8, or 8 / scale after a scaled decode).
    """

    rows: np.ndarray | None
    cols: np.ndarray | None
    height: int
    width: int
    cell_px: float = CELL_PX

    def grids(self):
        """(grid, is_rows) of the grids present."""
        return [(g, r) for g, r in ((self.rows, True), (self.cols, False)) if g is not None]


def _cells(n: int) -> int:
    return -(-n // CELL_PX)


def grids_of_pixels(img: np.ndarray, *, rows: bool = True, cols: bool = True) -> Grids:
    """The exact cell grids of a rendered image (n_rows, n_cols, 3): means of runs of 8
    pixels, the last run of a line shorter when the side is not a multiple of 8."""
    x = np.asarray(img, np.float32)
    h, w = x.shape[:2]

    def runs(a: np.ndarray) -> np.ndarray:  # (lines, across, 3) -> (lines, cells, 3)
        n = a.shape[1]
        starts = np.arange(0, n, CELL_PX)
        sums = np.add.reduceat(a, starts, axis=1)
        return sums / np.diff(np.append(starts, n)).astype(np.float32)[None, :, None]

    return Grids(runs(x) if rows else None, runs(x.transpose(1, 0, 2)) if cols else None, h, w)


def _resize2(x: np.ndarray, n: int, axis: int, area: bool | None = None) -> np.ndarray:
    """Resize along one axis: area mean when shrinking, linear interpolation when enlarging."""
    h, w = x.shape[:2]
    if (h, w)[axis] == n:
        return x
    size = (w, n) if axis == 0 else (n, h)
    shrink = n < (h, w)[axis] if area is None else area
    out = cv2.resize(x, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return out.reshape(size[1], size[0], *x.shape[2:])


def _resize(x: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """`_resize2` along rows, then columns (how `training.data` resizes a scene)."""
    return _resize2(_resize2(x, rows, 0), cols, 1)


@dataclass(frozen=True)
class SceneGrids:
    """A scene's reflectance on the cell grids, lines first: the mean over each cell's pixels
    and their variance (what clipping and the sRGB curve turn into a bias).

    Attributes
    ----------
    rows_mean, rows_var : ndarray of shape (n_rows, ceil(n_cols / 8), 3) or None
    cols_mean, cols_var : ndarray of shape (n_cols, ceil(n_rows / 8), 3) or None
    """

    rows_mean: np.ndarray | None
    rows_var: np.ndarray | None
    cols_mean: np.ndarray | None
    cols_var: np.ndarray | None

    @property
    def size(self) -> tuple[int, int]:
        """(n_rows, n_cols) of the frame."""
        if self.rows_mean is not None:
            return self.rows_mean.shape[0], self.rows_mean.shape[1] * CELL_PX
        return self.cols_mean.shape[1] * CELL_PX, self.cols_mean.shape[0]


def _moments_along(refl: np.ndarray, sq: np.ndarray | None, n: int, axis: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Resize a map (and the mean of its squares) along ``axis`` to ``n``: an area mean of
    both when shrinking, linear interpolation of the value (and of the variance) when
    enlarging."""
    if refl.shape[axis] == n:
        return refl, (refl * refl if sq is None else sq)
    if n < refl.shape[axis]:
        return _resize2(refl, n, axis), _resize2(refl * refl if sq is None else sq, n, axis)
    m = _resize2(refl, n, axis)
    if sq is None:
        return m, m * m
    return m, _resize2(np.maximum(sq - refl * refl, 0.0), n, axis) + m * m


def _grid_moments(refl: np.ndarray, n_lines: int, n_across: int, line_axis: int, sub: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of the cells of one grid, lines first: the map resized across to
    ``sub`` samples per cell, then along the lines, then the cell's samples pooled."""
    across = 1 - line_axis
    m, sq = _moments_along(refl, None, _cells(n_across) * sub, across)
    m, sq = _moments_along(m, sq, n_lines, line_axis)
    if line_axis == 1:
        m, sq = m.transpose(1, 0, 2), sq.transpose(1, 0, 2)
    m, sq = _pool(m, sub), _pool(sq, sub)
    return m, np.maximum(sq - m * m, 0.0)


def _pool(x: np.ndarray, sub: int) -> np.ndarray:
    """Means of runs of ``sub`` samples along axis 1 (strided sums: fast for small runs)."""
    out = x[:, 0::sub].copy()
    for j in range(1, sub):
        out += x[:, j::sub]
    out *= np.float32(1.0 / sub)
    return out


def scene_grids(refl: np.ndarray, n_rows: int, n_cols: int, *, rows: bool = True,
                cols: bool = True, sub: int = 2) -> SceneGrids:
    """Cell grids of a linear reflectance map resized to (n_rows, n_cols).

    Parameters
    ----------
    refl : ndarray of shape (h, w, 3), float32
        Linear reflectance of any size (a photo crop, or a full-size procedural scene),
        resized like `training.data` resizes it for the full render (area mean when shrinking
        an axis, linear interpolation when enlarging it).
    n_rows, n_cols : int
        Frame size in pixels.
    rows, cols : bool
        Which grids to make.
    sub : int
        Samples per cell (a divisor of 8) from which the spread within a cell is taken, on
        top of what shrinking merges.
    """
    refl = np.ascontiguousarray(refl, dtype=np.float32)
    ra = _grid_moments(refl, n_rows, n_cols, 0, sub) if rows else (None, None)
    ca = _grid_moments(refl, n_cols, n_rows, 1, sub) if cols else (None, None)
    return SceneGrids(ra[0], ra[1], ca[0], ca[1])


_MU_SQRT_MAX = 1.3  # the pixel tables cover mean signals up to 1.69 x saturation
_N_MU, _N_SIGMA, _SIGMA_MAX, _SIGMA0 = 384, 48, 0.8, 1e-3
_N_CV, _CV_MIN, _CV_MAX = 40, 0.01, 8.0
_MAP_WIDTH = 4096  # cv2.remap wants maps under 32767 on a side


def _stored(v: np.ndarray) -> np.ndarray:
    """Stored 8-bit value of linear signals (`synth.camera.linear_to_srgb8`), float64."""
    from synth.camera import _LUT_BITS, _srgb8_lut

    top = 2**_LUT_BITS - 1
    return _srgb8_lut().astype(np.float64)[np.clip(np.floor(v * top + 0.5), 0,
                                                   top).astype(np.int64)]


@cache
def _pixel_tables() -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of the stored 8-bit value of a pixel of mean linear signal mu, by
    quadrature: (N_SIGMA, N_MU, 2) for mu + sigma z (z standard normal: sensor noise) and
    (N_CV, N_MU, 2) for mu exp(s z - s^2 / 2), s^2 = ln(1 + cv^2) (a log-normal spread of
    reflectance within a cell: sparse highlights)."""
    mu = np.linspace(0.0, _MU_SQRT_MAX, _N_MU) ** 2
    sigma = _SIGMA0 * np.expm1(np.linspace(0.0, math.log1p(_SIGMA_MAX / _SIGMA0), _N_SIGMA))
    cv = np.geomspace(_CV_MIN, _CV_MAX, _N_CV)
    z = np.linspace(-6.0, 6.0, 241)
    w = np.exp(-0.5 * z * z)
    w /= w.sum()
    out = []
    for draws in ([mu[:, None] + s * z[None, :] for s in sigma],
                  [mu[:, None] * np.exp(math.sqrt(math.log1p(c * c)) * z[None, :]
                                        - math.log1p(c * c) / 2) for c in cv]):
        t = np.empty((len(draws), _N_MU, 2))
        for i, v in enumerate(draws):
            code = _stored(v)
            t[i, :, 0] = code @ w
            t[i, :, 1] = ((code - t[i, :, 0][:, None]) ** 2) @ w
        out.append(t.astype(np.float32))
    return out[0], out[1]


def _flat_index(values: np.ndarray, fn) -> np.ndarray:
    """``fn(values)`` as a flat float32 map padded to whole rows of `_MAP_WIDTH`."""
    n = values.size
    out = np.zeros(n + (-n) % _MAP_WIDTH, np.float32)
    out[:n] = fn(values.reshape(-1))
    return out.reshape(-1, _MAP_WIDTH)


@cache
def _slope_table() -> np.ndarray:
    """d(stored value)/d(linear signal) at the `_pixel_tables` grid of mu (noise-free)."""
    mu = np.linspace(0.0, _MU_SQRT_MAX, _N_MU) ** 2
    x = np.clip(mu, 1e-6, 1.0)
    d = np.where(x <= 0.0031308, 12.92, 1.055 / 2.4 * x ** (1 / 2.4 - 1)) * 255.0
    return np.where(mu < 1.0, d, 0.0).astype(np.float32)


def _pixel_stats(mu: np.ndarray, sigma: np.ndarray, spread: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Statistics of a stored pixel of mean signal ``mu`` whose noise has standard deviation
    ``sigma`` and whose reflectance varies within its cell with standard deviation ``spread``
    (same units as mu): the Gaussian table where noise dominates, the log-normal one (total
    spread) where the scene does.

    Returns (mean, variance, noise variance): the stored value's mean and variance over the
    cell's pixels, and the part of the variance the noise alone gives (slope squared times
    sigma squared, plus rounding), which is what differs between two captures.
    """
    gauss, logn = _pixel_tables()
    n = mu.size
    root = np.sqrt(np.maximum(mu, 0.0)) * np.float32((_N_MU - 1) / _MU_SQRT_MAX)
    mx = _flat_index(root, lambda v: v)
    total = sigma if spread is None else np.sqrt(sigma * sigma + spread * spread)
    my = _flat_index(total, lambda v: np.log1p(v / np.float32(_SIGMA0)) * np.float32(
        (_N_SIGMA - 1) / math.log1p(_SIGMA_MAX / _SIGMA0)))
    got = cv2.remap(gauss, mx, my, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2)[:n].reshape(*mu.shape, 2)
    if spread is not None:
        cv = _flat_index(total / np.maximum(mu, np.float32(1e-9)), lambda v: np.log(np.clip(
            v, _CV_MIN, _CV_MAX) / np.float32(_CV_MIN)) * np.float32(
                (_N_CV - 1) / math.log(_CV_MAX / _CV_MIN)))
        ln = cv2.remap(logn, mx, cv, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2)[:n].reshape(*mu.shape, 2)
        got = np.where((spread > sigma)[..., None], ln, got)
    slope = _slope_table()[np.minimum(root + np.float32(0.5), _N_MU - 1).astype(np.int32)]
    noise_var = np.minimum(slope * slope * sigma * sigma, got[..., 1]) + np.float32(1 / 12)
    return got[..., 0], got[..., 1], noise_var


@cache
def _tone_cache(gamma: float, s_curve: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.arange(1021, dtype=np.float64) / 4.0
    v = _tone(x, {"gamma": gamma, "s_curve": s_curve}).astype(np.float64)
    d1 = np.gradient(v, 0.25)
    return (v.astype(np.float32), d1.astype(np.float32),
            np.gradient(d1, 0.25).astype(np.float32))


def _tone(x: np.ndarray, t: dict) -> np.ndarray:
    """The tone curve of `training.data` (``gamma``, ``s_curve``) on values 0..255."""
    y = np.clip(np.asarray(x, np.float64) / 255.0, 0.0, 1.0) ** t["gamma"]
    y = y + t["s_curve"] * (y - 0.5) * y * (1 - y) * 2
    return (np.clip(y, 0.0, 1.0) * 255.0).astype(np.float32)


def capture_grids(scene: SceneGrids, led_rows: np.ndarray, *, ambient: float,
                  coverage, exposure_s: float, pixels_per_cell: float,
                  rng: np.random.Generator, sensor=None, target_mean: float = 0.18,
                  tone: dict | None = None) -> tuple[Grids, float]:
    """The stored 8-bit frame on the scene's grids: scene x light x auto gain, with each
    cell's pixel statistics.

    Parameters
    ----------
    scene : SceneGrids
        Reflectance at the frame's size (`scene_grids`).
    led_rows : ndarray of shape (n_rows, 3)
        Normalised light of every frame row (`synth.camera.led_rows_rgb` of the sensor rows,
        averaged over the sensor rows of each frame row).
    ambient : float
        Steady ambient light / LED average, unitless.
    coverage : callable or None
        ``coverage(rows_frac, cols_frac) -> (n, m)`` LED coverage in [0, 1] at those positions
        (fractions of the frame); None: everywhere.
    exposure_s : float
        Exposure time in seconds.
    pixels_per_cell : float
        Sensor pixels averaged into one cell (8 x the square of the resize factor).
    rng : numpy.random.Generator
        Noise.
    sensor : synth.camera.SensorModel, optional
    target_mean : float
        Auto-gain target, as in `synth.camera.simulate_frame`.
    tone : dict, optional
        A tone curve applied to every stored pixel (``gamma``, ``s_curve``): its mean over a
        cell's pixels to second order in their spread.

    Returns
    -------
    Grids
        Stored values 0..255 (float32).
    gain : float
        The auto gain.

    Notes
    -----
    A pixel's linear value is mu + sigma z, where mu is the cell's mean signal and sigma^2 the
    pixels' variance around it: the scene's spread within the cell (times the light) plus shot
    and read noise. Its stored value's mean and variance come from `_pixel_stats`; the cell's
    value is that mean plus the noise of a mean of ``pixels_per_cell`` pixels.
    """
    from synth.camera import SensorModel

    sensor = sensor or SensorModel()
    n_rows, n_cols = scene.size
    led = led_rows.astype(np.float32)
    led_cells = _resize2(led[:, None, :], _cells(n_rows), 0)[:, 0, :]
    r_frac = (np.arange(n_rows, dtype=np.float32) + 0.5) / n_rows
    c_frac = (np.arange(n_cols, dtype=np.float32) + 0.5) / n_cols
    rc_frac = (np.arange(_cells(n_rows), dtype=np.float32) * 8 + 4) / n_rows
    cc_frac = (np.arange(_cells(n_cols), dtype=np.float32) * 8 + 4) / n_cols
    grids = []
    if scene.rows_mean is not None:
        cov = None if coverage is None else coverage(r_frac, cc_frac)
        grids.append((scene.rows_mean, scene.rows_var, led[:, None, :], cov))
    if scene.cols_mean is not None:
        cov = None if coverage is None else coverage(rc_frac, c_frac).T
        grids.append((scene.cols_mean, scene.cols_var, led_cells[None, :, :], cov))
    # auto gain from the first grid's mean signal (the frame's mean, as metering gives it)
    m0, _, l0, c0 = grids[0]
    lit = l0 if c0 is None else c0[:, :, None] * l0
    e_scale = exposure_s * sensor.light_e_per_s
    row_mean = m0.mean(axis=1)  # (lines, 3): the light varies along one axis only
    if c0 is None and l0.shape[1] == 1:
        mean_e = float(((row_mean * (l0[:, 0] + np.float32(ambient))).mean())) * e_scale
    else:
        mean_e = float((m0 * (lit + np.float32(ambient))).mean()) * e_scale
    gain = float(np.clip(target_mean * sensor.full_well_e / max(mean_e, 1e-12),
                         sensor.min_gain, sensor.max_gain))
    dn = gain / sensor.full_well_e
    k = np.float32(e_scale * dn)
    read_var = np.float32((sensor.read_noise_e * dn) ** 2)
    out = []
    for mean, var, light, cov in grids:
        level = (light if cov is None else cov[:, :, None] * light) + np.float32(ambient)
        level = level * k
        mu = mean * level
        sigma = np.sqrt(mu * np.float32(dn) + read_var)
        spread = np.sqrt(var) * level
        cell, pixel_var, noise_var = _pixel_stats(mu, sigma, spread)
        if tone:  # to second order in the stored values' spread over the cell
            value, slope, curve = _tone_cache(float(tone["gamma"]), float(tone["s_curve"]))
            i = np.clip(cell * np.float32(4) + np.float32(0.5), 0, 1020).astype(np.int32)
            cell = value[i] + np.float32(0.5) * curve[i] * pixel_var
            noise_var = noise_var * slope[i] ** 2
        cell = cell + np.sqrt(noise_var / np.float32(pixels_per_cell)) * \
            rng.standard_normal(mu.shape, dtype=np.float32)
        out.append(cell)
    rows = out[0] if scene.rows_mean is not None else None
    cols = out[-1] if scene.cols_mean is not None else None
    return Grids(rows, cols, n_rows, n_cols), gain


def still_grids(scene: SceneGrids, gain: float) -> Grids:
    """A noiseless 8-bit rendering of a scene at a fixed gain (a clean photo in a collage or
    frame): each cell's expected stored value given its pixels' spread."""
    g = np.float32(gain)
    vals = [None if m is None else
            _pixel_stats(m * g, np.zeros_like(m), np.sqrt(v) * g)[0]
            for m, v in ((scene.rows_mean, scene.rows_var), (scene.cols_mean, scene.cols_var))]
    return Grids(vals[0], vals[1], *scene.size)


def resize_lines(g: Grids, n_rows: int, n_cols: int) -> Grids:
    """Both grids at a new frame size along their lines (a sensor frame resized; the cells
    across are re-binned exactly)."""
    out = []
    for grid, is_rows in ((g.rows, True), (g.cols, False)):
        if grid is None:
            out.append(None)
            continue
        n_lines, n_across = (n_rows, n_cols) if is_rows else (n_cols, n_rows)
        x = _resize2(grid, n_lines, 0)
        old_across = g.width if is_rows else g.height
        if n_across != old_across:
            dst = np.zeros((n_lines, _cells(n_across), 3), np.float32)
            _place(dst, x, 0.0, CELL_PX, CELL_PX * n_across / old_across)
            x = dst
        out.append(x)
    return Grids(out[0], out[1], n_rows, n_cols)


def _gauss_lines(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur along the lines (axis 0)."""
    if sigma <= 0:
        return x
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k = (k / k.sum()).astype(np.float32)
    flat = np.ascontiguousarray(x.reshape(x.shape[0], -1))
    out = cv2.sepFilter2D(flat, -1, np.ones((1, 1), np.float32), k.reshape(-1, 1),
                          borderType=cv2.BORDER_REFLECT)
    return out.reshape(x.shape)


def postprocess_grids(g: Grids, *, denoise: tuple[str, float] | None,
                      sharpen: float) -> Grids:
    """Denoising and unsharp masking along the lines, in the order of `training.data.render`
    (a tone curve is applied per pixel by `capture_grids`)."""
    out = []
    for grid in (g.rows, g.cols):
        if grid is not None:
            if denoise:
                grid = _gauss_lines(grid, denoise[1])
            if sharpen:
                s = np.float32(sharpen)
                grid = np.clip(grid * (1 + s) - _gauss_lines(grid, 1.5) * s, 0, 255)
        out.append(grid)
    return replace(g, rows=out[0], cols=out[1])


def rotate_grids(g: Grids, degrees: int) -> Grids:
    """The grids of the canvas rotated clockwise by ``degrees`` (0, 90 or 270)."""
    if degrees == 0:
        return g
    rows, cols = g.rows, g.cols
    if degrees == 90:  # new row i = old column i, read from the bottom: cells reversed
        new_rows = None if cols is None else cols[:, ::-1]
        new_cols = None if rows is None else rows[::-1]
    elif degrees == 270:  # new row i = old column w-1-i
        new_rows = None if cols is None else cols[::-1]
        new_cols = None if rows is None else rows[:, ::-1]
    else:
        raise ValueError(f"degrees must be 0, 90 or 270, got {degrees!r}")
    return Grids(None if new_rows is None else np.ascontiguousarray(new_rows),
                 None if new_cols is None else np.ascontiguousarray(new_cols),
                 g.width, g.height)


def _place(dst: np.ndarray, src: np.ndarray, offset_px: float, dst_cell_px: float,
           src_cell_px: float) -> None:
    """Write ``src`` (cells of ``src_cell_px`` pixels along axis 1, its first pixel at
    ``offset_px``) into ``dst`` (cells of ``dst_cell_px``): exact area resampling of piecewise
    constant cells, blended with what ``dst`` holds where a cell is partly covered."""
    n_src, n_dst = src.shape[1], dst.shape[1]
    edges = np.arange(n_dst + 1, dtype=np.float64) * dst_cell_px
    pos = np.clip((edges - offset_px) / src_cell_px, 0.0, n_src)
    covered = np.diff(pos) * (src_cell_px / dst_cell_px)  # share of each dst cell covered
    hit = np.flatnonzero(covered > 0)
    if not hit.size:
        return
    j0, j1 = int(hit[0]), int(hit[-1]) + 1  # the covered dst cells are contiguous
    cum = np.zeros((src.shape[0], n_src + 1, src.shape[2]), np.float32)
    np.cumsum(src, axis=1, out=cum[:, 1:])
    p = pos[j0:j1 + 1]
    k = np.minimum(p.astype(np.int64), n_src - 1)
    frac = (p - k).astype(np.float32)[None, :, None]
    lo, hi = cum[:, k], cum[:, k + 1]
    at = lo + frac * (hi - lo)  # integral (in cells) up to each edge
    vals = np.diff(at, axis=1) * np.float32(src_cell_px / dst_cell_px)
    keep = (1.0 - covered[j0:j1]).astype(np.float32)[None, :, None]
    dst[:, j0:j1] = dst[:, j0:j1] * keep + vals


def _paste(canvas: Grids, g: Grids, r0: int, c0: int, scale: float = 1.0) -> None:
    """Paste ``g`` (shrunk by ``scale`` <= 1 along both axes) into ``canvas`` at (r0, c0)."""
    h, w = int(round(g.height * scale)), int(round(g.width * scale))
    for dst, src, start, offset, n in ((canvas.rows, g.rows, r0, c0, h),
                                       (canvas.cols, g.cols, c0, r0, w)):
        if dst is None or src is None:
            continue
        src = _resize2(src, n, 0) if n != src.shape[0] else src
        stop = min(start + n, dst.shape[0])
        part = dst[start:stop]
        _place(part, src[:stop - start], float(offset), CELL_PX, CELL_PX * scale)
        dst[start:stop] = part


def blank_grids(height: int, width: int, colour, *, rows: bool = True, cols: bool = True
                ) -> Grids:
    """A canvas of one colour (sRGB 0..255 per channel)."""
    c = np.asarray(colour, np.float32)
    return Grids(np.broadcast_to(c, (height, _cells(width), 3)).copy() if rows else None,
                 np.broadcast_to(c, (width, _cells(height), 3)).copy() if cols else None,
                 height, width)


def compose_border(g: Grids, *, height: int, width: int, r0: int, c0: int, colour) -> Grids:
    """``g`` inside a uniform border: a canvas of ``height`` x ``width`` filled with
    ``colour`` (sRGB 0..255), ``g`` at (r0, c0)."""
    canvas = blank_grids(height, width, colour, rows=g.rows is not None,
                         cols=g.cols is not None)
    _paste(canvas, g, r0, c0)
    return canvas


def compose_collage(tiles: list[Grids]) -> Grids:
    """Four tiles of equal size as a 2x2 collage (row-major)."""
    h, w = tiles[0].height, tiles[0].width
    canvas = blank_grids(2 * h, 2 * w, (0, 0, 0), rows=tiles[0].rows is not None,
                         cols=tiles[0].cols is not None)
    for k, t in enumerate(tiles):
        _paste(canvas, t, (k // 2) * h, (k % 2) * w)
    return canvas


def compose_frame(g: Grids, background: Grids, *, shrink: float, where: tuple[float, float]
                  ) -> Grids:
    """``g`` shrunk by ``shrink`` and placed inside ``background`` (same size as ``g``)."""
    canvas = Grids(None if background.rows is None else background.rows.copy(),
                   None if background.cols is None else background.cols.copy(),
                   background.height, background.width)
    h, w = max(8, int(g.height * shrink)), max(8, int(g.width * shrink))
    r0, c0 = int((g.height - h) * where[0]), int((g.width - w) * where[1])
    _paste(canvas, g, r0, c0, scale=min(h / g.height, w / g.width))
    return canvas


def _qtable(base: np.ndarray, quality: int) -> np.ndarray:
    """libjpeg's table for ``quality`` (IJG scaling, baseline-clamped)."""
    q = min(max(int(quality), 1), 100)
    s = (5000.0 / q if q < 50 else 200.0 - 2.0 * q) / 100.0
    return np.clip(np.floor(base * s + 0.5), 1, 255).astype(np.float32)


@cache
def _dct_pair() -> tuple[np.ndarray, np.ndarray]:
    """JPEG's 8-point DCT for means across a block: F(u) = sum_x D[u, x] m(x); and D^-1."""
    x = np.arange(8)
    u = np.arange(8)[:, None]
    c = np.where(u == 0, 1 / math.sqrt(2), 1.0)
    d = math.sqrt(2) * c * np.cos((2 * x + 1) * u * math.pi / 16)
    return d.astype(np.float32), np.linalg.inv(d).astype(np.float32)


def _quantise_lines(x: np.ndarray, q: np.ndarray, keep: int) -> np.ndarray:
    """Quantise the DCT of runs of 8 lines (axis 0, level-shifted by 128) with steps ``q``,
    keep the first ``keep`` coefficients (a scaled decode drops the others), invert; the
    lines are padded by repetition to whole runs."""
    d, dinv = _dct_pair()
    n = x.shape[0]
    pad = (-n) % 8
    if pad:
        x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)])
    rest = x.shape[1:]
    blocks = (x.reshape(-1, 8, int(np.prod(rest))) - np.float32(128)).transpose(1, 0, 2)
    coef = (d @ blocks.reshape(8, -1)).reshape(8, -1)
    coef = np.round(coef / q[:, None]) * q[:, None]
    coef[keep:] = 0
    out = (dinv @ coef).reshape(8, -1, int(np.prod(rest))).transpose(1, 0, 2)
    return (out.reshape(-1, *rest)[:n] + np.float32(128)).astype(np.float32)


def _fancy_up(x: np.ndarray, n: int) -> np.ndarray:
    """libjpeg's triangular 2x upsampling along axis 0 to ``n`` samples."""
    prev = np.concatenate([x[:1], x[:-1]])
    nxt = np.concatenate([x[1:], x[-1:]])
    up = np.empty((2 * x.shape[0],) + x.shape[1:], np.float32)
    up[0::2] = 0.75 * x + 0.25 * prev
    up[1::2] = 0.75 * x + 0.25 * nxt
    return up[:n]


def _pairs(x: np.ndarray, axis: int) -> np.ndarray:
    """Means of consecutive pairs along ``axis`` (the last one alone when odd)."""
    x = np.moveaxis(x, axis, 0)
    if x.shape[0] % 2:
        x = np.concatenate([x, x[-1:]])
    return np.moveaxis(0.5 * (x[0::2] + x[1::2]), 0, axis)


def _jpeg_grid(grid: np.ndarray, *, luma_q: np.ndarray, quality: int, subsampling: str,
               scale: int) -> np.ndarray:
    """One grid (lines first, cells across) through JPEG and a decode at 1/``scale``."""
    keep = 8 // scale
    ycc = grid @ _YCC.T
    ycc[..., 1:] += 128.0
    out = np.empty_like(ycc)
    out[..., 0] = _quantise_lines(ycc[..., 0], _qtable(luma_q, quality), keep)
    chroma = ycc[..., 1:]
    cq = _qtable(_CHROMA, quality)
    if subsampling == "4:2:0":
        n_line, n_cell = chroma.shape[:2]
        pair = _pairs(chroma, 1)  # a chroma block spans two cells
        dev = chroma - np.repeat(pair, 2, axis=1)[:, :n_cell]
        q = _quantise_lines(_pairs(pair, 0), cq, keep)  # the encoder's 2x2 means
        out[..., 1:] = np.repeat(_fancy_up(q, n_line), 2, axis=1)[:, :n_cell] + dev
    else:
        out[..., 1:] = _quantise_lines(chroma, cq, keep)
    out[..., 1:] -= 128.0
    rgb = np.clip(out @ _RGB.T, 0.0, 255.0)
    if scale > 1:
        pad = (-rgb.shape[0]) % scale
        if pad:
            rgb = np.concatenate([rgb, np.repeat(rgb[-1:], pad, axis=0)])
        rgb = rgb.reshape(-1, scale, *rgb.shape[1:]).mean(axis=1)
    return rgb.astype(np.float32)


def jpeg_roundtrip(g: Grids, *, quality: int, subsampling: str, scale: int = 1) -> Grids:
    """The grids after JPEG encoding at ``quality`` and decoding at 1/``scale`` (1, 2, 4, 8)
    in the DCT domain: lines become ``ceil(lines / scale)`` long, a cell 8 / scale pixels."""
    rows = None if g.rows is None else _jpeg_grid(g.rows, luma_q=_LUMA_COL, quality=quality,
                                                  subsampling=subsampling, scale=scale)
    cols = None if g.cols is None else _jpeg_grid(g.cols, luma_q=_LUMA_ROW, quality=quality,
                                                  subsampling=subsampling, scale=scale)
    return Grids(rows, cols, -(-g.height // scale), -(-g.width // scale), CELL_PX / scale)


def _overlap(n_decoded: int, n_cells: int, cell_px: float, n_blocks: int) -> np.ndarray:
    """(n_cells, n_blocks) weights: each cell's share of each block's pixels."""
    k = max(1, min(n_blocks, n_decoded))
    edges = np.linspace(0, n_decoded, k + 1).round()
    c_edges = np.minimum(np.arange(n_cells + 1) * cell_px, n_decoded)
    lo = np.maximum(edges[:-1, None], c_edges[None, :-1])
    hi = np.minimum(edges[1:, None], c_edges[None, 1:])
    w = np.clip(hi - lo, 0, None)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-9)
    if k < n_blocks:
        w = np.concatenate([w] + [w[-1:]] * (n_blocks - k))
    return np.ascontiguousarray(w.T, dtype=np.float32)


def block_profiles(g: Grids, *, n_blocks: int = _N_BLOCKS) -> dict[int, np.ndarray]:
    """Block line means of a decoded canvas, as `spectra.block_profiles_rgb` gives them.

    Returns
    -------
    dict
        0 -> (3, n_blocks, height) (lines are rows) when ``rows`` is present, 1 -> (3,
        n_blocks, width) when ``cols`` is.
    """
    out = {}
    for axis, grid, across in ((0, g.rows, g.width), (1, g.cols, g.height)):
        if grid is not None:
            w = _overlap(across, grid.shape[1], g.cell_px, n_blocks)
            prof = np.matmul(grid.transpose(0, 2, 1), w)  # (lines, 3, blocks)
            out[axis] = np.ascontiguousarray(prof.transpose(1, 2, 0))
    return out
