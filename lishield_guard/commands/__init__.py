"""CLI command groups; each module defines ``register(app)`` and imports heavy parts lazily."""

from __future__ import annotations

from enum import IntEnum

import typer

__all__ = ["EXIT_CODES_HELP", "ExitCode", "fail"]


EXIT_CODES_HELP = ("Exit status: 0 every image clean (or the command succeeded); 1 at least one "
                   "image protected (wins over errors); 2 usage error (bad arguments or "
                   "config); 3 no image protected but input errors (a missing, empty or "
                   "unreadable input) or undetermined results present (images that could not "
                   "be looked at), or the command failed.")


class ExitCode(IntEnum):
    """Process exit codes of every command (one table; `EXIT_CODES_HELP` in command help).

    ====  ==========  ====================================================================
    code  name        meaning
    ====  ==========  ====================================================================
    0     CLEAN       every image analysed and clean (or the command succeeded)
    1     PROTECTED   at least one image carries a policy barcode; wins over errors
    2     USAGE       bad arguments, bad config (`errors.EXIT_USAGE`)
    3     ERROR       no image protected, but input errors (a missing, empty or unreadable
                      input: `errors.EXIT_INPUT_ERROR`) or undetermined results are
                      present (a tool that could not look never says clean), or the
                      command failed for another reason

    Which error code leads to which status: `lishield_guard.errors.ERROR_CODES`.
    ====  ==========  ====================================================================
    """

    CLEAN = 0
    PROTECTED = 1
    USAGE = 2
    ERROR = 3


def fail(message: object, code: ExitCode = ExitCode.USAGE) -> typer.Exit:
    """Print ``error: <message>`` on stderr; the `typer.Exit` to raise with exit ``code``.

    Examples
    --------
    >>> raise fail("--jobs must be >= 1")  # doctest: +SKIP
    """
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(int(code))
