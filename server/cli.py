"""``linemap server``: migrate the database, make the first operator token, serve the API with uvicorn."""

from __future__ import annotations

import contextlib
import logging
import sys
from typing import Annotated, Any

import typer

from server.settings import DEFAULT_DATABASE_URL

__all__ = ["server_app"]

log = logging.getLogger(__name__)

server_app = typer.Typer(
    help="The linemap server: REST API for robots, control messages, kernels and live maps.",
    invoke_without_command=True,
)
token_app = typer.Typer(help="Operator tokens.", no_args_is_help=True)
server_app.add_typer(token_app, name="token")

DbOption = Annotated[
    str,
    typer.Option(
        "--db",
        envvar="LINEMAP_DATABASE_URL",
        help="SQLAlchemy URL or SQLite file path (PostgreSQL: postgresql://user@host/db).",
    ),
]


@server_app.callback()
def serve(
    ctx: typer.Context,
    db: DbOption = DEFAULT_DATABASE_URL,
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port.")] = 8000,
) -> None:
    """Serve the API (migrating the database first). Prints the first operator token once, on first start."""
    if ctx.invoked_subcommand is not None:
        ctx.obj = db
        return
    import uvicorn

    from server.app import create_app
    from server.bootstrap import ensure_admin_token
    from server.settings import Settings

    settings = Settings(database_url=db)
    app = create_app(settings)
    token = ensure_admin_token(app.state.linemap.db)
    base = f"http://{host}:{port}"
    if token is not None:
        typer.echo(f"First start: operator token 'admin' (shown once, keep it): {token}")
    docs = f"{base}/docs" if settings.api_docs else f"{base}/openapi.json"
    typer.echo(f"linemap server on {base}  (API: {docs}, database: {app.state.linemap.db.url})")
    sys.stdout.flush()  # a pipe or log file must see these lines before the server blocks
    _tune_gc()
    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level="warning",
        timeout_graceful_shutdown=5,
        # proxy_headers=False: uvicorn would otherwise rewrite the client address from X-Forwarded-For sent
        # by any local client (its default trusts 127.0.0.1); the app reads forwarded headers itself, and
        # only from the operator's LINEMAP_TRUSTED_PROXIES (server.limiter.client_source).
        proxy_headers=False,
    )
    server = _server_class()(config, app.state.shutdown)
    with contextlib.suppress(KeyboardInterrupt):  # uvicorn re-raises the Ctrl-C it handled, once stopped
        server.run()
    if not server.started:
        typer.echo(f"linemap server could not listen on {host}:{port} (see the message above)", err=True)
        raise typer.Exit(3)


def _server_class() -> Any:
    """uvicorn's server whose exit handler (SIGINT, SIGTERM) also ends the app's long-polls and streams
    (:mod:`server.shutdown`), so Ctrl-C stops at once, cleanly, instead of cancelling them after the
    graceful timeout with a traceback each."""
    import uvicorn

    from server.shutdown import ShutdownSignal

    class Server(uvicorn.Server):
        def __init__(self, config: uvicorn.Config, stopping: ShutdownSignal) -> None:
            super().__init__(config)
            self.stopping = stopping

        def handle_exit(self, sig: int, frame: object) -> None:
            self.stopping.set()
            super().handle_exit(sig, frame)  # type: ignore[arg-type]

    return Server


def _tune_gc() -> None:
    """Move everything loaded at start-up out of the garbage collector's sight (``gc.freeze``): the
    collector then never re-scans the imported libraries' objects while serving."""
    import gc

    gc.collect()
    gc.freeze()


@token_app.command("create")
def token_create(
    ctx: typer.Context,
    name: Annotated[str, typer.Option(help="Who the token is for.")] = "operator",
) -> None:
    """Create an operator token and print it (shown once)."""
    from server.bootstrap import create_token
    from server.database import Database
    from server.migrate import upgrade

    db = Database(ctx.obj or DEFAULT_DATABASE_URL)
    upgrade(db.engine)
    typer.echo(create_token(db, name))
    db.dispose()
