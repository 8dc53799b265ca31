"""The hot write path (map uploads). On SQLite a small job runs on the caller's (event-loop) thread, in its
own transaction: at once when no other thread of this process is writing or that thread is done within
``INLINE_WAIT_S``, else as soon as it is done (waited for in a thread of its own, so the event loop never
waits behind a long write); a ``heavy`` job runs in the thread pool. On other databases one writer thread
applies queued jobs in batches, one transaction per batch (group commit); a ``heavy`` job (a near-limit
upload) runs alone in the thread pool instead, so it does not hold up the batch behind it.

A database has one writer at a time anyway (SQLite) or pays a round trip per commit (PostgreSQL), so many
request threads writing in turn only add thread switches and commits. Jobs are functions of a Core
connection. A job must raise its expected errors (conflicts) before it writes anything; then its error goes
to its caller alone and the batch commits the others. An unexpected database error rolls the batch back and
its jobs are retried one by one, so one bad job never sinks the rest.

Cost: one thread hop and ``1/batch`` of a commit per job. On PostgreSQL a batch's statements go in one
pipeline (:mod:`server.pgbatch`): a job's Python runs while the database applies the job before it.

On PostgreSQL, keep every write of robot rows that may run beside the upload batches to one robot per
transaction or route it through :meth:`WriteBatcher.submit` with that robot's ``key`` (as
:meth:`WriteBatcher.shard` and the last-seen flush do): a transaction that locks two robots' rows while two
writer threads each hold one of them deadlocks (PostgreSQL aborts one after ``deadlock_timeout``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Generic, TypeVar

from fastapi.concurrency import run_in_threadpool
from sqlalchemy import Connection
from sqlalchemy.exc import SQLAlchemyError

from server.database import Database
from server.errors import ServerError, StorageFullError
from server.pgbatch import BatchPipeline
from server.pgrows import pipelined

__all__ = ["PG_WRITERS", "WriteBatcher"]

log = logging.getLogger(__name__)
T = TypeVar("T")
_STOP = object()
#: SQLite: how long a small job blocks the event loop for another thread's write before it waits off the
#: loop (s). A short block is the quicker: blocked, the loop lets go of the GIL and the other writer (a
#: checkpoint, a control message) finishes in milliseconds; waited for off the loop, that writer competes
#: for the GIL with the busy loop and held the write queue ~1 s each time under server_load (with every
#: upload of that second waiting for it).
INLINE_WAIT_S = 0.05
#: Writer threads on a database other than SQLite by default (each holds one connection of the pool while it
#: writes; the server's setting ``pg_writers``). More threads wait for the database side by side but compete
#: for the GIL with everything else. Under ``benchmarks/server_load.py`` (100 robots, PostgreSQL, one
#: process), once a write batch ran as one pipeline (:mod:`server.pgbatch`), 1 thread took 199.6 uploads/s
#: with a control message reaching its long-poll in 38 ms (median); 2 threads were worse (p50 377-446 ms
#: against 54-75, messages 114-127 ms against 49-52, alternating runs; docs/fleet-scale.md). One keeps
#: control messages within their 50 ms; more processes add uploads/s.
PG_WRITERS = 1
#: A write batch slower than this is logged (debug level), in milliseconds.
_SLOW_BATCH_MS = 30.0


class _Job(Generic[T]):
    __slots__ = ("fn", "future", "key", "prefetch")

    def __init__(
        self, fn: Callable[[Connection], T], key: int, prefetch: Callable[[Connection], None] | None
    ) -> None:
        self.fn = fn
        self.key = key
        self.prefetch = prefetch
        self.future: Future[T] = Future()


class WriteBatcher:
    """Runs ``submit``-ted jobs on ``writers`` threads (1 on SQLite; default :data:`PG_WRITERS`), up to
    ``max_batch`` per transaction; a job's ``key`` picks its thread (``key % writers``)."""

    def __init__(self, db: Database, max_batch: int = 8, writers: int | None = None) -> None:
        if writers is None:
            writers = 1 if db.is_sqlite else PG_WRITERS
        if writers < 1:
            raise ValueError(f"writers={writers}: expected at least 1 writer thread")
        self._db = db
        self._max = max_batch
        self._queues: list[queue.SimpleQueue[Any]] = [queue.SimpleQueue() for _ in range(writers)]
        self._threads = [
            threading.Thread(target=self._run, args=(q,), name=f"linemap-writer-{i}", daemon=True)
            for i, q in enumerate(self._queues)
        ]
        for thread in self._threads:
            thread.start()
        self._stats_lock = threading.Lock()
        self.batches = 0
        self.jobs = 0
        # SQLite writes are short local I/O: done on the event loop they avoid handing the GIL back and
        # forth with a writer thread (measured with 100 robots: upload p95 ~80 -> ~29 ms).
        self.inline = db.is_sqlite
        self._writable: asyncio.Future[None] | None = None
        self._waiter = ThreadPoolExecutor(1, thread_name_prefix="linemap-write-wait")

    @property
    def shards(self) -> int:
        """The number of writer threads (``key`` values ``0 .. shards - 1`` reach each one)."""
        return len(self._queues)

    def shard(self, key: int) -> int:
        """The writer thread that applies the jobs of ``key``."""
        return key % len(self._queues)

    async def submit(
        self,
        fn: Callable[[Connection], T],
        *,
        heavy: bool = False,
        key: int = 0,
        prefetch: Callable[[Connection], None] | None = None,
    ) -> T:
        """Run ``fn(conn)`` (on SQLite inline, once this process's write queue is free; else in the next
        batch of the writer thread of ``key``, the robot whose rows it writes); its result, or its error.
        ``heavy``: a long job (many rows), kept off the event loop and out of the batches.

        ``prefetch(conn)``: in a batch, called before the batch's jobs run, inside one pipeline for the
        whole batch (:func:`server.pgrows.pipelined`), to queue statements whose answers ``fn`` then
        takes (an upload's lock and reads: one round trip for the batch instead of one per job). Only for
        the first job of each key in a batch (a later one must read after the earlier one's writes), and
        not at all inline or for a heavy job: ``fn`` must do its reads itself when it was not called."""
        while self.inline and not heavy:
            # Block the loop only when no job waits off the loop yet: behind a long write, each upload
            # arriving would otherwise block it again.
            waiting = self._writable is not None and not self._writable.done()
            with self._db.try_write_conn(0.0 if waiting else INLINE_WAIT_S) as conn:
                if conn is not None:
                    return fn(conn)
            # Another thread is writing a long job: wait for it off the loop (the loop goes on), then write
            # here. Not the job itself in the thread pool: it would hold the write queue across thread
            # switches, the next uploads would find it taken and follow it there, and the whole stream of
            # uploads would move to the pool for good (measured: 26% of the server's samples).
            # One waiting thread of its own for all waiting jobs, not the shared thread pool: under load the
            # pool is full of long-poll reads, and a wait queued behind them held uploads for seconds.
            if self._writable is None or self._writable.done():
                loop = asyncio.get_running_loop()
                self._writable = loop.run_in_executor(self._waiter, self._db.wait_writable)
            await asyncio.shield(self._writable)
        if heavy:
            return await run_in_threadpool(self._alone, fn)
        job: _Job[T] = _Job(fn, key, prefetch)
        self._queues[self.shard(key)].put(job)
        return await asyncio.wrap_future(job.future)

    def _alone(self, fn: Callable[[Connection], T]) -> T:
        with self._db.write_conn() as conn:
            return fn(conn)

    def close(self) -> None:
        for q in self._queues:
            q.put(_STOP)
        for thread in self._threads:
            thread.join(timeout=10)
        self._waiter.shutdown(wait=False, cancel_futures=True)

    def _run(self, jobs: queue.SimpleQueue[Any]) -> None:
        own = _OwnConnection(self._db)
        try:
            self._serve(jobs, own)
        finally:
            own.drop()

    def _serve(self, jobs: queue.SimpleQueue[Any], own: _OwnConnection) -> None:
        while True:
            first = jobs.get()
            if first is _STOP:
                return
            batch = [first]
            while len(batch) < self._max:
                try:
                    nxt = jobs.get_nowait()
                except queue.Empty:
                    break
                if nxt is _STOP:
                    jobs.put(_STOP)
                    break
                batch.append(nxt)
            started = time.perf_counter()
            self._apply(batch, own)
            took_ms = (time.perf_counter() - started) * 1e3
            if took_ms > _SLOW_BATCH_MS:
                log.debug("write batch of %d jobs took %.0f ms", len(batch), took_ms)

    def _apply(self, batch: list[_Job[Any]], own: _OwnConnection, retried: bool = False) -> None:
        results: list[tuple[_Job[Any], Any, BaseException | None]] = []
        try:
            with own.transaction() as conn, BatchPipeline(conn) as pipe:
                _prefetch(conn, batch)
                for job in batch:
                    pipe.resume()  # (a job's read ended the batch's pipeline: server.pgbatch)
                    try:
                        results.append((job, job.fn(conn), None))
                    except ServerError as exc:  # expected, raised before the job wrote anything
                        results.append((job, None, exc))
        except StorageFullError as exc:  # no space: every job of the batch is refused with the reason
            for job in batch:
                _settle(job, None, exc)
            return
        except SQLAlchemyError:
            if own.drop() and not retried:  # the connection broke (a restart, a cut): once more on a new one
                log.warning("the writer's database connection broke; applying its batch again on a new one")
                self._apply(batch, own, retried=True)
                return
            if len(batch) == 1:
                log.exception("write failed")
                _settle(batch[0], None, ServerError("the database refused the write; see the server log"))
                return
            log.warning("a batch of %d writes failed; retrying them one by one", len(batch))
            for job in batch:
                self._apply([job], own, retried=True)
            return
        except BaseException as exc:  # a bug in a job: fail the batch's callers, keep the writer alive
            log.exception("unexpected error in a write batch")
            for job in batch:
                _settle(job, None, exc)
            return
        with self._stats_lock:
            self.batches += 1
            self.jobs += len(batch)
        for job, value, error in results:
            _settle(job, value, error)


class _OwnConnection:
    """A writer thread's own connection, kept across its batches: no pool checkout (and its ping) per
    batch, and one database backend whose caches and prepared statements stay warm (from the pool, each
    batch got the next of up to 40 connections, each preparing every statement anew; at start each was
    opened during the first burst). After a database error it is dropped (returned to the pool, which
    checks it before handing it out again) and the next batch takes another."""

    def __init__(self, db: Database) -> None:
        self._db = db
        self._conn: Connection | None = None

    @contextmanager
    def transaction(self) -> Iterator[Connection]:
        """A write transaction on the kept connection (taken from the pool when there is none); on SQLite
        (whose writes take its write lock) one from the pool each time."""
        if self._db.is_sqlite:
            with self._db.write_conn() as conn:
                yield conn
            return
        if self._conn is None or self._conn.closed or self._conn.invalidated:
            self.drop()
            self._conn = self._db.engine.connect()
        with self._db.write_on(self._conn) as conn:
            yield conn

    def drop(self) -> bool:
        """Give the connection back to the pool; whether it was broken (the database closed it)."""
        conn, self._conn = self._conn, None
        if conn is None:
            return False
        broken = conn.invalidated or _broken(conn)
        with contextlib.suppress(SQLAlchemyError):
            conn.close()
        return broken


def _broken(conn: Connection) -> bool:
    try:
        return bool(getattr(conn.connection.driver_connection, "broken", False))
    except SQLAlchemyError:
        return True


def _prefetch(conn: Connection, batch: list[_Job[Any]]) -> None:
    """Call the batch's ``prefetch`` functions (the first job of each key only) in one pipeline."""
    first: dict[int, _Job[Any]] = {}
    for job in batch:
        first.setdefault(job.key, job)
    todo = [job.prefetch for job in first.values() if job.prefetch is not None]
    if not todo:
        return
    with pipelined(conn):
        for prefetch in todo:
            prefetch(conn)


def _settle(job: _Job[Any], value: Any, error: BaseException | None) -> None:
    if job.future.done():
        return
    if error is not None:
        job.future.set_exception(error)
    else:
        job.future.set_result(value)
