"""Engine and sessions for the server database: any SQLAlchemy URL; SQLite files get WAL and foreign keys."""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError
from sqlalchemy.orm import Session, sessionmaker

from server.errors import ServerError, StorageFullError
from server.storage import StorageState, disk_full_reason

__all__ = ["PG_MAX_OVERFLOW", "PG_POOL_SIZE", "Database", "normalize_url"]

log = logging.getLogger(__name__)

#: PostgreSQL: connections a server process keeps (the writer, request threads) and may open beyond them;
#: with the notice listener's own connection a process uses at most PG_POOL_SIZE + PG_MAX_OVERFLOW + 1 of
#: the database's max_connections (docs/fleet-scale.md).
PG_POOL_SIZE = 20
PG_MAX_OVERFLOW = 20
#: SQLite: how long a writer waits for a lock (ms), and how long a log reset waits for readers (ms).
BUSY_TIMEOUT_MS = 30_000
WAL_RESET_WAIT_MS = 200
#: PostgreSQL: how a read-only unit of work runs (Database.read).
_SNAPSHOT: dict[str, Any] = {"isolation_level": "REPEATABLE READ", "postgresql_readonly": True}


def normalize_url(url: str) -> str:
    """``url`` as SQLAlchemy should see it: a bare file path becomes a SQLite URL, ``postgresql://`` uses
    psycopg 3. Raises :class:`ServerError` naming the URL when it cannot be read."""
    if "://" not in url:
        return f"sqlite:///{Path(url).expanduser()}"
    try:
        parsed = make_url(url)
    except ArgumentError:
        raise ServerError(
            f"database URL {url!r} is not a SQLAlchemy URL (e.g. sqlite:///server.db)"
        ) from None
    if parsed.drivername in ("postgresql", "postgres"):
        parsed = parsed.set(drivername="postgresql+psycopg")
    return parsed.render_as_string(hide_password=False)


class Database:
    """One engine and its session factory; a session is a unit of work: commit on success, else roll back."""

    def __init__(self, url: str, *, sqlite_max_mb: float | None = None) -> None:
        self.url = normalize_url(url)
        self.storage = StorageState()  # whether the last write found space (server.storage)
        self.is_sqlite = self.url.startswith("sqlite")
        kwargs: dict[str, Any] = {}
        if self.is_sqlite:
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
            # as many kept connections as the thread pool has threads (anyio's 40): a connection above
            # pool_size is closed when returned, and opening one runs the pragmas again (100 waiting
            # long-polls re-reading every poll_recheck_s opened and closed ~20 a second at pool_size 20)
            kwargs.update(pool_size=40, max_overflow=20)
        else:
            kwargs.update(pool_size=PG_POOL_SIZE, max_overflow=PG_MAX_OVERFLOW, pool_pre_ping=True)
        try:
            self.engine: Engine = create_engine(self.url, **kwargs)
        except (ArgumentError, ImportError) as exc:
            shown = make_url(self.url).render_as_string(hide_password=True)
            raise ServerError(
                f"database URL {shown!r} cannot be used ({exc}); expected sqlite:///FILE or "
                "postgresql://USER@HOST/DB"
            ) from None
        if self.is_sqlite:
            event.listen(self.engine, "connect", functools.partial(_sqlite_pragmas, max_mb=sqlite_max_mb))
        self._factory = sessionmaker(self.engine, expire_on_commit=False)
        # SQLite has one writer at a time: queue writers of this process here instead of in busy-waits.
        self._write_lock = threading.Lock() if self.is_sqlite else None
        self._reset_misses = 0

    @contextmanager
    def _space(self) -> Iterator[None]:
        """A write's verdict on space (:mod:`server.storage`): refused for want of it, the error becomes
        :class:`StorageFullError` naming the reason."""
        try:
            yield
        except StorageFullError:
            raise
        except Exception as exc:
            reason = disk_full_reason(exc)
            if reason is None:
                raise
            self.storage.failed(reason)
            log.error("database full: %s", reason)
            raise StorageFullError(
                f"the server's database has no space left ({reason}): nothing of this request was "
                "stored; free space on its disk (or raise sqlite_max_mb) and send it again"
            ) from None
        self.storage.succeeded()

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A unit of work that may write."""
        if self._write_lock is None:
            with self._space(), self._factory() as session, session.begin():
                yield session
            return
        with self._space(), self._write_lock, self._factory() as session, session.begin():
            yield session

    @contextmanager
    def write_conn(self) -> Iterator[Connection]:
        """A Core connection in a transaction that may write (for the hot paths: no ORM overhead)."""
        if self._write_lock is None:
            with self._space(), self.engine.begin() as conn:
                yield conn
            return
        with self._space(), self._write_lock, self.engine.begin() as conn:
            yield conn

    @contextmanager
    def write_on(self, conn: Connection) -> Iterator[Connection]:
        """:meth:`write_conn` on a connection the caller keeps open across transactions (the PostgreSQL
        writer thread's own: :class:`server.writer.WriteBatcher`). Not for SQLite (no write lock here)."""
        if self._write_lock is not None:
            raise ValueError("SQLite's writes go through write_conn (its write lock)")
        with self._space(), conn.begin():
            yield conn

    @contextmanager
    def try_write_conn(self, timeout_s: float = 0.0) -> Iterator[Connection | None]:
        """:meth:`write_conn` if this process's SQLite write queue is free now or within ``timeout_s``, else
        ``None`` (the caller, on the event loop, must not wait for another thread's long write). Other
        databases: like :meth:`write_conn`."""
        if self._write_lock is None:
            with self._space(), self.engine.begin() as conn:
                yield conn
            return
        lock = self._write_lock
        if not (lock.acquire(timeout=timeout_s) if timeout_s > 0 else lock.acquire(blocking=False)):
            yield None
            return
        try:
            with self._space(), self.engine.begin() as conn:
                yield conn
        finally:
            self._write_lock.release()

    def wait_writable(self) -> None:
        """Block until this process's SQLite write queue is free (returns at once on other databases); the
        caller then tries :meth:`try_write_conn` again (another writer may come first)."""
        if self._write_lock is not None:
            with self._write_lock:
                pass

    @contextmanager
    def read(self) -> Iterator[Session]:
        """A unit of work that only reads (never takes the SQLite write queue), on one snapshot of the
        database: every statement in it sees the same committed state, so a rollout read while its driver
        commits a tick never shows the robots' new states beside the rollout's old wave.

        PostgreSQL: ``REPEATABLE READ READ ONLY`` (its default, READ COMMITTED, takes a new snapshot per
        statement; a read-only transaction at this level never fails to serialise). SQLite: an explicit
        ``BEGIN`` (the driver otherwise runs each SELECT in its own implicit transaction); in WAL mode the
        snapshot is taken at the first read and writers are not blocked."""
        with self._factory() as session, session.begin():
            if self.is_sqlite:
                session.connection().exec_driver_sql("BEGIN")
            else:
                session.connection(execution_options=_SNAPSHOT)
            yield session

    def checkpoint(self) -> bool:
        """Fold the SQLite write-ahead log back into the database and start it again from empty; True when
        the log was reset (always True on other databases).

        A PASSIVE checkpoint alone never blocks, but under steady load it never lets the log restart
        either: some reader always holds a snapshot that began in the log, so the file grew by ~25 MB/s
        under the server benchmark (1.6 GB after a minute, and the process's memory with its index).
        So: PASSIVE first (the bulk of the copying, writers go on), then TRUNCATE under this process's
        write lock, waiting at most ``WAL_RESET_WAIT_MS`` for readers to leave the log (they are short);
        if they do not, the log is reset at the next call. Writers of this process wait meanwhile
        (milliseconds)."""
        if not self.is_sqlite:
            return True
        assert self._write_lock is not None
        with self.engine.connect() as conn:
            conn.exec_driver_sql("PRAGMA wal_checkpoint(PASSIVE)")
            with self._write_lock:
                conn.exec_driver_sql(f"PRAGMA busy_timeout={WAL_RESET_WAIT_MS}")
                try:
                    busy, _log, _done = conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)").one()
                finally:
                    conn.exec_driver_sql(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        if busy:
            self._reset_misses += 1
            (log.warning if self._reset_misses % 30 == 0 else log.debug)(
                "the write-ahead log could not be reset (%d tries in a row): readers stayed in it",
                self._reset_misses,
            )
        else:
            self._reset_misses = 0
        return not busy

    def dispose(self) -> None:
        self.engine.dispose()


def _sqlite_pragmas(dbapi_connection: Any, _record: Any, *, max_mb: float | None = None) -> None:
    cursor = dbapi_connection.cursor()
    if max_mb is not None:  # a size limit: beyond it writes fail as on a full disk (SQLITE_FULL)
        page = int(cursor.execute("PRAGMA page_size").fetchone()[0])
        cursor.execute(f"PRAGMA max_page_count={max(1, int(max_mb * 1e6 / page))}")
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
    # No checkpoint inside a request's commit (it stalled uploads by 100+ ms): the app checkpoints the
    # write-ahead log in the background instead (Database.checkpoint).
    cursor.execute("PRAGMA wal_autocheckpoint=0")
    cursor.close()
