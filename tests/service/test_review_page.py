"""The reviewer's page (/review), /v1/review and /v1/screen/plot; the page in a real browser.

The browser test drives Debian's Chromium through Selenium (chromium + chromium-driver from
apt, selenium from PyPI; `make test` installs them when run as root). It is skipped, with the
reason, when any of them is missing. Set LISHIELD_SCREENSHOT_DIR to keep the screenshot of the
page after an upload (`make docs` does, for docs/figures/review_page.png), and
LISHIELD_REVIEW_IMAGE to upload another image than the demo's protected capture; without
either, the screenshot is compared with docs/figures/review_page.png, so a changed page or
figure fails until `make docs` retakes it.
"""

from __future__ import annotations

import base64
import os
import shutil
from pathlib import Path

import pytest
from svc_helpers import headless_browser, live_server, make_settings, review_upload

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TOKEN = "review-test-token"


@pytest.fixture(scope="module")
def authed():
    """A server that requires a bearer token."""
    with live_server(make_settings(api_token=TOKEN)) as srv:
        yield srv


def test_page_and_assets_are_served_without_a_token(authed):
    with authed.client() as c:
        page = c.get("/review")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert "/review/static/review.js" in page.text and "http" not in page.text.replace(
            "http-equiv", "")  # no CDN, no absolute links: works offline
        for name, kind in (("review.js", "javascript"), ("review.css", "css")):
            r = c.get(f"/review/static/{name}")
            assert r.status_code == 200 and kind in r.headers["content-type"]
        assert c.get("/review/static/..%2Fapp.py").status_code == 404
        assert c.get("/review/static/index.html").status_code == 404


def test_review_and_plot_need_the_token(authed, demo_pair):
    protected, _ = demo_pair
    with authed.client() as c:
        for route in ("/v1/review", "/v1/screen/plot"):
            r = c.post(route, files={"file": ("p.jpg", protected.read_bytes(), "image/jpeg")})
            assert r.status_code == 401 and r.json()["code"] == "unauthorized"


def test_review_answers_verdict_reason_and_figure(authed, demo_pair):
    protected, clean = demo_pair
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with authed.client(headers=auth) as c:
        r = c.post("/v1/review", files={"file": ("p.jpg", protected.read_bytes(), "image/jpeg")})
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["status"] == "protected"  # synth's demo capture (test_service_screen)
        assert d["title"].startswith(d["status"].upper())
        assert d["reason"] and d["verdict"]["evidence"]["reason"] == d["reason"]
        screened = c.post("/v1/screen", files={"file": ("p.jpg", protected.read_bytes(),
                                                        "image/jpeg")}).json()
        assert screened["protected"] == (d["status"] == "protected") == d["verdict"]["protected"]
        assert base64.b64decode(d["figure_png_base64"])[:8] == PNG_MAGIC
        r = c.post("/v1/screen/plot", content=clean.read_bytes(),
                   headers={"Content-Type": "image/jpeg"})
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        assert r.content[:8] == PNG_MAGIC and len(r.content) > 10_000
        assert r.headers["x-lishield-status"] == "clean"
        bad = c.post("/v1/screen/plot", content=b"not an image",
                     headers={"Content-Type": "image/jpeg"})
        assert bad.status_code == 415 and bad.json()["code"] == "unsupported_media_type"


def test_reviewer_page_in_a_headless_browser(authed, demo_pair, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    image = Path(os.environ.get("LISHIELD_REVIEW_IMAGE") or demo_pair[0]).resolve()
    with authed.client(headers={"Authorization": f"Bearer {TOKEN}"}) as c:
        expected = c.post("/v1/review", content=image.read_bytes(),
                          headers={"Content-Type": "application/octet-stream"}).json()
    with headless_browser() as browser:
        review_upload(browser, authed.url, image, token=TOKEN)
        title = browser.find_element(By.ID, "title")
        assert title.text == expected["title"]
        assert title.get_attribute("data-status") == expected["status"]
        assert "Why:" in browser.find_element(By.ID, "reason").text
        WebDriverWait(browser, 30).until(lambda b: b.execute_script(
            "const i = document.getElementById('figure'); "
            "return i.complete && i.naturalWidth > 0"))
        width = browser.execute_script("return document.getElementById('figure').naturalWidth")
        assert width >= 800
        assert not browser.find_element(By.ID, "frames-box").is_displayed()  # photos: no table
        browser.execute_script("document.querySelector('#drop').scrollIntoView()")
        shot = tmp_path / "review_page.png"
        assert browser.save_screenshot(str(shot)) and shot.read_bytes()[:8] == PNG_MAGIC
        keep = os.environ.get("LISHIELD_SCREENSHOT_DIR")
        if keep:
            Path(keep).mkdir(parents=True, exist_ok=True)
            shutil.copy(shot, Path(keep) / "review_page.png")
        elif not os.environ.get("LISHIELD_REVIEW_IMAGE"):  # the docs' screenshot is this page
            _assert_docs_screenshot_is(shot)


def _assert_docs_screenshot_is(shot: Path) -> None:
    """docs/figures/review_page.png is what the page shows now (issue 41: it showed the old
    page and figure for a capture today's default calls clean); `make docs` retakes it."""
    import sys

    root = Path(__file__).resolve().parents[2]
    sys.path.insert(0, str(root / "scripts"))
    try:
        import make_docs
    finally:
        sys.path.remove(str(root / "scripts"))
    assert make_docs.figure_problems({"review_page.png": shot}) == []
