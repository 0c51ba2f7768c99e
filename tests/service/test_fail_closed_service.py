"""Issue #22 at the service's edges: undetermined verdicts, client disconnects, slow and large
bodies, offline /docs and an OpenAPI schema as strict as the server."""

from __future__ import annotations

import io
import re
import socket
import time

import numpy as np
import pytest
from hostile_cases import jpeg_declaring
from PIL import Image
from svc_helpers import live_server, make_settings

from service.app import create_app
from service.settings import ServiceSettings


def _codes() -> set[str]:
    from service.errors import ErrorCode  # imported late: the suite also runs on older code

    return {e.value for e in ErrorCode}


def _png(n_rows: int, n_cols: int) -> bytes:
    buf = io.BytesIO()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (n_rows, n_cols), dtype=np.uint8)).save(buf, "PNG")
    return buf.getvalue()


def _port(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


def _metric(text: str, outcome: str) -> float:
    total = 0.0
    for line in text.splitlines():
        if line.startswith("lishield_http_requests_total{") and f'outcome="{outcome}"' in line:
            total += float(line.rsplit(" ", 1)[1])
    return total


# --------------------------------------------------------------------- 3: undetermined


def test_too_small_image_is_undetermined_over_http(client):
    r = client.post("/v1/screen", content=_png(40, 40))
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "undetermined" and body["protected"] is None
    assert "too small" in body["undetermined_reason"]
    assert 'lishield_verdicts_total{policy="undetermined"}' in client.get("/metrics").text


def test_clean_answer_carries_status(client):
    r = client.post("/v1/screen", content=_png(200, 200))
    assert r.json()["status"] == "clean" and r.json()["undetermined_reason"] is None


# --------------------------------------------------------------------- 7, 9 over HTTP


def test_jpeg_bomb_and_narrow_jpegs_over_http():
    # the pixel cap of the shipped config (100 MP) lets 10000x10000 through: the truncation
    # check and the memory budget must stop it
    with live_server(make_settings(warmup=False, max_pixels=None)) as srv, srv.client() as c:
        r = c.post("/v1/screen", content=jpeg_declaring(10_000, 10_000))
        assert (r.status_code, r.json()["code"]) == (422, "undecodable_image")
        buf = io.BytesIO()
        Image.fromarray(np.full((6200, 17), 128, np.uint8)).save(buf, "JPEG")
        assert c.post("/v1/screen", content=buf.getvalue()).status_code == 200


def test_memory_budget_setting_refuses_before_decoding():
    buf = io.BytesIO()
    Image.new("L", (3000, 3000)).save(buf, "PNG", optimize=True)
    with live_server(make_settings(warmup=False, max_decode_bytes=64 * 1024 * 1024)) as srv, \
            srv.client() as c:
        r = c.post("/v1/screen", content=buf.getvalue())
    assert (r.status_code, r.json()["code"]) == (413, "image_too_large")
    assert "max_decode_bytes" in r.json()["message"]


# --------------------------------------------------------------------- 11: disconnects


@pytest.mark.timeout(120)
def test_client_disconnect_mid_upload_is_not_a_500():
    n = 20
    with live_server(make_settings(warmup=False)) as srv:
        for _ in range(n):
            s = socket.create_connection(("127.0.0.1", _port(srv.url)))
            s.sendall(b"POST /v1/screen HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n"
                      b"Content-Type: application/octet-stream\r\n\r\n" + b"\xff" * 50_000)
            time.sleep(0.02)
            s.close()
        with srv.client() as c:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                text = c.get("/metrics").text
                if _metric(text, "client_disconnected") >= n:
                    break
                time.sleep(0.1)
    assert _metric(text, "client_disconnected") == n
    assert _metric(text, "internal_error") == 0


# --------------------------------------------------------------------- 12: slow, big bodies


@pytest.mark.timeout(60)
def test_slow_body_gets_408():
    with live_server(make_settings(warmup=False, body_timeout_s=1.0)) as srv:
        s = socket.create_connection(("127.0.0.1", _port(srv.url)), timeout=15)
        try:
            s.sendall(b"POST /v1/screen HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n"
                      b"\xff\xd8")
            t0 = time.monotonic()
            head = b""
            while b"body_timeout" not in head and time.monotonic() - t0 < 15:
                got = s.recv(4096)
                if not got:
                    break
                head += got
            elapsed = time.monotonic() - t0
        finally:
            s.close()
    assert head.startswith(b"HTTP/1.1 408"), head[:200]
    assert b"body_timeout" in head and elapsed < 10


def test_bodies_held_are_bounded_with_503_and_retry_after():
    s = make_settings(warmup=False, max_receiving_bytes=100_000, retry_after_s=2)
    with live_server(s) as srv, srv.client() as c:
        r = c.post("/v1/screen", content=b"\xff" * 200_000)
        assert r.status_code == 503 and r.json()["code"] == "overloaded"
        assert r.headers["retry-after"] == "2"

        def chunks():  # no Content-Length: counted while streaming
            for _ in range(20):
                yield b"\xff" * 10_000

        r = c.post("/v1/screen", content=chunks())
        assert r.status_code == 503 and r.headers["retry-after"] == "2"
        # what was held is given back: a small body still fits afterwards
        assert c.post("/v1/screen", content=_png(80, 80)).status_code == 200
        assert srv.app.state.service.bodies.held_bytes == 0


# --------------------------------------------------------------------- 13: offline docs


def test_docs_are_served_from_the_package(client):
    for page in ("/docs", "/redoc"):
        html = client.get(page).text
        assert "cdn" not in html.lower() and "https://" not in html
        assets = re.findall(r'(?:src|href)="([^"]+)"', html)
        local = [a for a in assets if a.startswith("/")]
        assert local, html
        for a in local:
            r = client.get(a)
            assert r.status_code == 200 and len(r.content) > 1000, a


# --------------------------------------------------------------------- 14: strict schema


def _schema(**kw) -> dict:
    return create_app(make_settings(warmup=False, **kw)).openapi()


def test_batch_schema_bounds_the_file_count():
    files = (_schema(max_batch_files=5)["paths"]["/v1/screen/batch"]["post"]["requestBody"]
             ["content"]["multipart/form-data"]["schema"]["properties"]["files"])
    assert files["minItems"] == 1 and files["maxItems"] == 5
    assert all(t in files["items"]["description"] for t in ("image/jpeg", "video/mp4"))


def test_screen_schema_declares_image_bytes():
    content = _schema()["paths"]["/v1/screen"]["post"]["requestBody"]["content"]
    assert "image/jpeg" in content and "image/png" in content
    mp = content["multipart/form-data"]
    assert "image/jpeg" in mp["encoding"]["file"]["contentType"]


def test_error_code_is_an_enum_in_the_schema():
    schema = _schema()
    code = schema["components"]["schemas"]["ErrorBody"]["properties"]["code"]
    ref = code.get("$ref", "").rsplit("/", 1)[-1]
    enum = schema["components"]["schemas"][ref]["enum"] if ref else code["enum"]
    assert set(enum) == _codes()
    from lishield_guard import errors

    for cls in vars(errors).values():
        if isinstance(cls, type) and issubclass(cls, errors.LishieldError) and \
                cls.__module__ == errors.__name__ and not issubclass(cls, errors.ConfigError) \
                and not issubclass(cls, errors.InputFileError) \
                and cls not in (errors.LishieldError, errors.FirmwareError):
            assert cls.code in enum, cls  # (the service reads no files: no InputFileError)


def test_metrics_security_is_declared_as_enforced():
    open_op = _schema()["paths"]["/metrics"]["get"]
    assert "security" not in open_op
    guarded = _schema(api_token="s3cret", protect_metrics=True)["paths"]["/metrics"]["get"]
    assert guarded.get("security")


def test_metrics_protected_by_default_when_a_token_is_set():
    assert ServiceSettings(_env_file=None).protect_metrics is True
    s = make_settings(warmup=False, api_token="s3cret")
    s = s.model_copy(update={"protect_metrics": ServiceSettings(_env_file=None).protect_metrics})
    with live_server(s) as srv, srv.client() as c:
        assert c.get("/metrics").status_code == 401
        assert c.get("/metrics", headers={"Authorization": "Bearer s3cret"}).status_code == 200


def test_every_answered_error_code_is_in_the_enum(client):
    seen = set()
    for kw in ({"content": b""}, {"content": b"junk"}, {"content": jpeg_declaring(10, 10)[:50]},
               {"files": {"nope": ("x", b"1")}}):
        r = client.post("/v1/screen", **kw)
        seen.add(r.json()["code"])
    seen.add(client.get("/nope").json()["code"])
    seen.add(client.put("/v1/screen").json()["code"])
    assert seen <= _codes(), seen
