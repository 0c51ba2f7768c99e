"""`lishield-guard serve`: run the upload-screening HTTP service under uvicorn."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from lishield_guard.commands import ExitCode

__all__ = ["register", "serve"]

TOKEN_ENV_DEFAULT = "LISHIELD_API_TOKEN"


def serve(
    host: Annotated[str, typer.Option(help="Interface to bind.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port.", min=0, max=65535)] = 8000,
    workers: Annotated[int, typer.Option(help="Worker processes (each with its own "
                                         "detection thread pool).", min=1)] = 1,
    config: Annotated[Path | None, typer.Option(help="Detector/policy TOML file; default: the "
                                                "shipped config.")] = None,
    token_env: Annotated[str, typer.Option(help="Environment variable holding the bearer "
                                           "token for /v1 routes (unset or empty: no auth).")
                         ] = TOKEN_ENV_DEFAULT,
) -> None:
    """Serve POST /v1/screen, /v1/screen/batch, /v1/policies, /healthz, /readyz and /metrics.

    Other settings come from LISHIELD_* environment variables (LISHIELD_MAX_UPLOAD_BYTES,
    LISHIELD_MAX_CONCURRENCY, LISHIELD_MAX_QUEUE, LISHIELD_DETECT_TIMEOUT_S, ...).
    """
    import uvicorn

    from lishield_guard.errors import ConfigError
    from service.app import create_app
    from service.settings import ServiceSettings

    if config is not None:
        os.environ["LISHIELD_CONFIG_PATH"] = str(config)
    token = os.environ.get(token_env, "")
    if token:
        os.environ["LISHIELD_API_TOKEN"] = token
    else:
        os.environ.pop("LISHIELD_API_TOKEN", None)
    try:
        app = create_app(ServiceSettings())  # also validates config and settings up front
    except (ConfigError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(ExitCode.USAGE) from None
    common = {"host": host, "port": port, "access_log": False, "log_level": "info",
              "timeout_graceful_shutdown": 10}
    if workers > 1:  # each process builds its own app from the environment set above
        del app
        uvicorn.run("service.app:create_app", factory=True, workers=workers, **common)
    else:
        uvicorn.run(app, **common)


def register(app: typer.Typer) -> None:
    """Add the ``serve`` command to the CLI."""
    app.command("serve")(serve)
