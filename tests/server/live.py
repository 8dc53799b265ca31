"""A real uvicorn server on 127.0.0.1 per database backend, and httpx clients to talk to it.

Backends: a SQLite file always; PostgreSQL when ``LINEMAP_TEST_POSTGRES_URL`` is set (``.ci/run`` sets
it). The PostgreSQL database is emptied (its public schema dropped and made again) before the session's server
migrates it; under pytest-xdist each worker has a database of its own on that server (:func:`postgres_url`).
Tests share one server per backend and create their own robots, so they do not depend on each other.
"""

from __future__ import annotations

import functools
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import uvicorn
from fastapi import FastAPI
from sqlalchemy import create_engine, make_url, text

from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.cli import KEEP_ALIVE_S
from server.database import normalize_url
from server.deps import AppState
from server.settings import Settings

POSTGRES_ENV = "LINEMAP_TEST_POSTGRES_URL"
BACKENDS = ["sqlite", "postgresql"]


@dataclass
class Live:
    """A running server: its base URL, the admin token and the app state (for white-box checks)."""

    base_url: str
    admin_token: str
    state: AppState
    backend: str
    app: FastAPI

    def client(self, token: str | None = None, **kwargs: object) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.base_url + "/api/v1", headers=headers, timeout=30.0, **kwargs)  # type: ignore[arg-type]

    def operator(self) -> httpx.Client:
        return self.client(self.admin_token)

    def new_robot(self) -> tuple[int, str]:
        """Register a robot with a unique name; returns (id, token)."""
        with self.operator() as op:
            r = op.post("/robots", json={"name": f"r-{uuid.uuid4().hex[:10]}"})
            assert r.status_code == 201, r.text
            body = r.json()
            return int(body["id"]), str(body["token"])


@functools.cache
def postgres_url() -> str | None:
    """The PostgreSQL database this test process may empty and fill: ``LINEMAP_TEST_POSTGRES_URL``'s, or
    under pytest-xdist ``<that database>_<worker>`` on the same server (made on first use), so parallel
    workers never drop each other's tables. None when the variable is not set."""
    url = os.environ.get(POSTGRES_ENV)
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if not url or not worker:
        return url
    base = make_url(normalize_url(url))
    name = f"{base.database}_{worker}"
    admin = create_engine(base, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as conn:
            known = conn.execute(text("SELECT 1 FROM pg_database WHERE datname = :n"), {"n": name}).first()
            if known is None:
                conn.execute(text(f'CREATE DATABASE "{name}"'))
    finally:
        admin.dispose()
    return make_url(url).set(database=name).render_as_string(hide_password=False)


def database_url(backend: str, tmp: Path) -> str:
    if backend == "sqlite":
        return f"sqlite:///{tmp / 'server.db'}"
    url = postgres_url()
    if not url:
        pytest.skip(f"{POSTGRES_ENV} is not set (CI sets it to its PostgreSQL)")
    # An empty database whatever an earlier run left (another branch's migrations, a killed run): every
    # table, type and the Alembic version dropped, not downgraded (a downgrade needs the revision it is at
    # to be this tree's).
    engine = create_engine(normalize_url(url))
    with engine.begin() as conn:
        conn.execute(text("DROP SCHEMA IF EXISTS public CASCADE"))
        conn.execute(text("CREATE SCHEMA public"))
    engine.dispose()
    return url


class ServerThread:
    """uvicorn serving ``app`` on a socket bound to 127.0.0.1 and a free port, in a daemon thread."""

    def __init__(self, app: object, port: int = 0) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.port = self.sock.getsockname()[1]
        config = uvicorn.Config(
            app,  # type: ignore[arg-type]
            log_level="warning",
            lifespan="on",
            timeout_graceful_shutdown=2,
            timeout_keep_alive=KEEP_ALIVE_S,  # as `linemap server` runs it
            proxy_headers=False,  # as `linemap server` runs it: forwarded headers are the app's business
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self) -> ServerThread:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:  # readiness wait, not a timing assertion
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(10)
        self.sock.close()


def start_live(backend: str, tmp: Path, **settings: object) -> Iterator[Live]:
    url = database_url(backend, tmp)
    app = create_app(Settings(database_url=url, **settings))  # type: ignore[arg-type]
    state: AppState = app.state.linemap
    token = ensure_admin_token(state.db)
    assert token is not None, "a fresh database gets an admin token"
    with ServerThread(app) as srv:
        yield Live(f"http://127.0.0.1:{srv.port}", token, state, backend, app)
