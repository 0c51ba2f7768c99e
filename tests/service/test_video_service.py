"""Videos over a real uvicorn server (issue #34 item 4): ``/v1/screen`` takes a clip declared
as a video or recognised by its bytes, each kind under its own size cap and time budget; broken
and long clips get their codes; the schema says what is accepted; the reviewer's routes and
page show a clip's deciding frame and per-frame scores.

Clips are real H.264 MP4s from ``synth.video`` (360p, 2 s), rendered once per module.
"""

from __future__ import annotations

import base64
import time

import pytest
from svc_helpers import headless_browser, live_server, make_settings, review_upload

from lishield_guard.batch.types import VIDEO_MEDIA_TYPES
from lishield_guard.video import detect_media

pytest.importorskip("av")
synth_video = pytest.importorskip("synth.video")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CLIP = {"size": "360p", "duration_s": 2.0, "fps": 30, "bitrate": 1_500_000}
#: A strong RGB barcode (f_B = 200 Hz) under dim ambient light: flagged (tests/video).
BARCODE = dict(CLIP, motion=False, seed=3, preset="table2-rgb", switching_hz=200.0,
               ambient_ratio=0.2, exposure_s=1 / 4000)
#: A steady light over a photo, camera panning: cleared.
CLEAN = dict(CLIP, motion=True, seed=2, negative="steady")


@pytest.fixture(scope="module")
def clips() -> dict[str, bytes]:
    """``{"protected": barcode clip, "clean": clean clip}`` as MP4 bytes."""
    return {name: synth_video.render_video_item(synth_video.clip_params(**params))[0]
            for name, params in (("protected", BARCODE), ("clean", CLEAN))}


def _err(r, status: int, code: str) -> dict:
    assert (r.status_code, r.json()["code"]) == (status, code), r.text
    return r.json()


def _post_clip(client, data: bytes, mode: str, route: str = "/v1/screen?explain=true"):
    if mode == "multipart":
        return client.post(route, files={"file": ("clip.mp4", data, "video/mp4")})
    content_type = {"raw": "video/mp4", "sniffed": "application/octet-stream"}[mode]
    return client.post(route, content=data, headers={"Content-Type": content_type})


# --------------------------------------------------------------------- verdicts


@pytest.mark.parametrize("which", ["protected", "clean"])
@pytest.mark.parametrize("mode", ["raw", "multipart"])
def test_clip_verdict_with_its_frames(client, clips, which, mode):
    r = _post_clip(client, clips[which], mode)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["status"] == which and body["protected"] == (which == "protected")
    ev = body["evidence"]
    assert ev["stage"] == "video" and ev["video"]["info"]["codec"] == "h264"
    frames = ev["video"]["frames"]
    assert frames and {"index", "time_s", "logit", "where", "keyframe", "run"} <= set(frames[0])
    assert set(ev["deciding_frames"]) <= {f["index"] for f in frames}


def test_clip_without_a_video_type_is_judged_by_its_bytes(client, clips):
    r = _post_clip(client, clips["protected"], "sniffed", route="/v1/screen")
    assert r.status_code == 200 and r.json()["status"] == "protected"
    assert "evidence" not in r.json()
    lying = client.post("/v1/screen", content=clips["clean"],
                        headers={"Content-Type": "image/jpeg"})
    assert lying.status_code == 200 and lying.json()["status"] == "clean"


def test_truncated_clip_is_undecodable_video(client, clips):
    cut = clips["protected"][: len(clips["protected"]) * 2 // 3]
    for mode in ("raw", "multipart"):
        _err(_post_clip(client, cut, mode), 422, "undecodable_video")


def test_image_is_held_to_the_image_cap_below_the_video_cap(api, client):
    """A body under max_video_upload_bytes but over max_upload_bytes that is not a video."""
    at = api.settings.max_upload_bytes
    assert api.settings.max_video_upload_bytes > at + 1
    msg = _err(client.post("/v1/screen", content=b"\xff" * (at + 1)), 413, "payload_too_large")
    assert "max_upload_bytes" in msg["message"]


def test_batch_takes_clips_and_images(client, clips, demo_pair):
    cut = clips["protected"][:1000]
    files = [("files", ("a.mp4", clips["protected"], "video/mp4")),
             ("files", ("b.jpg", demo_pair[1].read_bytes(), "image/jpeg")),
             ("files", ("c.mp4", cut, "video/mp4"))]
    r = client.post("/v1/screen/batch?explain=true", files=files)
    assert r.status_code == 200, r.text
    res = r.json()["results"]
    assert [e["status"] for e in res] == [200, 200, 422]
    assert res[0]["result"]["status"] == "protected"
    assert res[0]["result"]["evidence"]["stage"] == "video"
    assert res[1]["result"]["evidence"]["stage"] != "video"
    assert res[2]["error"]["code"] == "undecodable_video"


# --------------------------------------------------------------------- limits


@pytest.fixture(scope="module")
def tight(clips, tmp_path_factory):
    """A server whose video cap is the barcode clip's size and whose duration cap is 1.5 s."""
    cfg = tmp_path_factory.mktemp("video_cfg") / "short.toml"
    cfg.write_text("[video.limits]\nmax_duration_s = 1.5\n")
    settings = make_settings(config_path=cfg, max_video_upload_bytes=len(clips["protected"]),
                             max_concurrency=1, warmup=False)
    with live_server(settings) as srv:
        yield srv


def test_video_at_the_size_cap_is_read_and_one_byte_over_is_refused(tight, clips):
    at = clips["protected"]
    with tight.client() as c:
        # at the cap: read and opened, then refused for its 2 s > max_duration_s = 1.5 s
        msg = _err(_post_clip(c, at, "raw"), 413, "video_too_long")
        assert "1.5" in msg["message"]
        for mode in ("raw", "multipart"):
            msg = _err(_post_clip(c, at + b"\0", mode), 413, "payload_too_large")
            assert "max_video_upload_bytes" in msg["message"]


def test_policies_list_the_video_limits(tight, clips):
    with tight.client() as c:
        lim = c.get("/v1/policies").json()["video_limits"]
    assert lim["max_bytes"] == len(clips["protected"]) and lim["max_duration_s"] == 1.5


def slow_media(data, config):
    """`detect_media` half a second late (thread isolation: closures need no pickling)."""
    time.sleep(0.5)
    return detect_media(data, config)


def test_video_has_its_own_time_budget(clips, demo_pair):
    s = make_settings(detect_isolation="thread", video_timeout_s=0.2, detect_timeout_s=60.0,
                      warmup=False, max_concurrency=1)
    with live_server(s, detect_fn=slow_media) as srv, srv.client() as c:
        msg = _err(_post_clip(c, clips["clean"], "raw"), 504, "timeout")
        assert "video_timeout_s=0.2" in msg["message"]
        r = c.post("/v1/screen", content=demo_pair[1].read_bytes())
        assert r.status_code == 200, r.text  # an image keeps detect_timeout_s


# --------------------------------------------------------------------- schema


def test_openapi_lists_the_video_types(client):
    schema = client.get("/openapi.json").json()
    for route in ("/v1/screen", "/v1/review", "/v1/screen/plot"):
        content = schema["paths"][route]["post"]["requestBody"]["content"]
        assert set(VIDEO_MEDIA_TYPES) <= set(content), route
        part = content["multipart/form-data"]["encoding"]["file"]["contentType"]
        assert "video/mp4" in part and "image/jpeg" in part
    batch = schema["paths"]["/v1/screen/batch"]["post"]["requestBody"]["content"]
    assert "video/mp4" in batch["multipart/form-data"]["encoding"]["files"]["contentType"]
    codes = schema["components"]["schemas"]["ErrorCode"]["enum"]
    assert {"undecodable_video", "video_too_long"} <= set(codes)


# --------------------------------------------------------------------- reviewer


def test_review_and_plot_of_a_clip(api, client, clips):
    r = _post_clip(client, clips["protected"], "multipart", route="/v1/review")
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["status"] == "protected" and d["verdict"]["evidence"]["video"]["frames"]
    assert base64.b64decode(d["figure_png_base64"])[:8] == PNG_MAGIC
    assert "frame" in d["figure_caption"]
    r = _post_clip(client, clips["clean"], "raw", route="/v1/screen/plot")
    assert r.status_code == 200 and r.content[:8] == PNG_MAGIC
    assert r.headers["x-lishield-status"] == "clean"
    assert api.app.state.service.bodies.held_bytes == 0  # the review routes give bodies back


def test_review_page_accepts_clips(client):
    page = client.get("/review").text
    assert 'accept="image/*,video/*' in page and 'id="frames"' in page


def test_review_page_lists_the_frames_of_a_clip(api, clips, tmp_path):
    from selenium.webdriver.common.by import By

    path = tmp_path / "barcode.mp4"
    path.write_bytes(clips["protected"])
    with headless_browser() as browser:
        review_upload(browser, api.url, path)
        title = browser.find_element(By.ID, "title")
        assert title.get_attribute("data-status") == "protected"
        assert browser.find_element(By.ID, "preview-video").is_displayed()
        rows = browser.find_elements(By.CSS_SELECTOR, "#frames tbody tr")
        assert rows and browser.find_elements(By.CSS_SELECTOR, "#frames tr.deciding")
