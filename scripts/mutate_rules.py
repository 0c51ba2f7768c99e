"""Mutation check of the pass rules, the look-alike defences, scan --resume and the
regressions of issue #33 (batch cap, batch crash, archive names, flat config, truncated images).

Each mutant is a one- or two-line change (a threshold comparison flipped, a look-alike term
removed, the steady-wave gate turned off, resume that rescans everything). For each, the
repository is used through a temporary copy: the mutant is written into the copy (never into
the working tree), and a chosen subset of the tests runs against it with the copy first on
``PYTHONPATH``. A mutant that no test fails "survives": the tests named after that regression
cannot see it.

Usage
-----
    python scripts/mutate_rules.py                  # every mutant, its tests
    python scripts/mutate_rules.py --list           # names, edits and test subsets
    python scripts/mutate_rules.py --only grid-lookalike-margin-off --only steady-gate-off
    python scripts/mutate_rules.py --group rules    # rules | defences | resume | issue33
    python scripts/mutate_rules.py --keep           # leave the temporary copy for a look

Exit status: 0 every mutant killed, 1 some survived, 2 the unmutated baseline fails, a mutant
no longer applies (its source line changed: update the mutant) or it does not import.
Plain Python and pytest only; nothing to install.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# not copied: history, environments, outputs and caches (the copy is a few MB)
IGNORE = shutil.ignore_patterns(".git", ".venv", "venv", "out", "*.egg-info", "__pycache__",
                                ".hypothesis", ".pytest_cache", ".ruff_cache", ".mypy_cache")

RULE_TESTS = ("tests/calibrate/test_rule_agreement.py",)
LOOKALIKE_TESTS = (
    "tests/core/test_detect.py::"
    "test_steady_wave_plane_is_gated_and_its_grid_fit_fails_only_on_the_lookalike_margin",
    "tests/core/test_detect.py::"
    "test_sine_flicker_reaches_every_fit_and_only_the_lookalike_rejects_it",
    "tests/core/test_detect.py::"
    "test_jittering_pwm_tone_is_not_a_barcode_without_a_fit_that_beats_the_lookalike",
)
# real cached fits judged by a literal rule (about 15 s to build the tiny sets' records)
TABLE_TESTS = ("tests/calibrate/test_core.py::test_cached_fit_tables_judged_as_the_rules_say",)
REGRESSION_TESTS = "tests/test_regressions_33.py"
RESUME_TESTS = ("tests/scan/test_scan_cli.py::test_resume_after_sigkill",
                "tests/scan/test_scan_cli.py::test_torn_last_line_repaired")


@dataclass(frozen=True)
class Edit:
    """Replace ``old`` (exactly one occurrence) by ``new`` inside function ``scope`` of
    ``path`` (the whole file when scope is None)."""

    path: str
    scope: str | None
    old: str
    new: str


@dataclass(frozen=True)
class Mutant:
    name: str
    group: str
    what: str
    edits: tuple[Edit, ...]
    tests: tuple[str, ...]


def _rule(name: str, what: str, func: str | None, old: str, new: str,
          path: str = "lishield_guard/detector/rules.py", group: str = "rules",
          extra: tuple[str, ...] = ()) -> Mutant:
    return Mutant(name, group, what, (Edit(path, func, old, new),),
                  RULE_TESTS + extra + LOOKALIKE_TESTS)


MUTANTS: tuple[Mutant, ...] = (
    # --- the look-alike defences
    _rule("grid-lookalike-margin-off", "grid_rule: rho - rho_lookalike -> rho - 0.0 * "
          "rho_lookalike", "grid_rule", "rho - rho_lookalike", "rho - 0.0 * rho_lookalike",
          group="defences", extra=TABLE_TESTS),
    _rule("fold-lookalike-margin-off", "fold_rule: rho - rho_lookalike -> rho - 0.0 * "
          "rho_lookalike", "fold_rule", "rho - rho_lookalike", "rho - 0.0 * rho_lookalike",
          group="defences", extra=TABLE_TESTS),
    _rule("fit-gain-off", "fit_paths: gain >= fit.min_gain -> gain >= -inf", "fit_paths",
          "f.min_rho, f.min_gain)", "f.min_rho, -np.inf)", group="defences"),
    _rule("fit-periodic-gain-off", "fit_paths: gain >= fit.min_gain_periodic -> gain >= -inf",
          "fit_paths", "f.min_rho_periodic, f.min_gain_periodic)", "f.min_rho_periodic, -np.inf)",
          group="defences"),
    _rule("fit-rgb-gain-off", "fit_paths: gain >= fit.min_gain_rgb -> gain >= -inf",
          "fit_paths", "f.min_rho_rgb, f.min_gain_rgb)", "f.min_rho_rgb, -np.inf)",
          group="defences"),
    _rule("tone-gain-off", "tone_rule: gain >= tones.min_fit_gain -> gain >= -inf", "tone_rule",
          "(gain >= det.tones.min_fit_gain)", "(gain >= -np.inf)", group="defences"),
    _rule("gain-ignores-lookalike", "ModelFit.gain: rho^2 - rho_lookalike^2 -> rho^2 - 0.0 * "
          "rho_lookalike^2", "gain", "self.rho ** 2 - self.rho_lookalike ** 2",
          "self.rho ** 2 - 0.0 * self.rho_lookalike ** 2",
          path="lishield_guard/detector/results.py", group="defences"),
    _rule("steady-gate-off", "axis_sweeps: planes a steady square wave fits at rho >= "
          "LOOKALIKE_DOMINANT_RHO are refined like any other", "axis_sweeps",
          "if steady >= LOOKALIKE_DOMINANT_RHO:", "if False:",
          path="lishield_guard/detector/search.py", group="defences"),
    _rule("screen-steady-gate-off", "screen_plane: a plane with stripes passes the first stage "
          "even when one steady square wave fits them at rho >= LOOKALIKE_DOMINANT_RHO",
          "screen_plane", "passed = steady is None or steady < LOOKALIKE_DOMINANT_RHO",
          "passed = True", path="lishield_guard/detector/screen.py", group="defences"),
    _rule("steady-gate-at-0.95", "LOOKALIKE_DOMINANT_RHO = 0.99 -> 0.95 (more planes gated)",
          None, "LOOKALIKE_DOMINANT_RHO = 0.99", "LOOKALIKE_DOMINANT_RHO = 0.95",
          path="lishield_guard/detector/numerics.py", group="defences"),
    # --- thresholds and terms of the pass rules, changed in the one place both forms use
    _rule("grid-rho-strict", "grid_rule: rho >= sweep.min_rho -> rho > sweep.min_rho",
          "grid_rule", "(rho >= det.sweep.min_rho)", "(rho > det.sweep.min_rho)"),
    _rule("grid-coherence-off", "grid_rule: coherence term dropped", "grid_rule",
          "(coherence_t >= det.sweep.min_coherence)", "(coherence_t >= -np.inf)"),
    _rule("fit-rho-strict", "fit_rule: rho >= a path's min_rho -> rho > min_rho", "fit_rule",
          "(rho >= path.min_rho)", "(rho > path.min_rho)"),
    _rule("fit-coherence-off", "fit_rule: coherence term dropped", "fit_rule",
          "(coherence_t >= det.sweep.min_coherence)", "(coherence_t >= -np.inf)"),
    _rule("fit-periods-off", "fit_paths: n_periods >= PERIODIC_MIN_PERIODS -> n_periods >= 0",
          "fit_paths", "n_periods >= PERIODIC_MIN_PERIODS,", "n_periods >= 0,"),
    _rule("fit-leak-limit-off", "fit_paths: chroma_leak <= fit.max_leak_rgb -> <= inf",
          "fit_paths", "(leak <= f.max_leak_rgb)", "(leak <= np.inf)"),
    _rule("fit-unmeasured-leak-passes", "fit_paths: isfinite(chroma_leak) -> not nan",
          "fit_paths", "np.isfinite(leak)", "(leak == leak)"),
    _rule("tone-floor-off", "tone_rule: rho >= FIT_RHO_FLOOR -> rho >= 0", "tone_rule",
          "(rho >= FIT_RHO_FLOOR)", "(rho >= 0.0)"),
    _rule("fold-snr-off", "fold_rule: fold_snr >= fold.min_snr -> >= -inf", "fold_rule",
          "(fold_snr >= det.fold.min_snr)", "(fold_snr >= -np.inf)"),
    _rule("fold-rho-strict", "fold_rule: rho >= fold.min_rho -> rho > fold.min_rho",
          "fold_rule", "(rho >= det.fold.min_rho)", "(rho > det.fold.min_rho)"),
    # --- one form changed, the other not
    _rule("calibrate-sweep-drops-fit", "calibrate.sweep_protected: only the grid rule "
          "(exact fits ignored)", "sweep_protected", "grid_rule(rho, alt, t, det) | fit_rule(",
          "grid_rule(rho, alt, t, det) | 0 * fit_rule(",
          path="lishield_guard/calibration/evidence.py", extra=TABLE_TESTS),
    _rule("detect-sweep-drops-fit", "rules.sweep_passes: only the grid rule (exact fits "
          "ignored)", "sweep_passes", " or fit_passes(entry.fit, det)", ""),
    # --- scan --resume
    Mutant("resume-rescans-all", "resume", "scan --resume reads no done keys: every input is "
           "scanned again and appended",
           (Edit("lishield_guard/scan.py", "scan_to_output",
                 "done: set[str] = read_done_keys(output, fmt) if resume else set()",
                 "done: set[str] = set()"),), RESUME_TESTS),
    Mutant("resume-truncates-and-rescans", "resume", "scan --resume empties the output and "
           "scans everything again (no duplicates, earlier records rewritten)",
           (Edit("lishield_guard/scan.py", "scan_to_output",
                 "done: set[str] = read_done_keys(output, fmt) if resume else set()",
                 "done: set[str] = set()\n    if resume:\n        open(output, 'w').close()"),),
           RESUME_TESTS),
    Mutant("resume-summary-uncounted", "resume", "scan --resume skips done inputs but its "
           "summary does not count them", (Edit("lishield_guard/scan.py",
                                                "on_skip", "n_resumed += 1",
                                                "n_resumed += 0"),), RESUME_TESTS),
    # --- issue #33 item 8: regressions the suite could not see (tests/test_regressions_33.py)
    Mutant("batch-cap-x1024", "issue33", "routes/screen.py: the batch body cap "
           "max_batch_bytes multiplied by 1024",
           (Edit("service/routes/screen.py", None, "read_form(request, "
                 "s.max_batch_bytes,", "read_form(request, s.max_batch_bytes * 1024,"),),
           (f"{REGRESSION_TESTS}::test_batch_body_over_max_batch_bytes_is_413",)),
    Mutant("batch-crash-swallowed", "issue33", "routes/screen.py: a detector crash in "
           "/v1/screen/batch becomes a per-file 500 entry of a 200 answer, logged nowhere",
           (Edit("service/routes/screen.py", None, 'if code == "internal_error":',
                 'if False:'),),
           (f"{REGRESSION_TESTS}::test_detector_crash_in_batch_is_a_logged_500",)),
    Mutant("member-backslash-kept", "issue33", "batch/listing.py: archive member names no longer "
           "normalise \\ to /, so ..\\x.jpg passes the traversal check",
           (Edit("lishield_guard/batch/listing.py", "unsafe_member_reason",
                 'norm = name.replace("\\\\", "/")', "norm = name"),),
           (f"{REGRESSION_TESTS}::test_backslash_member_names_are_caught",
            f"{REGRESSION_TESTS}::test_backslash_traversal_in_a_zip_is_recorded_unsafe")),
    Mutant("flat-config-typo-skipped", "issue33", "config.py: an unknown key of an old-style "
           "flat [detector] table is skipped silently",
           (Edit("lishield_guard/config.py", "_ungroup_legacy",
                 'raise ConfigError(f"{source}: unknown [detector] key {key!r}")', "pass"),),
           (f"{REGRESSION_TESTS}::test_unknown_key_in_a_flat_detector_table_is_an_error",)),
    Mutant("load-truncated-images", "issue33", "decode.py: ImageFile.LOAD_TRUNCATED_IMAGES = "
           "True, so a PNG cut at 50 % decodes (and may read clean)",
           (Edit("lishield_guard/decode.py", None, "ImageFile.LOAD_TRUNCATED_IMAGES = False",
                 "ImageFile.LOAD_TRUNCATED_IMAGES = True"),),
           (f"{REGRESSION_TESTS}::test_png_cut_short_is_an_error_not_clean",
            f"{REGRESSION_TESTS}::test_png_cut_short_is_422_over_http")),
)


class StaleMutant(RuntimeError):
    """A mutant's source text is no longer in the code (the code changed: update it)."""


def _scope_span(text: str, scope: str | None) -> tuple[int, int]:
    """Character span of function ``scope`` (its def line to the first later line indented no
    deeper), or the whole text."""
    if scope is None:
        return 0, len(text)
    m = re.search(rf"^([ \t]*)def {re.escape(scope)}\(", text, flags=re.M)
    if m is None:
        raise StaleMutant(f"no function {scope!r}")
    indent = len(m.group(1))
    body = text.index("\n", m.end()) + 1  # from the line after the def line
    end = len(text)
    for later in re.finditer(r"^([ \t]*)(\S)", text[body:], flags=re.M):
        if len(later.group(1)) <= indent and later.group(2) not in ")]}":
            end = body + later.start()
            break
    return m.start(), end


def apply_edit(text: str, edit: Edit) -> str:
    """``text`` with ``edit`` applied; StaleMutant unless ``edit.old`` occurs exactly once in
    its scope."""
    lo, hi = _scope_span(text, edit.scope)
    n = text.count(edit.old, lo, hi)
    if n != 1:
        where = f"{edit.path}:{edit.scope or '<module>'}"
        raise StaleMutant(f"{edit.old!r} occurs {n} times in {where} (want exactly 1)")
    i = text.index(edit.old, lo, hi)
    return text[:i] + edit.new + text[i + len(edit.old):]


def _env(copy: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(copy), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def _check_imports_from(copy: Path) -> None:
    """The copy, not the editable install of the working tree, is what the tests import."""
    code = ("import lishield_guard, lishield_guard.detector, lishield_guard.calibration, "
            "lishield_guard.commands.scan; print(lishield_guard.__file__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=copy, env=_env(copy),
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1] if out.stderr else "import failed")
    if not Path(out.stdout.strip()).resolve().is_relative_to(copy.resolve()):
        raise RuntimeError(f"lishield_guard imported from {out.stdout.strip()}, not the copy")


def run_tests(copy: Path, tests: tuple[str, ...]) -> tuple[int, list[str], str]:
    """Run ``tests`` in the copy; (pytest exit code, failed/errored node ids, output tail)."""
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfE",
           "--no-header", *tests]
    out = subprocess.run(cmd, cwd=copy, env=_env(copy), capture_output=True, text=True)
    failed = sorted({m.group(2) for m in re.finditer(r"^(FAILED|ERROR) (.+?)(?: - .*)?$",
                                                      out.stdout, flags=re.M)})
    tail = "\n".join(out.stdout.strip().splitlines()[-3:])
    return out.returncode, failed, tail


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", default=[], metavar="NAME",
                    help="run this mutant (repeatable)")
    ap.add_argument("--group", choices=sorted({m.group for m in MUTANTS}),
                    help="run the mutants of one group")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("--keep", action="store_true", help="keep the temporary copy")
    ap.add_argument("--no-baseline", action="store_true",
                    help="skip the unmutated run of each test subset")
    args = ap.parse_args(argv)

    unknown = set(args.only) - {m.name for m in MUTANTS}
    if unknown:
        ap.error(f"unknown mutant(s): {', '.join(sorted(unknown))}")
    chosen = [m for m in MUTANTS if (not args.only or m.name in args.only)
              and (args.group is None or m.group == args.group)]
    if not chosen:
        ap.error("no mutant matches --only and --group together")
    if args.list:
        for m in chosen:
            print(f"{m.name}  [{m.group}]\n    {m.what}")
            for e in m.edits:
                print(f"    {e.path}:{e.scope or '<module>'}: {e.old!r} -> {e.new!r}")
            print(f"    tests: {' '.join(m.tests)}")
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="mutants-"))
    copy = tmp / "repo"
    shutil.copytree(ROOT, copy, ignore=IGNORE)
    print(f"copy of {ROOT} in {copy}", flush=True)
    try:
        # every mutant must still apply to the current source before anything runs
        for m in chosen:
            for e in m.edits:
                apply_edit((copy / e.path).read_text(), e)
        _check_imports_from(copy)
        if not args.no_baseline:
            for tests in dict.fromkeys(m.tests for m in chosen):
                t0 = time.perf_counter()
                code, failed, tail = run_tests(copy, tests)
                print(f"baseline ({len(tests)} test target(s)): exit {code} in "
                      f"{time.perf_counter() - t0:.0f} s", flush=True)
                if code != 0:
                    print(f"the unmutated tests fail; fix them first:\n{tail}")
                    return 2
        results = []
        for m in chosen:
            originals = {e.path: (copy / e.path).read_text() for e in m.edits}
            try:
                for e in m.edits:
                    p = copy / e.path
                    p.write_text(apply_edit(p.read_text(), e))
                try:
                    _check_imports_from(copy)
                except RuntimeError as exc:
                    print(f"{m.name}: INVALID (does not import: {exc})", flush=True)
                    results.append((m, "invalid", [], 0.0))
                    continue
                t0 = time.perf_counter()
                code, failed, tail = run_tests(copy, m.tests)
                dt = time.perf_counter() - t0
                status = "killed" if code != 0 else "SURVIVED"
                if code not in (0, 1):  # interrupted, internal error, usage or collection
                    status = f"killed (pytest exit {code})" if failed else f"error {code}"
                results.append((m, status, failed, dt))
                print(f"{m.name}: {status} in {dt:.0f} s", flush=True)
                for f in failed:
                    print(f"    {f}", flush=True)
                if status.startswith("error"):
                    print(tail)
            finally:
                for path, text in originals.items():
                    (copy / path).write_text(text)
    except StaleMutant as exc:
        print(f"stale mutant: {exc}")
        return 2
    finally:
        if args.keep:
            print(f"kept {copy}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)

    print("\nsummary")
    for m, status, failed, dt in results:
        print(f"  {m.name:<30} {status:<9} {len(failed):>3} failing test(s)  {dt:5.0f} s")
    survived = [m.name for m, s, _, _ in results if s == "SURVIVED"]
    broken = [m.name for m, s, _, _ in results if s == "invalid" or s.startswith("error")]
    print(f"{len(results) - len(survived) - len(broken)} killed, {len(survived)} survived"
          + (f": {', '.join(survived)}" if survived else "")
          + (f"; {len(broken)} invalid/error: {', '.join(broken)}" if broken else ""))
    return 2 if broken else (1 if survived else 0)


if __name__ == "__main__":
    sys.exit(main())
