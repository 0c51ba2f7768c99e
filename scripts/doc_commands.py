"""Every command the docs show, checked against the code, so that a renamed option fails a test.

    python scripts/doc_commands.py          # list the problems (exit 1 when there is one)

The README and every page of ``docs/`` are read: code blocks (with ``\\`` continuations) and
inline code. What is checked:

- ``lishield-guard ...`` lines (and inline code that starts with one of its commands, as in
  "run `calibrate-videos`") are parsed by the command line itself (click's
  ``make_context``: the subcommand exists, every option exists and takes the values given,
  choices are valid), without running anything; a missing required argument or a file that
  does not exist here is fine (the docs show placeholders);
- ``python path/to/script.py --opt`` and ``python -m package.module --opt``: the script
  exists and declares every option given (``"--opt"`` in its source, argparse style);
- ``make target``: the Makefile has the target;
- ``curl ... http://HOST:PORT/route``: the service has the route (its OpenAPI paths, plus
  ``/review``).

`make docs --check` runs these checks; ``tests/test_docs_commands.py`` runs them in the suite.
"""

from __future__ import annotations

import contextlib
import functools
import io
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
_FENCE = re.compile(r"^\s*```")
_INLINE = re.compile(r"`([^`\n]+)`")
_STARTS = ("lishield-guard ", ".venv/bin/lishield-guard ", "python ", "python3 ",
           ".venv/bin/python ", "make ", "curl ", "$(BIN)/")
_ENV = re.compile(r"^[A-Z_][A-Z0-9_]*=\S*$")
_SHELL_SPLIT = re.compile(r"\s(?:\|\||&&|\||;)\s")


@dataclass(frozen=True)
class DocCommand:
    """One command written in the docs.

    Attributes
    ----------
    where : str
        ``file:line`` of its first line.
    argv : tuple of str
        The command, split as a shell would (comments and environment prefixes removed).
    inline : bool
        Written as inline code in a sentence (often just a command's name).
    """

    where: str
    argv: tuple[str, ...]
    inline: bool


def _split(text: str) -> list[str] | None:
    """``text`` split as a POSIX shell would (comments dropped); None when it does not parse
    (prose that merely starts like a command)."""
    try:
        argv = shlex.split(text, comments=True)
    except ValueError:
        return None
    while argv and _ENV.match(argv[0]):  # VAR=value prefixes
        argv = argv[1:]
    # a placeholder of alternatives (`c|json|bin`, `PRESET|SPEC.toml`): the first one
    return [a.split("|")[0] if "|" in a and " " not in a else a for a in argv]


def _shown(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def _commands_of(line: str) -> list[str]:
    """The commands of one shell line (split at pipes and ``&&``), each a string."""
    return [part.strip() for part in _SHELL_SPLIT.split(line) if part.strip()]


def documented_commands(files: tuple[Path, ...] = DOC_FILES) -> list[DocCommand]:
    """Every command line of ``files``' code blocks and inline code that starts with a tool
    this project documents (`_STARTS`)."""
    out: list[DocCommand] = []
    for path in files:
        lines = path.read_text(encoding="utf-8").splitlines()
        in_block = False
        pending, start = "", 0
        for i, line in enumerate(lines, 1):
            if _FENCE.match(line):
                in_block = not in_block
                continue
            if in_block:
                text = line.strip().removeprefix("$ ")
                if pending:
                    text, pending = pending + " " + text, ""
                else:
                    start = i
                if text.endswith("\\"):
                    pending = text[:-1].strip()
                    continue
                candidates = [(text, False)]
            else:
                start = i
                candidates = [(m.group(1), True) for m in _INLINE.finditer(line)]
            for text, inline in candidates:
                for part in _commands_of(text):
                    if inline and part.split(" ", 1)[0] in _cli_names():
                        part = "lishield-guard " + part  # `calibrate --videos` in a sentence
                    if part.startswith(_STARTS):
                        argv = _split(part)
                        if argv:
                            out.append(DocCommand(f"{_shown(path)}:{start}",
                                                  tuple(argv), inline))
    return out


@functools.cache
def _root_command():
    """The click command of ``lishield-guard`` (built once)."""
    import typer.main

    from lishield_guard.cli import app

    return typer.main.get_command(app)


def _cli_names() -> frozenset[str]:
    """The command line's top-level command names (``detect``, ``calibrate-videos``, ...)."""
    return frozenset(_root_command().commands)


# ---------------------------------------------------------------------------- the checks

def _cli_problem(args: list[str], *, inline: bool = False) -> str | None:
    """Why ``lishield-guard *args`` does not parse (None when it does). Exceptions are told
    apart by class name: Typer vendors click, so its classes are not ``click``'s."""
    import typer

    cmd = _root_command()
    path = ["lishield-guard"]
    rest = list(args)
    while hasattr(cmd, "get_command") and rest and not rest[0].startswith("-"):
        sub = cmd.get_command(cmd.context_class(cmd), rest[0])
        if sub is None:
            return f"no command {' '.join(path + rest[:1])!r}"
        path.append(rest.pop(0))
        cmd = sub
    try:
        with contextlib.redirect_stdout(io.StringIO()), \
                cmd.make_context(" ".join(path), rest):
            pass  # parsed: nothing runs
    except typer.Exit:  # --help, --version
        return None
    except Exception as exc:  # noqa: BLE001 - click's usage errors, by name (see above)
        kinds = {k.__name__ for k in type(exc).__mro__}
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        if kinds & {"MissingParameter", "NoArgsIsHelpError"}:
            return None  # the docs name a command without its arguments
        if "BadParameter" in kinds and "does not exist" in message:
            return None  # a placeholder path
        if inline and "requires an argument" in message:
            return None  # prose naming an option (`detect --plot`)
        if "UsageError" in kinds:
            return message
        raise
    return None


def _script_problem(argv: list[str]) -> str | None:
    """Why ``python script.py --opt ...`` (or ``-m module``) does not match the script."""
    args = argv[1:]
    if args[:1] == ["-m"]:
        if len(args) < 2:
            return "python -m without a module"
        module = args[1]
        if module in ("pytest", "pip", "venv", "doctest"):
            return None
        base = ROOT / Path(*module.split("."))
        script = base.with_suffix(".py") if base.with_suffix(".py").exists() \
            else base / "__main__.py"
        opts = args[2:]
    else:
        if not args or not args[0].endswith(".py"):
            return None  # python -c, python itself
        script, opts = ROOT / args[0], args[1:]
    if not script.exists():
        return f"no script {script.relative_to(ROOT)}"
    source = script.read_text(encoding="utf-8")
    missing = [o.split("=", 1)[0] for o in opts if o.startswith("--")
               and f'"{o.split("=", 1)[0]}"' not in source]
    return f"{script.relative_to(ROOT)} has no option {', '.join(missing)}" if missing else None


def _make_problem(argv: list[str]) -> str | None:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    targets = set(re.findall(r"^([A-Za-z][\w.-]*):", makefile, re.M))
    wanted = [a for a in argv[1:] if not a.startswith("-") and "=" not in a]
    missing = [t for t in wanted if t not in targets]
    return f"no make target {', '.join(missing)}" if missing else None


def _routes() -> set[str]:
    """The service's routes: its OpenAPI paths and the pages kept out of the schema."""
    from service.app import create_app
    from service.settings import ServiceSettings

    app = create_app(ServiceSettings(_env_file=None, warmup=False))
    return set(app.openapi()["paths"]) | {"/review", "/docs", "/redoc", "/openapi.json"}


def _curl_problem(argv: list[str], routes: set[str]) -> str | None:
    for a in argv:
        m = re.match(r"'?https?://[^/]+(/[^?'\s]*)", a)
        if m:
            route = m.group(1).rstrip("/") or "/"
            return None if route in routes else f"no route {route}"
    return None


def command_problems(commands: list[DocCommand] | None = None) -> list[str]:
    """``"file:line: command: why"`` for every documented command the code does not take."""
    commands = documented_commands() if commands is None else commands
    problems: list[str] = []
    routes: set[str] | None = None
    for c in commands:
        tool = Path(c.argv[0]).name
        if tool == "lishield-guard":
            why = _cli_problem(list(c.argv[1:]), inline=c.inline)
        elif tool.startswith("python"):
            why = _script_problem(list(c.argv))
        elif tool == "make":
            why = _make_problem(list(c.argv))
        elif tool == "curl":
            routes = _routes() if routes is None else routes
            why = _curl_problem(list(c.argv), routes)
        else:
            why = None
        if why:
            problems.append(f"{c.where}: {' '.join(c.argv)}: {why}")
    return problems


def main() -> int:
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    problems = command_problems()
    for p in problems:
        print(p, file=sys.stderr)
    print(f"{len(documented_commands())} documented commands, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
