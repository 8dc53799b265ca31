"""PostgreSQL's statements for a map upload's rows (issue 22 item 3): an upload's walls, its poses and the
wall ids it removes go as **constant statements with one array parameter a column**, unpacked by the
database (``unnest``, ``= ANY(array)``), whatever the number of rows.

Why: a multi-row ``VALUES`` statement has a text that grows with the rows (1,400 placeholders for a
200-wall delta). psycopg caches its conversion of a query text to PostgreSQL's ``$n`` form only for short
texts, so it re-split that text in Python at every upload; profiled under load, that split was the largest
CPU cost of a PostgreSQL upload (``psycopg._queries._split_query``, ~4 of every 5 ms of the process's CPU
for the upload's rows). A constant text is converted once, and psycopg prepares it on the server after a
few executions, so the database parses and plans it once per connection too. The columns travel as the
text of PostgreSQL arrays (:func:`array_text`), whose shortest round-trip spelling of a float, read back
by ``float8`` input, is the same double (round trip exact); they first went as one JSON text of the rows,
whose ``->>`` extractions cost the database 0.9 ms more per 200-wall upsert.

And an upload's statements go in two pipelines (:func:`lock_and_read` or, in a write batch, every upload's
lock and reads in one: :func:`queue_lock_and_read`; then :func:`pipelined`): one round trip for the lock
and the reads that decide (three statements), one for all the writes (two: :mod:`server.pgwrite`'s, of
which :data:`SEGMENTS_SQL`, :data:`TRAJECTORY_SQL` and :data:`DELETE_SQL` are parts, and the delta log's),
where one statement after another waited for its answer (13 round trips; each one, on a loaded machine,
also waits for the database's process to be scheduled).

SQLite keeps its multi-row ``VALUES`` statements (:mod:`server.mapstore`): its driver has no such cost.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import psycopg
from sqlalchemy import Connection

from server import jsontext
from server.mapcounts import Counts
from server.maphistory import UndoReads
from server.pgdriver import driver, driver_errors

__all__ = [
    "BATCH_KEY",
    "DELETE_SQL",
    "SEGMENTS_SQL",
    "TRAJECTORY_SQL",
    "DeltaProbe",
    "PendingReads",
    "UploadReads",
    "array_text",
    "columns",
    "delete_walls",
    "driver",
    "driver_errors",
    "lock_and_read",
    "pipelined",
    "queue_lock_and_read",
    "upsert_segments",
]

#: Rows ``[robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version]``, one array parameter a column; a segment
#: id at most once per call (``ON CONFLICT`` cannot touch one row twice in a statement).
SEGMENTS_SQL = (
    "INSERT INTO map_segments (robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version) "
    "SELECT * FROM unnest(%s::integer[], %s::bigint[], %s::float8[], %s::float8[], %s::float8[], "
    "%s::float8[], %s::bigint[]) "
    "ON CONFLICT (robot_id, segment_id) DO UPDATE SET x0_m = excluded.x0_m, y0_m = excluded.y0_m, "
    "x1_m = excluded.x1_m, y1_m = excluded.y1_m, version = excluded.version"
)
#: Rows ``[robot_id, version, stamp_s, x_m, y_m, theta_rad]``, one array a column, inserted in their order
#: (``WITH ORDINALITY``: the ids follow the rows, as the multi-row insert's do).
TRAJECTORY_SQL = (
    "INSERT INTO trajectory_points (robot_id, version, stamp_s, x_m, y_m, theta_rad) "
    "SELECT r, v, s, x, y, t FROM unnest(%s::integer[], %s::bigint[], %s::float8[], %s::float8[], "
    "%s::float8[], %s::float8[]) WITH ORDINALITY AS u(r, v, s, x, y, t, n) ORDER BY n"
)
DELETE_SQL = "DELETE FROM map_segments WHERE robot_id = %s AND segment_id = ANY(%s::bigint[])"


def array_text(values: Iterable[Any]) -> str:
    """PostgreSQL's text form of a one-dimensional array of ints or finite floats (``{1,2.5,-3e-7}``),
    read by the statements' ``::bigint[]`` / ``::float8[]`` casts: the JSON array's text
    (:func:`server.jsontext.dumps`, pydantic-core's serialiser, 0.07 ms for a 200-wall upload's columns
    against 0.38 ms joining ``repr`` in Python) with braces for brackets. Its float spelling is the
    shortest that reads back as the same double, and ``float8`` input reads it back so (round trip exact:
    property test in tests/server/test_pgrows.py). Why arrays, not a list or JSON: psycopg adapts a list
    element by element in Python, and PostgreSQL's JSON operators re-parse each element's text (measured:
    a 200-wall upsert cost the database 2.43 ms from one JSON text of the rows against 1.55 ms from
    arrays). O(values)."""
    text = jsontext.dumps(values if isinstance(values, (list, tuple)) else list(values))
    return "{" + text[1:-1] + "}"


def columns(rows: Sequence[Sequence[Any]]) -> tuple[str, ...]:
    """``rows``' columns, each as one array's text (:func:`array_text`). O(rows)."""
    return tuple(array_text(col) for col in zip(*rows, strict=True))


def upsert_segments(conn: Connection, rows: Sequence[Sequence[Any]]) -> None:
    """Insert or replace the walls ``rows`` (see :data:`SEGMENTS_SQL`) in ``conn``'s transaction: one
    statement, one round trip (an upload's walls go in :mod:`server.pgwrite`'s statement; this writes walls
    alone, as the tests of the pipelines do). O(rows)."""
    if rows:
        conn.exec_driver_sql(SEGMENTS_SQL, columns(rows))


def delete_walls(conn: Connection, robot_id: int, ids: Sequence[int]) -> None:
    """Delete the robot's walls ``ids`` (absent ones are no error): one statement. O(ids)."""
    if ids:
        conn.exec_driver_sql(DELETE_SQL, (int(robot_id), array_text(int(i) for i in ids)))


_LOCK_SQL = "SELECT pg_advisory_xact_lock(%s, %s)"
#: the robot's map version and session, its stored walls and poses (:mod:`server.mapcounts`) and the upload
#: already applied under the idempotency key: one row, NULLs for what is absent (no robot, a new key)
_ROBOT_SQL = (
    "SELECT r.map_version, r.map_session, s.n_walls, s.n_poses, u.version, u.map_session "
    "FROM (SELECT 1) AS one LEFT JOIN robots AS r ON r.id = %(rid)s "
    "LEFT JOIN map_states AS s ON s.robot_id = %(rid)s "
    "LEFT JOIN map_uploads AS u ON u.robot_id = %(rid)s AND u.idempotency_key = %(key)s"
)
#: and for a delta also what its undo record reads of the map state: whether the base version's log entry
#: holds its body, the map state (its centroids only if not)
_DELTA_SQL = (
    "SELECT r.map_version, r.map_session, s.n_walls, s.n_poses, u.version, u.map_session, l.logged, "
    "s.stamp_s, s.pose::text, s.wall_time_s, CASE WHEN l.logged THEN NULL ELSE s.centroids::text END "
    "FROM (SELECT EXISTS (SELECT 1 FROM map_deltas WHERE robot_id = %(rid)s AND version = %(base)s "
    "AND body IS NOT NULL) AS logged) AS l LEFT JOIN robots AS r ON r.id = %(rid)s "
    "LEFT JOIN map_states AS s ON s.robot_id = %(rid)s "
    "LEFT JOIN map_uploads AS u ON u.robot_id = %(rid)s AND u.idempotency_key = %(key)s"
)


#: a delta's touched walls, the ids as one array's text (:func:`array_text`: a Python list is adapted
#: element by element in Python, 0.4 ms a 200-wall delta under load)
_TOUCHED_SQL = (
    "SELECT segment_id, x0_m, y0_m, x1_m, y1_m FROM map_segments WHERE robot_id = %s "
    "AND segment_id = ANY(%s::bigint[]) ORDER BY segment_id"
)


@dataclass(frozen=True, slots=True)
class DeltaProbe:
    """What a delta's undo record reads besides the robot (:func:`lock_and_read`): the walls it touches
    (``touched``, :func:`server.maphistory.touched_ids`), and whether the log holds ``base_version``'s
    body."""

    touched: list[int]
    base_version: int


@dataclass(frozen=True, slots=True)
class UploadReads:
    """What an upload reads before it writes: the robot's ``(map_version, map_session)`` (None: no such
    robot), the ``(version, map_session)`` an upload with the same idempotency key got (None: new), the
    walls and poses stored now (:class:`server.mapcounts.Counts`), and with a :class:`DeltaProbe` the undo
    record's reads (``undo``; else None)."""

    robot: tuple[int, str | None] | None
    seen: tuple[int, str | None] | None
    counts: Counts = field(default_factory=Counts)
    undo: UndoReads | None = None


class PendingReads:
    """An upload's lock and reads queued in a pipeline (:func:`queue_lock_and_read`); :meth:`result` once
    the pipeline has synced (its block has ended)."""

    __slots__ = ("_curs", "_delta")

    def __init__(self, curs: list[psycopg.Cursor[Any]], delta: bool) -> None:
        self._curs, self._delta = curs, delta

    def result(self) -> UploadReads:
        """The answers (the cursors are closed). O(rows read). Inside a write batch's pipeline the answers
        may come here, and an earlier statement's error with them (as SQLAlchemy's error)."""
        with driver_errors():
            return self._result()

    def _result(self) -> UploadReads:
        curs = self._curs
        row = curs[1].fetchone()
        assert row is not None  # one row whatever exists (outer joins)
        seen = None if row[4] is None else (int(row[4]), row[5])
        undo = None
        if self._delta:
            touched = curs[2].fetchall()
            logged, stamp, pose, wall_time, centroids = row[6:11]
            state = None
            if stamp is not None and pose is not None:  # a map state row (its columns are NOT NULL)
                state = (
                    float(stamp),
                    json.loads(pose),
                    wall_time,
                    None if centroids is None else json.loads(centroids),
                )
            undo = UndoReads(touched, bool(logged), state)
        for cur in curs:
            cur.close()
        if row[0] is None:
            return UploadReads(None, seen)
        return UploadReads((int(row[0]), row[1]), seen, Counts(int(row[2] or 0), int(row[3] or 0)), undo)


def queue_lock_and_read(
    conn: Connection, lock_class: int, robot_id: int, key: str, delta: DeltaProbe | None = None
) -> PendingReads:
    """Queue :func:`lock_and_read`'s statements in the pipeline open on ``conn`` (:func:`pipelined`):
    the write batches queue every upload's lock and reads in one pipeline, one round trip for all."""
    rid = int(robot_id)
    pg = driver(conn)
    curs = [pg.cursor() for _ in range(2 + (delta is not None))]
    curs[0].execute(_LOCK_SQL, (lock_class, rid))
    if delta is None:
        curs[1].execute(_ROBOT_SQL, {"rid": rid, "key": key})
    else:
        curs[1].execute(_DELTA_SQL, {"rid": rid, "key": key, "base": int(delta.base_version)})
        curs[2].execute(_TOUCHED_SQL, (rid, array_text(delta.touched)))
    return PendingReads(curs, delta is not None)


def lock_and_read(
    conn: Connection, lock_class: int, robot_id: int, key: str, delta: DeltaProbe | None = None
) -> UploadReads:
    """Take the robot's upload lock (a transaction advisory lock ``(lock_class, robot_id)``), then read
    what :class:`UploadReads` holds, in one round trip (pipeline mode): each statement runs after the one
    before, so the reads see every upload committed before the lock was granted. A delta's reads
    (``delta``) go in the same round trip; they are wasted only when the delta is then refused (a
    conflict, a duplicate). O(walls in the delta): primary-key probes only."""
    with pipelined(conn):
        pending = queue_lock_and_read(conn, lock_class, robot_id, key, delta)
    return pending.result()


#: ``conn.info`` key set while a write batch's pipeline is open on the connection (:mod:`server.pgbatch`)
BATCH_KEY = "linemap_batch_pipeline"


@contextmanager
def pipelined(conn: Connection) -> Iterator[None]:
    """On PostgreSQL, send the statements ``conn`` executes in the block without waiting for each answer
    (psycopg's pipeline mode), all answered in one round trip at the block's end; elsewhere nothing.
    Only statements that return no rows may run in the block (SQLAlchemy reads a result at once). A
    statement's error is raised at the block's end as SQLAlchemy's error (so callers see one kind).
    Inside a write batch's pipeline (:mod:`server.pgbatch`) the statements join it: no round trip here."""
    if conn.dialect.name != "postgresql" or conn.info.get(BATCH_KEY) is not None:
        yield
        return
    with driver_errors(), driver(conn).pipeline():
        yield
