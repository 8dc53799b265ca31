"""A read-only unit of work (``Database.read``) sees one snapshot of the database on every backend: what
another connection commits while it runs is not seen half (the torn read that let CI see a rollout's
robot committed beside the rollout's old wave). Real SQLite files and a real PostgreSQL database."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import text
from sqlalchemy.exc import DBAPIError

from server.database import Database
from tests.server.procs import fresh_database


@pytest.fixture(params=["sqlite", "postgresql"])
def db(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Database]:
    with fresh_database(request.param, tmp_path) as url:
        database = Database(url)
        with database.write_conn() as conn:
            conn.execute(text("CREATE TABLE head (id INTEGER PRIMARY KEY, wave INTEGER NOT NULL)"))
            conn.execute(text("CREATE TABLE member (id INTEGER PRIMARY KEY, state VARCHAR(20) NOT NULL)"))
            conn.execute(text("INSERT INTO head (id, wave) VALUES (1, 0)"))
            conn.execute(text("INSERT INTO member (id, state) VALUES (1, 'applied')"))
        try:
            yield database
        finally:
            database.dispose()


def _tick(db: Database) -> None:
    """What a rollout driver's tick commits at once: the member decided and the head's wave moved on."""
    with db.write_conn() as conn:
        conn.execute(text("UPDATE member SET state = 'installed' WHERE id = 1"))
        conn.execute(text("UPDATE head SET wave = 1 WHERE id = 1"))


def test_a_read_sees_one_snapshot_while_another_connection_commits(db: Database) -> None:
    with db.read() as s:
        wave = s.execute(text("SELECT wave FROM head WHERE id = 1")).scalar_one()
        _tick(db)  # commits on another connection between the read's two statements
        state = s.execute(text("SELECT state FROM member WHERE id = 1")).scalar_one()
    assert (wave, state) == (0, "applied"), "the read mixed two states of the database"
    with db.read() as s:
        wave = s.execute(text("SELECT wave FROM head WHERE id = 1")).scalar_one()
        state = s.execute(text("SELECT state FROM member WHERE id = 1")).scalar_one()
    assert (wave, state) == (1, "installed"), "the next read sees the commit"


def test_a_write_committed_before_the_read_is_seen(db: Database) -> None:
    _tick(db)
    with db.read() as s:
        assert s.execute(text("SELECT wave FROM head")).scalar_one() == 1


def test_a_read_does_not_hold_writers_back(db: Database) -> None:
    with db.read() as s:
        s.execute(text("SELECT wave FROM head")).scalar_one()
        for _ in range(3):  # writers commit while the snapshot is held (WAL on SQLite, MVCC on PostgreSQL)
            _tick(db)
    with db.write_conn() as conn:
        assert conn.execute(text("SELECT wave FROM head")).scalar_one() == 1


def test_a_read_on_postgresql_cannot_write(tmp_path: Path) -> None:
    with fresh_database("postgresql", tmp_path) as url:
        database = Database(url)
        try:
            with database.write_conn() as conn:
                conn.execute(text("CREATE TABLE head (id INTEGER PRIMARY KEY, wave INTEGER NOT NULL)"))
            with pytest.raises(DBAPIError, match="read-only transaction"), database.read() as s:
                s.execute(text("INSERT INTO head (id, wave) VALUES (1, 7)"))
        finally:
            database.dispose()
