"""Fixtures of the scan tests (helpers live in scan_helpers.py)."""

from __future__ import annotations

import pytest
from scan_helpers import jpeg_bytes, read_jsonl, write_images  # noqa: F401 - re-exported
from typer.testing import CliRunner

from lishield_guard.cli import app


@pytest.fixture
def run_cli():
    """Invoke the CLI in-process; returns the click Result."""
    runner = CliRunner()

    def run(*args: str):
        return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)

    return run
