"""Fixtures for core tests: a seeded rng and a factory of striped test images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from core_led_model import row_waveform

from lishield_guard.spec import BarcodeSpec


@pytest.fixture
def rng():
    """A generator with a fixed seed."""
    return np.random.default_rng(1234)


@pytest.fixture
def make_led_image(rng):
    """Factory: a scene lit by a barcode LED (or steady light), as 8-bit RGB or JPEG bytes."""

    def make(spec: BarcodeSpec | None, *, scene: np.ndarray | None = None, n_rows: int = 1080,
             n_cols: int = 1440, row_rate_hz: float = 30_000.0, exposure_s: float = 1 / 4000,
             switching_hz: float | None = None, ambient: float = 1.0, jpeg: int | None = 90,
             flicker: np.ndarray | None = None, phase: str = "restart",
             lit_fraction: float = 1.0):
        if scene is None:
            from skimage import data

            scene = cv2.resize(data.coffee(), (n_cols, n_rows))
        lin = (scene.astype(np.float32) / 255.0) ** 2.2
        if spec is None:
            led = np.full((n_rows, 3), 0.5) if flicker is None else flicker[:, None] * np.ones(3)
        else:
            w = row_waveform(spec, row_time_s=1 / row_rate_hz, n_rows=n_rows,
                             exposure_s=exposure_s, switching_hz=switching_hz,
                             t0_s=float(rng.random() * 0.01), phase=phase)
            led = (np.repeat(w["W"][:, None], 3, 1) if "W" in w
                   else np.stack([w["R"], w["G"], w["B"]], 1))
        # the LED lights the right-hand lit_fraction of the columns, ambient all of them
        width = lin.shape[1]
        lit = (np.arange(width) >= (1.0 - lit_fraction) * width).astype(np.float32)
        img = lin * (ambient * 0.5 + led[:, None, :] * lit[None, :, None]).astype(np.float32)
        img = img / np.percentile(img, 99.5) * 0.85
        img = np.clip(img + rng.normal(0, 0.002, img.shape), 0, 1) ** (1 / 2.2)
        img8 = (img * 255 + 0.5).astype(np.uint8)
        if jpeg is None:
            return img8
        ok, buf = cv2.imencode(".jpg", img8[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, jpeg])
        assert ok
        return buf.tobytes()

    return make
