"""The `lishield-guard` command line: one Typer app composing every part of the project.

Each command group lives in ``lishield_guard/commands/<group>.py`` and imports ``synth``,
``firmware`` and ``service`` lazily inside the commands that need them (DESIGN.md).
"""

from __future__ import annotations

import importlib
from typing import Annotated

import typer
import typer.core

__all__ = ["app", "main"]


def _tidy_help() -> None:
    """Help text as a reader expects it, whatever Typer version renders it:

    - on/off flags show no value type (Typer prints a fake ``<bool>``), and arguments that name
      their own metavar (``IMG...``) no ``<list[str]>``;
    - prose paragraphs of a docstring are re-flowed (Typer keeps the source's line breaks), while
      a paragraph with indented lines (an ``Examples:`` block) keeps its lines and indentation.
    """
    option, argument = (getattr(typer.core, "TyperOption", None),
                        getattr(typer.core, "TyperArgument", None))
    if option is not None and hasattr(option, "display_type_rich"):
        shown = option.display_type_rich

        def option_type(self, ctx):
            return None if (self.is_flag or self.count) else shown(self, ctx)

        option.display_type_rich = option_type
    if argument is not None and hasattr(argument, "display_type_rich"):
        shown_arg = argument.display_type_rich

        def argument_type(self, ctx):
            return None if self.metavar else shown_arg(self, ctx)

        argument.display_type_rich = argument_type
    # Rich's help formatter costs about 0.1 s to import: it is patched when help is rendered,
    # not at every start of the command line
    for cls in (getattr(typer.core, "TyperCommand", None), getattr(typer.core, "TyperGroup",
                                                                      None)):
        if cls is not None and hasattr(cls, "format_help"):
            cls.format_help = _tidied_first(cls.format_help)


def _tidied_first(format_help):
    """``format_help`` that re-flows Rich's paragraphs (`_tidy_rich_paragraphs`) first."""

    def tidied(self, ctx, formatter):
        _tidy_rich_paragraphs()
        return format_help(self, ctx, formatter)

    return tidied


def _tidy_rich_paragraphs() -> None:
    """Re-flow prose paragraphs in Rich's help, keep indented blocks (`_tidy_help`); once."""
    import inspect

    try:
        import typer.rich_utils as rich_utils
    except ImportError:  # Rich not installed: click's own formatter re-flows paragraphs
        return
    if getattr(rich_utils, "_lishield_tidy", False) or not (
            hasattr(rich_utils, "_fix_linebreaks")
            and len(inspect.signature(rich_utils._fix_linebreaks).parameters) == 2):
        return

    def fix_linebreaks(paragraphs, markup_mode):
        out: list[str] = []
        for para in paragraphs:
            lines = para.split("\n")
            if lines and lines[0].strip() == "\b":  # click's "keep this block as written"
                block = "\n".join(lines[1:])
                if out and out[-1].rstrip().endswith(":") and "\n" not in out[-1]:
                    out[-1] += "\n" + block  # "Examples:" then its block, no blank line
                else:
                    out.append(block)
            elif any(ln[:1].isspace() for ln in lines[1:] if ln.strip()):
                out.append(para)  # an indented block: keep it as written
            else:
                out.append(" ".join(ln.strip() for ln in lines))
        # a leading newline keeps inspect.cleandoc (run on this text) from removing the
        # indentation of an Examples block that comes first
        return "\n" + "\n\n".join(out)

    rich_utils._fix_linebreaks = fix_linebreaks
    rich_utils._lishield_tidy = True


_tidy_help()

app = typer.Typer(
    name="lishield-guard",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from lishield_guard import __version__

        typer.echo(f"lishield-guard {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Find LiShield privacy barcodes (LED flicker stripes) in photos, screen uploads over
    HTTP, scan archives, calibrate false-alarm rates, and generate barcodes, LED firmware and
    synthetic captures.

    Every command takes --config FILE.toml (default: the shipped calibrated config). Exit
    status: 0 every image clean (or the command succeeded), 1 a barcode found, 2 usage error,
    3 an input error or an image the detector could not look at (never "clean"), or the
    command failed. Documentation: README.md and docs/ in the source tree.

    Examples:
      lishield-guard detect photo.jpg --plot verdict.png
      lishield-guard scan /photos --output results.jsonl --jobs 4
      lishield-guard serve --port 8000
    """

# Modules under lishield_guard/commands that register commands, in help order.
COMMAND_MODULES = ("detect", "scan", "serve", "calibrate", "calibrate_videos", "bench", "spec",
                   "firmware", "synth", "config")

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
