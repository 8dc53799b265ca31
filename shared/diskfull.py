"""Whether an exception says the disk (or the database's size limit) is full: the server's database
(:mod:`server.storage`) and the robot's Robot DB (:mod:`robot_agent.mapping`) both tell a full disk from
other failures with it, to pause and report instead of failing.

Recognised: SQLite's ``SQLITE_FULL`` ("database or disk is full"), PostgreSQL's ``disk_full`` (SQLSTATE
53100) and ``ENOSPC`` from the operating system, wherever they sit in the exception chain. O(chain).
"""

from __future__ import annotations

import errno
import sqlite3

__all__ = ["disk_full_reason"]

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
