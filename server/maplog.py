"""The map delta log: the last :data:`KEEP_VERSIONS` uploads of each robot's map as the stream sends them,
written in the upload's own transaction, so that any server process can send a live-map viewer the deltas
it missed: another process's uploads (woken by a notice, :mod:`server.hub`), a viewer that fell behind,
a browser reconnecting with ``Last-Event-ID``.

A delta is kept as its stream event (JSON text, sent as is); a snapshot upload as a row without a body (a
viewer behind it is sent the whole current map instead). Each upload costs one insert and one indexed
delete (the rows ``KEEP_VERSIONS`` versions older); a read costs O(rows read) on the primary key.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import Connection, Table, bindparam, delete, insert, select
from sqlalchemy.orm import Session

from server import jsontext
from server.models import MapDeltaRecord
from server.notices import CHANNEL
from server.pgdriver import driver, driver_errors

__all__ = ["KEEP_VERSIONS", "LoggedUpload", "append", "chain_from", "clear", "read_after"]

#: Versions kept per robot: 25 s of uploads at 10 Hz (the agent uploads at 2 Hz: two minutes).
KEEP_VERSIONS = 256
_LOG: Table = MapDeltaRecord.__table__  # type: ignore[assignment]
#: built once: a statement built per upload is compiled from its cache key, made anew every time
_INSERT = insert(_LOG)
#: PostgreSQL: the entry, the trim and the notice to other processes (when the last parameter is true) as
#: one statement, sent to psycopg itself in the upload's pipeline (server.pgwrite says why); the trim never
#: reaches the new entry
_LOG_SQL = (
    "WITH logged AS (INSERT INTO map_deltas (robot_id, version, base_version, body, undo) "
    "VALUES (%s, %s, %s, %s, %s)), trimmed AS (DELETE FROM map_deltas WHERE robot_id = %s AND version <= %s) "
    "SELECT pg_notify(%s, %s) WHERE %s"
)
_TRIM = delete(_LOG).where(_LOG.c.robot_id == bindparam("log_robot"), _LOG.c.version <= bindparam("log_upto"))


@dataclass(frozen=True, slots=True)
class LoggedUpload:
    """One logged upload: a delta (``body``: its event as JSON) or a snapshot (``body`` None), of map
    session ``session`` (known for an upload to this process; the log itself holds the robot's current
    session only, see :func:`clear`)."""

    version: int
    base_version: int | None
    body: str | None
    session: str | None = None


def clear(conn: Connection, robot_id: int) -> None:
    """Drop the robot's logged uploads (a new mapping session began: its versions count anew, and a delta
    of the old map must never continue the new one). In ``conn``'s transaction."""
    conn.execute(delete(_LOG).where(_LOG.c.robot_id == robot_id))


def append(
    conn: Connection,
    robot_id: int,
    event: dict[str, Any],
    keep: int = KEEP_VERSIONS,
    undo: str | None = None,
    notice: str | None = None,
) -> LoggedUpload:
    """Log the upload whose stream event is ``event`` (:class:`server.mapstore.AppliedUpload`'s) in
    ``conn``'s transaction, with a delta's undo record (``undo``, :func:`server.maphistory.capture_undo`),
    and drop the robot's entries ``keep`` or more versions older; returns the
    entry (its JSON is what every stream sends, encoded once here). ``notice``: a payload for the other
    server processes (:meth:`server.hub.Hub.notice`, PostgreSQL only), sent in the same statement.
    O(event)."""
    if notice is not None and conn.dialect.name != "postgresql":
        raise ValueError(f"a notice needs PostgreSQL's NOTIFY, not {conn.dialect.name}")
    version = int(event["version"])
    if event["kind"] == "delta":
        base, body = event["base_version"], jsontext.dumps(event)
    else:
        base, body = None, None
    if conn.dialect.name == "postgresql":
        with driver_errors():
            tell = notice is not None
            params = (
                robot_id,
                version,
                base,
                body,
                undo,
                robot_id,
                version - keep,
                CHANNEL,
                notice or "",
                tell,
            )
            driver(conn).execute(_LOG_SQL, params)
        return LoggedUpload(version, base, body, event.get("map_session"))
    row = {"robot_id": robot_id, "version": version, "base_version": base, "body": body, "undo": undo}
    conn.execute(_INSERT, row)
    conn.execute(_TRIM, {"log_robot": robot_id, "log_upto": version - keep})
    return LoggedUpload(version, base, body, event.get("map_session"))


def read_after(s: Session, robot_id: int, after: int, limit: int = KEEP_VERSIONS) -> list[LoggedUpload]:
    """The robot's logged uploads above version ``after``, oldest first (at most ``limit``)."""
    rows = s.execute(
        select(_LOG.c.version, _LOG.c.base_version, _LOG.c.body)
        .where(_LOG.c.robot_id == robot_id, _LOG.c.version > after)
        .order_by(_LOG.c.version)
        .limit(limit)
    )
    return [LoggedUpload(int(v), None if b is None else int(b), body) for v, b, body in rows]


def chain_from(version: int, logged: list[LoggedUpload]) -> list[LoggedUpload]:
    """The leading run of ``logged`` that continues a map at ``version`` delta by delta: each a delta whose
    base is the version before it. Empty when the first is missing (a gap, older than the log keeps) or a
    snapshot. O(len(logged))."""
    out: list[LoggedUpload] = []
    for entry in logged:
        if entry.body is None or entry.base_version != version:
            break
        out.append(entry)
        version = entry.version
    return out
