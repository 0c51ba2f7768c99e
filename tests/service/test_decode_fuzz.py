"""Issue 41: a seeded fuzz of the decode boundary. Mutated bytes of every supported format go
through the Python API, `detect`, `scan` and HTTP (single and batch); every outcome is a verdict
or a typed error, never ``internal_error``, a 500 or a crashed worker, and within its time
budget; one bad file in a batch fails only its own entry.

Before issue 41, 2 of 150 mutated JPEGs made the fast JPEG decoder raise an untyped ValueError
("Corrupt JPEG data: 40 extraneous bytes before marker 0xc4": 500 over HTTP, a 500 for a whole
batch, ``internal_error`` in `detect` and `scan`), an MP4 whose sample entry was broken
raised an AttributeError in the video reader, and FFmpeg's errors reached the message as
"[Errno 1094995529] Invalid data found when processing input: '<none>'"."""

from __future__ import annotations

import json
import time

import pytest
from media_samples import SUFFIX, VIDEO_FORMATS, mutate, sample_bytes
from typer.testing import CliRunner

from lishield_guard.cli import app
from lishield_guard.errors import classify
from lishield_guard.video import detect_media
from service.settings import ServiceSettings

SEEDS = range(8)  # mutants per format; `_mutants` adds the two crashers found by hand
BAD_CODES = {"internal_error", "worker_crashed"}


def _mutants(fmt: str) -> list[tuple[str, bytes]]:
    good = sample_bytes(fmt)
    out = [(f"{fmt}-{seed}{SUFFIX[fmt]}", mutate(good, seed)) for seed in SEEDS]
    if fmt == "jpeg":  # the APP0 marker's type byte zeroed: the ValueError of issue 41
        out.append((f"jpeg-marker{SUFFIX[fmt]}", good[:3] + b"\0" + good[4:]))
    if fmt == "mp4":  # a stream FFmpeg finds no codec for (seed 11 of the mutator)
        out.append((f"mp4-nocodec{SUFFIX[fmt]}", mutate(good, 11)))
    return out


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> dict[str, list[tuple[str, bytes]]]:
    """format -> [(file name, mutated bytes)], also written to one folder."""
    folder = tmp_path_factory.mktemp("fuzz")
    out = {fmt: _mutants(fmt) for fmt in SUFFIX}
    for items in out.values():
        for name, data in items:
            (folder / name).write_bytes(data)
    out["_folder"] = folder  # type: ignore[assignment]
    return out


def _formats(corpus) -> list[str]:
    return [f for f in corpus if not f.startswith("_")]


def test_python_api_gives_a_verdict_or_a_typed_error_within_budget(corpus):
    settings = ServiceSettings(_env_file=None)
    for fmt in _formats(corpus):
        _, budget_s = settings.time_budget("video" if fmt in VIDEO_FORMATS else "image")
        for name, data in corpus[fmt]:
            t0 = time.perf_counter()
            try:
                outcome = detect_media(data).status
            except Exception as exc:  # noqa: BLE001 - the outcome is the code
                outcome, message = classify(exc)
                assert "[Errno" not in message, (name, message)  # FFmpeg's words only
            elapsed_s = time.perf_counter() - t0
            assert outcome not in BAD_CODES, (name, outcome)
            assert elapsed_s < budget_s, (name, elapsed_s)


def test_detect_and_scan_report_no_internal_error(corpus, tmp_path):
    folder = corpus["_folder"]
    names = sorted(p.name for p in folder.iterdir())
    res = CliRunner().invoke(app, ["detect", *(str(folder / n) for n in names), "--json"])
    assert "Traceback" not in res.output
    assert not any(f"[{code}]" in res.output for code in BAD_CODES), res.output
    outcomes = [ln for ln in res.output.splitlines() if ln.startswith(("{", "error: "))]
    assert len(outcomes) == len(names), res.output  # one verdict or one error per file
    out = tmp_path / "scan.jsonl"
    CliRunner().invoke(app, ["scan", str(folder), "-o", str(out), "-j", "1", "--quiet"])
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(records) == len(names)
    assert not [r for r in records if r["code"] in BAD_CODES], records


def test_http_answers_each_mutant_and_each_batch_entry_without_a_500(corpus, client):
    for fmt in _formats(corpus):
        items = corpus[fmt]
        for name, data in items[:2] + items[len(SEEDS):]:  # two, and the hand-found crashers
            r = client.post("/v1/screen", content=data,
                            headers={"Content-Type": "application/octet-stream"})
            assert r.status_code < 500 and r.headers["content-type"] == "application/json", \
                (name, r.status_code, r.text)
            assert r.status_code == 200 or r.json()["code"] not in BAD_CODES
        good = (f"good{SUFFIX[fmt]}", sample_bytes(fmt))
        files = [("files", (n, d, "application/octet-stream"))
                 for n, d in [good, *items[:len(SEEDS)]]]
        r = client.post("/v1/screen/batch", files=files)
        assert r.status_code == 200, (fmt, r.status_code, r.text)
        entries = r.json()["results"]
        assert entries[0]["status"] == 200 and entries[0]["result"]["status"] in (
            "clean", "protected", "undetermined"), entries[0]
        for e in entries[1:]:
            assert e["status"] < 500 and (e["status"] == 200) == ("result" in e), e
