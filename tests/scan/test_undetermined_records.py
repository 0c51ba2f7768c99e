"""Issue #33 items 1-2 in the CLI: blank frames are undetermined, ``protected`` is null unless
the status is clean or protected, and scan records carry the reason and skipped work."""

from __future__ import annotations

import csv
import io
import json

import cv2
import numpy as np
from scan_helpers import jpeg_bytes, read_jsonl

from lishield_guard.commands import ExitCode
from lishield_guard.scan import RECORD_FIELDS
from lishield_guard.verdict import Verdict


def _white_jpeg() -> bytes:
    ok, buf = cv2.imencode(".jpg", np.full((480, 640, 3), 255, np.uint8))
    assert ok
    return buf.tobytes()


def test_scan_record_of_a_white_frame(tmp_path, run_cli):
    (tmp_path / "imgs").mkdir()
    (tmp_path / "imgs" / "white.jpg").write_bytes(_white_jpeg())
    (tmp_path / "imgs" / "noise.jpg").write_bytes(jpeg_bytes(0))
    out = tmp_path / "o.jsonl"
    res = run_cli("scan", tmp_path / "imgs", "-o", out, "-j", "1", "--quiet")
    recs = {r["path"].rsplit("/", 1)[-1]: r for r in read_jsonl(out)}
    white, noise = recs["white.jpg"], recs["noise.jpg"]
    assert white["status"] == "undetermined" and white["protected"] is None
    assert white["reason"].startswith("no dynamic range")
    assert white["undetermined_reason"] == white["reason"]
    assert isinstance(white["skipped"], list)
    assert noise["status"] == "clean" and noise["protected"] is False
    assert noise["reason"] and isinstance(noise["skipped"], list)
    assert res.exit_code == ExitCode.ERROR  # an undetermined image is not a clean scan


def test_csv_record_joins_skipped_notes(tmp_path, run_cli):
    (tmp_path / "imgs").mkdir()
    (tmp_path / "imgs" / "noise.jpg").write_bytes(jpeg_bytes(0, shape=(2000, 300)))
    out = tmp_path / "o.csv"
    run_cli("scan", tmp_path / "imgs", "-o", out, "-j", "1", "--quiet", "--format", "csv")
    (row,) = list(csv.DictReader(io.StringIO(out.read_text())))
    assert list(row) == list(RECORD_FIELDS)
    assert row["reason"] and "[" not in row["skipped"]


def test_detect_json_of_a_white_frame(tmp_path, run_cli):
    p = tmp_path / "white.jpg"
    p.write_bytes(_white_jpeg())
    res = run_cli("detect", p, "--json")
    rec = json.loads(res.output.splitlines()[0])
    assert rec["status"] == "undetermined" and rec["protected"] is None
    assert res.exit_code != ExitCode.CLEAN


def test_verdict_protected_is_derived_from_status():
    """A constructor passing protected=False with a reason still says None (fail closed)."""
    v = Verdict(False, None, 0, 2, undetermined="why")
    assert v.protected is None and v.to_dict()["protected"] is None
    assert Verdict(False, None, 0, 2).protected is False
    assert Verdict(1, "p", 2, 2).protected is True  # coerced to bool
    late = Verdict(False, None, 0, 2)
    object.__setattr__(late, "undetermined", "set late")
    assert late.to_dict()["protected"] is None
