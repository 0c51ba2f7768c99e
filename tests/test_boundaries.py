"""The core must not pull in the web stack, synth or firmware at import time."""

from __future__ import annotations

import subprocess
import sys


def test_core_import_is_light():
    code = ("import sys, lishield_guard, lishield_guard.cli; "
            "bad = [m for m in ('fastapi', 'uvicorn', 'synth', 'firmware', 'service', 'dask') "
            "if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_every_module_has_a_docstring():
    import importlib
    import pkgutil

    import lishield_guard

    missing = []
    for info in pkgutil.walk_packages(lishield_guard.__path__, "lishield_guard."):
        mod = importlib.import_module(info.name)
        if not (mod.__doc__ or "").strip():
            missing.append(info.name)
    assert not missing


def test_detector_stages_do_not_import_the_orchestration():
    """Dependencies point one way: the stage modules of `lishield_guard.detector` import
    earlier stages and shared core modules, never the orchestration (`pipeline`, the package
    itself) nor the tools built on it (calibration, scanning, the CLI)."""
    import ast
    from pathlib import Path

    import lishield_guard.detector as pkg

    banned = ("lishield_guard.detector.pipeline", "lishield_guard.calibration",
              "lishield_guard.scan", "lishield_guard.cli", "lishield_guard.commands")
    bad = []
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        if path.stem in ("__init__", "pipeline"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
                if node.module == "lishield_guard.detector":
                    names = [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            bad += [f"{path.name}: {n}" for n in names
                    if n == "lishield_guard.detector" or n.startswith(banned)]
    assert not bad


MAX_COMMAND_FUNCTION_LINES = 80
# Functions of lishield_guard/commands/ still over the limit, each with the issue that owns it;
# an entry that is no longer needed fails the test, so the list only shrinks.
LONG_COMMAND_FUNCTIONS: set[tuple[str, str]] = set()


def test_command_functions_are_short():
    """Commands are shells (parse, call the library, print): no function of
    `lishield_guard/commands/` is longer than MAX_COMMAND_FUNCTION_LINES lines (signature and
    docstring included); the work belongs in the library."""
    import ast
    from pathlib import Path

    import lishield_guard.commands as pkg

    long = set()
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                if node.end_lineno - node.lineno + 1 > MAX_COMMAND_FUNCTION_LINES:
                    long.add((path.name, node.name))
    assert long <= LONG_COMMAND_FUNCTIONS, sorted(long - LONG_COMMAND_FUNCTIONS)
    assert not LONG_COMMAND_FUNCTIONS - long, ("shortened: drop from LONG_COMMAND_FUNCTIONS",
                                               sorted(LONG_COMMAND_FUNCTIONS - long))


# The detector's stage modules in the order one image meets them (`detector.pipeline` runs
# them): row profiles and usable blocks, spectra and tone tracks, the first stage, the learned
# decision and its explanation, then the cascade's tones, fold, sweep, free-running timing,
# exact fit and pass rules; the paper's Algorithm 1 is its own profile, last. SHARED modules
# (typed results and stage names, shared numerics, emitter variants) import no stage.
STAGE_ORDER = ("profiles", "usable", "spectra", "tracks", "screen", "learned", "decision",
               "explain", "tones", "fold", "sweep", "freerun", "fit", "rules", "paper")
SHARED = ("results", "numerics", "emitters")


def _detector_imports(path) -> set[str]:
    """Modules of `lishield_guard.detector` that a file imports (at any depth)."""
    import ast

    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            names = ([f"{node.module}.{a.name}" for a in node.names]
                     if node.module == "lishield_guard.detector" else [node.module])
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        out |= {n.split(".")[2] for n in names
                if n.startswith("lishield_guard.detector.") and n.count(".") >= 2}
    return out


def test_detector_stages_import_only_earlier_stages_and_shared_modules():
    """Data enters each stage once, in order, and never climbs back: a stage module imports
    earlier stages and the shared modules only; a shared module imports no stage."""
    from pathlib import Path

    import lishield_guard.detector as pkg

    folder = Path(pkg.__file__).parent
    modules = {p.stem for p in folder.glob("*.py")} - {"__init__", "pipeline"}
    assert modules == set(STAGE_ORDER) | set(SHARED), "place a new module in STAGE_ORDER or SHARED"
    bad = []
    for name in sorted(modules):
        if name in SHARED:
            allowed = set()
        else:
            allowed = set(SHARED) | set(STAGE_ORDER[:STAGE_ORDER.index(name)])
        bad += [f"{name} imports {m}" for m in sorted(_detector_imports(folder / f"{name}.py"))
                if m not in allowed]
    assert not bad
