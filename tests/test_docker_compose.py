"""docker-compose.yml agrees with the code (issue 22 item 5; no container engine here, so this is what
shows that its setup works): every ``linemap`` command in it parses with the real CLI (its options and
the environment it reads), every ``LINEMAP_*`` variable is a server setting or a CLI option's variable,
the database URL is PostgreSQL in the form the server accepts and names the compose database with its
credentials, more than one worker only with PostgreSQL, the server waits for a healthy database and its
own health check asks a route the server has, on the port it listens on, and the database accepts the
connections of every worker. With PostgreSQL at hand the
server is then run as the file runs it (its options and workers, on a fresh database) and the file's
own health-check command passes against it."""

from __future__ import annotations

import os
import re
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import typer
import yaml
from sqlalchemy.engine import make_url

from server.app import create_app
from server.database import PG_MAX_OVERFLOW, PG_POOL_SIZE, normalize_url
from server.settings import Settings
from shared.cli.main import app as linemap_app
from tests.server.procs import LINEMAP, fresh_database

COMPOSE = Path(__file__).resolve().parents[1] / "docker-compose.yml"


def _compose() -> dict[str, Any]:
    doc = yaml.safe_load(COMPOSE.read_text())
    assert isinstance(doc, dict) and "services" in doc, f"{COMPOSE} has no services"
    services: dict[str, Any] = doc["services"]
    return services


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _env(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment") or {}
    if isinstance(env, list):  # the "KEY=value" form
        env = dict(item.split("=", 1) for item in env)
    return {str(k): str(v) for k, v in env.items()}


def _linemap_commands(service: dict[str, Any]) -> list[list[str]]:
    """The ``linemap ...`` invocations in a service's command (a ``sh -c "a && b"`` line, or a list)."""
    command = service.get("command")
    words = shlex.split(command) if isinstance(command, str) else list(command or [])
    parts = [shlex.split(p) for p in words[2].split("&&")] if words[:2] == ["sh", "-c"] else [words]
    return [p[1:] for p in parts if p and p[0] == "linemap"]


def _parse(args: list[str], env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> Any:
    """``linemap args`` parsed by the real CLI down to its last command (nothing is run), with the
    service's environment in force; the last command's context."""
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    cmd: Any = typer.main.get_command(linemap_app)
    ctx = cmd.make_context("linemap", list(args))
    while isinstance(cmd, typer.core.TyperGroup):
        rest = [*ctx._protected_args, *ctx.args]
        if not rest:
            break
        name, sub, sub_args = cmd.resolve_command(ctx, rest)
        assert sub is not None and name is not None, f"linemap {' '.join(args)}: no command {rest[0]!r}"
        cmd, ctx = sub, sub.make_context(name, sub_args, parent=ctx)
    return ctx


def _cli_envvars(ctx: Any) -> set[str]:
    names: set[str] = set()
    for param in ctx.command.params:
        envvar = param.envvar
        names.update([envvar] if isinstance(envvar, str) else list(envvar or []))
    return names


def _server(monkeypatch: pytest.MonkeyPatch) -> tuple[dict[str, Any], dict[str, str], Any]:
    service = _compose()["server"]
    env = _env(service)
    commands = _linemap_commands(service)
    assert [c[0] for c in commands] == ["server"], f"the server service runs {commands}"
    return service, env, _parse(commands[0], env, monkeypatch)


def _health_url(service: dict[str, Any]) -> str:
    test = service.get("healthcheck", {}).get("test")
    assert test, "the server service has no health check"
    found = re.findall(r"https?://[^\s'\"]+", " ".join(test) if isinstance(test, list) else test)
    assert len(found) == 1, f"expected one URL in the server's health check, found {found}"
    return str(found[0])


def test_every_linemap_command_parses_with_the_cli(monkeypatch: pytest.MonkeyPatch) -> None:
    ran = 0
    for _name, service in _compose().items():
        for args in _linemap_commands(service):
            with monkeypatch.context() as m:
                _parse(args, _env(service), m)  # click.UsageError (unknown option, bad value) fails here
            ran += 1
    assert ran >= 2, "expected the server's and the benchmark's linemap commands"


def test_the_servers_environment_is_settings_and_cli_variables(monkeypatch: pytest.MonkeyPatch) -> None:
    _, env, ctx = _server(monkeypatch)
    known = {f"LINEMAP_{name.upper()}" for name in Settings.model_fields} | _cli_envvars(ctx)
    unknown = sorted(k for k in env if k.startswith("LINEMAP_") and k not in known)
    assert not unknown, f"docker-compose.yml sets {unknown}, which neither the settings nor the CLI read"
    Settings(database_url=ctx.params["db"])  # the server's own validation of the URL setting


def test_the_database_url_is_the_compose_postgresql(monkeypatch: pytest.MonkeyPatch) -> None:
    _, _, ctx = _server(monkeypatch)
    url = make_url(normalize_url(ctx.params["db"]))
    db_service = _compose()["db"]
    pg = _env(db_service)
    assert url.drivername == "postgresql+psycopg"
    assert (url.host, url.port or 5432) == ("db", 5432), "the server must reach the db service on 5432"
    assert (url.username, url.password, url.database) == (
        pg["POSTGRES_USER"],
        pg["POSTGRES_PASSWORD"],
        pg["POSTGRES_DB"],
    )
    assert f"-U {pg['POSTGRES_USER']}" in " ".join(db_service["healthcheck"]["test"])
    assert _compose()["server"]["depends_on"]["db"]["condition"] == "service_healthy"


def test_several_workers_and_only_on_postgresql(monkeypatch: pytest.MonkeyPatch) -> None:
    _, _, ctx = _server(monkeypatch)
    assert ctx.params["workers"] > 1, "the fleet topology runs the server with several workers"
    assert not normalize_url(ctx.params["db"]).startswith("sqlite"), "SQLite refuses --workers above 1"


def test_the_databases_connections_suffice_for_every_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    _, _, ctx = _server(monkeypatch)
    command = _compose()["db"].get("command") or []
    words = shlex.split(command) if isinstance(command, str) else [str(w) for w in command]
    settings = dict(w.split("=", 1) for w in words if "=" in w)
    max_connections = int(settings.get("max_connections", 100))  # PostgreSQL's default
    per_process = PG_POOL_SIZE + PG_MAX_OVERFLOW + 1  # the pool and the notice listener
    reserved = 3  # PostgreSQL's superuser_reserved_connections
    assert ctx.params["workers"] * per_process <= max_connections - reserved, (
        f"{ctx.params['workers']} workers x {per_process} connections exceed the database's "
        f"max_connections {max_connections}"
    )


def test_the_health_check_asks_a_route_the_server_has_on_its_port(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    service, _, ctx = _server(monkeypatch)
    url = urlsplit(_health_url(service))
    path = url.path
    monkeypatch.delenv("LINEMAP_WORKERS", raising=False)
    app = create_app(Settings(database_url=f"sqlite:///{tmp_path / 'routes.db'}"))
    paths = app.openapi()["paths"]  # the routes the server serves, as its API document lists them
    assert "get" in paths.get(path, {}), f"the server has no GET route {path}"
    assert url.port == ctx.params["port"], "the health check asks another port than the server's"
    assert ctx.params["host"] == "0.0.0.0", "the server must listen beyond the container's loopback"
    published = [str(p).rsplit(":", 1)[-1] for p in service["ports"]]
    assert str(ctx.params["port"]) in published


def test_the_server_runs_as_the_file_runs_it_and_passes_its_health_check(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    service, env, ctx = _server(monkeypatch)
    with fresh_database("postgresql", tmp_path) as url:
        port = _free_port()
        swap = {"--host": "127.0.0.1", "--port": str(port)}  # here: loopback and a free port
        words = _linemap_commands(service)[0]
        args = [LINEMAP, *(swap.get(words[i - 1], w) if i else w for i, w in enumerate(words))]
        proc = subprocess.Popen(
            args,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **env, "LINEMAP_DATABASE_URL": url},  # the file's workers, a fresh database
        )
        try:
            test = list(service["healthcheck"]["test"])
            assert test[:2] == ["CMD", "python"], f"unexpected health-check form {test[:2]}"
            argv = [sys.executable, *(w.replace(f":{ctx.params['port']}/", f":{port}/") for w in test[2:])]
            deadline = time.monotonic() + 300  # readiness wait (N workers start), not a timing assertion
            while True:
                done = subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)
                if done.returncode == 0:
                    break
                assert proc.poll() is None, f"the server exited: {proc.communicate()[1][-2000:]}"
                assert time.monotonic() < deadline, f"the health check never passed: {done.stderr[-500:]}"
                time.sleep(0.5)
            workers = subprocess.run(  # the worker processes under the server's
                ["pgrep", "-P", str(proc.pid), "-f", "multiprocessing.spawn"],
                capture_output=True,
                text=True,
                check=False,
            )
            assert len(workers.stdout.split()) == ctx.params["workers"], workers.stdout
        finally:
            proc.terminate()  # the server stops its workers
            try:
                proc.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
