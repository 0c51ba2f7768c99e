"""Issue #33 item 3: a detection the service stops waiting for (504, or the client left) stops
consuming CPU at once: its worker process is ended and the in-flight gauge falls."""

from __future__ import annotations

import os
import threading
import time

import httpx
import pytest
from svc_helpers import live_server, make_settings, metric_value

import lishield_guard

SPIN = b"spin-for-a-minute"
QUICK = b"answer-at-once"
GAUGE = "lishield_detections_in_flight"
FALL_WITHIN_S = 2.0


def spinning_detect(data, config):
    """Burns CPU for a minute on ``SPIN``, detects anything else (module level: picklable)."""
    if isinstance(data, bytes) and data == QUICK:
        from lishield_guard.verdict import Verdict

        return Verdict(False, None, 0, 2, undetermined="quick test answer")
    if isinstance(data, bytes) and data == SPIN:
        end = time.monotonic() + 60
        x = 0
        while time.monotonic() < end:
            x += 1
        return None
    return lishield_guard.detect(data, config)


def _gauge(client: httpx.Client) -> float:
    return metric_value(client.get("/metrics").text, GAUGE)


def _falls_to_zero(client: httpx.Client, within_s: float) -> float | None:
    """Seconds until the gauge reads 0, or None when it did not within ``within_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < within_s:
        if _gauge(client) == 0:
            return time.monotonic() - t0
        time.sleep(0.05)
    return None


def _replacement_ready(workers, *, within_s: float) -> bool:
    """True once one worker process is alive and idle (the replacement has warmed up)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        if len(workers.pids()) == 1 and not workers.pids(busy=True):
            return True
        time.sleep(0.05)
    return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return os.path.exists(f"/proc/{pid}") and "Z" not in _proc_state(pid)


def _proc_state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


@pytest.fixture()
def server():
    # warmed up: the worker process exists before the first request, so the spin starts at once
    s = make_settings(detect_timeout_s=0.5, max_concurrency=1, max_queue=2, warmup=True)
    with live_server(s, detect_fn=spinning_detect) as srv:
        yield srv


def test_gauge_falls_within_2s_of_a_504(server):
    with server.client() as c:
        r = c.post("/v1/screen", content=SPIN)
        assert r.status_code == 504 and r.json()["code"] == "timeout"
        took = _falls_to_zero(c, FALL_WITHIN_S)
        assert took is not None, f"{GAUGE} still {_gauge(c)} {FALL_WITHIN_S} s after the 504"
        # the next detection gets a fresh worker (started and warmed up when the old one was
        # ended; on a loaded machine its warm-up alone can take longer than the 0.5 s budget)
        assert _replacement_ready(server.app.state.service.pool.workers, within_s=30.0)
        ok = c.post("/v1/screen", content=QUICK)
        assert ok.status_code == 200 and ok.json()["undetermined_reason"] == "quick test answer"
        assert metric_value(c.get("/metrics").text, "lishield_detect_timeouts_total") == 1


def test_process_of_a_timed_out_detection_is_ended(server):
    pool = server.app.state.service.pool
    seen: list[int] = []

    def watch() -> None:
        for _ in range(100):
            if pids := pool.workers.pids(busy=True):
                seen.extend(pids)
                return
            time.sleep(0.01)

    t = threading.Thread(target=watch)
    t.start()
    with server.client() as c:
        assert c.post("/v1/screen", content=SPIN).status_code == 504
    t.join()
    assert seen, "no worker process was seen running the detection"
    deadline = time.monotonic() + FALL_WITHIN_S
    while _alive(seen[0]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(seen[0])


def test_gauge_falls_when_the_client_leaves(server):
    with server.client() as c:
        with server.client(timeout=0.3) as leaving:
            with pytest.raises(httpx.TimeoutException):
                leaving.post("/v1/screen", content=SPIN)
        # the server notices within its poll interval, ends the process, and the gauge falls
        took = _falls_to_zero(c, FALL_WITHIN_S)
        assert took is not None, f"{GAUGE} still {_gauge(c)} after the client left"


def test_queued_detection_behind_a_timeout_is_cancelled(server):
    """Two spinning requests on one worker: both 504, and nothing stays admitted."""
    with server.client() as c1, server.client() as c2:
        out: dict = {}
        t = threading.Thread(target=lambda: out.setdefault("r", c1.post("/v1/screen",
                                                                         content=SPIN)))
        t.start()
        r2 = c2.post("/v1/screen", content=SPIN)
        t.join(30)
        assert {r2.status_code, out["r"].status_code} == {504}
        assert _falls_to_zero(c2, FALL_WITHIN_S) is not None
