"""`lishield-guard spec list|show`: inspect barcode presets and spec files and their validation."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Annotated, Any

import typer

from lishield_guard.commands import ExitCode, fail
from lishield_guard.errors import LishieldError, SpecError
from lishield_guard.spec import (
    DEFAULT_FLICKER_THRESHOLD_HZ,
    DEFAULT_MAX_FREQ_HZ,
    DEFAULT_MIN_READOUT_S,
    DEFAULT_RATIO_TOL,
    EMITTER_RULES,
    PRESETS,
    RULES,
    BarcodeSpec,
    check_spec,
)

__all__ = ["load_spec_arg", "register", "spec_summary"]

spec_app = typer.Typer(name="spec", help="List barcode presets, or show and validate one spec.",
                       no_args_is_help=True)


def load_spec_arg(arg: str) -> BarcodeSpec:
    """Resolve a CLI argument to a spec: a preset name, or a TOML file.

    Parameters
    ----------
    arg : str
        A key of `PRESETS`, or a path to a TOML file holding a spec table (the keys of
        `BarcodeSpec.to_dict`), either at top level or under ``[spec]``.

    Returns
    -------
    BarcodeSpec

    Raises
    ------
    SpecError
        If ``arg`` is neither a preset nor a readable TOML spec, or the spec is malformed.
    """
    if arg in PRESETS:
        return PRESETS[arg]
    path = Path(arg)
    if not (path.suffix.lower() == ".toml" or path.exists()):
        raise SpecError(f"{arg!r} is neither a preset ({', '.join(PRESETS)}) nor a TOML file",
                        rule="preset")
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SpecError(f"cannot read spec file {arg!r}: {exc.strerror}", rule="file") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"{arg}: not valid TOML: {exc}", rule="file") from exc
    if set(table) == {"spec"} and isinstance(table["spec"], dict):
        table = table["spec"]
    try:
        return BarcodeSpec.from_dict(table)
    except TypeError as exc:  # wrong value types reach the dataclass
        raise SpecError(f"{arg}: {exc}", rule="structure") from exc


def spec_summary(spec: BarcodeSpec, *, ratio_tol: float = DEFAULT_RATIO_TOL,
                 flicker_threshold_hz: float = DEFAULT_FLICKER_THRESHOLD_HZ,
                 allow: tuple[str, ...] = ()) -> dict[str, Any]:
    """JSON-ready description of a spec with its ratio set and every validation rule's status.

    Parameters
    ----------
    spec : BarcodeSpec
        The spec to describe.
    ratio_tol : float, optional
        T_b used by the ``ratios_distinct`` rule, absolute, unitless. Default 0.05.
    flicker_threshold_hz : float, optional
        Threshold of the ``flicker`` rule, in Hz. Default 80.
    allow : tuple of str, optional
        Emitter rules reported as warnings, as ``firmware --allow`` does.

    Returns
    -------
    summary : dict
        ``name``, ``description``, ``channels`` (name -> Hz list), ``f_b_hz``, ``slot_s``,
        ``pattern_period_s``, ``lowest_side_lobe_hz``, ``duty``, ``intensity_levels``,
        ``order``, ``slot_order``, ``ratios`` (value and producing pairs), ``rules`` (one entry
        per rule with ``status`` "pass", "fail" or "warning" and a message), ``ok`` (our
        firmware compiles it with this ``allow``: ``firmware`` exits 0 exactly then) and
        ``ok_as_policy`` (the config loader accepts it as a policy's barcode).
    """
    report = check_spec(spec, ratio_tol=ratio_tol, flicker_threshold_hz=flicker_threshold_hz,
                        allow=allow)
    by_rule: dict[str, list] = {}
    for v in report.violations:
        by_rule.setdefault(v.rule, []).append(v)
    rules = []
    for rule in RULES:
        vs = by_rule.get(rule, [])
        if not vs:
            rules.append({"rule": rule, "status": "pass", "message": ""})
        else:
            status = "fail" if any(v.severity == "error" for v in vs) else "warning"
            rules.append({"rule": rule, "status": status,
                          "message": "; ".join(v.message for v in vs)})
    return {
        "name": spec.name,
        "description": spec.description,
        "channels": {c: list(fs) for c, fs in spec.channels},
        "f_b_hz": spec.f_b_hz,
        "slot_s": spec.slot_s,
        "pattern_period_s": spec.pattern_period_s,
        "lowest_side_lobe_hz": spec.lowest_side_lobe_hz,
        "duty": spec.duty,
        "intensity_levels": spec.intensity_levels,
        "order": spec.order,
        "slot_order": list(spec.slot_order()),
        "phase": spec.phase,
        "ratio_tol": ratio_tol,
        "flicker_threshold_hz": flicker_threshold_hz,
        "max_freq_hz": DEFAULT_MAX_FREQ_HZ,
        "min_readout_s": DEFAULT_MIN_READOUT_S,
        "ratios": [{"value": r.value,
                    "pairs": [[f"{a[0]}:{a[1]:g}", f"{b[0]}:{b[1]:g}"] for a, b in r.pairs]}
                   for r in spec.ratios()],
        "rules": rules,
        "ok": report.ok,
        "ok_as_policy": report.ok_as_policy,
    }


def _print_summary(s: dict[str, Any]) -> None:
    typer.echo(f"spec {s['name']}" + (f": {s['description']}" if s["description"] else ""))
    for c, fs in s["channels"].items():
        typer.echo(f"  channel {c}: {', '.join(f'{f:g}' for f in fs)} Hz")
    typer.echo(f"  f_B = {s['f_b_hz']:g} Hz (slot {s['slot_s'] * 1e3:.4g} ms), pattern period "
               f"M/f_B = {s['pattern_period_s'] * 1e3:.4g} ms, slot order {s['slot_order']}, "
               f"phase {s['phase']}")
    typer.echo(f"  lowest side lobe f_B/M = {s['lowest_side_lobe_hz']:.4g} Hz, duty {s['duty']:g},"
               f" intensity levels {s['intensity_levels']}, order {s['order']}")
    typer.echo(f"  ratio set ({len(s['ratios'])} values, "
               f"{sum(len(r['pairs']) for r in s['ratios'])} pairs):")
    for r in s["ratios"]:
        pairs = ", ".join(f"{a}/{b}" for a, b in r["pairs"])
        typer.echo(f"    {r['value']:.4f}  <- {pairs}")
    typer.echo(f"  rules (ratio_tol={s['ratio_tol']:g}, flicker_threshold_hz="
               f"{s['flicker_threshold_hz']:g}):")
    for r in s["rules"]:
        line = f"    {r['status'].upper():<7} {r['rule']}"
        typer.echo(line + (f": {r['message']}" if r["message"] else ""))
    emitter = [r["rule"] for r in s["rules"] if r["rule"] in EMITTER_RULES
               and r["status"] == "fail"]
    if emitter:
        flags = " ".join(f"--allow {e}" for e in emitter)
        typer.echo(f"  note: {', '.join(emitter)} concern(s) what our firmware emits (it compiles "
                   f"this spec only with `firmware {flags}`, and `spec show {flags}` passes "
                   f"it); a policy may still name it: the detector searches such emitters "
                   f"(docs/policies.md)")


@spec_app.command("list")
def list_cmd(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of text.")] = False,
) -> None:
    """List the built-in barcode presets (paper Tables 1-3).

    Each line gives the preset's switching rate f_B and its tones per channel.

    Examples:
      lishield-guard spec list
      lishield-guard spec list --json
    """
    rows = [{"name": n, "channels": {c: list(fs) for c, fs in s.channels}, "f_b_hz": s.f_b_hz,
             "description": s.description} for n, s in PRESETS.items()]
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    for r in rows:
        tones = "; ".join(f"{c}: {', '.join(f'{f:g}' for f in fs)}" for c, fs in
                          r["channels"].items())
        typer.echo(f"{r['name']:<12} f_B={r['f_b_hz']:>5g} Hz  {tones} Hz")


@spec_app.command("show")
def show_cmd(
    spec: Annotated[str, typer.Argument(metavar="PRESET|SPEC.toml",
                                        help="Preset name or TOML spec file.")],
    ratio_tol: Annotated[float, typer.Option(
        "--ratio-tol", min=0.0, help="T_b for the ratios_distinct rule (absolute, unitless).")
    ] = DEFAULT_RATIO_TOL,
    flicker_threshold_hz: Annotated[float, typer.Option(
        "--flicker-threshold-hz", min=0.0, help="Flicker-fusion threshold in Hz.")
    ] = DEFAULT_FLICKER_THRESHOLD_HZ,
    allow: Annotated[list[str] | None, typer.Option(
        "--allow", help="Report this emitter rule (switching, flicker) as a warning, as "
                        "`firmware --allow` does. Repeatable.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of text.")] = False,
) -> None:
    """Show a spec's tones, switching rate, ratio set and every validation rule's status.

    Exits 0 exactly when `lishield-guard firmware` compiles the spec (with the same --allow),
    2 otherwise; ratios_distinct and readout are notes that never fail a spec. A spec that
    breaks only an emitter rule (switching, flicker) is still accepted as a policy by the
    config loader. The spec file format is described in docs/firmware.md.

    Examples:
      lishield-guard spec show table1-seq1
      lishield-guard spec show venue.toml --ratio-tol 0.03 --json
    """
    try:
        s = spec_summary(load_spec_arg(spec), ratio_tol=ratio_tol,
                         flicker_threshold_hz=flicker_threshold_hz, allow=tuple(allow or ()))
    except LishieldError as exc:
        raise fail(exc) from None
    if as_json:
        typer.echo(json.dumps(s, indent=2))
    else:
        _print_summary(s)
    if not s["ok"]:
        failed = [r["rule"] for r in s["rules"] if r["status"] == "fail"]
        typer.echo(f"error: spec {s['name']!r} breaks rule(s): {', '.join(failed)}", err=True)
        raise typer.Exit(int(ExitCode.USAGE))


def register(app: typer.Typer) -> None:
    """Add the ``spec`` command group to the main CLI app."""
    app.add_typer(spec_app, name="spec")
