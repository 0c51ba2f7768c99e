"""Issue #22 hostile-input suite: every hostile body over HTTP (raw and multipart) answers a
typed 4xx or a verdict, never a 5xx; bombs stay within the memory budget (peak RSS measured)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hostile_cases import BOMB_CASES, hostile_bodies
from svc_helpers import live_server, make_settings

from service.errors import ErrorCode

CASES = hostile_bodies()
BOMB_BUDGET_BYTES = 256 * 1024 * 1024
RSS_SLACK_BYTES = 48 * 1024 * 1024


@pytest.fixture(scope="module")
def hostile_api():
    with live_server(make_settings(max_concurrency=2, max_queue=64, detect_timeout_s=120.0,
                                   max_pixels=None, max_decode_bytes=BOMB_BUDGET_BYTES)) as srv:
        yield srv


@pytest.mark.timeout(600)
def test_hostile_corpus_never_gets_a_5xx(hostile_api):
    statuses: dict[str, tuple[int, str]] = {}
    with hostile_api.client() as c:
        for name, body in CASES:
            for mode in ("raw", "multipart"):
                if mode == "raw":
                    r = c.post("/v1/screen", content=body)
                else:
                    r = c.post("/v1/screen", files={"file": ("x.bin", body)})
                j = r.json()
                statuses[f"{name}/{mode}"] = (r.status_code, j.get("code") or j.get("status"))
                assert r.status_code < 500, (name, mode, r.status_code, j)
                if r.status_code >= 400:
                    assert j["code"] in {e.value for e in ErrorCode}, j
        text = c.get("/metrics").text
    assert "internal_error" not in text
    assert len(statuses) == 2 * len(CASES) >= 80
    # the shapes the issue reproduced
    assert statuses["jpeg_10000x10000_in_700_bytes/raw"] == (422, "undecodable_image")
    assert statuses["narrow_1x65000_jpeg/raw"][0] == 200
    assert statuses["narrow_17x6200_jpeg/raw"][0] == 200
    assert statuses["small_40x40_png_undetermined/raw"] == (200, "undetermined")
    assert statuses["jpeg_cut_at_50pct/raw"] == (422, "undecodable_image")


_RSS_PROBE = r"""
import json, resource, sys
import numpy as np
import lishield_guard as lg
lg.detect(np.random.default_rng(0).integers(0, 256, (256, 256), dtype=np.uint8))
data = open(sys.argv[1], "rb").read()
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
cfg = lg.load_config()
import dataclasses
cfg = dataclasses.replace(cfg, limits=lg.Limits(max_decode_bytes=int(sys.argv[2])))
try:
    out = lg.detect(data, cfg).status
except lg.LishieldError as exc:
    out = exc.code
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"outcome": out, "peak_over_baseline_bytes": max(0, peak - before)}))
"""


@pytest.mark.timeout(300)
@pytest.mark.parametrize("name,data", BOMB_CASES, ids=[n for n, _ in BOMB_CASES])
def test_bomb_peak_memory_stays_within_the_budget(tmp_path, name, data):
    f = tmp_path / "bomb.bin"
    f.write_bytes(data)
    res = subprocess.run([sys.executable, "-c", _RSS_PROBE, str(f), str(BOMB_BUDGET_BYTES)],
                         capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr
    got = json.loads(res.stdout.strip().splitlines()[-1])
    print(name, got)
    assert got["peak_over_baseline_bytes"] <= BOMB_BUDGET_BYTES + RSS_SLACK_BYTES, got
    Path(tmp_path / "result.json").write_text(json.dumps(got))
