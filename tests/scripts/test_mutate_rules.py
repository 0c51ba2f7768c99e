"""scripts/mutate_rules.py stays in step with the code it mutates (no mutant is run here)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

import mutate_rules  # noqa: E402


@pytest.mark.parametrize("mutant", mutate_rules.MUTANTS, ids=lambda m: m.name)
def test_every_mutant_still_applies_to_the_code(mutant):
    """Each edit's text occurs exactly once in its scope: a rule rewritten without its mutant
    (`make mutate` would stop on it as stale) fails here, on every `make test`."""
    for edit in mutant.edits:
        text = (ROOT / edit.path).read_text(encoding="utf-8")
        mutated = mutate_rules.apply_edit(text, edit)
        assert mutated != text
