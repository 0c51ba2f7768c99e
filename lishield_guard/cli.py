"""The `lishield-guard` command line: one Typer app composing every part of the project.

Each command group lives in ``lishield_guard/commands/<group>.py`` and imports ``synth``,
``firmware`` and ``service`` lazily inside the commands that need them (DESIGN.md).
"""

from __future__ import annotations

import importlib

import typer

__all__ = ["app", "main"]

app = typer.Typer(
    name="lishield-guard",
    help="Find LiShield privacy barcodes (LED flicker stripes) in photos, screen uploads over "
    "HTTP, scan archives, calibrate false-alarm rates, and generate barcodes, LED firmware and "
    "synthetic captures.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# Modules under lishield_guard/commands that register commands, in help order.
COMMAND_MODULES = ("detect", "scan", "serve", "calibrate", "bench", "spec", "firmware", "synth",
                   "config")

for _name in COMMAND_MODULES:
    try:
        _mod = importlib.import_module(f"lishield_guard.commands.{_name}")
    except ModuleNotFoundError as _exc:  # a command group not written yet
        if _exc.name != f"lishield_guard.commands.{_name}":
            raise
        continue
    _mod.register(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
