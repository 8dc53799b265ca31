"""Server processes starting together on a fresh database: each migrates under the schema lock
(server.migrate.hold_schema_lock), so all of them start, the schema ends at head, and only one of them
makes the first admin token. Real processes (what ``linemap server`` runs before serving), a fresh
uniquely named PostgreSQL database, a fresh SQLite file."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import create_engine, func, select, text

from benchmarks.fleet_load import fresh_postgres as new_postgres_database
from server.database import normalize_url
from server.migrate import current_revision, head_revision
from server.models import OperatorToken
from tests.server.live import POSTGRES_ENV

ROOT = Path(__file__).resolve().parents[2]
PROCESSES = 4

# What `linemap server` does before uvicorn serves (server/cli.py): create_app migrates, then the first
# operator token. Each child waits at a gate so that all of them migrate at the same moment.
CHILD = """
import sys, time
from pathlib import Path
from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.settings import Settings
url, gate = sys.argv[1], Path(sys.argv[2])
deadline = time.monotonic() + 60
while not gate.exists():
    if time.monotonic() > deadline:
        sys.exit("the start gate never opened")
    time.sleep(0.005)
app = create_app(Settings(database_url=url))
token = ensure_admin_token(app.state.linemap.db)
print("TOKEN" if token else "NO-TOKEN")
app.state.linemap.writer.close()
app.state.linemap.db.dispose()
"""


@pytest.fixture
def fresh_postgres() -> Iterator[str]:
    """A new, empty PostgreSQL database on the test server, dropped afterwards."""
    base = os.environ.get(POSTGRES_ENV)
    if not base:
        pytest.skip(f"{POSTGRES_ENV} is not set")
    with new_postgres_database(base, "linemap_fresh") as url:
        yield url


def _start_together(url: str, tmp_path: Path) -> list[subprocess.CompletedProcess[str]]:
    gate = tmp_path / "gate"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", CHILD, url, str(gate)],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(PROCESSES)
    ]
    gate.touch()
    done = []
    for p in procs:
        out, err = p.communicate(timeout=180)
        done.append(subprocess.CompletedProcess(p.args, p.returncode, out, err))
    return done


def _check(url: str, done: list[subprocess.CompletedProcess[str]]) -> None:
    for r in done:
        assert r.returncode == 0, r.stderr[-2000:]
    outputs = sorted(r.stdout.strip() for r in done)
    assert outputs == ["NO-TOKEN"] * (PROCESSES - 1) + ["TOKEN"], outputs
    engine = create_engine(normalize_url(url))
    try:
        assert current_revision(engine) == head_revision()
        with engine.connect() as conn:
            assert conn.scalar(select(func.count()).select_from(OperatorToken)) == 1
            assert conn.scalar(text("SELECT count(*) FROM alembic_version")) == 1
    finally:
        engine.dispose()


def test_processes_migrate_a_fresh_postgres_database_together(fresh_postgres: str, tmp_path: Path) -> None:
    _check(fresh_postgres, _start_together(fresh_postgres, tmp_path))


def test_processes_migrate_a_fresh_sqlite_file_together(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'fresh.db'}"
    _check(url, _start_together(url, tmp_path))
