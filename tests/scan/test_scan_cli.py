"""The scan command end to end: lists, CSV, resume after SIGKILL, Dask equal to local."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from scan_helpers import read_jsonl, write_images

from lishield_guard.scan import RECORD_FIELDS, read_done_keys

CLI = Path(sys.executable).with_name("lishield-guard")


def _strip(recs: list[dict]) -> dict[str, dict]:
    return {r["path"]: {k: v for k, v in r.items() if k != "elapsed_ms"} for r in recs}


def test_from_list_and_records_contract(tmp_path, run_cli):
    imgs = write_images(tmp_path / "imgs", ["a.jpg", "b.jpg"])
    (tmp_path / "note.txt").write_text("hello")
    lst = tmp_path / "list.txt"
    lst.write_text(f"{imgs[0]}\n{tmp_path / 'note.txt'}\n{tmp_path / 'missing.jpg'}\n")
    out = tmp_path / "o.jsonl"
    res = run_cli("scan", imgs[1], "--from-list", lst, "-o", out, "--jobs", "1", "--quiet")
    assert res.exit_code == 3  # input errors present, nothing protected
    recs = {Path(r["path"]).name: r for r in read_jsonl(out)}
    assert set(recs) == {"a.jpg", "b.jpg", "note.txt", "missing.jpg"}
    for r in recs.values():
        assert list(r) == list(RECORD_FIELDS)
    assert recs["a.jpg"]["protected"] is False and recs["a.jpg"]["error"] is None
    assert recs["note.txt"]["protected"] is None and recs["note.txt"]["code"]
    assert recs["missing.jpg"]["code"] == "not_found"


def test_csv_output(tmp_path, run_cli):
    write_images(tmp_path / "imgs", ["a.jpg", "b.jpg", "c.jpg"])
    (tmp_path / "imgs" / "x.txt").write_text("no")
    out = tmp_path / "o.csv"
    res = run_cli("scan", tmp_path / "imgs", "-o", out, "--format", "csv", "--quiet")
    assert res.exit_code == 0
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 3 and list(rows[0]) == list(RECORD_FIELDS)  # x.txt ignored
    assert {r["protected"] for r in rows} == {"false"}
    assert read_done_keys(out, "csv") == {r["key"] for r in rows}


def test_usage_errors(tmp_path, run_cli):
    assert run_cli("scan", tmp_path / "nope").exit_code == 3  # input error: not_found (#33)
    assert run_cli("scan", tmp_path, "--format", "xml").exit_code == 2
    assert run_cli("scan", tmp_path, "--resume").exit_code == 2
    out = tmp_path / "o.jsonl"
    out.write_text('{"key": "x"}\n')
    assert run_cli("scan", tmp_path, "-o", out).exit_code == 2  # would clobber


def test_torn_last_line_repaired(tmp_path, run_cli):
    write_images(tmp_path / "imgs", [f"{i}.jpg" for i in range(4)])
    out = tmp_path / "o.jsonl"
    assert run_cli("scan", tmp_path / "imgs", "-o", out, "--quiet", "-j", "1").exit_code == 0
    lines = out.read_text().splitlines(keepends=True)
    out.write_text("".join(lines[:2]) + lines[2][:25])  # killed mid-write
    assert run_cli("scan", tmp_path / "imgs", "-o", out, "--resume", "--quiet").exit_code == 0
    recs = read_jsonl(out)
    assert sorted(r["path"] for r in recs) == sorted(json.loads(x)["path"] for x in lines)


@pytest.mark.timeout(900)  # correctness, not speed: ~50 detections on one core, on a busy CI
def test_resume_after_sigkill(tmp_path):
    """A scan killed with SIGKILL and resumed: every input recorded exactly once, the records
    written before the kill kept byte for byte (not rescanned and rewritten), only the rest
    scanned, and the summary says how many were skipped. Catches a resume that rescans
    everything, whether it appends duplicates or rewrites the file."""
    names = [f"d{i // 20}/{i:03d}.jpg" for i in range(60)]
    write_images(tmp_path / "imgs", names)
    out = tmp_path / "o.jsonl"
    cmd = [str(CLI), "scan", str(tmp_path / "imgs"), "-o", str(out), "--jobs", "1"]
    proc = subprocess.Popen([*cmd, "--quiet"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if out.exists() and out.read_bytes().count(b"\n") >= 10:
            break
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = out.read_bytes()
    kept = before[: before.rfind(b"\n") + 1]  # a torn last line is repaired away
    partial = kept.count(b"\n")
    assert 10 <= partial < 60, "the scan must be killed mid-way"
    done = {json.loads(line)["path"] for line in kept.decode().splitlines()}
    assert len(done) == partial

    res = subprocess.run([*cmd, "--resume", "--no-progress"], capture_output=True, text=True,
                         timeout=800)
    assert res.returncode == 0, res.stderr
    after = out.read_bytes()
    assert after.startswith(kept), "records written before the kill were rewritten"
    recs = [json.loads(line) for line in after.decode().splitlines()]  # every line valid
    paths = [r["path"] for r in recs]
    assert len(paths) == len(set(paths)) == 60
    assert {Path(p).relative_to(tmp_path / "imgs").as_posix() for p in paths} == set(names)
    new = {json.loads(line)["path"] for line in after[len(kept):].decode().splitlines()}
    assert new == set(paths) - done  # only the unfinished inputs were scanned
    assert f"scanned {60 - partial} input(s)" in res.stderr, res.stderr
    assert f"({partial} already recorded, not rescanned)" in res.stderr, res.stderr


@pytest.mark.timeout(120)
def test_dask_local_equals_local(tmp_path, run_cli):
    write_images(tmp_path / "imgs", [f"{i}.jpg" for i in range(8)])
    (tmp_path / "imgs" / "bad.jpg").write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    import zipfile

    with zipfile.ZipFile(tmp_path / "imgs" / "z.zip", "w") as z:
        z.write(tmp_path / "imgs" / "0.jpg", "in/0.jpg")
        z.writestr("../evil.jpg", b"x")
    local, dsk = tmp_path / "local.jsonl", tmp_path / "dask.jsonl"
    assert run_cli("scan", tmp_path / "imgs", "-o", local, "-j", "2", "--quiet").exit_code == 3
    res = run_cli("scan", tmp_path / "imgs", "-o", dsk, "-j", "2", "--dask", "local", "--quiet")
    assert res.exit_code == 3
    a, b = _strip(read_jsonl(local)), _strip(read_jsonl(dsk))
    assert len(a) == 11 and a == b
