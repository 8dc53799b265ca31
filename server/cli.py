"""``linemap server``: migrate the database, make the first operator token, serve the API with uvicorn."""

from __future__ import annotations

import contextlib
import logging
import sys
from typing import Annotated, Any

import typer

from server.settings import DEFAULT_DATABASE_URL
from server.workers import server_class

__all__ = ["KEEP_ALIVE_S", "server_app"]

log = logging.getLogger(__name__)

#: How long the server keeps an idle HTTP/1.1 connection open (s). Longer than the idle time after which
#: httpx clients (the agent, the CLI, scripts; 5 s by default) drop a pooled connection, so the client
#: always closes first: with equal timers (uvicorn's default is also 5 s) a request sent on a connection the
#: server is closing at that moment is reset ("Connection reset by peer") and is not retried by the client.
KEEP_ALIVE_S = 20

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
    workers: Annotated[
        int,
        typer.Option(
            min=1,
            max=64,
            envvar="LINEMAP_WORKERS",
            help="Server processes on the port (PostgreSQL only: SQLite has one writer, so one process).",
        ),
    ] = 1,
) -> None:
    """Serve the API (migrating the database first). Prints the first operator token once, on first start."""
    if ctx.invoked_subcommand is not None:
        ctx.obj = db
        return
    from server.database import normalize_url

    if workers > 1 and normalize_url(db).startswith("sqlite"):
        raise typer.BadParameter(
            f"{workers} workers need a PostgreSQL database (--db postgresql://USER@HOST/DB); this one is "
            "SQLite, which allows one writer at a time and whose server wakes its waiters in-process only, "
            "so it runs as one process (--workers 1)",
            param_hint="'--workers' / LINEMAP_WORKERS",
        )
    if workers > 1:
        _serve_workers(db, host, port, workers)
        return
    import uvicorn

    from server.app import create_app
    from server.bootstrap import ensure_admin_token
    from server.settings import Settings

    settings = Settings(database_url=db)
    app = create_app(settings)
    token = ensure_admin_token(app.state.linemap.db)
    _announce(token, host, port, settings.api_docs, app.state.linemap.db.url, 1)
    _tune_gc()
    server = server_class()(uvicorn.Config(app, **_uvicorn_config(host, port)), app.state.shutdown)
    with contextlib.suppress(KeyboardInterrupt):  # uvicorn re-raises the Ctrl-C it handled, once stopped
        server.run()
    if not server.started:
        typer.echo(f"linemap server could not listen on {host}:{port} (see the message above)", err=True)
        raise typer.Exit(3)


def _uvicorn_config(host: str, port: int) -> dict[str, Any]:
    return {
        "host": host,
        "port": port,
        "log_level": "warning",
        "timeout_graceful_shutdown": 5,
        "timeout_keep_alive": KEEP_ALIVE_S,
        # proxy_headers=False: uvicorn would otherwise rewrite the client address from X-Forwarded-For sent
        # by any local client (its default trusts 127.0.0.1); the app reads forwarded headers itself, and
        # only from the operator's LINEMAP_TRUSTED_PROXIES (server.limiter.client_source).
        "proxy_headers": False,
    }


def _announce(token: str | None, host: str, port: int, api_docs: bool, url: str, workers: int) -> None:
    base = f"http://{host}:{port}"
    if token is not None:
        typer.echo(f"First start: operator token 'admin' (shown once, keep it): {token}")
    docs = f"{base}/docs" if api_docs else f"{base}/openapi.json"
    procs = f", {workers} worker processes" if workers > 1 else ""
    typer.echo(f"linemap server on {base}  (API: {docs}, database: {url}{procs})")
    sys.stdout.flush()  # a pipe or log file must see these lines before the server blocks


def _serve_workers(db: str, host: str, port: int, workers: int) -> None:
    """``--workers N``: migrate and make the first token here, then N processes serve (server.workers)."""
    from server.bootstrap import ensure_admin_token
    from server.database import Database
    from server.migrate import upgrade
    from server.settings import Settings
    from server.workers import serve_workers

    settings = Settings(database_url=db)
    database = Database(settings.database_url)
    try:
        upgrade(database.engine)
        token = ensure_admin_token(database)
        url = database.url
    finally:
        database.dispose()
    _announce(token, host, port, settings.api_docs, url, workers)
    code = serve_workers(settings.database_url, host, port, workers, _uvicorn_config(host, port))
    if code:
        typer.echo(f"linemap server could not serve on {host}:{port} (see the message above)", err=True)
        raise typer.Exit(code)


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
