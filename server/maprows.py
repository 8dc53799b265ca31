"""The rows of a map upload on both backends: the walls, the poses, the map state, the robot row and the
upload record (:func:`write_rows`), and the trims that keep them bounded (:func:`thin_trajectory`,
:func:`trim_upload_records`). :mod:`server.mapstore` decides what an upload writes; this module writes it.

SQLite gets multi-row ``VALUES`` statements at driver level; PostgreSQL gets all of an upload's rows as one
statement (:mod:`server.pgwrite`, with one array parameter a column: :mod:`server.pgrows`). Statements used
at every upload are built once: SQLAlchemy makes a cache key anew for a statement built per call.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from datetime import datetime
from itertools import chain
from typing import Any

from sqlalchemy import Connection, Table, bindparam, delete, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite

from server import pgrows, pgwrite
from server.mapcounts import Counts
from server.models import MapSegment, MapState, MapUploadRecord, Robot, TrajectoryPoint, utcnow
from server.schemas import MapUpload
from server.snapdiff import SnapshotDiff
from shared.protocol import MAX_TRAJECTORY_POSES, STATUS_FIELDS, RobotStatus, thin_positions

__all__ = [
    "KEEP_UPLOAD_RECORDS",
    "PreparedRows",
    "delete_walls",
    "prepare_rows",
    "status_columns",
    "thin_trajectory",
    "trim_upload_records",
    "write_rows",
]

_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
_STATE: Table = MapState.__table__  # type: ignore[assignment]
_UPLOADS: Table = MapUploadRecord.__table__  # type: ignore[assignment]
_ROBOTS: Table = Robot.__table__  # type: ignore[assignment]
#: built once; the robot row's SET clause is the columns given with it
_ROBOT_UPDATE = update(_ROBOTS).where(_ROBOTS.c.id == bindparam("robot_row"))
_UPLOAD_INSERT = insert(_UPLOADS).inline()  # inline: no RETURNING of the new id (none is read)
_COORDS = ("x0_m", "y0_m", "x1_m", "y1_m", "version")
#: Idempotency records kept per robot (a retry older than that many uploads is answered as a new upload:
#: a delta from an old base or an old snapshot version gets 409, never applied twice).
KEEP_UPLOAD_RECORDS = 10_000


@functools.lru_cache(maxsize=16)
def _on_conflict_update(dialect: str, table: Table, keys: tuple[str, ...], columns: tuple[str, ...]) -> Any:
    """``INSERT ... ON CONFLICT (keys) DO UPDATE SET columns`` (its values come at execution), built once per
    table: building ``excluded`` anew took ~0.3 ms of a routine upload's ~2.7 ms on the event loop."""
    ins: Any = (postgresql if dialect == "postgresql" else sqlite).insert(table)
    return ins.on_conflict_do_update(
        index_elements=list(keys), set_={c: getattr(ins.excluded, c) for c in columns}
    )


def _upsert(
    conn: Connection, table: Any, keys: list[str], columns: tuple[str, ...], values: list[dict[str, Any]]
) -> None:
    """Insert ``values``, replacing rows whose ``keys`` exist (SQLite and PostgreSQL ``ON CONFLICT``)."""
    if not values:
        return
    dialect = conn.dialect.name
    if dialect in ("postgresql", "sqlite"):
        conn.execute(_on_conflict_update(dialect, table, tuple(keys), columns), values)
        return
    for row in values:  # other backends: delete then insert
        conn.execute(delete(table).where(*(table.c[k] == row[k] for k in keys)))
    conn.execute(insert(table), values)


_SEGMENT_SQL = (
    "INSERT INTO map_segments (robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version) VALUES {rows} "
    "ON CONFLICT (robot_id, segment_id) DO UPDATE SET x0_m = excluded.x0_m, y0_m = excluded.y0_m, "
    "x1_m = excluded.x1_m, y1_m = excluded.y1_m, version = excluded.version"
)
_TRAJECTORY_SQL = (
    "INSERT INTO trajectory_points (robot_id, version, stamp_s, x_m, y_m, theta_rad) VALUES {rows}"
)
_CHUNK_ROWS = 500  # 7 parameters a row: well under SQLite's 32,766 and PostgreSQL's 65,535


@dataclass(frozen=True, slots=True)
class PreparedRows:
    """An upload's wall rows ``(robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version)`` and pose rows
    ``(robot_id, version, stamp_s, x_m, y_m, theta_rad)``, a segment id at most once. Built by
    :func:`prepare_rows` before the write transaction, so a near-limit upload (~120,000 rows, ~0.3 s of
    Python) does not hold the writer (SQLite's one write lock) while it is built.

    For a snapshot written as a diff (:mod:`server.snapdiff`): the rows are the diff's (changed walls,
    new poses), valid only while the stored map is at ``diff_base``; ``removed`` lists the wall ids to
    delete and ``replace_trajectory`` says whether the stored poses go first."""

    segments: list[tuple[Any, ...]]
    trajectory: list[tuple[Any, ...]]
    diff_base: int | None = None
    removed: list[int] = field(default_factory=list)
    replace_trajectory: bool = True


def _chunks(rows: list[tuple[Any, ...]]) -> list[tuple[int, tuple[Any, ...]]]:
    """``rows`` cut into chunks, each flattened in C (``itertools.chain``)."""
    return [
        (len(chunk), tuple(chain.from_iterable(chunk)))
        for chunk in (rows[i : i + _CHUNK_ROWS] for i in range(0, len(rows), _CHUNK_ROWS))
    ]


def prepare_rows(robot_id: int, up: MapUpload, diff: SnapshotDiff | None = None) -> PreparedRows:
    """The upload's rows for the multi-row inserts of :func:`apply_upload`. A segment id given twice keeps
    its last row (``ON CONFLICT`` cannot touch one row twice in a statement). ``diff``: a snapshot's diff
    against the stored map; then only its rows. O(rows)."""
    if diff is not None and up.base_version is None:
        segs = [(robot_id, int(r[0]), *r[1:5], up.version) for r in diff.upsert.tolist()]
        poses = [(robot_id, up.version, *r) for r in diff.trajectory.tolist()]
        removed = diff.removed.tolist()
        return PreparedRows(segs, poses, diff.base_version, removed, diff.replace_trajectory)
    last = {int(r[0]): r for r in up.segments}
    segments = [(robot_id, sid, *r[1:5], up.version) for sid, r in last.items()]
    trajectory = [(robot_id, up.version, *r) for r in up.trajectory]
    return PreparedRows(segments, trajectory)


def _multi_row(conn: Connection, sql: str, width: int, rows: list[tuple[Any, ...]]) -> None:
    """One multi-row ``VALUES`` statement per chunk of ``_CHUNK_ROWS`` rows, at driver level (SQLite; on
    PostgreSQL :mod:`server.pgrows` sends the rows as one parameter). A driver ``executemany`` goes back
    to Python (and the GIL) after every row, and under load each return waited for the GIL: 200-row
    uploads stalled for 100+ ms. One statement per chunk costs one round trip."""
    mark = "?" if conn.dialect.paramstyle == "qmark" else "%s"
    one = "(" + ", ".join([mark] * width) + ")"
    texts: dict[int, str] = {}
    for n, params in _chunks(rows):
        if n not in texts:
            texts[n] = sql.format(rows=", ".join([one] * n))
        conn.exec_driver_sql(texts[n], params)


def _bulk_segments(
    conn: Connection, robot_id: int, version: int, rows: list[list[float]], prepared: PreparedRows
) -> None:
    """Upsert walls (the hot path: ~200 rows several times a second), on SQLite as multi-row ``ON CONFLICT
    ... DO UPDATE`` statements; other backends but PostgreSQL (:mod:`server.pgwrite`) go through
    :func:`_upsert`. A segment id given twice in one upload keeps its last row."""
    if not rows:
        return
    if conn.dialect.name not in ("sqlite", "postgresql"):
        last = {int(r[0]): r for r in rows}
        values = [
            dict(zip(("robot_id", "segment_id", *_COORDS), (robot_id, sid, *r[1:5], version), strict=True))
            for sid, r in last.items()
        ]
        _upsert(conn, _SEG, ["robot_id", "segment_id"], _COORDS, values)
    else:
        _multi_row(conn, _SEGMENT_SQL, 7, prepared.segments)


def delete_walls(conn: Connection, robot_id: int, ids: list[int]) -> None:
    """Delete the robot's walls ``ids`` (absent ones are no error), ``_CHUNK_ROWS`` ids a statement
    (PostgreSQL: all in one)."""
    if conn.dialect.name == "postgresql":
        pgrows.delete_walls(conn, robot_id, ids)
        return
    for start in range(0, len(ids), _CHUNK_ROWS):
        chunk = ids[start : start + _CHUNK_ROWS]
        conn.execute(delete(_SEG).where(_SEG.c.robot_id == robot_id, _SEG.c.segment_id.in_(chunk)))


def write_rows(
    conn: Connection,
    robot_id: int,
    up: MapUpload,
    rows: PreparedRows,
    seen_at: datetime | None,
    key: str,
    graph: dict[str, Any],
    counts: Counts,
) -> None:
    """The upload's writes, after its checks: the delta's removed walls, the walls and poses, the map
    state (with the pose graph's columns ``graph`` and the walls and poses stored after the upload,
    ``counts``: :mod:`server.mapcounts`), the robot row, the upload record. No statement here returns
    rows (PostgreSQL pipelines them)."""
    v = up.version
    now = utcnow()
    state = {
        "robot_id": robot_id,
        "version": v,
        "stamp_s": up.stamp_s,
        "centroids": {"xy": up.centroids},
        "pose": {"x_m": up.pose[0], "y_m": up.pose[1], "theta_rad": up.pose[2]},
        "wall_time_s": up.wall_time_s,
        "updated_at": now,
        "n_walls": counts.walls,
        "n_poses": counts.poses,
        **graph,
    }
    changes: dict[str, Any] = {"map_version": v, "map_session": up.map_session}
    if seen_at is not None:
        changes["last_seen_at"] = seen_at
    if up.status is not None:
        changes.update(status_columns(up.status))
    record = {
        "robot_id": robot_id,
        "idempotency_key": key,
        "version": v,
        "base_version": up.base_version,
        "map_session": up.map_session,
        "n_segments": len(up.segments),
        "n_removed": len(up.removed),
        "received_at": now,
    }
    if conn.dialect.name == "postgresql":  # all of it as one statement (server.pgwrite)
        pgwrite.write_upload(conn, robot_id, up, rows.segments, rows.trajectory, state, changes, record)
        return
    if up.base_version is not None:
        delete_walls(conn, robot_id, up.removed)
    _bulk_segments(conn, robot_id, v, up.segments, rows)
    _multi_row(conn, _TRAJECTORY_SQL, 6, rows.trajectory)
    _upsert(conn, _STATE, ["robot_id"], tuple(c for c in state if c != "robot_id"), [state])
    conn.execute(_ROBOT_UPDATE, {"robot_row": robot_id, **changes})
    conn.execute(_UPLOAD_INSERT, record)


def _delete_ids(conn: Connection, table: Table, ids: list[int]) -> None:
    for start in range(0, len(ids), _CHUNK_ROWS):
        conn.execute(delete(table).where(table.c.id.in_(ids[start : start + _CHUNK_ROWS])))


def _newest_id_past(conn: Connection, table: Table, robot_id: int, skip: int) -> int | None:
    """The id of the robot's row in ``table`` that has ``skip`` newer ones (None: there are not that many).
    One index probe."""
    newest_first = select(table.c.id).where(table.c.robot_id == robot_id).order_by(table.c.id.desc())
    got = conn.execute(newest_first.limit(1).offset(skip)).scalar()
    return None if got is None else int(got)


def thin_trajectory(
    conn: Connection, robot_id: int, max_poses: int = MAX_TRAJECTORY_POSES, *, poses: int | None = None
) -> int:
    """Thin the robot's stored trajectory to at most ``max_poses`` poses
    (:func:`shared.protocol.thin_positions`: the newest half whole, older ones ever sparser), and store
    the poses left in ``map_states.n_poses`` (:mod:`server.mapcounts`); the poses dropped. ``poses``: the
    poses stored (from ``map_states``), nothing read when they fit; without it one index probe. O(max_poses)
    when it does not fit (once per ~max_poses / 4 poses stored)."""
    over = (
        _newest_id_past(conn, _TRAJ, robot_id, max_poses) is not None if poses is None else poses > max_poses
    )
    if not over:
        return 0
    ids = [
        int(r[0])
        for r in conn.execute(select(_TRAJ.c.id).where(_TRAJ.c.robot_id == robot_id).order_by(_TRAJ.c.id))
    ]
    drop = [ids[i] for i in thin_positions(len(ids), max_poses)]
    _delete_ids(conn, _TRAJ, drop)
    conn.execute(update(_STATE).where(_STATE.c.robot_id == robot_id).values(n_poses=len(ids) - len(drop)))
    return len(drop)


def trim_upload_records(conn: Connection, robot_id: int, keep: int = KEEP_UPLOAD_RECORDS) -> None:
    """Drop the robot's idempotency records older than its last ``keep`` (:data:`KEEP_UPLOAD_RECORDS`)."""
    edge = _newest_id_past(conn, _UPLOADS, robot_id, keep)
    if edge is not None:
        conn.execute(delete(_UPLOADS).where(_UPLOADS.c.robot_id == robot_id, _UPLOADS.c.id <= edge))


def status_columns(st: RobotStatus) -> dict[str, Any]:
    """The robot row's columns a status sets: each field of :class:`RobotStatus` (a column of the same
    name) that the robot sent, and ``last_error`` always (None clears it)."""
    columns: dict[str, Any] = {}
    for name in STATUS_FIELDS:
        value = getattr(st, name)
        if name == "kernels" and value is not None:
            value = [k.model_dump() for k in value]
        if value is not None or name == "last_error":
            columns[name] = value
    return columns
