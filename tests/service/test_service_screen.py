"""Verdicts over HTTP equal in-process detect(); batch, policies, health, concurrency, auth."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest
from svc_helpers import live_server, make_settings

import lishield_guard
from service.app import effective_config


def _core(d: dict) -> tuple:
    return d["protected"], d["policy"], d["matches"], d["required"]


def _in_process(path, api) -> dict:
    return lishield_guard.detect(path, effective_config(api.settings)).to_dict(explain=False)


@pytest.mark.parametrize("which", [0, 1], ids=["protected", "clean"])
@pytest.mark.parametrize("mode", ["multipart", "raw"])
def test_verdict_equals_in_process(api, client, demo_pair, which, mode):
    path = demo_pair[which]
    data = path.read_bytes()
    if mode == "multipart":
        r = client.post("/v1/screen", files={"file": (path.name, data, "image/jpeg")})
    else:
        r = client.post("/v1/screen", content=data, headers={"Content-Type": "image/jpeg"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert _core(body) == _core(_in_process(path, api))
    assert "evidence" not in body
    assert body["request_id"] == r.headers["x-request-id"]
    assert set(body) >= {"protected", "policy", "matches", "required", "skipped", "timings_ms"}


def test_demo_pair_verdicts_differ_when_synth_is_present(client, demo_pair):
    """With synth's demo images the protected one is flagged and the clean one is not."""
    pytest.importorskip("synth")
    got = [client.post("/v1/screen", content=p.read_bytes()).json()["protected"]
           for p in demo_pair]
    assert got == [True, False]


def test_explain_and_request_id(client, demo_pair):
    r = client.post("/v1/screen?explain=true", content=demo_pair[0].read_bytes(),
                    headers={"X-Request-ID": "upload-42"})
    assert r.status_code == 200
    want = lishield_guard.detect(demo_pair[0].read_bytes()).to_dict()["evidence"]
    assert r.json()["evidence"]["reason"] == want["reason"]
    assert r.json()["evidence"]["spec_fit"]["spec"] == want["spec_fit"]["spec"]
    assert r.json()["evidence"]["logit"] == want["logit"]
    assert r.json()["request_id"] == "upload-42" == r.headers["x-request-id"]


def test_lying_content_type_is_judged_by_bytes(api, client, demo_pair):
    r = client.post("/v1/screen", content=demo_pair[1].read_bytes(),
                    headers={"Content-Type": "text/plain"})
    assert r.status_code == 200
    assert _core(r.json()) == _core(_in_process(demo_pair[1], api))
    r = client.post("/v1/screen", files={"file": ("x.png", b"GIF89a?" + b"\0" * 20, "image/png")})
    assert r.status_code in (415, 422)


def test_batch_with_one_bad_file(api, client, demo_pair):
    prot, clean = demo_pair
    files = [("files", ("p.jpg", prot.read_bytes(), "image/jpeg")),
             ("files", ("bad.jpg", b"not an image at all", "image/jpeg")),
             ("files", ("c.jpg", clean.read_bytes(), "image/jpeg"))]
    r = client.post("/v1/screen/batch", files=files)
    assert r.status_code == 200, r.text
    res = r.json()["results"]
    assert [e["index"] for e in res] == [0, 1, 2]
    assert res[1]["status"] == 415 and res[1]["error"]["code"] == "unsupported_media_type"
    assert set(res[1]["error"]) == {"code", "message"}
    assert _core(res[0]["result"]) == _core(_in_process(prot, api))
    assert _core(res[2]["result"]) == _core(_in_process(clean, api))


def test_batch_needs_multipart(client):
    assert client.post("/v1/screen/batch", content=b"abc").json()["code"] == \
        "unsupported_media_type"


def test_policies_and_health(client):
    p = client.get("/v1/policies").json()
    assert p["policies"] and {"id", "ratios", "specs"} <= set(p["policies"][0])
    assert p["detector"]["profile"] in ("default", "paper")
    assert p["limits"]["max_bytes"] <= 3_000_000
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ok"}
    assert client.get("/docs").status_code == 200
    schema = client.get("/openapi.json").json()
    assert "ScreenResult" in schema["components"]["schemas"]


def test_sixteen_concurrent_requests(api, demo_pair):
    bodies = [demo_pair[i % 2].read_bytes() for i in range(16)]
    expected = [_core(_in_process(demo_pair[i % 2], api)) for i in range(2)]

    def one(i):
        with api.client() as c:
            return c.post("/v1/screen", content=bodies[i])

    with ThreadPoolExecutor(16) as ex:
        answers = list(ex.map(one, range(16)))
    assert [r.status_code for r in answers] == [200] * 16
    assert [_core(r.json()) for r in answers] == [expected[i % 2] for i in range(16)]
    assert len({r.json()["request_id"] for r in answers}) == 16


def test_metrics_count_what_happened(demo_pair):
    with live_server(make_settings()) as srv, srv.client() as c:
        c.post("/v1/screen", content=demo_pair[0].read_bytes())
        c.post("/v1/screen", content=demo_pair[1].read_bytes())
        c.post("/v1/screen", content=b"")
        c.post("/v1/screen", content=b"junk")
        text = c.get("/metrics").text
    protected = lishield_guard.detect(demo_pair[0]).policy or "none"
    assert 'lishield_http_requests_total{method="POST",outcome="ok",route="/v1/screen"} 2.0' \
        in text
    assert 'outcome="empty_body",route="/v1/screen"} 1.0' in text
    assert 'outcome="unsupported_media_type",route="/v1/screen"} 1.0' in text
    assert f'lishield_verdicts_total{{policy="{protected}"}}' in text
    assert 'lishield_verdicts_total{policy="none"}' in text
    assert "lishield_http_request_duration_seconds_bucket" in text
    received = [ln for ln in text.splitlines()
                if ln.startswith('lishield_http_received_bytes_total{route="/v1/screen"}')]
    total = sum(p.stat().st_size for p in demo_pair) + 4
    assert float(received[0].split()[-1]) == total
    assert "lishield_http_requests_in_flight" in text
    assert "lishield_rejected_overload_total 0.0" in text


TOKEN = "s3cret-token"


@pytest.fixture(scope="module")
def secured():
    with live_server(make_settings(api_token=TOKEN, warmup=False)) as srv:
        yield srv


class TestAuth:
    TOKEN = TOKEN

    @pytest.mark.parametrize("headers", [{}, {"Authorization": "Bearer wrong"},
                                         {"Authorization": "Basic czNjcmV0LXRva2Vu"},
                                         {"Authorization": "Bearer s3cret-token-and-more"}])
    @pytest.mark.parametrize("route", ["/v1/screen", "/v1/policies"])
    def test_refused_without_right_token(self, secured, headers, route):
        with secured.client() as c:
            r = c.post(route, content=b"x", headers=headers) if route == "/v1/screen" \
                else c.get(route, headers=headers)
        assert r.status_code == 401
        assert r.json()["code"] == "unauthorized"
        assert r.headers["www-authenticate"].startswith("Bearer")

    def test_accepted_with_token_and_ops_open(self, secured, demo_pair):
        auth = {"Authorization": f"Bearer {self.TOKEN}"}
        with secured.client() as c:
            r = c.post("/v1/screen", content=demo_pair[1].read_bytes(), headers=auth)
            assert r.status_code == 200
            assert c.get("/v1/policies", headers=auth).status_code == 200
            assert c.get("/healthz").status_code == 200
            assert c.get("/metrics").status_code == 200

    def test_protected_metrics(self):
        s = make_settings(api_token=self.TOKEN, protect_metrics=True, warmup=False)
        with live_server(s) as srv, srv.client() as c:
            assert c.get("/metrics").status_code == 401
            ok = c.get("/metrics", headers={"Authorization": f"Bearer {self.TOKEN}"})
            assert ok.status_code == 200


def test_auth_off_by_default(client):
    assert client.get("/v1/policies").status_code == 200
