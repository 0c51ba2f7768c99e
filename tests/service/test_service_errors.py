"""Hostile and faulty inputs get the right 4xx JSON error; limits, overload and timeouts."""

from __future__ import annotations

import threading

import pytest
from svc_helpers import TEST_MAX_UPLOAD_BYTES, bomb_png, live_server, make_settings, png_declaring

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
    r = client.post("/v1/screen", content=b"--zz\r\nContent-Disposition: form-data; name=\"file\"",
                    headers={"Content-Type": "multipart/form-data"})
    assert r.status_code in (400, 422)
    assert r.json()["code"] in ("invalid_multipart", "invalid_request")


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
    started, release = threading.Event(), threading.Event()

    def slow_detect(data, config):
        started.set()
        release.wait(20)
        return lishield_guard.detect(data, config)

    s = make_settings(max_concurrency=1, max_queue=0, retry_after_s=2, warmup=False)
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
    assert "lishield_rejected_overload_total 1.0" in text
    assert 'outcome="overloaded",route="/v1/screen"} 1.0' in text


def test_timeout_gives_504(demo_pair):
    release = threading.Event()

    def stuck_detect(data, config):
        release.wait(10)
        return lishield_guard.detect(data, config)

    s = make_settings(detect_timeout_s=0.2, warmup=False)
    with live_server(s, detect_fn=stuck_detect) as srv, srv.client() as c:
        _err(c.post("/v1/screen", content=demo_pair[1].read_bytes()), 504, "timeout")
        release.set()
        assert "lishield_detect_timeouts_total 1.0" in c.get("/metrics").text


def test_bug_in_detector_is_a_logged_500(demo_pair, caplog):
    def broken(data, config):
        raise RuntimeError("boom")

    with live_server(make_settings(warmup=False), detect_fn=broken) as srv, srv.client() as c:
        _err(c.post("/v1/screen", content=b"x"), 500, "internal_error")


def test_bad_config_fails_at_startup(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[detector]\nprofile = 'nope'\n")
    with pytest.raises(lishield_guard.ConfigError):
        with live_server(make_settings(config_path=bad)):
            pass


def test_no_input_above_produced_a_500(client):
    text = client.get("/metrics").text
    assert 'outcome="internal_error"' not in text
    assert 'outcome="http_500"' not in text
