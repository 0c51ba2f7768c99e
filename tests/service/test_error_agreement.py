"""Issue 41: the same bad input gets the same code from `detect`, `scan`, the Python API and HTTP
(one mapping, `lishield_guard.errors.classify`); before, a symlink loop was `not_found` in
`detect` and `read_error` in `scan`, a missing file `unsupported_media_type` from the API, and a
JPEG with a broken marker a 500 over HTTP."""

from __future__ import annotations

import json
import os

import pytest
from media_samples import image_bytes, mutate, video_bytes
from typer.testing import CliRunner

from lishield_guard.cli import app
from lishield_guard.errors import classify
from lishield_guard.video import detect_media


def _broken_marker_jpeg() -> bytes:
    """The APP0 marker's type byte zeroed: libjpeg-turbo refuses the header ("extraneous bytes
    before marker 0xdb"); Pillow reads the image."""
    data = bytearray(image_bytes("jpeg"))
    data[3] = 0
    return bytes(data)


def _bytes_cases() -> dict[str, tuple[bytes, str]]:
    """name -> (bytes, the outcome every interface must give: a status or an error code)."""
    jpeg, mp4 = image_bytes("jpeg"), video_bytes("mp4")
    return {"empty.jpg": (b"", "empty_body"),
            "text.jpg": (b"not an image, just words\n", "unsupported_media_type"),
            "half.jpg": (jpeg[: len(jpeg) // 2], "undecodable_image"),
            "broken-marker.jpg": (_broken_marker_jpeg(), "clean"),
            "cut.mp4": (mp4[: len(mp4) * 2 // 3], "undecodable_video"),
            "no-codec.mp4": (mutate(mp4, 11), "unsupported_media_type")}


def _api(source) -> str:
    try:
        return detect_media(source).status
    except Exception as exc:  # noqa: BLE001 - the outcome is the code
        return classify(exc)[0]


def _cli(path) -> str:
    res = CliRunner().invoke(app, ["detect", str(path), "--json"])
    assert "Traceback" not in res.output, res.output
    for line in res.output.splitlines():
        if line.startswith("{"):
            return json.loads(line)["status"]
        if line.startswith("error: ") and line.endswith("]"):
            return line.rsplit("[", 1)[1][:-1]
    raise AssertionError(res.output)


def _scan(paths, tmp_path) -> dict[str, str]:
    out = tmp_path / "records.jsonl"
    CliRunner().invoke(app, ["scan", *map(str, paths), "-o", str(out), "-j", "1", "--quiet"])
    records = [json.loads(line) for line in out.read_text().splitlines()]
    return {os.path.basename(r["path"]): r["code"] or r["status"] for r in records}


def _http(client, data: bytes) -> str:
    r = client.post("/v1/screen", content=data,
                    headers={"Content-Type": "application/octet-stream"})
    assert r.headers["content-type"] == "application/json", r.text
    return r.json()["status"] if r.status_code == 200 else r.json()["code"]


def test_the_same_bad_bytes_get_the_same_outcome_everywhere(tmp_path, client):
    cases = _bytes_cases()
    paths = []
    for name, (data, _) in cases.items():
        (tmp_path / name).write_bytes(data)
        paths.append(tmp_path / name)
    scanned = _scan(paths, tmp_path)
    for (name, (data, want)), path in zip(cases.items(), paths, strict=True):
        got = {"api bytes": _api(data), "api path": _api(path), "detect": _cli(path),
               "scan": scanned[name], "http": _http(client, data)}
        assert set(got.values()) == {want}, (name, got)


def test_the_same_bad_paths_get_the_same_code_in_detect_scan_and_the_api(tmp_path):
    (tmp_path / "loop.jpg").symlink_to(tmp_path / "loop.jpg")
    (tmp_path / "dangling.jpg").symlink_to(tmp_path / "gone.jpg")
    os.mkfifo(tmp_path / "fifo.jpg")
    cases = {"missing.jpg": "not_found", "loop.jpg": "read_error", "dangling.jpg": "not_found",
             "fifo.jpg": "special_member", "loop.mp4": "read_error"}
    (tmp_path / "loop.mp4").symlink_to(tmp_path / "loop.mp4")
    paths = [tmp_path / name for name in cases]
    scanned = _scan(paths, tmp_path)
    for name, want in cases.items():
        path = tmp_path / name
        got = {"api": _api(path), "detect": _cli(path), "scan": scanned[name]}
        assert set(got.values()) == {want}, (name, got)


def test_an_archive_is_refused_with_a_pointer_to_scan(tmp_path, client):
    """Everywhere but `scan`, which reads the images inside archives."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("a.jpg", image_bytes("jpeg"))
    (tmp_path / "photos.zip").write_bytes(buf.getvalue())
    assert _api(buf.getvalue()) == _cli(tmp_path / "photos.zip") == "unsupported_media_type"
    r = client.post("/v1/screen", content=buf.getvalue())
    assert r.status_code == 415 and "`lishield-guard scan` reads" in r.json()["message"]


@pytest.mark.parametrize("kind", ["raw", "multipart"])
def test_a_jpeg_with_a_broken_marker_is_screened_not_a_500(client, kind):
    data = _broken_marker_jpeg()
    if kind == "raw":
        r = client.post("/v1/screen", content=data, headers={"Content-Type": "image/jpeg"})
    else:
        r = client.post("/v1/screen", files={"file": ("x.jpg", data, "image/jpeg")})
    assert r.status_code == 200 and r.json()["status"] == "clean", r.text
