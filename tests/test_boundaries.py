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
    earlier stages and shared core modules, never the profiles that run them
    (`lishield_guard.profiles`), the package facade itself, nor the tools built on them
    (calibration, scanning, the CLI)."""
    import ast
    from pathlib import Path

    import lishield_guard.detector as pkg

    banned = ("lishield_guard.profiles", "lishield_guard.calibration",
              "lishield_guard.scan", "lishield_guard.cli", "lishield_guard.commands")
    bad = []
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        if path.stem == "__init__":
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


# The detector's stage modules in the order one image meets them (the profiles run them):
# row profiles and usable blocks, spectra, the time-frequency input and the first look,
# tone tracks, the first stage, the learned decision and its explanation, then the cascade's tones, fold, sweep, free-running timing,
# exact fit, pass rules and its search over one axis; the paper's Algorithm 1 is its own
# profile, last. SHARED modules (typed results and stage names, shared numerics, emitter
# variants) import no stage.
STAGE_ORDER = ("profiles", "usable", "spectra", "tfinput", "firstlook", "tracks", "screen",
               "learned", "decision", "explain", "tones", "fold", "sweep", "freerun", "fit",
               "rules", "search", "paper")
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
    modules = {p.stem for p in folder.glob("*.py")} - {"__init__"}
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


# The whole package in layers, bottom first (module names below ``lishield_guard``; a name
# ending in ".*" stands for the modules of that package, whose own order the detector tests
# above check). A module imports, at module level or inside a function, only modules of its
# own layer or of layers below it, and no import closes a circle: a new module takes its
# place here. Detect functions and profile modules named in a registry (`profiles`,
# `batch.types`) are imported by name on first use: the registries stay at the bottom.
PACKAGE_LAYERS = (
    ("errors", "camera", "stats", "threads", "files", "data", "data_files", "spec", "profiles",
     "batch.types", "batch.cache", "batch.pool", "calibration.split", "calibration.firstlook",
     "figure_text"),
    ("verdict",),  # the result, its typed evidence base and the one undetermined constructor
    ("settings",),  # every settings group (the profile names come from the registry)
    ("config",),  # the TOML file
    ("batch.listing", "batch"),
    ("decode", "video.decode"),
    ("detector.*",),
    ("figure_learned", "plot", "video.figure"),  # figures draw typed evidence, never profiles
    ("profiles.*",),  # one module per profile (the registry itself is at the bottom)
    ("detector",),  # the facade: `detect`, `detect_decoded` of `profiles.detect`
    ("video.screen",),
    ("video",),  # `detect_media`: the media kinds' detect functions
    ("calibration.evidence", "calibration.bounds", "calibration.selection",
     "calibration.report", "calibration.run", "calibration"),
    ("video.calibrate",),
    ("scan", "bench_report", "bench"),
    ("commands", "commands.*", "cli", "__init__"),
)


def _package_graph() -> dict[str, set[str]]:
    """Module name (below ``lishield_guard``; ``__init__`` for the package) -> the package's
    modules it imports anywhere in its text."""
    import ast
    from pathlib import Path

    import lishield_guard

    root = Path(lishield_guard.__file__).parent
    mods = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts) or "__init__"] = path
    graph = {}
    for name, path in mods.items():
        out = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and (
                    node.module == "lishield_guard" or node.module.startswith("lishield_guard.")):
                base = node.module.partition(".")[2]
                for alias in node.names:
                    sub = f"{base}.{alias.name}" if base else alias.name
                    out.add(sub if sub in mods else base or "__init__")
            elif isinstance(node, ast.Import):
                out |= {a.name.partition(".")[2] for a in node.names
                        if a.name.startswith("lishield_guard.")}
        graph[name] = out - {name}
    return graph


def _layer_of(name: str) -> int | None:
    for i, layer in enumerate(PACKAGE_LAYERS):
        for pattern in layer:
            if name == pattern or (pattern.endswith(".*") and name.startswith(pattern[:-1])):
                return i
    return None


def test_no_module_imports_upward_or_in_a_circle():
    """The stage-order rule for the whole package: every module has a layer
    (`PACKAGE_LAYERS`), imports nothing of a higher layer, and no chain of imports comes back
    to where it started (e.g. the config importing the video package, or the figures of the
    photo and of the clip importing each other, both of which happened)."""
    graph = _package_graph()
    unplaced = sorted(m for m in graph if _layer_of(m) is None)
    assert not unplaced, f"place these modules in PACKAGE_LAYERS: {unplaced}"
    upward = sorted(f"{a} imports {b}" for a, deps in graph.items() for b in deps
                    if _layer_of(b) > _layer_of(a))
    assert not upward
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return [*path[path.index(dep):], dep] if dep in path else [node, dep]
            if state.get(dep) is None and (cycle := visit(dep, [*path, dep])):
                return cycle
        state[node] = 2
        return None

    for start in sorted(graph):
        if state.get(start) is None and (cycle := visit(start, [start])):
            raise AssertionError("import circle: " + " -> ".join(cycle))


MAX_MODULE_LINES = 600


def test_no_module_is_over_600_lines():
    """One module per profile, per stage, per media kind: none of `lishield_guard` grows past
    `MAX_MODULE_LINES` lines (the one orchestration file of three profiles had 848)."""
    from pathlib import Path

    import lishield_guard

    root = Path(lishield_guard.__file__).parent
    long = {str(p.relative_to(root)): n for p in root.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, long
