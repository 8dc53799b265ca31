"""Whether the server's database can still grow: a write refused for want of space (a full disk, or the
SQLite size limit ``sqlite_max_mb``) is answered 507 with the reason, and ``/healthz`` fails until a write
succeeds again (space was freed: the robots' next uploads find it).

Recognised: SQLite's ``SQLITE_FULL`` ("database or disk is full"), PostgreSQL's ``disk_full`` (SQLSTATE
53100) and ``ENOSPC`` from the operating system, wherever they sit in the exception chain.
"""

from __future__ import annotations

import errno
import sqlite3
import threading
import time

__all__ = ["StorageState", "disk_full_reason"]

_PG_DISK_FULL = "53100"


def disk_full_reason(exc: BaseException) -> str | None:
    """The reason when ``exc`` (or what caused it) says the database has no space left, else None."""
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        if isinstance(e, sqlite3.Error) and (
            getattr(e, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL or "disk is full" in str(e)
        ):
            return f"SQLite: {e}"
        if getattr(e, "sqlstate", None) == _PG_DISK_FULL or getattr(e, "pgcode", None) == _PG_DISK_FULL:
            return f"PostgreSQL: {str(e).strip().splitlines()[0]}"
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:
            return f"{e.strerror} ({e.filename or 'the database'})"
        todo.extend([getattr(e, "orig", None), e.__cause__, e.__context__])
    return None


class StorageState:
    """The last write's verdict on space: :meth:`problem` is the reason and since when (Unix s) while the
    last write was refused for want of space, else None. Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._problem: tuple[str, float] | None = None

    def failed(self, reason: str) -> None:
        with self._lock:
            if self._problem is None:
                self._problem = (reason, time.time())

    def succeeded(self) -> None:
        if self._problem is not None:
            with self._lock:
                self._problem = None

    def problem(self) -> tuple[str, float] | None:
        with self._lock:
            return self._problem
