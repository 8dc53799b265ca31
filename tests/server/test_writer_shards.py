"""The write path's writer threads on PostgreSQL (server.writer): a job's key (the robot) picks its thread,
so one robot's jobs run on one thread in the order submitted and different robots' jobs run side by side;
the last-seen flush is split the same way (each writer writes its own robots' rows)."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from datetime import datetime
from pathlib import Path

import pytest
from sqlalchemy import Connection, insert, select, text

from server.database import Database
from server.deps import AppState
from server.migrate import upgrade
from server.models import Robot
from server.settings import Settings
from server.writer import WriteBatcher
from tests.server.live import database_url


@pytest.fixture
def pg(tmp_path: Path) -> Iterator[Database]:
    db = Database(database_url("postgresql", tmp_path))
    with db.write_conn() as conn:
        conn.execute(text("CREATE TABLE t (id SERIAL PRIMARY KEY, k INTEGER, n INTEGER)"))
    yield db
    db.dispose()


def _job(k: int, n: int, log: list[tuple[int, int, int]]) -> Callable[[Connection], int]:
    def job(conn: Connection) -> int:
        conn.execute(text("INSERT INTO t (k, n) VALUES (:k, :n)"), {"k": k, "n": n})
        log.append((k, n, threading.get_ident()))
        return n

    return job


WRITERS = 4


def test_a_keys_jobs_run_on_one_thread_in_order_and_keys_spread(pg: Database) -> None:
    writer = WriteBatcher(pg, writers=WRITERS)
    assert writer.shards == WRITERS
    log: list[tuple[int, int, int]] = []

    async def go() -> list[int]:
        jobs = [writer.submit(_job(k, n, log), key=k) for n in range(10) for k in range(2 * WRITERS)]
        return await asyncio.gather(*jobs)

    try:
        assert asyncio.run(go()) == [n for n in range(10) for _ in range(2 * WRITERS)]
    finally:
        writer.close()
    threads = {k: {ident for kk, _, ident in log if kk == k} for k in range(2 * WRITERS)}
    assert all(len(t) == 1 for t in threads.values())  # one thread per key
    assert len({next(iter(threads[k])) for k in range(WRITERS)}) == WRITERS  # keys spread
    for k in range(2 * WRITERS):
        assert threads[k] == threads[k % WRITERS]  # same shard, same thread
        assert [n for kk, n, _ in log if kk == k] == list(range(10))  # in the order submitted
    with pg.read() as s:
        stored = s.execute(text("SELECT k, n FROM t ORDER BY id")).all()
    for k in range(2 * WRITERS):  # committed in that order too
        assert [n for kk, n in stored if kk == k] == list(range(10))


def test_no_writer_threads_is_refused(pg: Database) -> None:
    with pytest.raises(ValueError, match="writers=0"):
        WriteBatcher(pg, writers=0)


def test_the_last_seen_flush_writes_one_shard_at_a_time(tmp_path: Path) -> None:
    url = database_url("postgresql", tmp_path)
    db = Database(url)
    upgrade(db.engine)
    writer = WriteBatcher(db, writers=WRITERS)
    state = AppState(settings=Settings(database_url=url), db=db, writer=writer)
    try:
        with db.write_conn() as conn:
            for i in range(8):
                conn.execute(insert(Robot).values(name=f"r{i}", token_hash=f"{i:064d}"))
        with db.read() as s:
            ids = sorted(s.scalars(select(Robot.id)))
        for rid in ids:
            state.mark_seen(rid)
        state.flush_seen(shard=(1, 4))
        with db.read() as s:
            seen = {int(r[0]): r[1] for r in s.execute(select(Robot.id, Robot.last_seen_at))}
        assert {rid for rid, at in seen.items() if at is not None} == {rid for rid in ids if rid % 4 == 1}
        state.flush_seen()  # the rest, none twice
        with db.read() as s:
            seen = {int(r[0]): r[1] for r in s.execute(select(Robot.id, Robot.last_seen_at))}
        assert all(isinstance(at, datetime) for at in seen.values())  # every robot once the rest is flushed
    finally:
        writer.close()
        db.dispose()


def test_a_batch_prefetches_the_first_job_of_each_key_in_one_pipeline(pg: Database) -> None:
    """Jobs queued while the writer is busy form one batch; its prefetches run before any job, for the
    first job of each key only (a later job of the same key must read after the earlier one's writes)."""
    writer = WriteBatcher(pg, writers=1)
    calls: list[str] = []
    gate, inside = threading.Event(), threading.Event()

    def blocker(conn: Connection) -> None:
        inside.set()
        gate.wait(30)  # holds the writer thread until every job below is queued

    def job(name: str) -> Callable[[Connection], str]:
        def fn(conn: Connection) -> str:
            calls.append(f"run {name}")
            return name

        return fn

    def pre(name: str) -> Callable[[Connection], None]:
        def fn(conn: Connection) -> None:
            conn.exec_driver_sql("SELECT 1")  # a statement in the batch's pipeline
            calls.append(f"prefetch {name}")

        return fn

    async def go() -> list[str]:
        first = asyncio.ensure_future(writer.submit(blocker))
        assert await asyncio.get_running_loop().run_in_executor(None, inside.wait, 30)  # in its own batch
        names = [("a1", 1), ("b1", 2), ("a2", 1), ("c1", 3)]
        jobs = [writer.submit(job(n), key=k, prefetch=pre(n)) for n, k in names]
        plain = writer.submit(job("plain"), key=4)
        waiting = asyncio.gather(*jobs, plain)
        await asyncio.sleep(0)  # one loop turn: each submission above has queued its job
        gate.set()
        await first
        return list(await waiting)

    try:
        assert asyncio.run(go()) == ["a1", "b1", "a2", "c1", "plain"]
    finally:
        writer.close()
    assert calls == [
        "prefetch a1",
        "prefetch b1",
        "prefetch c1",
        "run a1",
        "run b1",
        "run a2",
        "run c1",
        "run plain",
    ]


def _pid_job(n: int) -> Callable[[Connection], int]:
    def job(conn: Connection) -> int:
        conn.execute(text("INSERT INTO t (k, n) VALUES (0, :n)"), {"n": n})
        return int(conn.execute(text("SELECT pg_backend_pid()")).scalar_one())

    return job


def test_a_writer_keeps_its_connection_and_replaces_it_when_the_database_drops_it(pg: Database) -> None:
    """One backend serves a writer's batches (warm caches and prepared statements); when the database
    ends it between batches (a restart, ``pg_terminate_backend``), the next job, alone in its batch, is
    applied on a new connection: the caller sees no error."""
    writer = WriteBatcher(pg, writers=1)

    async def run(n: int) -> int:
        return await writer.submit(_pid_job(n), key=0)

    try:
        pids = [asyncio.run(run(n)) for n in range(4)]
        assert len(set(pids)) == 1
        with pg.write_conn() as conn:
            assert conn.execute(text("SELECT pg_terminate_backend(:p, 10000)"), {"p": pids[0]}).scalar()
        after = asyncio.run(run(4))
    finally:
        writer.close()
    assert after != pids[0]
    with pg.read() as s:
        assert [n for (n,) in s.execute(text("SELECT n FROM t ORDER BY id"))] == [0, 1, 2, 3, 4]
