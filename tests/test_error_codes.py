"""Issue #33 item 4: one error-code table (`lishield_guard.errors.ERROR_CODES`) for CLI exit
statuses, scan records and HTTP answers; the README's table is generated from it."""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

import pytest

import lishield_guard.errors as errors
from lishield_guard.commands import ExitCode
from lishield_guard.errors import ERROR_CODES, error_code, error_code_table_markdown

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "scripts") not in sys.path:
    sys.path.insert(0, str(ROOT / "scripts"))


def _lishield_errors() -> list[type]:
    return [c for _, c in inspect.getmembers(errors, inspect.isclass)
            if issubclass(c, errors.LishieldError) and c is not errors.LishieldError]


def test_codes_are_unique_and_exit_statuses_are_the_cli_ones():
    codes = [e.code for e in ERROR_CODES]
    assert len(codes) == len(set(codes))
    assert errors.EXIT_USAGE == ExitCode.USAGE and errors.EXIT_INPUT_ERROR == ExitCode.ERROR
    assert {e.exit_status for e in ERROR_CODES} <= {None, ExitCode.USAGE, ExitCode.ERROR}


@pytest.mark.parametrize("cls", _lishield_errors(), ids=lambda c: c.__name__)
def test_every_core_error_code_is_in_the_table(cls):
    assert error_code(cls.code).source == "core"


def test_every_scan_record_code_is_in_the_table():
    import lishield_guard.scan as scan

    for name, value in vars(scan).items():
        if name.startswith("CODE_"):
            error_code(value)  # KeyError when missing


def test_service_statuses_and_enum_come_from_the_table():
    from service.errors import ErrorCode, describe

    for cls in _lishield_errors():
        if cls.__name__ == "SpecError":
            continue  # needs a rule; a ConfigError, as below
        status, code, _, _ = describe(cls("x"))
        statuses = error_code(cls.code).http_statuses
        if statuses and not issubclass(cls, errors.ConfigError):
            assert (status, code) == (statuses[0], cls.code), cls
        else:  # never from an upload (files, config): a bug if it happens
            assert (status, code) == (500, "internal_error"), cls
    assert {c.value for c in ErrorCode} == {e.code for e in ERROR_CODES
                                            if e.http_statuses or e.code == "http_error"}


def test_every_service_error_raised_in_the_source_matches_the_table():
    """``ServiceError(status, "code", ...)`` anywhere in service/: status listed for the code."""
    found = 0
    for path in (ROOT / "service").rglob("*.py"):
        for status, code in re.findall(r'ServiceError\(\s*(\d{3}),\s*"([a-z_]+)"',
                                       path.read_text()):
            assert int(status) in error_code(code).http_statuses, (path.name, status, code)
            found += 1
    assert found >= 10


def test_readme_and_service_doc_tables_are_generated_from_the_code_table():
    from make_docs import README, SERVICE_DOC, code_blocks, read_block

    assert set(code_blocks()) == {README, SERVICE_DOC}
    for path, blocks in code_blocks().items():
        for name, block in blocks.items():
            assert read_block(path.read_text(), name) == block, \
                f"{path.name}'s {name} table is stale: run `make docs`"
    assert "`empty_body`" in error_code_table_markdown()


def test_exit_meanings_cover_the_cli_exit_codes():
    assert set(errors.EXIT_MEANINGS) == {int(c) for c in ExitCode}


def test_empty_file_has_one_code_everywhere(tmp_path):
    """An empty file: `empty_body` in a scan record, in `detect` and over HTTP (issue: it was
    unsupported_media_type in scan and empty_body over HTTP)."""
    import json

    from typer.testing import CliRunner

    from lishield_guard.cli import app

    (tmp_path / "in").mkdir()
    empty = tmp_path / "in" / "empty.jpg"
    empty.write_bytes(b"")
    out = tmp_path / "o.jsonl"
    runner = CliRunner()
    res = runner.invoke(app, ["scan", str(tmp_path / "in"), "-o", str(out), "-j", "1", "--quiet"])
    (rec,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert rec["code"] == "empty_body" and res.exit_code == ExitCode.ERROR
    res = runner.invoke(app, ["detect", str(empty)])
    assert "[empty_body]" in res.output and res.exit_code == ExitCode.ERROR
    from service.errors import describe

    assert describe(errors.EmptyImageError("x"))[:2] == (400, "empty_body")


def test_missing_path_is_an_input_error_in_detect_and_scan(tmp_path):
    from typer.testing import CliRunner

    from lishield_guard.cli import app

    runner = CliRunner()
    res = runner.invoke(app, ["detect", str(tmp_path / "missing.jpg")])
    assert res.exit_code == error_code("not_found").exit_status == ExitCode.ERROR
    assert "[not_found]" in res.output
    out = tmp_path / "o.jsonl"
    res = runner.invoke(app, ["scan", str(tmp_path / "nope"), "-o", str(out), "--quiet"])
    assert res.exit_code == ExitCode.ERROR and '"code": "not_found"' in out.read_text()
