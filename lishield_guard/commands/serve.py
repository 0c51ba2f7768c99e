"""`lishield-guard serve`: run the upload-screening HTTP service under uvicorn."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from lishield_guard.commands import ExitCode

__all__ = ["register", "serve"]

TOKEN_ENV_DEFAULT = "LISHIELD_API_TOKEN"


def _port_busy(host: str, port: int) -> str | None:
    """Why ``host:port`` cannot be bound (e.g. "address already in use"), or None."""
    import socket

    if port == 0:
        return None
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        return f"cannot resolve host: {exc}"
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            return (exc.strerror or str(exc)).lower()
    return None


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
    """Serve the screening API (POST /v1/screen) and a reviewer page (/review).

    Also /v1/screen/batch, /v1/screen/plot, /v1/policies, /healthz, /readyz, /metrics and
    /docs. Other settings come from LISHIELD_* environment variables (LISHIELD_MAX_UPLOAD_BYTES,
    LISHIELD_MAX_CONCURRENCY, LISHIELD_MAX_QUEUE, LISHIELD_DETECT_TIMEOUT_S, ...); see
    docs/service.md.

    Examples:
      lishield-guard serve --port 8000
      LISHIELD_API_TOKEN=s3cret lishield-guard serve --host 0.0.0.0 --workers 2
    """
    import uvicorn

    from lishield_guard.errors import ConfigError
    from service.app import create_app
    from service.protocol import UVICORN_HTTP
    from service.settings import ServiceSettings

    busy = _port_busy(host, port)
    if busy:
        typer.echo(f"error: cannot listen on {host}:{port}: {busy}; choose another with "
                   f"--port, or stop what is listening there (e.g. `lsof -i :{port}`)", err=True)
        raise typer.Exit(ExitCode.USAGE)
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
              "timeout_graceful_shutdown": 10, "http": UVICORN_HTTP}
    if workers > 1:  # each process builds its own app from the environment set above
        del app
        uvicorn.run("service.app:create_app", factory=True, workers=workers, **common)
    else:
        uvicorn.run(app, **common)


def register(app: typer.Typer) -> None:
    """Add the ``serve`` command to the CLI."""
    app.command("serve")(serve)
