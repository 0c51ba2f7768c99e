"""Issue #33 items 1-2 over HTTP: a blank frame is undetermined with ``protected`` null, in
single and batch answers, and the OpenAPI schema says null is possible and what it means."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image
from svc_helpers import make_settings

from service.app import create_app


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "PNG")
    return buf.getvalue()


WHITE = _png(np.full((300, 400), 255, np.uint8))
NOISE = _png(np.random.default_rng(0).integers(0, 256, (200, 200), dtype=np.uint8))


def test_white_frame_is_undetermined_with_protected_null(client):
    body = client.post("/v1/screen", content=WHITE).json()
    assert body["status"] == "undetermined" and body["protected"] is None
    assert body["undetermined_reason"].startswith("no dynamic range")
    assert body["policy"] is None


def test_clean_answer_keeps_protected_false(client):
    body = client.post("/v1/screen", content=NOISE).json()
    assert body["status"] == "clean" and body["protected"] is False


def test_batch_entries_carry_protected_null(client):
    files = [("files", ("w.png", WHITE, "image/png")), ("files", ("n.png", NOISE, "image/png"))]
    res = client.post("/v1/screen/batch", files=files).json()["results"]
    assert res[0]["result"]["status"] == "undetermined" and res[0]["result"]["protected"] is None
    assert res[1]["result"]["protected"] is False


def test_openapi_says_protected_may_be_null():
    schema = create_app(make_settings(warmup=False)).openapi()
    prop = schema["components"]["schemas"]["ScreenResult"]["properties"]["protected"]
    kinds = {alt.get("type") for alt in prop.get("anyOf", [prop])}
    assert kinds == {"boolean", "null"}, prop
    assert "null" in prop["description"] and "undetermined" in prop["description"]


def test_review_caption_follows_the_verdict_and_counts_undetermined(client):
    """The reviewer page's caption comes with the answer (no fixed fit caption), and an
    undetermined review is counted as undetermined, as /v1/screen counts it."""
    before = client.get("/metrics").text.count('policy="undetermined"')
    body = client.post("/v1/review", content=WHITE).json()
    assert body["status"] == "undetermined" and body["verdict"]["protected"] is None
    assert body["figure_caption"].startswith("Left: the image")
    assert body["figure_png_base64"]
    clean = client.post("/v1/review", content=NOISE).json()
    assert "fitted barcode template" not in clean["figure_caption"] or \
        clean["verdict"]["evidence"].get("stage") not in (None, "first stage")
    assert 'lishield_verdicts_total{policy="undetermined"}' in client.get("/metrics").text
    assert before <= client.get("/metrics").text.count('policy="undetermined"')


def test_review_page_has_no_fixed_caption():
    from pathlib import Path

    html = (Path(__file__).resolve().parents[2] / "service" / "static" / "review"
            / "index.html").read_text()
    assert "the rows that were fitted" not in html
