"""Real `linemap server` processes on one database (SQLite file or a fresh PostgreSQL database), for the
tests of what must hold across server processes (shared limits, revocation)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from benchmarks.fleet_load import fresh_postgres
from tests.server.live import POSTGRES_ENV

__all__ = ["ServerProc", "fresh_database", "server_procs"]

LINEMAP = str(Path(sys.executable).parent / "linemap")


@dataclass
class ServerProc:
    """One running server process: its base URL (``.../api/v1`` in :meth:`client`)."""

    proc: subprocess.Popen[str]
    base_url: str

    def client(self, token: str | None = None, **kwargs: object) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.base_url + "/api/v1", headers=headers, timeout=30.0, **kwargs)  # type: ignore[arg-type]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def fresh_database(backend: str, tmp: Path) -> Iterator[str]:
    """A database URL no one else uses: a new SQLite file, or a uniquely named PostgreSQL database on the
    server of ``LINEMAP_TEST_POSTGRES_URL`` (dropped afterwards)."""
    if backend == "sqlite":
        yield f"sqlite:///{tmp / f'procs-{uuid.uuid4().hex[:8]}.db'}"
        return
    base = os.environ.get(POSTGRES_ENV)
    if not base:
        pytest.skip(f"{POSTGRES_ENV} is not set (CI sets it to its PostgreSQL)")
    with fresh_postgres(base, "lm_procs") as url:
        yield url


def _start(url: str, env: dict[str, str], args: tuple[str, ...] = ()) -> tuple[ServerProc, str]:
    port = _free_port()
    proc = subprocess.Popen(
        [LINEMAP, "server", "--db", url, "--port", str(port), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **env},
    )
    try:
        return _ready(proc, port)
    except BaseException:  # a server that did not come up is not left running
        proc.kill()
        proc.communicate()
        raise


def _ready(proc: subprocess.Popen[str], port: int) -> tuple[ServerProc, str]:
    assert proc.stdout is not None
    lines = [proc.stdout.readline()]
    while lines[-1] and "linemap server on" not in lines[-1]:  # the token line, if any, comes first
        lines.append(proc.stdout.readline())
    out = "".join(lines)
    assert "linemap server on" in out, (
        f"server did not start: {out}{proc.stderr.read() if proc.stderr else ''}"
    )
    srv = ServerProc(proc, f"http://127.0.0.1:{port}")
    deadline = time.monotonic() + 30
    while True:  # readiness wait, not a timing assertion
        try:
            if httpx.get(srv.base_url + "/healthz", timeout=2).status_code == 200:
                return srv, out
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline and proc.poll() is None, "server did not come up"
        time.sleep(0.05)


@contextmanager
def server_procs(
    url: str, n: int = 2, args: tuple[str, ...] = (), **settings: object
) -> Iterator[tuple[list[ServerProc], str]]:
    """``n`` server processes on ``url`` (started one after the other), with ``settings`` as ``LINEMAP_*``
    environment and ``args`` added to the command line; yields them and the admin token the first one
    printed. Stopped with SIGTERM afterwards."""
    env = {f"LINEMAP_{k.upper()}": str(v) for k, v in settings.items()}
    procs: list[ServerProc] = []
    try:
        first, out = _start(url, env, args)
        procs.append(first)
        token = out.split("keep it): ")[1].split()[0]
        for _ in range(n - 1):
            procs.append(_start(url, env, args)[0])
        yield procs, token
    finally:
        for p in procs:
            p.proc.terminate()
        for p in procs:
            try:
                p.proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                p.proc.kill()
                p.proc.communicate()
