"""One pipeline across a write batch (server/pgbatch.py): which statements may wait in it, a read through
SQLAlchemy sees every write queued before it, the batch commits all its writes, and a queued statement's
error (seen only when the pipeline is answered) rolls the batch back and its jobs are applied one by one,
so only the bad job fails. Against real PostgreSQL, with the writer's threads."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from sqlalchemy import Connection, insert, text
from sqlalchemy.exc import SQLAlchemyError

from server import pgrows
from server.database import Database
from server.errors import ServerError
from server.migrate import upgrade
from server.models import Robot
from server.pgbatch import BatchPipeline, queueable
from server.pgrows import driver
from server.writer import WriteBatcher
from tests.server.live import database_url


@pytest.mark.parametrize(
    ("statement", "queued"),
    [
        ("INSERT INTO t (k) VALUES (1)", True),
        ("  insert into t (k) values (1)", True),
        ("UPDATE robots SET mode='online' WHERE id = 1", True),
        ("DELETE FROM map_segments WHERE robot_id = %s", True),
        ("SELECT pg_notify(%s, %s)", True),
        ("INSERT INTO t (k) VALUES (1) RETURNING id", False),
        ("UPDATE t SET k = 2\nRETURNING t.id", False),
        ("SELECT 1", False),
        ("SELECT pg_advisory_xact_lock(1, 2)", False),
        ("WITH x AS (DELETE FROM t RETURNING id) SELECT count(*) FROM x", False),
        ("COMMIT", False),
    ],
)
def test_only_writes_that_return_nothing_wait_in_the_pipeline(statement: str, queued: bool) -> None:
    assert queueable(statement) is queued


@pytest.fixture
def pg(tmp_path: Path) -> Iterator[Database]:
    db = Database(database_url("postgresql", tmp_path))
    with db.write_conn() as conn:
        conn.execute(text("CREATE TABLE u (id INTEGER PRIMARY KEY, job TEXT)"))
    yield db
    db.dispose()


def _rows(db: Database) -> list[tuple[int, str]]:
    with db.write_conn() as conn:
        return [(int(r[0]), str(r[1])) for r in conn.execute(text("SELECT id, job FROM u ORDER BY id"))]


def test_a_read_in_the_batch_sees_the_writes_queued_before_it(pg: Database) -> None:
    with pg.write_conn() as conn, BatchPipeline(conn) as pipe:
        conn.execute(text("INSERT INTO u VALUES (1, 'a')"))
        assert driver(conn).pgconn.pipeline_status, "the insert waits in a pipeline"
        assert conn.execute(text("SELECT job FROM u WHERE id = 1")).scalar() == "a"
        assert not driver(conn).pgconn.pipeline_status, "the read ended the pipeline first"
        pipe.resume()
        conn.execute(text("INSERT INTO u VALUES (2, 'b')"))
        assert driver(conn).pgconn.pipeline_status
    assert _rows(pg) == [(1, "a"), (2, "b")]


def test_a_queued_statements_error_is_sqlalchemys_and_nothing_is_written(pg: Database) -> None:
    def batch() -> None:
        with pg.write_conn() as conn, BatchPipeline(conn):
            conn.execute(text("INSERT INTO u VALUES (1, 'a')"))
            conn.execute(text("INSERT INTO u VALUES (1, 'again')"))  # the duplicate is seen at the end

    with pytest.raises(SQLAlchemyError) as err:
        batch()
    assert "duplicate key" in str(err.value)
    assert _rows(pg) == []


def test_a_bad_job_in_a_batch_fails_alone(pg: Database) -> None:
    """Three jobs in one batch, the second's insert refused by the database only when the pipeline is
    answered: the batch is rolled back and applied job by job; the first and third are written."""
    writer = WriteBatcher(pg, writers=1)
    gate, inside = threading.Event(), threading.Event()

    def blocker(conn: Connection) -> None:
        inside.set()
        gate.wait(30)  # holds the writer thread until every job below is queued

    def job(row: int, name: str) -> Callable[[Connection], str]:
        def fn(conn: Connection) -> str:
            conn.execute(text("INSERT INTO u VALUES (:id, :job)"), {"id": row, "job": name})
            return name

        return fn

    async def go() -> list[str | BaseException]:
        first = asyncio.ensure_future(writer.submit(blocker))
        assert await asyncio.get_running_loop().run_in_executor(None, inside.wait, 30)
        jobs = [writer.submit(job(1, "a")), writer.submit(job(1, "dup")), writer.submit(job(2, "c"))]
        waiting = asyncio.gather(*jobs, return_exceptions=True)
        await asyncio.sleep(0)  # one loop turn: each submission above has queued its job
        gate.set()
        await first
        return list(await waiting)

    try:
        got = asyncio.run(go())
    finally:
        writer.close()
    assert got[0] == "a" and got[2] == "c"
    assert isinstance(got[1], ServerError) and "refused the write" in str(got[1])
    assert _rows(pg) == [(1, "a"), (2, "c")]


def test_a_robots_second_upload_in_a_batch_reads_the_first_ones_walls(tmp_path: Path) -> None:
    """Two uploads of one robot in one batch: the second is not prefetched, so it takes its lock and reads
    in the batch's pipeline (psycopg's own cursors): it must see the walls the first one queued."""
    db = Database(database_url("postgresql", tmp_path))
    upgrade(db.engine)
    try:
        with db.write_conn() as conn:
            added = conn.execute(insert(Robot).values(name="b", token_hash="1" * 64).returning(Robot.id))
            rid = int(added.scalar_one())
        with db.write_conn() as conn, BatchPipeline(conn):
            pgrows.upsert_segments(conn, [(rid, 7, 0.0, 0.0, 1.0, 1.0, 1)])  # the first upload's walls
            assert driver(conn).pgconn.pipeline_status
            reads = pgrows.lock_and_read(conn, 1, rid, "k", delta=pgrows.DeltaProbe([7, 8], 1))
        assert reads.undo is not None and [tuple(r) for r in reads.undo.touched] == [(7, 0.0, 0.0, 1.0, 1.0)]
    finally:
        db.dispose()
