"""The SQLite write path (server.writer) on a real database file: a small job runs on the event loop's
thread; while another thread holds the write queue the loop goes on serving, and the job then still runs on
the loop's thread (not moved to the thread pool, where the following uploads would follow it); a heavy job
runs in the thread pool. Ordering is shown with events, not timing."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Connection, text

from server.database import Database
from server.writer import WriteBatcher


@pytest.fixture
def db(tmp_path: Path) -> Iterator[Database]:
    database = Database(f"sqlite:///{tmp_path / 'server.db'}")
    with database.write_conn() as conn:
        conn.execute(text("CREATE TABLE t (id INTEGER PRIMARY KEY, who TEXT)"))
    yield database
    database.dispose()


def _insert(who: str) -> Callable[[Connection], tuple[str, int]]:
    def job(conn: Connection) -> tuple[str, int]:
        conn.execute(text("INSERT INTO t (who) VALUES (:w)"), {"w": who})
        return who, threading.get_ident()

    return job


def test_a_small_job_waits_for_another_writer_without_holding_the_loop(db: Database) -> None:
    writer = WriteBatcher(db)
    holding, release = threading.Event(), threading.Event()

    def other_writer() -> None:  # e.g. a checkpoint or a heavy upload in the thread pool
        with db.write_conn() as conn:
            conn.execute(text("INSERT INTO t (who) VALUES ('other')"))
            holding.set()
            release.wait(30)

    async def scenario() -> tuple[int, list[str], tuple[str, int], tuple[str, int]]:
        loop_thread = threading.get_ident()
        other = threading.Thread(target=other_writer)
        other.start()
        await asyncio.to_thread(holding.wait, 30)
        upload = asyncio.ensure_future(writer.submit(_insert("first")))
        second = asyncio.ensure_future(writer.submit(_insert("second")))
        served: list[str] = []
        for _ in range(5):  # the loop keeps turning while both jobs wait for the write queue
            await asyncio.sleep(0)
            served.append("tick")
        assert not upload.done() and not second.done()
        release.set()
        first_result, second_result = await upload, await second
        await asyncio.to_thread(other.join, 30)
        return loop_thread, served, first_result, second_result

    try:
        loop_thread, served, first, second = asyncio.run(scenario())
    finally:
        release.set()
        writer.close()
    assert served == ["tick"] * 5
    assert first == ("first", loop_thread) and second == ("second", loop_thread)  # inline, on the loop
    with db.read() as s:
        rows = [r[0] for r in s.execute(text("SELECT who FROM t ORDER BY id"))]
    assert rows[0] == "other" and sorted(rows[1:]) == ["first", "second"]


def test_a_heavy_job_runs_in_the_thread_pool(db: Database) -> None:
    writer = WriteBatcher(db)

    async def scenario() -> tuple[int, tuple[str, int]]:
        return threading.get_ident(), await writer.submit(_insert("heavy"), heavy=True)

    try:
        loop_thread, (who, thread) = asyncio.run(scenario())
    finally:
        writer.close()
    assert who == "heavy" and thread != loop_thread


def test_behind_a_long_write_only_the_first_job_blocks_the_loop(db: Database) -> None:
    """Each job that finds the write queue taken may block the loop for INLINE_WAIT_S; the jobs that come
    while one already waits off the loop do not (behind a 1 s write, 200 uploads/s would otherwise keep the
    loop blocked all along)."""
    writer = WriteBatcher(db)
    holding, release = threading.Event(), threading.Event()
    timeouts: list[float] = []
    real = db.try_write_conn

    def recording(timeout_s: float = 0.0) -> Any:
        timeouts.append(timeout_s)
        return real(timeout_s)

    def long_writer() -> None:
        with db.write_conn():
            holding.set()
            release.wait(30)

    async def scenario() -> list[tuple[str, int]]:
        other = threading.Thread(target=long_writer)
        other.start()
        await asyncio.to_thread(holding.wait, 30)
        jobs = [asyncio.ensure_future(writer.submit(_insert(f"u{i}"))) for i in range(10)]
        for _ in range(5):
            await asyncio.sleep(0)
        blocking_tries = sum(1 for t in timeouts if t > 0)
        release.set()
        done = await asyncio.gather(*jobs)
        await asyncio.to_thread(other.join, 30)
        assert blocking_tries == 1, timeouts
        return done

    db.try_write_conn = recording  # type: ignore[method-assign]
    try:
        done = asyncio.run(scenario())
    finally:
        release.set()
        writer.close()
    assert sorted(who for who, _ in done) == sorted(f"u{i}" for i in range(10))
