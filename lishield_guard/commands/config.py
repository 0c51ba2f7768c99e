"""`lishield-guard config [show|validate]`: print the config that will run, or check a file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import typer

from lishield_guard.commands import fail
from lishield_guard.errors import LishieldError

__all__ = ["overrides", "register", "show_command", "validate_command"]

config_app = typer.Typer(
    name="config",
    help="Show the config that will run (alone: `config show`), or validate a config "
    "file.\n\n"
    "A config file holds only what it changes: every key left out (policies included) keeps "
    "the shipped, calibrated value; a config that leaves no policy is refused.",
    invoke_without_command=True,
)


@config_app.callback()
def _config_root(ctx: typer.Context) -> None:
    """Plain ``lishield-guard config`` shows the config that will run (``config show``)."""
    if ctx.invoked_subcommand is None:
        show_command(config=None, effective=False)


def _flat(cfg) -> dict[str, object]:
    out: dict[str, object] = {f"detector.{k}": v for k, v in cfg.detector.values().items()}
    for k, v in dataclasses.asdict(cfg.limits).items():
        out[f"limits.{k}"] = v
    out["policies"] = tuple((p.id, tuple(s.name for s in p.specs)) for p in cfg.policies)
    return out


def overrides(cfg) -> list[str]:
    """``key=value`` for every setting of ``cfg`` that differs from the shipped default.

    Parameters
    ----------
    cfg : AppConfig
        A loaded (merged) config.

    Returns
    -------
    list of str
        ``"detector.fit.min_rho=0.85"``-style lines, sorted; policies as ``policies=[ids]``.
    """
    from lishield_guard.config import default_config

    mine, base = _flat(cfg), _flat(default_config())
    lines = []
    for k in sorted(mine):  # a stage turned off shows as "detector.fold=None", once
        if k not in base or mine[k] != base[k]:
            v = [p[0] for p in mine[k]] if k == "policies" else mine[k]
            lines.append(f"{k}={v!r}")
    return lines


@config_app.command(name="show")
def show_command(
    config: Path | None = typer.Option(None, "--config", help="Config TOML (default: shipped)."),
    effective: bool = typer.Option(False, "--effective",
                                   help="Print every setting that will run: the file laid "
                                   "over the shipped default, as complete TOML."),
) -> None:
    """Print a config file as written, or (--effective) the complete config that will run.

    Exit status: 0 on success, 2 when the file is unreadable or invalid.

    Examples:

        lishield-guard config show

        lishield-guard config show --config mine.toml --effective
    """
    from lishield_guard.config import DEFAULT_CONFIG_RESOURCE, dump_config, load_config

    try:
        cfg = load_config(config)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    if not effective:
        if config is None:
            from importlib import resources

            text = resources.files("lishield_guard.data").joinpath(
                DEFAULT_CONFIG_RESOURCE).read_text()
        else:
            text = Path(config).read_text(encoding="utf-8")
        typer.echo(text, nl=not text.endswith("\n"))
        return
    where = ("the shipped default.toml" if config is None
             else f"{config} laid over the shipped default.toml")
    changed = overrides(cfg)
    header = [f"effective config: {where}",
              "changed from the shipped default: " + (", ".join(changed) or "nothing")]
    typer.echo(dump_config(cfg, header="\n".join(header)), nl=False)


@config_app.command(name="validate")
def validate_command(
    file: Path = typer.Argument(..., metavar="FILE", help="Config TOML to check."),
) -> None:
    """Check a config file: it must load, merge over the shipped default and define a policy.

    Prints the policies that will be screened for and every setting the file changes.
    Exit status: 0 when valid, 2 when not (the reason is printed).

    Examples:

        lishield-guard config validate mine.toml
    """
    from lishield_guard.config import load_config

    try:
        cfg = load_config(file)
    except LishieldError as exc:
        raise fail(str(exc)) from None
    n_specs = sum(len(p.specs) for p in cfg.policies)
    typer.echo(f"ok: {file}: profile {cfg.detector.profile!r}, {len(cfg.policies)} "
               f"polic{'y' if len(cfg.policies) == 1 else 'ies'} "
               f"({', '.join(p.id for p in cfg.policies)}), {n_specs} barcode spec(s)")
    changed = overrides(cfg)
    typer.echo("changed from the shipped default: " + ("none" if not changed else ""))
    for line in changed:
        typer.echo(f"  {line}")


def register(app: typer.Typer) -> None:
    """Add the ``config`` command group to the main CLI app."""
    app.add_typer(config_app, name="config")
