"""CLI command groups; each module defines ``register(app)`` and imports heavy parts lazily."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitCode"]


class ExitCode(IntEnum):
    """Process exit codes of the CLI."""

    CLEAN = 0  # no barcode found (or the command succeeded)
    PROTECTED = 1  # a barcode was found
    USAGE = 2  # bad arguments, bad config, unreadable input
    ERROR = 3  # the command failed for another reason
