"""A robot's map history: which earlier versions of its current mapping session can be replayed, and
version N rebuilt (the dashboard's history slider; ``?version=N`` on ``/maps/latest`` and the exports).

The database holds only each robot's current map. Each delta logged in the delta log
(:mod:`server.maplog`, the last :data:`server.maplog.KEEP_VERSIONS` uploads of the current session) also
keeps its *undo record* (:func:`capture_undo`, written in the upload's transaction): the walls it changed
or removed as they were before it, the ids it added, and the centroids, pose and stamps before it. Version
N is rebuilt by undoing, newest first, the logged deltas above N from the current map; its trajectory is
the stored poses uploaded at or before N.

So the replayable versions are the current one and, going down the log, each delta's base version, as long
as the deltas chain (each one's base is the version logged below it). The chain stops at a snapshot upload
(it replaced the whole map and keeps no undo record: its own version is the oldest replayable), at a
version that has left the log (it keeps the last ``KEEP_VERSIONS`` uploads), at a delta logged before undo
records were kept, and at the start of the session (a new session clears the log).

Costs: the undo record costs one primary-key read of the touched walls and of the map state per delta
upload, O(walls in the delta); listing is O(log rows); rebuilding is O(walls + poses + the undone deltas).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Connection, Table, select
from sqlalchemy.orm import Session

from server import jsontext
from server.errors import ConflictError, GoneError, NotFoundError, UnavailableError
from server.mapgraph import GRAPH_COLUMNS, graph_fields
from server.maplog import KEEP_VERSIONS
from server.models import MapDeltaRecord, MapSegment, MapState, Robot, TrajectoryPoint
from server.schemas import MapHistoryOut, MapHistoryVersion, MapOut, MapUpload

__all__ = [
    "UndoReads",
    "capture_undo",
    "map_version",
    "read_history",
    "read_undo",
    "read_version",
    "touched_ids",
    "undo_record",
]

_LOG: Table = MapDeltaRecord.__table__  # type: ignore[assignment]
_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_STATE: Table = MapState.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
_CHUNK = 500
#: reads retried when an upload commits in between (PostgreSQL reads each statement at its own time)
_READ_TRIES = 5


@dataclass(frozen=True, slots=True)
class UndoReads:
    """What a delta's undo record reads before the delta is applied: the touched walls that exist
    (``touched``: rows ``(id, x0, y0, x1, y1)``), whether the base version's log entry holds its body
    (``base_logged``), and the map state's ``(stamp_s, pose, wall_time_s, centroids)`` (None before the
    first upload; ``centroids`` the stored ``{"xy": ...}`` value, read only when ``base_logged`` is
    false). PostgreSQL reads them in the upload's first round trip (:func:`server.pgrows.lock_and_read`)."""

    touched: list[Any]
    base_logged: bool
    state: tuple[float, dict[str, float], float | None, dict[str, Any] | None] | None


def capture_undo(conn: Connection, robot_id: int, up: MapUpload, reads: UndoReads | None = None) -> str:
    """The undo record of delta ``up`` as JSON, read in ``conn``'s transaction before it is applied (or
    from ``reads``, read already in that transaction): see :func:`undo_record`. O(walls in ``up``):
    without ``reads``, two statements and one primary-key probe."""
    return undo_record(up, reads if reads is not None else read_undo(conn, robot_id, up))[0]


def undo_record(up: MapUpload, reads: UndoReads) -> tuple[str, frozenset[int]]:
    """The undo record of delta ``up`` as JSON, from what it read before the delta is applied: the touched
    walls as they are (``walls``: rows ``[id, x0, y0, x1, y1]``; those the delta sends unchanged are left
    out), the touched ids that do not exist yet (``absent``), and the small part of the map state
    (``stamp_s``, ``pose``, ``wall_time_s``). The centroids only when the base version's own log entry
    does not hold them (a snapshot is logged without its body): a delta's entry carries them all, and
    keeping them twice doubled the log (8.3 of 17 KB a version on the simulator).

    And the ids of the walls the delta sends exactly as they are stored (a wall sent twice counts with
    its last row) and does not remove: writing them again would change nothing but the database's work (a
    robot re-sending its window of walls sends mostly these), so :func:`server.mapstore.apply_upload`
    leaves them out of its writes. O(walls in ``up``)."""
    touched = touched_ids(up)
    present = {int(r[0]) for r in reads.touched}
    sent = {int(r[0]): (r[1], r[2], r[3], r[4]) for r in up.segments}
    removed = set(up.removed)
    walls: list[list[Any]] = []
    same: list[int] = []
    for i, x0, y0, x1, y1 in reads.touched:
        if sent.get(int(i)) != (x0, y0, x1, y1):
            walls.append([int(i), x0, y0, x1, y1])
        elif int(i) not in removed:
            same.append(int(i))
    st = reads.state
    record: dict[str, Any] = {
        "walls": walls,
        "absent": [i for i in touched if i not in present],
        "stamp_s": st[0] if st else 0.0,
        "pose": [st[1]["x_m"], st[1]["y_m"], st[1]["theta_rad"]] if st else [0.0, 0.0, 0.0],
        "wall_time_s": st[2] if st else None,
    }
    if not reads.base_logged:
        record["centroids"] = list((st[3] or {}).get("xy", [])) if st else []
    return jsontext.dumps(record), frozenset(same)


def read_undo(conn: Connection, robot_id: int, up: MapUpload) -> UndoReads:
    """What delta ``up``'s undo record reads (:class:`UndoReads`), read in ``conn``'s transaction: two
    statements and one primary-key probe. O(walls in ``up``)."""
    return _undo_reads(conn, robot_id, up, touched_ids(up))


def touched_ids(up: MapUpload) -> list[int]:
    """The wall ids delta ``up`` sends or removes, sorted, each once."""
    return sorted({int(r[0]) for r in up.segments} | {int(i) for i in up.removed})


def _undo_reads(conn: Connection, robot_id: int, up: MapUpload, touched: list[int]) -> UndoReads:
    rows = _touched_walls(conn, robot_id, touched)
    base_logged = bool(
        conn.execute(
            select(_LOG.c.body.is_not(None)).where(
                _LOG.c.robot_id == robot_id, _LOG.c.version == up.base_version
            )
        ).scalar()
    )
    columns = [_STATE.c.stamp_s, _STATE.c.pose, _STATE.c.wall_time_s]
    st = conn.execute(
        select(*columns, *([] if base_logged else [_STATE.c.centroids])).where(_STATE.c.robot_id == robot_id)
    ).first()
    state = None if st is None else (st[0], st[1], st[2], None if base_logged else st[3])
    return UndoReads(rows, base_logged, state)


#: the touched walls in one constant statement with the ids as one parameter (SQLAlchemy's expanding IN
#: re-renders 200 placeholders per upload: measured 3.5 ms of the upload's 9.4 ms on SQLite)
_TOUCHED_SQL = {
    "sqlite": "SELECT segment_id, x0_m, y0_m, x1_m, y1_m FROM map_segments "
    "WHERE robot_id = ? AND segment_id IN (SELECT value FROM json_each(?)) ORDER BY segment_id",
    "postgresql": "SELECT segment_id, x0_m, y0_m, x1_m, y1_m FROM map_segments "
    "WHERE robot_id = %s AND segment_id = ANY(%s::bigint[]) ORDER BY segment_id",
}


def _touched_walls(conn: Connection, robot_id: int, ids: list[int]) -> list[Any]:
    """Rows ``(id, x0, y0, x1, y1)`` of the robot's walls among ``ids`` (sorted; absent ones are left
    out), by id. One statement on SQLite and PostgreSQL; ``_CHUNK`` ids a statement elsewhere. O(ids)."""
    if not ids:
        return []
    name = conn.dialect.name
    if name in _TOUCHED_SQL:
        param: Any = jsontext.dumps(ids) if name == "sqlite" else ids
        return list(conn.exec_driver_sql(_TOUCHED_SQL[name], (int(robot_id), param)))
    rows: list[Any] = []
    for start in range(0, len(ids), _CHUNK):
        q = (
            select(_SEG.c.segment_id, _SEG.c.x0_m, _SEG.c.y0_m, _SEG.c.x1_m, _SEG.c.y1_m)
            .where(_SEG.c.robot_id == robot_id, _SEG.c.segment_id.in_(ids[start : start + _CHUNK]))
            .order_by(_SEG.c.segment_id)
        )
        rows.extend(conn.execute(q))
    return rows


def map_version(s: Session, robot_id: int) -> tuple[str | None, int]:
    """The robot's current (map session, map version), read anew."""
    robot = s.get(Robot, robot_id, populate_existing=True)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    return robot.map_session, robot.map_version


@dataclass(frozen=True, slots=True)
class _Chain:
    """The replayable versions, newest first, with their scan stamps, and why the chain ends there."""

    session: str | None
    current: int
    versions: list[tuple[int, float]]
    undo: dict[int, dict[str, Any]]  # by the version of the delta that keeps it
    stop: str


def _chain(s: Session, robot_id: int, below: int = -1) -> _Chain:
    """Walk the delta log down from the current version (to ``below`` at the lowest, exclusive)."""
    session, current = map_version(s, robot_id)
    st = s.get(MapState, robot_id, populate_existing=True)
    rows = {
        int(v): (None if b is None else int(b), u)
        for v, b, u in s.execute(
            select(_LOG.c.version, _LOG.c.base_version, _LOG.c.undo).where(
                _LOG.c.robot_id == robot_id, _LOG.c.version > below
            )
        )
    }
    versions = [(current, st.stamp_s if st else 0.0)]
    undo: dict[int, dict[str, Any]] = {}
    left_log = (
        "versions before it have left the delta log, which keeps each robot's last "
        f"{KEEP_VERSIONS} uploads of its current mapping session"
    )
    v, stop = current, ""
    while v > below and not stop:
        if v == 0:
            stop = "version 0 is the empty map before the first upload"
        elif v not in rows:
            stop = left_log
        elif rows[v][0] is None:
            stop = "it is a snapshot upload, which replaced the whole map (nothing before it is kept)"
        elif rows[v][1] is None:
            stop = "the delta after it was logged before undo records were kept"
        elif (
            "centroids" not in (record := json.loads(str(rows[v][1])))
            and rows[v][0] not in rows
            and rows[v][0]
        ):
            stop = left_log  # its base's centroids were in the base's own entry (capture_undo), gone now
        else:
            base = rows[v][0]
            assert base is not None
            undo[v] = record
            versions.append((base, float(record["stamp_s"])))
            v = base
    return _Chain(session, current, versions, undo, stop)


def read_history(s: Session, robot_id: int) -> MapHistoryOut:
    """The versions of the robot's current map session that can be replayed, oldest first, with the
    reason older ones cannot. O(log rows)."""
    for _ in range(_READ_TRIES):
        chain = _chain(s, robot_id)
        if map_version(s, robot_id) == (chain.session, chain.current):
            break
    else:
        raise UnavailableError(f"robot {robot_id}'s map kept changing while its history was read: ask again")
    versions = [MapHistoryVersion(version=v, stamp_s=t) for v, t in reversed(chain.versions)]
    return MapHistoryOut(
        robot_id=robot_id,
        map_session=chain.session,
        current_version=chain.current,
        first_version=versions[0].version,
        versions=versions,
        older=f"version {versions[0].version} is the oldest replayable: {chain.stop}",
    )


def _range(chain: _Chain) -> str:
    lo = chain.versions[-1][0]
    return f"{lo}..{chain.current}" if lo != chain.current else str(lo)


def read_version(s: Session, robot_id: int, version: int, tail: int | None) -> MapOut:
    """Version ``version`` of the robot's current map session, rebuilt from the current map and the undo
    records above it; 409 (with ``current_version``) for a version above the current one, 410 for one
    older than the replayable range, 404 for a number inside it that was never a version; each names the
    replayable range. ``tail``: only the last N trajectory poses. O(walls + poses + undone deltas)."""
    for _ in range(_READ_TRIES):
        chain = _chain(s, robot_id, below=version - 1)
        if version > chain.current or version not in {v for v, _t in chain.versions}:
            _refuse(_chain(s, robot_id), robot_id, version)  # the whole range, to name it
            continue  # held after all: an upload came between the two reads
        m = _rebuild(s, robot_id, chain, version, tail)
        if map_version(s, robot_id) == (chain.session, chain.current):
            return m
    raise UnavailableError(
        f"robot {robot_id}'s map kept changing while version {version} was rebuilt: ask again"
    )


def _refuse(chain: _Chain, robot_id: int, version: int) -> None:
    """Raise the refusal of ``version`` naming the replayable range of ``chain`` (the whole one); returns
    only if ``version`` is held after all (an upload came between the two reads)."""
    held = {v for v, _t in chain.versions}
    session = f" (session {chain.session})" if chain.session else ""
    where = f"replayable versions of robot {robot_id}'s map{session}: {_range(chain)}"
    if version > chain.current:
        raise ConflictError(
            f"version {version} of robot {robot_id}'s map is not held here (the current is "
            f"{chain.current}; {where}): ask again without version, or with one of those",
            current_version=chain.current,
        )
    if version not in held:
        lowest = chain.versions[-1][0]
        if version < lowest:
            raise GoneError(
                f"version {version} of robot {robot_id}'s map is no longer held ({where}; version {lowest} "
                f"is the oldest because {chain.stop})",
                current_version=chain.current,
                first_version=lowest,
            )
        raise NotFoundError(
            f"robot {robot_id}'s map has no version {version} (uploads skipped that number; {where})",
            current_version=chain.current,
            first_version=lowest,
        )


def _logged_centroids(s: Session, robot_id: int, version: int) -> list[Any]:
    """The centroids of ``version`` from its own log entry ([] for version 0, the empty map). One
    primary-key read."""
    if version == 0:
        return []
    body = s.execute(
        select(_LOG.c.body).where(_LOG.c.robot_id == robot_id, _LOG.c.version == version)
    ).scalar()
    return list(json.loads(str(body)).get("centroids", [])) if body is not None else []


def _rebuild(s: Session, robot_id: int, chain: _Chain, version: int, tail: int | None) -> MapOut:
    """Version ``version`` (held by ``chain``) from the current map and the undo records above it."""
    walls = {
        int(i): [float(i), x0, y0, x1, y1]
        for i, x0, y0, x1, y1 in s.execute(
            select(_SEG.c.segment_id, _SEG.c.x0_m, _SEG.c.y0_m, _SEG.c.x1_m, _SEG.c.y1_m).where(
                _SEG.c.robot_id == robot_id
            )
        )
    }
    st = s.get(MapState, robot_id, populate_existing=True)
    state: dict[str, Any] = {
        "stamp_s": st.stamp_s if st else 0.0,
        "centroids": list(st.centroids.get("xy", [])) if st else [],
        "pose": [st.pose["x_m"], st.pose["y_m"], st.pose["theta_rad"]] if st else [0.0, 0.0, 0.0],
        "wall_time_s": st.wall_time_s if st else None,
    }
    for v in sorted((v for v in chain.undo if v > version), reverse=True):
        record = chain.undo[v]
        for i in record["absent"]:
            walls.pop(int(i), None)
        for row in record["walls"]:
            walls[int(row[0])] = [float(row[0]), *map(float, row[1:5])]
        state = {k: record.get(k) for k in ("stamp_s", "centroids", "pose", "wall_time_s")}
    if state["centroids"] is None:  # an undo record without them: version's own log entry has them
        state["centroids"] = _logged_centroids(s, robot_id, version)
    tq = select(_TRAJ.c.stamp_s, _TRAJ.c.x_m, _TRAJ.c.y_m, _TRAJ.c.theta_rad).where(
        _TRAJ.c.robot_id == robot_id, _TRAJ.c.version <= version
    )
    if tail is not None:
        traj = list(s.execute(tq.order_by(_TRAJ.c.id.desc()).limit(tail)))[::-1]
    else:
        traj = list(s.execute(tq.order_by(_TRAJ.c.id)))
    # the pose graph is kept for the current version only (a past one's keyframes are not rebuilt)
    graph = {c: getattr(st, c) for c in GRAPH_COLUMNS} if st is not None and version == chain.current else {}
    return MapOut(
        robot_id=robot_id,
        version=version,
        map_session=chain.session,
        **graph_fields(graph),
        stamp_s=float(state["stamp_s"]),
        segments=[walls[i] for i in sorted(walls)],
        centroids=[list(c) for c in state["centroids"]],
        pose=[float(x) for x in state["pose"]],
        trajectory=[list(t) for t in traj],
        wall_time_s=state["wall_time_s"],
    )
