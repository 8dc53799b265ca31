"""The Alembic migrations: upgrade head -> downgrade base -> upgrade head on SQLite and PostgreSQL, and
the migrated schema matches the models (no drift between ``server.models`` and ``migrations/server``)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect

from server.database import normalize_url
from server.migrate import current_revision, downgrade, head_revision, upgrade
from server.models import Base
from tests.server.procs import fresh_database

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(params=["sqlite", "postgresql"])
def engine_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database of the test's own (a PostgreSQL one is made and dropped: the round trip empties it)."""
    with fresh_database(request.param, tmp_path) as url:
        yield normalize_url(url)


def test_round_trip_and_no_drift(engine_url: str) -> None:
    engine = create_engine(engine_url)
    try:
        downgrade(engine, "base")
        upgrade(engine)
        assert current_revision(engine) == head_revision()
        with engine.connect() as conn:
            diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
        assert diff == [], f"models and migrations differ: {diff}"
        downgrade(engine, "base")
        assert current_revision(engine) is None
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
        upgrade(engine)
        assert {"robots", "messages", "kernels", "map_segments"} <= set(inspect(engine).get_table_names())
    finally:
        engine.dispose()


def test_alembic_command_line_round_trip(tmp_path: Path) -> None:
    """What the README tells a user to run: `alembic upgrade head` then `alembic downgrade base`."""
    alembic = Path(sys.executable).parent / "alembic"
    db = f"sqlite:///{tmp_path / 'cli.db'}"
    for args in (["upgrade", "head"], ["downgrade", "base"], ["upgrade", "head"]):
        r = subprocess.run(
            [str(alembic), "-x", f"db={db}", *args], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
        assert r.returncode == 0, r.stderr
    assert "robots" in inspect(create_engine(db)).get_table_names()
