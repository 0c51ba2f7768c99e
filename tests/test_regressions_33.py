"""Issue #33 item 8: one test per regression that the suite could not see. Each fails under
its one-line mutation (`scripts/mutate_rules.py --group issue33`, part of `make mutants`)."""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
for sub in ("tests/service", ""):
    if str(ROOT / sub) not in sys.path:
        sys.path.append(str(ROOT / sub))


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "PNG")
    return buf.getvalue()


def _noise_png(n_rows: int = 256, n_cols: int = 256, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    return _png(rng.integers(0, 256, (n_rows, n_cols), dtype=np.uint8))


# ------------------------------------------------- 1: the batch body cap (max_batch_bytes)


def test_batch_body_over_max_batch_bytes_is_413():
    """At the cap the batch is screened; one byte over the whole body is refused with 413.
    Mutation: the cap multiplied by 1024 in routes/screen.py."""
    pytest.importorskip("fastapi")
    import httpx
    from svc_helpers import live_server, make_settings

    files = [("files", ("a.png", _noise_png(), "image/png"))]
    req = httpx.Request("POST", "http://x/v1/screen/batch", files=files)
    body, ctype = req.read(), req.headers["content-type"]
    s = make_settings(max_batch_bytes=len(body), warmup=False)
    with live_server(s) as srv, srv.client() as c:
        ok = c.post("/v1/screen/batch", content=body, headers={"content-type": ctype})
        assert ok.status_code == 200, ok.text
    s = make_settings(max_batch_bytes=len(body) - 1, warmup=False)
    with live_server(s) as srv, srv.client() as c:
        r = c.post("/v1/screen/batch", content=body, headers={"content-type": ctype})
        assert r.status_code == 413 and r.json()["code"] == "payload_too_large", r.text


# --------------------------------------- 2: a detector crash inside /v1/screen/batch


def crashing_detect(data, config):
    """A detector bug (module level: picklable into the worker processes)."""
    raise RuntimeError("boom in batch")


def test_detector_crash_in_batch_is_a_logged_500():
    """A bug is a 500 answered once and logged once, never a 200 with a per-file 500 entry.
    Mutation: the per-file handler swallows internal errors (routes/screen.py)."""
    pytest.importorskip("fastapi")
    from svc_helpers import captured_service_log, live_server, make_settings

    files = [("files", ("a.png", _noise_png(), "image/png")),
             ("files", ("b.png", _noise_png(seed=1), "image/png"))]
    with (captured_service_log() as records,
          live_server(make_settings(warmup=False), detect_fn=crashing_detect) as srv,
          srv.client() as c):
        r = c.post("/v1/screen/batch", files=files, headers={"X-Request-ID": "batch-bug"})
    assert r.status_code == 500 and r.json()["code"] == "internal_error", r.text
    errors = [rec for rec in records if rec.levelname == "ERROR"]
    assert len(errors) == 1 and "batch-bug" in errors[0].getMessage()
    assert "boom in batch" in str(errors[0].exc_info[1])


# ------------------------------------------- 3: backslashes in archive member names


@pytest.mark.parametrize("name", ["..\\x.jpg", "a\\..\\..\\x.jpg", "\\abs.jpg", "C:\\x.jpg",
                                  "ok\\..\\..\\etc\\x.jpg"])
def test_backslash_member_names_are_caught(name):
    """Windows separators cannot smuggle a traversal or an absolute name past the check.
    Mutation: member names no longer normalise \\ to / (scan.py)."""
    from lishield_guard.scan import unsafe_member_reason

    assert unsafe_member_reason(name) is not None, name


def test_backslash_traversal_in_a_zip_is_recorded_unsafe(tmp_path):
    import zipfile

    from typer.testing import CliRunner

    from lishield_guard.cli import app

    arc = tmp_path / "a.zip"
    with zipfile.ZipFile(arc, "w") as z:
        z.writestr("..\\evil.png", _noise_png())
        z.writestr("fine.png", _noise_png(seed=2))
    out = tmp_path / "o.jsonl"
    CliRunner().invoke(app, ["scan", str(arc), "-o", str(out), "-j", "1", "--quiet"])
    recs = {r["path"].rsplit("!", 1)[-1].lstrip("/"): r
            for r in map(json.loads, out.read_text().splitlines())}
    evil = next(r for k, r in recs.items() if "evil" in k)
    assert evil["code"] == "unsafe_member_name" and evil["status"] == "error"


# ---------------------------------------- 4: a typo in an old-style flat [detector] table


def test_unknown_key_in_a_flat_detector_table_is_an_error(tmp_path):
    """The flat (pre-grouping) form is still read; a typo in it must not be skipped silently.
    Mutation: the flat path's unknown-key error removed (config.py)."""
    from lishield_guard.config import load_config
    from lishield_guard.errors import ConfigError

    path = tmp_path / "c.toml"
    path.write_text("[detector]\nfit_min_gain = 5.0\nfit_min_gian = 6.0\n")  # typo: gian
    with pytest.raises(ConfigError, match="fit_min_gian"):
        load_config(path)


# ----------------------------------------------- 5: truncated images are never clean


@pytest.mark.parametrize("fraction", [0.5, 0.9])
def test_png_cut_short_is_an_error_not_clean(fraction):
    """A PNG cut at 50 % (or 90 %) is undecodable (422), never a clean verdict.
    Mutation: ImageFile.LOAD_TRUNCATED_IMAGES = True (decode.py)."""
    import lishield_guard
    from lishield_guard.errors import ImageDecodeError

    data = _noise_png(400, 400, seed=3)
    cut = data[: int(len(data) * fraction)]
    with pytest.raises(ImageDecodeError) as info:
        lishield_guard.detect(cut)
    assert info.value.code == "undecodable_image"


def test_png_cut_short_is_422_over_http():
    pytest.importorskip("fastapi")
    from svc_helpers import live_server, make_settings

    data = _noise_png(400, 400, seed=3)
    with live_server(make_settings(warmup=False)) as srv, srv.client() as c:
        r = c.post("/v1/screen", content=data[: len(data) // 2])
    assert r.status_code == 422 and r.json()["code"] == "undecodable_image", r.text
