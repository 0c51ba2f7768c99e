"""Issue 41: every command the docs show exists with the options it is shown with
(`scripts/doc_commands.py`, also run by `make docs --check`); docs/video.md told users to run
`calibrate --videos`, which fails with "No such option"."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "scripts") not in sys.path:
    sys.path.insert(0, str(ROOT / "scripts"))

doc_commands = pytest.importorskip("doc_commands")


def test_every_documented_command_parses():
    commands = doc_commands.documented_commands()
    tools = {c.argv[0].rsplit("/", 1)[-1] for c in commands}
    assert len(commands) > 100 and {"lishield-guard", "python", "make", "curl"} <= tools
    assert doc_commands.command_problems(commands) == []


@pytest.mark.parametrize("text, problem", [
    ("lishield-guard calibrate --videos", "No such option: --videos"),
    ("lishield-guard detect a.jpg --profile nope", "'nope' is not one of"),
    ("lishield-guard sken /photos", "no command 'lishield-guard sken'"),
    ("python benchmarks/evaluate.py out/x --no-such-flag", "has no option --no-such-flag"),
    ("python scripts/missing.py", "no script scripts/missing.py"),
    ("make nonsense", "no make target nonsense"),
    ("curl -s http://127.0.0.1:8000/v1/screne", "no route /v1/screne"),
])
def test_a_renamed_option_command_script_target_or_route_is_reported(tmp_path, text, problem):
    page = tmp_path / "page.md"
    page.write_text(f"Run:\n\n```\n{text}\n```\n")
    commands = doc_commands.documented_commands((page,))
    assert len(commands) == 1
    (found,) = doc_commands.command_problems(commands)
    assert problem in found, found


def test_inline_commands_in_sentences_are_checked(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("Certify clips with `calibrate --videos`; plots come from `detect --plot`.\n")
    problems = doc_commands.command_problems(doc_commands.documented_commands((page,)))
    assert len(problems) == 1 and "--videos" in problems[0]
