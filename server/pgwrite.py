"""An upload's rows on PostgreSQL as **one statement** (issue 22 item 3): the delta's removed walls, the
walls, the poses, the map state, the upload record and the robot row, as data-modifying ``WITH`` clauses
of one ``UPDATE`` (:func:`write_upload`); the delta log's entry and trim are one more
(:func:`server.maplog.append`).

Why: in a loaded server process the writer thread holds the interpreter lock about half the time, and it
is the writer that bounds a process's uploads/s (``benchmarks/server_load.py``: a write batch's thread
busy 99.9 % of the time at ~185 uploads/s, 5.5 ms of wall time and 2.4 ms of CPU a job). Every statement
costs it a pass through SQLAlchemy's execution (compiled-cache lookup, type processors, events, a result
object: ~0.1 ms each) and psycopg's (a cursor, a query conversion, a pipeline turn that waits on the socket
and takes the interpreter lock back). Six statements became one, built once per shape (which optional
parts an upload has: removed walls, walls, poses, pose-graph columns, status columns) and prepared by
psycopg on the server after a few uses like any constant text.

The same rows as :func:`server.maprows.write_rows` writes on the other backends, with one difference of
form only: a wall id both removed and sent is not deleted first (the statement's parts see one snapshot
and must not touch a row twice); it is written with its sent row, which is where the delete-then-insert
order left it. JSON columns get :func:`server.jsontext.dumps`' text (the same JSON values as SQLAlchemy's
``json.dumps``). Tests: tests/server/test_pgwrite.py compares the rows with the statements before it.
"""

from __future__ import annotations

import functools
from typing import Any

from sqlalchemy import JSON, Connection, Table

from server import jsontext, pgrows
from server.models import MapState, Robot
from server.pgdriver import driver, driver_errors
from server.schemas import MapUpload

__all__ = ["RECORD_COLUMNS", "write_upload"]

_STATE: Table = MapState.__table__  # type: ignore[assignment]
_ROBOTS: Table = Robot.__table__  # type: ignore[assignment]
#: the JSON columns of the two tables whose columns vary by upload (their values go as JSON text)
_JSON = {
    table.name: frozenset(c.name for c in table.columns if isinstance(c.type, JSON))
    for table in (_STATE, _ROBOTS)
}
#: the map state's columns every upload writes, before its pose-graph columns
_STATE_BASE = ("robot_id", "version", "stamp_s", "centroids", "pose", "wall_time_s", "updated_at")
#: the upload record's columns (its idempotency key and what it was)
RECORD_COLUMNS = (
    "robot_id",
    "idempotency_key",
    "version",
    "base_version",
    "map_session",
    "n_segments",
    "n_removed",
    "received_at",
)
_RECORD_SQL = (
    f"INSERT INTO map_uploads ({', '.join(RECORD_COLUMNS)}) "
    f"VALUES ({', '.join(['%s'] * len(RECORD_COLUMNS))})"
)


def _value(table: str, column: str, value: Any) -> Any:
    return jsontext.dumps(value) if value is not None and column in _JSON[table] else value


def _mark(table: str, column: str) -> str:
    return "%s::json" if column in _JSON[table] else "%s"


@functools.lru_cache(maxsize=64)
def _statement(delete: bool, walls: bool, poses: bool, state: tuple[str, ...], robot: tuple[str, ...]) -> str:
    """The statement's text for one shape (see the module docstring). O(columns), once per shape."""
    parts = []
    if delete:
        parts.append(f"removed AS ({pgrows.DELETE_SQL})")
    if walls:
        parts.append(f"walls AS ({pgrows.SEGMENTS_SQL})")
    if poses:
        parts.append(f"poses AS ({pgrows.TRAJECTORY_SQL})")
    marks = ", ".join(_mark("map_states", c) for c in state)
    updates = ", ".join(f"{c} = excluded.{c}" for c in state if c != "robot_id")
    parts.append(
        f"state AS (INSERT INTO map_states ({', '.join(state)}) VALUES ({marks}) "
        f"ON CONFLICT (robot_id) DO UPDATE SET {updates})"
    )
    parts.append(f"record AS ({_RECORD_SQL})")
    sets = ", ".join(f"{c} = {_mark('robots', c)}" for c in robot)
    return f"WITH {', '.join(parts)} UPDATE robots SET {sets} WHERE id = %s"


def write_upload(
    conn: Connection,
    robot_id: int,
    up: MapUpload,
    segments: list[tuple[Any, ...]],
    trajectory: list[tuple[Any, ...]],
    state: dict[str, Any],
    robot: dict[str, Any],
    record: dict[str, Any],
) -> None:
    """Queue the upload's writes in ``conn``'s open pipeline (:func:`server.pgrows.pipelined`) as one
    statement: delete the delta's removed walls (``up.removed`` when a delta), upsert ``segments``
    (:class:`server.maprows.PreparedRows` rows), append ``trajectory``, upsert the map state ``state``
    (column -> value, ``robot_id`` first), insert the upload ``record`` (:data:`RECORD_COLUMNS`) and
    update the robot row with ``robot`` (column -> value). Its error comes when the pipeline syncs, as
    SQLAlchemy's. O(rows)."""
    rid = int(robot_id)
    sent = {int(r[1]) for r in segments}
    removed = [] if up.base_version is None else [int(i) for i in up.removed if int(i) not in sent]
    state_cols, robot_cols = tuple(state), tuple(robot)
    sql = _statement(bool(removed), bool(segments), bool(trajectory), state_cols, robot_cols)
    params: list[Any] = []
    if removed:
        params += (rid, pgrows.array_text(removed))
    if segments:
        params += pgrows.columns(segments)
    if trajectory:
        params += pgrows.columns(trajectory)
    params += (_value("map_states", c, state[c]) for c in state_cols)
    params += (record[c] for c in RECORD_COLUMNS)
    params += (_value("robots", c, robot[c]) for c in robot_cols)
    params.append(rid)
    with driver_errors():
        driver(conn).execute(sql, params)
