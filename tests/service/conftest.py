"""Fixtures of the service tests: real uvicorn servers on loopback and test images."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from svc_helpers import LiveServer, live_server, make_settings

# tests/conftest.py puts tests/ on sys.path, where tests/synth (no __init__.py) would be
# imported as a namespace package named `synth`; with the repository root on the path the
# real package wins (a regular package beats namespace portions), so demo_pair uses it.
ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.append(str(ROOT))


@pytest.fixture(scope="session")
def api() -> Iterator[LiveServer]:
    """The default server: no auth, generous queue."""
    with live_server(make_settings()) as srv:
        yield srv


@pytest.fixture()
def client(api: LiveServer) -> Iterator[httpx.Client]:
    with api.client() as c:
        yield c


def _fallback_pair(out: Path) -> tuple[Path, Path]:
    """Striped photo (periods 2:3:4 cycled every ~60 rows) and the plain photo, as JPEGs."""
    from skimage import data

    photo = data.astronaut().astype(np.float32)
    rows = np.arange(photo.shape[0])
    period = np.array([12.0, 18.0, 24.0])[(rows // 60) % 3]
    gain = 1.0 + 0.25 * np.sign(np.sin(2 * np.pi * rows / period))
    striped = np.clip(photo * gain[:, None, None] / 1.25, 0, 255).astype(np.uint8)
    paths = []
    for name, img in (("protected.jpg", striped), ("clean.jpg", photo.astype(np.uint8))):
        Image.fromarray(img).save(out / name, quality=90)
        paths.append(out / name)
    return paths[0], paths[1]


@pytest.fixture(scope="session")
def demo_pair(tmp_path_factory) -> tuple[Path, Path]:
    """(protected, clean) JPEGs from ``synth.demo_images``, or a hand-made fallback."""
    out = tmp_path_factory.mktemp("demo")
    try:
        from synth import demo_images
    except ImportError:
        return _fallback_pair(out)
    return demo_images(out, seed=0)
