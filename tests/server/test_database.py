"""The SQLite write-ahead log is reset, not only checkpointed (docs/reliability/soak.md: under steady load a
PASSIVE checkpoint alone let the log grow without end, ~25 MB/s under the server benchmark, and the server's
memory with it). Real SQLite files on disk."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from sqlalchemy import text

from server.database import Database


def _db(tmp_path: Path) -> tuple[Database, Path]:
    db = Database(f"sqlite:///{tmp_path / 'server.db'}")
    with db.write_conn() as conn:
        conn.execute(text("CREATE TABLE t (id INTEGER PRIMARY KEY, body TEXT)"))
    return db, tmp_path / "server.db-wal"


def _write(db: Database, rows: int) -> None:
    for i in range(rows):
        with db.write_conn() as conn:
            conn.execute(text("INSERT INTO t (body) VALUES (:b)"), {"b": "x" * 500 + str(i)})


def test_a_checkpoint_empties_the_log(tmp_path: Path) -> None:
    db, wal = _db(tmp_path)
    try:
        _write(db, 200)
        assert wal.stat().st_size > 100_000
        assert db.checkpoint() is True
        assert wal.stat().st_size == 0
        _write(db, 1)
        with db.read() as s:
            assert s.execute(text("SELECT count(*) FROM t")).scalar_one() == 201
    finally:
        db.dispose()


def test_a_reader_inside_the_log_delays_the_reset_and_loses_nothing(tmp_path: Path) -> None:
    """A reader whose snapshot began in the log keeps it (its view must stay valid); the reset gives up
    after its short wait instead of stalling writers, and succeeds once the reader is gone."""
    db, wal = _db(tmp_path)
    reader = sqlite3.connect(tmp_path / "server.db")
    try:
        _write(db, 50)
        reader.execute("BEGIN")
        assert reader.execute("SELECT count(*) FROM t").fetchone() == (50,)  # snapshot inside the log
        _write(db, 50)
        assert db.checkpoint() is False
        assert wal.stat().st_size > 0
        assert reader.execute("SELECT count(*) FROM t").fetchone() == (50,)  # its view is intact
        reader.execute("COMMIT")
        assert db.checkpoint() is True
        assert wal.stat().st_size == 0
        with db.read() as s:
            assert s.execute(text("SELECT count(*) FROM t")).scalar_one() == 100
    finally:
        reader.close()
        db.dispose()
