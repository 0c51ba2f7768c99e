"""Hostile and faulty inputs get the right 4xx JSON error; limits, overload and timeouts."""

from __future__ import annotations

import json
import threading

import pytest
from svc_helpers import (
    TEST_MAX_UPLOAD_BYTES,
    bomb_png,
    captured_service_log,
    live_server,
    make_settings,
    metric_value,
    png_declaring,
)

import lishield_guard


def _err(r, status: int, code: str) -> None:
    assert r.status_code == status, r.text
    assert r.json()["code"] == code
    assert set(r.json()) == {"code", "message"}


def test_png_header_values_are_right():
    assert png_declaring(100_000, 100_000)[16:24] == bytes.fromhex("000186a0000186a0")


@pytest.mark.parametrize("name, body, status, code", [
    ("empty", b"", 400, "empty_body"),
    ("random", bytes(range(256)) * 40, 415, "unsupported_media_type"),
    ("text", b"hello, I am not an image", 415, "unsupported_media_type"),
    ("png_100000x100000", png_declaring(100_000, 100_000), 413, "image_too_large"),
    ("bomb", bomb_png(), 413, "image_too_large"),
])
@pytest.mark.parametrize("mode", ["raw", "multipart"])
def test_hostile_input(client, name, body, status, code, mode):
    if mode == "raw":
        r = client.post("/v1/screen", content=body, headers={"Content-Type": "image/png"})
    else:
        r = client.post("/v1/screen", files={"file": (f"{name}.png", body, "image/png")})
    _err(r, status, code)


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.02])
def test_truncated_jpeg(client, demo_pair, keep):
    data = demo_pair[0].read_bytes()
    r = client.post("/v1/screen", content=data[: int(len(data) * keep)],
                    headers={"Content-Type": "image/jpeg"})
    _err(r, 422, "undecodable_image")


def test_corrupt_png(client):
    body = bytearray(bomb_png(256))
    body[60:80] = b"\xff" * 20
    _err(client.post("/v1/screen", content=bytes(body)), 422, "undecodable_image")


def test_bomb_is_small_but_over_the_cap():
    assert len(bomb_png()) < 100_000


def test_upload_at_limit_and_one_byte_over(client):
    at = b"\x00" * TEST_MAX_UPLOAD_BYTES
    _err(client.post("/v1/screen", content=at), 415, "unsupported_media_type")
    _err(client.post("/v1/screen", content=at + b"\x00"), 413, "payload_too_large")
    r = client.post("/v1/screen", files={"file": ("a.bin", at + b"\x00")})
    _err(r, 413, "payload_too_large")
    _err(client.post("/v1/screen", files={"file": ("a.bin", at)}), 415,
         "unsupported_media_type")


def test_cap_enforced_while_streaming_without_content_length(client):
    sent = []

    def chunks():
        for _ in range(10):
            sent.append(1)
            yield b"\x00" * (TEST_MAX_UPLOAD_BYTES // 4)

    r = client.post("/v1/screen", content=chunks())
    assert "content-length" not in r.request.headers
    _err(r, 413, "payload_too_large")


def test_oversized_content_length_refused_before_reading(api):
    import socket

    host, port = api.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as s:
        s.sendall(b"POST /v1/screen HTTP/1.1\r\nHost: x\r\nContent-Type: image/jpeg\r\n"
                  b"Content-Length: 999999999999\r\n\r\n")
        answer = b""
        while b"}" not in answer:
            chunk = s.recv(65536)
            if not chunk:
                break
            answer += chunk
    answer = answer.decode("latin-1")
    assert answer.startswith("HTTP/1.1 413")
    assert '"code":"payload_too_large"' in answer


def test_multipart_without_file_field(client):
    _err(client.post("/v1/screen", data={"other": "x"}, files={"nope": ("a", b"b")}), 422,
         "invalid_request")
    _err(client.post("/v1/screen", data={"file": "just text"},
                     headers={"Content-Type": "multipart/form-data; boundary=zz"}), 400,
         "invalid_multipart")


def test_broken_multipart(client):
    """A multipart body without a boundary parameter is the client's 400, not a 422 or 500."""
    r = client.post("/v1/screen", content=b"--zz\r\nContent-Disposition: form-data; name=\"file\"",
                    headers={"Content-Type": "multipart/form-data"})
    _err(r, 400, "invalid_multipart")
    assert "boundary" in r.json()["message"]


def test_validation_error_and_unknown_route(client):
    _err(client.post("/v1/screen?explain=maybe", content=b"x"), 422, "invalid_request")
    _err(client.get("/v1/nothing"), 404, "not_found")
    _err(client.get("/v1/screen"), 405, "method_not_allowed")


def test_batch_limits(client):
    files = [("files", (f"{i}.bin", b"x")) for i in range(17)]
    _err(client.post("/v1/screen/batch", files=files), 422, "too_many_files")
    _err(client.post("/v1/screen/batch", files={"other": ("a", b"")}, data={"k": "v"}), 422,
         "invalid_request")
    r = client.post("/v1/screen/batch", files=[("files", ("e", b"")),
                                                ("files", ("big", b"\0" * (TEST_MAX_UPLOAD_BYTES
                                                                            + 1)))])
    res = r.json()["results"]
    assert [e["error"]["code"] for e in res] == ["empty_body", "payload_too_large"]


def test_overload_gives_503_with_retry_after(demo_pair):
    """A request over the queue limit is refused with 503 + Retry-After and counted once; its
    own server, so the counts do not depend on other tests."""
    started, release = threading.Event(), threading.Event()

    def slow_detect(data, config):
        started.set()
        release.wait(20)
        return lishield_guard.detect(data, config)

    s = make_settings(max_concurrency=1, max_queue=0, retry_after_s=2, warmup=False,
                      detect_isolation="thread")  # a closure: runs in the server's threads
    with live_server(s, detect_fn=slow_detect) as srv, srv.client() as c1, srv.client() as c2:
        first = {}
        t = threading.Thread(target=lambda: first.setdefault(
            "r", c1.post("/v1/screen", content=demo_pair[1].read_bytes())))
        t.start()
        assert started.wait(10)
        r = c2.post("/v1/screen", content=demo_pair[1].read_bytes())
        _err(r, 503, "overloaded")
        assert r.headers["retry-after"] == "2"
        release.set()
        t.join(20)
        assert first["r"].status_code == 200
        ok = c2.post("/v1/screen", content=demo_pair[1].read_bytes())
        assert ok.status_code == 200
        text = c2.get("/metrics").text
    assert metric_value(text, "lishield_rejected_overload_total") == 1.0
    screen = {"route": "/v1/screen", "method": "POST"}
    assert metric_value(text, "lishield_http_requests_total", outcome="overloaded", **screen) == 1
    assert metric_value(text, "lishield_http_requests_total", outcome="ok", **screen) == 2


def test_timeout_gives_504(demo_pair):
    """A detection over DETECT_TIMEOUT_S is a 504, counted once in its own server's metrics."""
    release = threading.Event()

    def stuck_detect(data, config):
        release.wait(10)
        return lishield_guard.detect(data, config)

    s = make_settings(detect_timeout_s=0.2, warmup=False, detect_isolation="thread")
    with live_server(s, detect_fn=stuck_detect) as srv, srv.client() as c:
        _err(c.post("/v1/screen", content=demo_pair[1].read_bytes()), 504, "timeout")
        release.set()
        text = c.get("/metrics").text
    assert metric_value(text, "lishield_detect_timeouts_total") == 1.0
    assert metric_value(text, "lishield_http_requests_total", route="/v1/screen",
                        method="POST", outcome="timeout") == 1.0


def _broken_detect(data, config):
    raise RuntimeError("boom")


def test_bug_in_detector_is_a_logged_500():
    """An exception inside the detector is a 500 whose traceback is logged once at ERROR with
    the request's id, counted as internal_error, and the client's connection stays usable."""
    with (captured_service_log() as records,
          live_server(make_settings(warmup=False), detect_fn=_broken_detect) as srv):
        with srv.client() as c:
            r = c.post("/v1/screen", content=b"x", headers={"X-Request-ID": "bug-500-test"})
            _err(r, 500, "internal_error")
            assert "boom" not in r.text  # the traceback stays in the log
            # the same keep-alive connection carries on: the 500 is answered inside the
            # request's context, the exception never reaches uvicorn (which would close it)
            for _ in range(3):
                assert c.get("/healthz").status_code == 200
            text = c.get("/metrics").text
    errors = [rec for rec in records if rec.levelname == "ERROR"]
    assert len(errors) == 1, [rec.getMessage() for rec in records]
    (rec,) = errors
    assert rec.name == "lishield_guard.service"
    assert rec.getMessage() == "unhandled error on POST /v1/screen (request_id=bug-500-test)"
    assert rec.exc_info is not None
    assert isinstance(rec.exc_info[1], RuntimeError) and str(rec.exc_info[1]) == "boom"
    assert metric_value(text, "lishield_http_requests_total", route="/v1/screen",
                        method="POST", outcome="internal_error") == 1.0


def test_500_carries_the_request_id_its_message_promises():
    """The 500's message sends the client to X-Request-ID; the header must be there."""
    with live_server(make_settings(warmup=False), detect_fn=_broken_detect) as srv, \
            srv.client() as c:
        r = c.post("/v1/screen", content=b"x", headers={"X-Request-ID": "bug-500-test"})
    _err(r, 500, "internal_error")
    assert "X-Request-ID" in r.json()["message"]
    assert r.headers.get("x-request-id") == "bug-500-test"


def test_client_errors_are_not_logged_as_errors(demo_pair):
    """4xx answers to bad input are the client's problem: nothing at ERROR in the log."""
    with (captured_service_log() as records,
          live_server(make_settings(warmup=False)) as srv, srv.client() as c):
        _err(c.post("/v1/screen", content=b"hello"), 415, "unsupported_media_type")
        data = demo_pair[0].read_bytes()
        _err(c.post("/v1/screen", content=data[: len(data) // 2]), 422, "undecodable_image")
    assert [rec for rec in records if rec.levelno >= 40] == []


def test_bad_config_fails_at_startup(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[detector]\nprofile = 'nope'\n")
    with pytest.raises(lishield_guard.ConfigError):
        with live_server(make_settings(config_path=bad)):
            pass


def test_hostile_inputs_are_counted_by_code_and_never_500(demo_pair):
    """Every hostile input of this file, sent to a fresh server (no dependence on which tests
    ran before): each is counted under its own error code, exactly as often as it was sent,
    and no request is counted as internal_error or http_500."""
    truncated = demo_pair[0].read_bytes()
    corrupt = bytearray(bomb_png(256))
    corrupt[60:80] = b"\xff" * 20
    over = b"\x00" * (TEST_MAX_UPLOAD_BYTES + 1)
    sent = [(b"", "empty_body"), (bytes(range(256)) * 40, "unsupported_media_type"),
            (b"hello, I am not an image", "unsupported_media_type"),
            (png_declaring(100_000, 100_000), "image_too_large"),
            (bomb_png(), "image_too_large"),
            (truncated[: len(truncated) // 2], "undecodable_image"),
            (bytes(corrupt), "undecodable_image"), (over, "payload_too_large")]
    with live_server(make_settings(warmup=False)) as srv, srv.client() as c:
        for body, code in sent:
            assert c.post("/v1/screen", content=body).json()["code"] == code
        text = c.get("/metrics").text
    screen = {"route": "/v1/screen", "method": "POST"}
    for code in {code for _, code in sent}:
        n = sum(c == code for _, c in sent)
        assert metric_value(text, "lishield_http_requests_total", outcome=code, **screen) == n
    for outcome in ("internal_error", "http_500", "ok"):
        assert metric_value(text, "lishield_http_requests_total", outcome=outcome,
                            **screen) == 0.0
    assert 'outcome="internal_error"' not in text and 'outcome="http_500"' not in text


# ------------------------------------------------------------------ issue 41: 413s and parse errors

@pytest.fixture(scope="module")
def small_caps():
    """A server with tiny caps (thread isolation, no warm-up: no detection is run)."""
    settings = make_settings(max_upload_bytes=1000, max_video_upload_bytes=2000,
                             multipart_overhead_bytes=100, max_batch_bytes=3000,
                             detect_isolation="thread", warmup=False)
    with live_server(settings) as srv:
        yield srv


def _raw_http(srv, request: bytes) -> tuple[str, bytes]:
    """Send ``request`` as it is over a socket; (status line and headers, body)."""
    import socket

    host, port = srv.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as s:
        s.sendall(request)
        answer = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            answer += chunk
    head, _, body = answer.partition(b"\r\n\r\n")
    return head.decode("latin-1"), body


def test_413_messages_name_the_setting_to_raise(small_caps):
    """They said "... bytes > limit of N bytes" (and "more than N bytes > limit of N" for a
    chunked body), where docs/service.md promises the setting's name."""
    cases = [  # (request kwargs, setting named, size said)
        ({"content": b"\0" * 2001}, "max_video_upload_bytes = 2000", "2001 bytes"),
        ({"content": iter([b"\0" * 1500, b"\0" * 1500])}, "max_video_upload_bytes = 2000",
         "more than 2000 bytes"),
        ({"content": b"\0" * 1500}, "max_upload_bytes = 1000", "1500 bytes"),
        ({"files": {"file": ("a.bin", b"\0" * 2500)}},
         "max_video_upload_bytes + multipart_overhead_bytes = 2100", "bytes"),
    ]
    with small_caps.client() as c:
        for kwargs, setting, size in cases:
            r = c.post("/v1/screen", **kwargs)
            _err(r, 413, "payload_too_large")
            message = r.json()["message"]
            assert setting in message and size in message, message
            assert "LISHIELD_" + setting.split(" ")[0].upper() in message, message
            assert "> limit of" not in message
        r = c.post("/v1/screen/batch", files=[("files", ("a", b"\0" * 1600)),
                                              ("files", ("b", b"\0" * 1600))])
        _err(r, 413, "payload_too_large")
        assert "max_batch_bytes = 3000 bytes (LISHIELD_MAX_BATCH_BYTES)" in r.json()["message"]


@pytest.mark.parametrize("request_bytes, code", [
    (b"POST /v1/screen HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n", "invalid_request"),
    (b"POST /v1/screen HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\nContent-Length: 7\r\n\r\n",
     "invalid_request"),
    (b"NOT HTTP AT ALL\r\n\r\n", "bad_request"),
    (b"GET / HTTP/1.1\r\nHost x\r\n\r\n", "bad_request"),
], ids=["content-length-abc", "two-content-lengths", "no-request-line", "header-no-colon"])
def test_requests_the_server_cannot_parse_get_json_errors(small_caps, request_bytes, code):
    """uvicorn answered them with a plain-text 400 before the app saw them."""
    head, body = _raw_http(small_caps, request_bytes)
    assert head.startswith("HTTP/1.1 400"), head
    assert "content-type: application/json" in head.lower(), head
    assert json.loads(body)["code"] == code
