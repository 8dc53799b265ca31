"""The server's copy of each robot's temporary map: apply snapshot and delta uploads, read the whole map.

Walls are rows keyed by (robot, segment id), so a delta costs O(changed walls), not O(map). An upload's
idempotency key is recorded in the same transaction as its changes: a retry finds the key and changes
nothing. A delta must start from the version the server has (``base_version`` == current) or it is
refused with 409 and the server's version, and the robot sends a snapshot instead.

Bounded whatever the run's length: a robot's stored trajectory is thinned past
:data:`shared.protocol.MAX_TRAJECTORY_POSES` poses (:func:`shared.protocol.thin_positions`, the rule the
robot applies to its own), and the idempotency records keep the robot's last :data:`KEEP_UPLOAD_RECORDS`
uploads; both are trimmed in the upload's transaction. The rows themselves are written by
:mod:`server.maprows`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, Table, delete, select

from server import pgrows
from server.errors import ConflictError, MapSessionMismatchError, NotFoundError
from server.mapcounts import Counts, reconcile, walls_after_delta, walls_of_snapshot
from server.mapgraph import graph_columns, prune_graph
from server.maphistory import read_undo, touched_ids, undo_record
from server.mapread import map_version, read_map  # the read side, importable from here as before
from server.maprows import (  # the rows' writes, importable from here as before
    KEEP_UPLOAD_RECORDS,
    PreparedRows,
    delete_walls,
    prepare_rows,
    status_columns,
    thin_trajectory,
    trim_upload_records,
    write_rows,
)
from server.mapsessions import check_not_ended, start_session
from server.models import MapSegment, MapState, MapUploadRecord, Robot, TrajectoryPoint, utcnow
from server.schemas import MapUpload, MapUploadOut
from server.wallcap import check_wall_cap  # importable from here as before
from shared.protocol import MAP_FIELDS, MAX_TRAJECTORY_POSES

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
#: First key of the per-robot upload advisory lock on PostgreSQL ("LMUP"; the second key is the robot id).
#: Distinct from the high half of server.migrate.SCHEMA_LOCK_KEY, so the two never collide.
_UPLOAD_LOCK_CLASS = 0x4C4D5550
_TRIM_EVERY = 256  # the records are trimmed when the upload's version is a multiple of this


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
    reads = pending.result() if pending is not None else _lock_and_read(conn, robot_id, key, up)
    robot, seen, stored = reads.robot, reads.seen, reads.counts
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    if seen is not None:  # answered with the session it was applied in: the robot checks it is its own
        return AppliedUpload(MapUploadOut(version=seen[0], duplicate=True, map_session=seen[1]), None)
    current, session = robot[0], robot[1]
    new_session, undo, same = up.map_session != session, None, frozenset[int]()
    # the walls and poses stored after the upload (server.mapcounts): poses kept, before the upload's own
    walls_after, poses_kept = stored.walls, stored.poses
    if new_session:
        check_not_ended(conn, robot_id, up.map_session, session)
    if up.base_version is None and new_session:
        if max_walls is not None:
            check_wall_cap(robot_id, up, max_walls)
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
        walls_after, poses_kept = walls_of_snapshot(up), 0
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
            check_wall_cap(robot_id, up, max_walls)
        if prepared is not None and prepared.diff_base is not None and prepared.diff_base != current:
            log.info(
                "robot %d's map moved (version %d -> %d) since its snapshot's diff: replacing it whole",
                robot_id,
                prepared.diff_base,
                current,
            )
            prepared = prepare_rows(robot_id, up)
        if prepared is not None and prepared.diff_base is not None:  # the diff against the stored map
            delete_walls(conn, robot_id, prepared.removed)
        else:
            conn.execute(delete(_SEG).where(_SEG.c.robot_id == robot_id))
        if prepared is None or prepared.replace_trajectory:
            conn.execute(delete(_TRAJ).where(_TRAJ.c.robot_id == robot_id))
            poses_kept = 0
        walls_after = walls_of_snapshot(up)  # whole or as a diff, the map becomes the snapshot's walls
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
        undo_reads = reads.undo if reads.undo is not None else read_undo(conn, robot_id, up)
        walls_after = walls_after_delta(stored.walls, up, (r[0] for r in undo_reads.touched))
        if max_walls is not None:
            check_wall_cap(robot_id, up, max_walls, before=stored.walls, after=walls_after)
        # what the delta replaces (read before the writes), and the walls it sends as they are stored
        undo, same = undo_record(up, undo_reads)
    v = up.version
    rows = prepared or prepare_rows(robot_id, up)
    if same:  # walls the delta sends again as they are stored are not written again
        rows = replace(rows, segments=[r for r in rows.segments if r[1] not in same])
    counts = Counts(walls_after, poses_kept + len(rows.trajectory))
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
        write_rows(conn, robot_id, up, rows, seen_at, key, graph, counts)
        extra = None if also is None else also(conn, applied)
    # bounded sizes (docs/reliability/bounded.md), in the same transaction, after the pipelined writes
    # (these read rows): the trajectory thinned past its cap, the idempotency records trimmed now and then
    if counts.poses > MAX_TRAJECTORY_POSES:
        dropped = thin_trajectory(conn, robot_id, poses=counts.poses)
        counts = Counts(counts.walls, counts.poses - dropped)
        prune_graph(conn, robot_id)  # and the keyframes that own none of the poses left
    if v % _TRIM_EVERY == 0:
        trim_upload_records(conn, robot_id)
        reconcile(conn, robot_id, counts)  # the counts checked against the rows now and then
    return applied if extra is None else replace(applied, extra=extra)


def queue_upload_reads(
    conn: Connection, robot_id: int, up: MapUpload, key: str
) -> pgrows.PendingReads | None:
    """On PostgreSQL, queue the lock and the reads :func:`apply_upload` begins with in the pipeline open on
    ``conn`` (:func:`server.pgrows.pipelined`), for ``apply_upload(..., pending=...)`` once it has synced;
    elsewhere None (it reads them itself)."""
    if conn.dialect.name != "postgresql":
        return None
    return pgrows.queue_lock_and_read(conn, _UPLOAD_LOCK_CLASS, robot_id, key, _delta_probe(up))


def _delta_probe(up: MapUpload) -> pgrows.DeltaProbe | None:
    if up.base_version is None:
        return None
    return pgrows.DeltaProbe(touched_ids(up), up.base_version)


def _lock_and_read(conn: Connection, robot_id: int, key: str, up: MapUpload) -> pgrows.UploadReads:
    """Serialise the robot's uploads, then read the robot's map version and session, its walls and poses
    stored (:mod:`server.mapcounts`) and the upload already applied under ``key``; on PostgreSQL with a
    delta ``up`` also what its undo record reads (:class:`server.pgrows.DeltaProbe`), in the same round trip.
    PostgreSQL: a per-robot advisory lock, not the robot's row: a near-limit upload's transaction lasts
    seconds, and the row lock held all along stalled every write batch that touched the row (last-seen
    times); the row itself is updated at the end of the transaction only. SQLite: its one write lock
    serialises. Other databases: the robot's row lock."""
    if conn.dialect.name == "postgresql":
        return pgrows.lock_and_read(conn, _UPLOAD_LOCK_CLASS, robot_id, key, _delta_probe(up))
    q = (
        select(_ROBOTS.c.map_version, _ROBOTS.c.map_session, _STATE.c.n_walls, _STATE.c.n_poses)
        .select_from(_ROBOTS.outerjoin(_STATE, _STATE.c.robot_id == _ROBOTS.c.id))
        .where(_ROBOTS.c.id == robot_id)
    )
    if conn.dialect.name != "sqlite":
        q = q.with_for_update(of=_ROBOTS)
    robot = conn.execute(q).first()
    seen = conn.execute(
        select(_UPLOADS.c.version, _UPLOADS.c.map_session).where(
            _UPLOADS.c.robot_id == robot_id, _UPLOADS.c.idempotency_key == key
        )
    ).first()
    if robot is None:
        return pgrows.UploadReads(None, None if seen is None else (seen[0], seen[1]))
    return pgrows.UploadReads(
        (robot[0], robot[1]),
        None if seen is None else (seen[0], seen[1]),
        Counts(int(robot[2] or 0), int(robot[3] or 0)),
    )


def _stamp(conn: Connection, robot_id: int) -> float | None:
    """The scan time stamp of the robot's current map version (None before its first upload): with the
    version and session in a 409, a robot tells its own lost answer (it recorded that version with that
    stamp) from a map it did not make (a Robot DB restored from an older copy)."""
    got = conn.execute(select(_STATE.c.stamp_s).where(_STATE.c.robot_id == robot_id)).scalar()
    return None if got is None else float(got)
