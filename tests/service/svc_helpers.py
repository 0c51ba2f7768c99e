"""Helpers of the service tests: a live uvicorn server, a headless browser and hand-crafted
hostile images."""

from __future__ import annotations

import contextlib
import io
import shutil
import socket
import struct
import threading
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pytest
import uvicorn
from PIL import Image

from service.app import create_app
from service.protocol import UVICORN_HTTP
from service.settings import ServiceSettings

# Small enough that limit tests stay fast, large enough for the 1080p demo JPEGs.
TEST_MAX_UPLOAD_BYTES = 3_000_000
TEST_MAX_PIXELS = 20_000_000


@dataclass
class LiveServer:
    """A uvicorn server running in a background thread."""

    url: str
    app: object
    settings: ServiceSettings

    def client(self, **kwargs) -> httpx.Client:
        # generous: the suite shares two cores with other work, and 16 detections queue
        return httpx.Client(base_url=self.url, timeout=kwargs.pop("timeout", 120.0), **kwargs)


@contextlib.contextmanager
def live_server(settings: ServiceSettings, **app_kwargs) -> Iterator[LiveServer]:
    """Start ``create_app(settings)`` under uvicorn on 127.0.0.1 with a free port."""
    app = create_app(settings, **app_kwargs)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False,
                                           lifespan="on", timeout_graceful_shutdown=2,
                                           http=UVICORN_HTTP))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    try:
        yield LiveServer(f"http://127.0.0.1:{port}", app, settings)
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()


def make_settings(**overrides) -> ServiceSettings:
    """Test settings, independent of the caller's LISHIELD_* environment."""
    base = {"config_path": None, "api_token": None, "protect_metrics": False,
            "max_upload_bytes": TEST_MAX_UPLOAD_BYTES, "max_pixels": TEST_MAX_PIXELS,
            "max_concurrency": 4, "max_queue": 32, "detect_timeout_s": 90.0,
            "log_level": "WARNING"}
    base.update(overrides)
    return ServiceSettings(_env_file=None, **base)


def metric_value(text: str, name: str, **labels: str) -> float:
    """The value of one sample of a Prometheus text exposition (0.0 when the sample is absent:
    a labelled counter that was never incremented is not exposed)."""
    from prometheus_client.parser import text_string_to_metric_families

    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            if sample.name == name and sample.labels == labels:
                return float(sample.value)
    return 0.0


@contextlib.contextmanager
def captured_service_log() -> Iterator[list]:
    """Records of the ``lishield_guard.service`` loggers while the block runs. They do not
    propagate to the root logger (`service.access_log.configure_logging`), so pytest's caplog
    never sees them; a handler is attached to the logger itself."""
    import logging

    records: list[logging.LogRecord] = []

    class _Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    logger = logging.getLogger("lishield_guard.service")
    handler = _Keep(level=logging.DEBUG)
    logger.addHandler(handler)
    try:
        yield records
    finally:
        logger.removeHandler(handler)


def png_declaring(n_cols: int, n_rows: int) -> bytes:
    """A PNG whose IHDR declares ``n_cols x n_rows`` 8-bit grey pixels (valid CRCs, tiny IDAT)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", n_cols, n_rows, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


def bomb_png(n_side: int = 6000) -> bytes:
    """A small PNG of a huge blank image (``n_side**2`` pixels, a few tens of kB)."""
    buf = io.BytesIO()
    Image.new("L", (n_side, n_side), 0).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _browser_paths() -> tuple[str, str]:
    """Paths of a Chromium binary and its driver, or skip with the reason."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        pytest.skip("selenium is not installed (pip install -e '.[dev]')")
    chromium = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser",
                                                           "google-chrome")) if p), None)
    driver = shutil.which("chromedriver")
    if chromium is None or driver is None:
        pytest.skip("no headless browser: Chromium and chromedriver are not installed "
                    "(Debian: apt-get install chromium chromium-driver; `make test` does it "
                    "when run as root)")
    return chromium, driver


@contextlib.contextmanager
def headless_browser() -> Iterator[object]:
    """A headless Chromium driven by Selenium (skips when there is none), quit afterwards."""
    chromium, driver_path = _browser_paths()
    from selenium import webdriver
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1400,1500", "--no-proxy-server"):
        opts.add_argument(arg)
    try:
        browser = webdriver.Chrome(service=Service(executable_path=driver_path), options=opts)
    except WebDriverException as exc:
        pytest.skip(f"Chromium would not start: {exc.msg}")
    try:
        yield browser
    finally:
        browser.quit()


def review_upload(browser, url: str, path, token: str | None = None) -> None:
    """Open the reviewer page at ``url``, upload ``path`` and wait until it has answered
    (``document.body.dataset.state`` is done or error)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(url + "/review")
    assert "lishield-guard" in browser.title
    if token:
        browser.find_element(By.ID, "token").send_keys(token)
    file_input = browser.find_element(By.ID, "file")
    browser.execute_script("arguments[0].style.display = 'block';", file_input)
    file_input.send_keys(str(path))
    WebDriverWait(browser, 120).until(
        lambda b: b.execute_script("return document.body.dataset.state") in ("done", "error"))
    error = browser.find_element(By.ID, "error")
    assert not error.is_displayed(), error.text
