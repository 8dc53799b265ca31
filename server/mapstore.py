"""The server's copy of each robot's temporary map: apply snapshot and delta uploads, read the whole map.

Walls are rows keyed by (robot, segment id), so a delta costs O(changed walls), not O(map). An upload's
idempotency key is recorded in the same transaction as its changes: a retry finds the key and changes
nothing. A delta must start from the version the server has (``base_version`` == current) or it is
refused with 409 and the server's version, and the robot sends a snapshot instead.

Bounded whatever the run's length: a robot's stored trajectory is thinned past
:data:`shared.protocol.MAX_TRAJECTORY_POSES` poses (:func:`shared.protocol.thin_positions`, the rule the
robot applies to its own), and the idempotency records keep the robot's last :data:`KEEP_UPLOAD_RECORDS`
uploads; both are trimmed in the upload's transaction.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime
from itertools import chain
from typing import Any

from sqlalchemy import Connection, Table, bindparam, delete, insert, select, update
from sqlalchemy.dialects import postgresql, sqlite

from server import pgrows
from server.errors import ConflictError, MapSessionMismatchError, NotFoundError
from server.mapgraph import graph_columns
from server.maphistory import capture_undo, touched_ids
from server.mapread import map_version, read_map  # the read side, importable from here as before
from server.mapsessions import check_not_ended, start_session
from server.models import MapSegment, MapState, MapUploadRecord, Robot, TrajectoryPoint, utcnow
from server.schemas import MapUpload, MapUploadOut
from server.snapdiff import SnapshotDiff
from server.wallcap import check_wall_cap  # importable from here as before
from shared.protocol import MAP_FIELDS, MAX_TRAJECTORY_POSES, STATUS_FIELDS, RobotStatus, thin_positions

__all__ = [
    "KEEP_UPLOAD_RECORDS",
    "AppliedUpload",
    "PreparedRows",
    "apply_upload",
    "check_wall_cap",
    "map_version",
    "prepare_rows",
    "queue_upload_reads",
    "read_map",
    "status_columns",
    "thin_trajectory",
    "trim_upload_records",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class AppliedUpload:
    """What the upload returned, and the event for stream subscribers (``None`` for a retry);
    ``new_session``: it started a new mapping session (the previous map is kept:
    :mod:`server.mapsessions`)."""

    out: MapUploadOut
    event: dict[str, Any] | None
    new_session: bool = False
    #: a delta's undo record (:func:`server.maphistory.capture_undo`), logged with it
    undo: str | None = None
    #: what :func:`apply_upload`'s ``also`` returned
    extra: Any = None


_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
_STATE: Table = MapState.__table__  # type: ignore[assignment]
_UPLOADS: Table = MapUploadRecord.__table__  # type: ignore[assignment]
_ROBOTS: Table = Robot.__table__  # type: ignore[assignment]
#: built once (a statement built per upload is compiled from a cache key made anew each time); the robot
#: row's SET clause is the columns given with it
_ROBOT_UPDATE = update(_ROBOTS).where(_ROBOTS.c.id == bindparam("robot_row"))
_UPLOAD_INSERT = insert(_UPLOADS).inline()  # inline: no RETURNING of the new id (none is read)
_COORDS = ("x0_m", "y0_m", "x1_m", "y1_m", "version")
#: First key of the per-robot upload advisory lock on PostgreSQL ("LMUP"; the second key is the robot id).
#: Distinct from the high half of server.migrate.SCHEMA_LOCK_KEY, so the two never collide.
_UPLOAD_LOCK_CLASS = 0x4C4D5550
#: Idempotency records kept per robot (a retry older than that many uploads is answered as a new upload:
#: a delta from an old base or an old snapshot version gets 409, never applied twice).
KEEP_UPLOAD_RECORDS = 10_000
_TRIM_EVERY = 256  # the records are trimmed when the upload's version is a multiple of this


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
    """Upsert walls (the hot path: ~200 rows several times a second). SQLite and PostgreSQL both speak
    ``ON CONFLICT ... DO UPDATE``; other backends go through :func:`_upsert`. A segment id given twice in
    one upload keeps its last row."""
    if not rows:
        return
    if conn.dialect.name not in ("sqlite", "postgresql"):
        last = {int(r[0]): r for r in rows}
        values = [
            dict(zip(("robot_id", "segment_id", *_COORDS), (robot_id, sid, *r[1:5], version), strict=True))
            for sid, r in last.items()
        ]
        _upsert(conn, _SEG, ["robot_id", "segment_id"], _COORDS, values)
    elif conn.dialect.name == "postgresql":
        pgrows.upsert_segments(conn, prepared.segments)
    else:
        _multi_row(conn, _SEGMENT_SQL, 7, prepared.segments)


def _delete_walls(conn: Connection, robot_id: int, ids: list[int]) -> None:
    """Delete the robot's walls ``ids`` (absent ones are no error), ``_CHUNK_ROWS`` ids a statement
    (PostgreSQL: all in one)."""
    if conn.dialect.name == "postgresql":
        pgrows.delete_walls(conn, robot_id, ids)
        return
    for start in range(0, len(ids), _CHUNK_ROWS):
        chunk = ids[start : start + _CHUNK_ROWS]
        conn.execute(delete(_SEG).where(_SEG.c.robot_id == robot_id, _SEG.c.segment_id.in_(chunk)))


def apply_upload(
    conn: Connection,
    robot_id: int,
    up: MapUpload,
    key: str,
    seen_at: datetime | None = None,
    max_walls: int | None = None,
    prepared: PreparedRows | None = None,
    actor: str = "robot",
    *,
    pending: pgrows.PendingReads | None = None,
    also: Callable[[Connection, AppliedUpload], Any] | None = None,
) -> AppliedUpload:
    """Apply one upload in the caller's transaction (SQLAlchemy Core: a robot sends one every few hundred
    milliseconds); ``max_walls``: refuse (422, before writing) a delta after which the map would hold more
    walls (:func:`check_wall_cap`); ``prepared``: its rows from :func:`prepare_rows`, built before the
    transaction (else here). A snapshot's rows prepared as a diff are applied as such only if the stored
    map is still at the diff's version; otherwise (another upload of the robot came between) the map is
    replaced whole, with the same result. O(rows in the upload, or in the diff).

    Map sessions: a snapshot of a session that is not the robot's current one starts a new map (the current
    one is kept, :func:`server.mapsessions.start_session`; ``actor`` names the robot in the audit entry),
    whatever its version; a delta of another session is refused (409 ``map_session_mismatch``), and an
    upload of a session that ended (409 ``map_session_ended``).

    ``pending``: the lock and reads queued already in this transaction by :func:`queue_upload_reads`
    (PostgreSQL's write batches queue every upload's in one round trip). ``also(conn, applied)``: more
    writes of the upload (its delta-log entry, its notice), run with the upload's own writes (on
    PostgreSQL in their round trip); its result is ``applied.extra``."""
    # Serialise the robot's uploads first: concurrent uploads of one robot (a retry racing its original)
    # queue here, so the idempotency check below sees every upload committed before it. PostgreSQL: a
    # per-robot advisory lock, not the robot's row: a near-limit upload's transaction lasts seconds, and
    # the row lock held all along stalled every write batch that touched the row (last-seen times). The
    # row itself is updated at the end of the transaction only. SQLite: its one write lock serialises.
    if pending is not None:
        reads = pending.result()
    else:
        reads = _lock_and_read(conn, robot_id, key, _counts(up, max_walls), up)
    robot, seen = reads.robot, reads.seen
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    if seen is not None:  # answered with the session it was applied in: the robot checks it is its own
        return AppliedUpload(MapUploadOut(version=seen[0], duplicate=True, map_session=seen[1]), None)
    current, session = robot[0], robot[1]
    new_session, undo = up.map_session != session, None
    if new_session:
        check_not_ended(conn, robot_id, up.map_session, session)
    if up.base_version is None and new_session:
        if max_walls is not None:
            check_wall_cap(conn, robot_id, up, max_walls)
        start_session(
            conn,
            robot_id,
            old=session,
            old_version=current,
            new=up.map_session,
            first_version=up.version,
            reason=up.map_session_reason,
            actor=actor,
            now=utcnow(),
        )
        if prepared is not None and prepared.diff_base is not None:
            prepared = prepare_rows(robot_id, up)  # the diff was against the other session's map
        conn.execute(delete(_SEG).where(_SEG.c.robot_id == robot_id))
        conn.execute(delete(_TRAJ).where(_TRAJ.c.robot_id == robot_id))
    elif up.base_version is None:
        if up.version <= current:
            raise ConflictError(
                f"snapshot version {up.version} is not newer than the server's map version {current} "
                f"of the same map session {session}",
                current_version=current,
                current_session=session,
                current_stamp_s=_stamp(conn, robot_id),
            )
        if max_walls is not None:
            check_wall_cap(conn, robot_id, up, max_walls)
        if prepared is not None and prepared.diff_base is not None and prepared.diff_base != current:
            log.info(
                "robot %d's map moved (version %d -> %d) since its snapshot's diff: replacing it whole",
                robot_id,
                prepared.diff_base,
                current,
            )
            prepared = prepare_rows(robot_id, up)
        if prepared is not None and prepared.diff_base is not None:  # the diff against the stored map
            _delete_walls(conn, robot_id, prepared.removed)
        else:
            conn.execute(delete(_SEG).where(_SEG.c.robot_id == robot_id))
        if prepared is None or prepared.replace_trajectory:
            conn.execute(delete(_TRAJ).where(_TRAJ.c.robot_id == robot_id))
    else:
        if new_session:
            raise MapSessionMismatchError(
                f"delta of map session {up.map_session}, but the server's current map of robot {robot_id} "
                f"is session {session} (version {current}): send a snapshot (base_version null)",
                current_version=current,
                current_session=session,
            )
        if up.base_version != current:
            raise ConflictError(
                f"delta from version {up.base_version}, but the server's map is at version {current}: "
                "send a snapshot (base_version null)",
                current_version=current,
                current_session=session,
                current_stamp_s=_stamp(conn, robot_id),
            )
        if max_walls is not None:
            check_wall_cap(conn, robot_id, up, max_walls, reads.walls)
        undo = capture_undo(conn, robot_id, up, reads.undo)  # what the delta replaces: before the writes
    v = up.version
    rows = prepared or prepare_rows(robot_id, up)
    # the pose graph's rows; a delta's corrected keyframes move the stored poses first (server.mapgraph:
    # it reads the stored keyframes, so before the pipelined writes, and before the delta's own poses)
    graph = graph_columns(conn, robot_id, up, whole=up.base_version is None)
    event = {
        "kind": "snapshot" if up.base_version is None else "delta",
        "robot_id": robot_id,
        **{name: getattr(up, name) for name in MAP_FIELDS},  # the lists themselves, not copies
    }
    applied = AppliedUpload(
        MapUploadOut(version=v, duplicate=False, map_session=up.map_session), event, new_session, undo
    )
    with pgrows.pipelined(conn):  # PostgreSQL: the writes below in one round trip
        _write_rows(conn, robot_id, up, rows, seen_at, key, graph)
        extra = None if also is None else also(conn, applied)
    # bounded sizes (docs/reliability/bounded.md), in the same transaction, after the pipelined writes
    # (these read rows): the trajectory thinned past its cap, the idempotency records trimmed now and then
    if rows.trajectory:
        thin_trajectory(conn, robot_id, over=reads.trajectory_over)
    if v % _TRIM_EVERY == 0:
        trim_upload_records(conn, robot_id)
    return applied if extra is None else replace(applied, extra=extra)


def queue_upload_reads(
    conn: Connection, robot_id: int, up: MapUpload, key: str, max_walls: int | None
) -> pgrows.PendingReads | None:
    """On PostgreSQL, queue the lock and the reads :func:`apply_upload` begins with in the pipeline open on
    ``conn`` (:func:`server.pgrows.pipelined`), for ``apply_upload(..., pending=...)`` once it has synced;
    elsewhere None (it reads them itself)."""
    if conn.dialect.name != "postgresql":
        return None
    return pgrows.queue_lock_and_read(
        conn, _UPLOAD_LOCK_CLASS, robot_id, key, _counts(up, max_walls), _delta_probe(up)
    )


def _counts(up: MapUpload, max_walls: int | None) -> bool:
    """Whether the upload's first reads count the stored walls (a delta under a wall cap)."""
    return up.base_version is not None and max_walls is not None


def _delta_probe(up: MapUpload) -> pgrows.DeltaProbe | None:
    if up.base_version is None:
        return None
    return pgrows.DeltaProbe(touched_ids(up), up.base_version, len(up.trajectory), MAX_TRAJECTORY_POSES)


def _lock_and_read(
    conn: Connection, robot_id: int, key: str, count: bool, up: MapUpload
) -> pgrows.UploadReads:
    """Serialise the robot's uploads, then read the robot's map version and session, the upload already
    applied under ``key`` and (``count``) the walls stored; on PostgreSQL with a delta ``up`` also what its
    undo record and the trajectory's cap read (:class:`server.pgrows.DeltaProbe`), in the same round trip.
    PostgreSQL: a per-robot advisory lock, not the robot's row: a near-limit upload's transaction lasts
    seconds, and the row lock held all along stalled every write batch that touched the row (last-seen
    times); the row itself is updated at the end of the transaction only. SQLite: its one write lock
    serialises. Other databases: the robot's row lock."""
    if conn.dialect.name == "postgresql":
        return pgrows.lock_and_read(conn, _UPLOAD_LOCK_CLASS, robot_id, key, count, _delta_probe(up))
    q = select(_ROBOTS.c.map_version, _ROBOTS.c.map_session).where(_ROBOTS.c.id == robot_id)
    if conn.dialect.name != "sqlite":
        q = q.with_for_update()
    robot = conn.execute(q).first()
    seen = conn.execute(
        select(_UPLOADS.c.version, _UPLOADS.c.map_session).where(
            _UPLOADS.c.robot_id == robot_id, _UPLOADS.c.idempotency_key == key
        )
    ).first()
    return pgrows.UploadReads(
        None if robot is None else (robot[0], robot[1]), None if seen is None else (seen[0], seen[1]), None
    )


def _write_rows(
    conn: Connection,
    robot_id: int,
    up: MapUpload,
    rows: PreparedRows,
    seen_at: datetime | None,
    key: str,
    graph: dict[str, Any],
) -> None:
    """The upload's writes, after its checks: the delta's removed walls, the walls and poses, the map
    state (with the pose graph's columns ``graph``), the robot row, the upload record. No statement here
    returns rows (PostgreSQL pipelines them)."""
    v = up.version
    if up.base_version is not None:
        _delete_walls(conn, robot_id, up.removed)
    _bulk_segments(conn, robot_id, v, up.segments, rows)
    if conn.dialect.name == "postgresql":
        pgrows.insert_trajectory(conn, rows.trajectory)
    else:
        _multi_row(conn, _TRAJECTORY_SQL, 6, rows.trajectory)
    now = utcnow()
    pose = {"x_m": up.pose[0], "y_m": up.pose[1], "theta_rad": up.pose[2]}
    _upsert(
        conn,
        _STATE,
        ["robot_id"],
        ("version", "stamp_s", "centroids", "pose", "wall_time_s", "updated_at", *graph),
        [
            {
                "robot_id": robot_id,
                "version": v,
                "stamp_s": up.stamp_s,
                "centroids": {"xy": up.centroids},
                "pose": pose,
                "wall_time_s": up.wall_time_s,
                "updated_at": now,
                **graph,
            }
        ],
    )
    changes: dict[str, Any] = {"map_version": v, "map_session": up.map_session}
    if seen_at is not None:
        changes["last_seen_at"] = seen_at
    if up.status is not None:
        changes.update(status_columns(up.status))
    conn.execute(_ROBOT_UPDATE, {"robot_row": robot_id, **changes})
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
    conn.execute(_UPLOAD_INSERT, record)


def _delete_ids(conn: Connection, table: Table, ids: list[int]) -> None:
    for start in range(0, len(ids), _CHUNK_ROWS):
        conn.execute(delete(table).where(table.c.id.in_(ids[start : start + _CHUNK_ROWS])))


def thin_trajectory(
    conn: Connection, robot_id: int, max_poses: int = MAX_TRAJECTORY_POSES, *, over: bool | None = None
) -> int:
    """Thin the robot's stored trajectory to at most ``max_poses`` poses
    (:func:`shared.protocol.thin_positions`: the newest half whole, older ones ever sparser); the poses
    dropped. One index probe when it fits (none when the caller probed already: ``over``, whether it
    holds more than ``max_poses``); O(max_poses) when it does not (once per ~max_poses / 4 poses
    stored)."""
    if over is None:
        over = (
            conn.execute(
                select(_TRAJ.c.id)
                .where(_TRAJ.c.robot_id == robot_id)
                .order_by(_TRAJ.c.id.desc())
                .limit(1)
                .offset(max_poses)
            ).first()
            is not None
        )
    if not over:
        return 0
    ids = [
        int(r[0])
        for r in conn.execute(select(_TRAJ.c.id).where(_TRAJ.c.robot_id == robot_id).order_by(_TRAJ.c.id))
    ]
    drop = [ids[i] for i in thin_positions(len(ids), max_poses)]
    _delete_ids(conn, _TRAJ, drop)
    return len(drop)


def trim_upload_records(conn: Connection, robot_id: int, keep: int = KEEP_UPLOAD_RECORDS) -> None:
    """Drop the robot's idempotency records older than its last ``keep`` (:data:`KEEP_UPLOAD_RECORDS`)."""
    edge = conn.execute(
        select(_UPLOADS.c.id)
        .where(_UPLOADS.c.robot_id == robot_id)
        .order_by(_UPLOADS.c.id.desc())
        .limit(1)
        .offset(keep)
    ).scalar()
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


def _stamp(conn: Connection, robot_id: int) -> float | None:
    """The scan time stamp of the robot's current map version (None before its first upload): with the
    version and session in a 409, a robot tells its own lost answer (it recorded that version with that
    stamp) from a map it did not make (a Robot DB restored from an older copy)."""
    got = conn.execute(select(_STATE.c.stamp_s).where(_STATE.c.robot_id == robot_id)).scalar()
    return None if got is None else float(got)
