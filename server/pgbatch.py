"""One psycopg pipeline across a write batch's jobs on PostgreSQL (:class:`server.writer.WriteBatcher`).

Each upload's writes already go in one pipeline (:func:`server.pgrows.pipelined`), but the writer then
waited for the database to finish them before it began the next upload's Python (its checks, its undo
record, its rows): the writer's time per upload was the sum of the two. In one pipeline for the batch the
next upload's Python runs while the database applies the one before: the writer's time per upload tends to
the larger of the two, and a batch costs one wait for the database instead of one per upload.

What keeps it correct:

- a statement that returns rows through SQLAlchemy (which reads its result at once) first ends the
  pipeline: every statement queued before it is answered, so it reads what they wrote (a hook on the
  connection's ``before_cursor_execute``); only writes without ``RETURNING`` and ``SELECT pg_notify(...)``
  (whose row nobody reads) are queued. The next job opens a pipeline again (:meth:`BatchPipeline.resume`);
- reads through psycopg's own cursors (:func:`server.pgrows.queue_lock_and_read`) fetch their answers
  in the pipeline;
- an error of a queued statement is raised when the pipeline ends or the next answer is fetched, as
  SQLAlchemy's error: the writer then rolls the batch back and applies its jobs one by one, as it does
  for any database error in a batch.

Elsewhere (SQLite) a no-op.
"""

from __future__ import annotations

import contextlib
import re
from types import TracebackType
from typing import Any

from sqlalchemy import Connection, event

from server.pgrows import BATCH_KEY, driver, driver_errors

__all__ = ["BatchPipeline", "queueable"]

#: statements that may wait in the pipeline: writes without RETURNING, and the notice (its row unread)
_QUEUEABLE = re.compile(r"\s*(INSERT|UPDATE|DELETE|SELECT pg_notify\()", re.IGNORECASE)
_RETURNING = re.compile(r"\bRETURNING\b", re.IGNORECASE)


def queueable(statement: str) -> bool:
    """Whether SQLAlchemy may run ``statement`` in an open pipeline without reading its answer: a write
    without ``RETURNING``, or ``SELECT pg_notify(...)``. O(len(statement))."""
    return _QUEUEABLE.match(statement) is not None and _RETURNING.search(statement) is None


class BatchPipeline:
    """A context manager around a write batch on ``conn`` (module docstring): :meth:`resume` before each
    job; the pipeline ends (its answers all read) before the block does, so the transaction's commit
    follows every write."""

    def __init__(self, conn: Connection) -> None:
        self._conn = conn
        self._on = conn.dialect.name == "postgresql"
        self._stack: contextlib.ExitStack | None = None

    def __enter__(self) -> BatchPipeline:
        if self._on:
            event.listen(self._conn, "before_cursor_execute", self._before)
            self.resume()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if not self._on:
            return
        try:
            self._end(exc_type, exc, tb)
        finally:
            event.remove(self._conn, "before_cursor_execute", self._before)

    def resume(self) -> None:
        """Open the pipeline again if a read ended it. O(1)."""
        if self._on and self._stack is None:
            stack = contextlib.ExitStack()
            with driver_errors():
                stack.enter_context(driver(self._conn).pipeline())
            self._stack = stack
            self._conn.info[BATCH_KEY] = self

    def settle(self) -> None:
        """End the pipeline now: every queued statement answered (an error among them raised as
        SQLAlchemy's error)."""
        self._end(None, None, None)

    def _end(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        stack, self._stack = self._stack, None
        self._conn.info.pop(BATCH_KEY, None)
        if stack is not None:
            with driver_errors():
                stack.__exit__(exc_type, exc, tb)

    def _before(self, conn: Connection, cursor: Any, statement: str, *args: Any) -> None:
        if self._stack is not None and not queueable(statement):
            self.settle()
