"""A robot's mapping sessions (docs/reliability/identity.md): one map per (robot, session).

The current session's map lives in ``map_segments`` / ``trajectory_points`` / ``map_states`` (the hot
upload path, :mod:`server.mapstore`, is unchanged by sessions); when a snapshot of a new session arrives
:func:`start_session` moves that map into ``map_session_segments`` / ``map_session_trajectory`` under the
ended session's ``map_sessions`` row (one ``INSERT ... SELECT`` each: O(walls + poses) in the database, no
rows through Python) and opens a row for the new session. :func:`list_sessions` and
:func:`read_session_map` read them back. An ended session is never reopened: an upload of it is refused
(:class:`~server.errors.MapSessionEndedError`), so two maps are never mixed.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import Connection, Table, func, insert, literal, select, update
from sqlalchemy.orm import Session

from server.errors import MapSessionEndedError, NotFoundError
from server.models import (
    AuditEntry,
    MapSegment,
    MapSession,
    MapSessionSegment,
    MapSessionTrajectoryPoint,
    MapState,
    Robot,
    TrajectoryPoint,
)
from server.schemas import MapOut, MapSessionOut

__all__ = ["check_not_ended", "list_sessions", "read_session_map", "start_session"]

_SESS: Table = MapSession.__table__  # type: ignore[assignment]
_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
_STATE: Table = MapState.__table__  # type: ignore[assignment]
_ARCH_SEG: Table = MapSessionSegment.__table__  # type: ignore[assignment]
_ARCH_TRAJ: Table = MapSessionTrajectoryPoint.__table__  # type: ignore[assignment]
_AUDIT: Table = AuditEntry.__table__  # type: ignore[assignment]
_ROBOTS: Table = Robot.__table__  # type: ignore[assignment]


def _same(column: Any, session_id: str | None) -> Any:
    return column.is_(None) if session_id is None else column == session_id


def check_not_ended(conn: Connection, robot_id: int, session_id: str | None, current: str | None) -> None:
    """Refuse (409 ``map_session_ended``) an upload of a session of ``robot_id`` that has ended. O(sessions
    of the robot) on an index; called only when the upload's session is not the current one."""
    if session_id == current:
        return
    row = conn.execute(
        select(_SESS.c.ended_at).where(
            _SESS.c.robot_id == robot_id, _same(_SESS.c.session_id, session_id), _SESS.c.ended_at.isnot(None)
        )
    ).first()
    if row is not None or (session_id is None and current is not None):
        raise MapSessionEndedError(
            f"map session {session_id or '(none: an agent from before map sessions)'} of robot {robot_id} "
            f"ended{' at ' + row[0].isoformat() if row is not None else ''}; the server's current session is "
            f"{current}: start a new session (a snapshot with a new map_session)",
            current_session=current,
        )


def start_session(
    conn: Connection,
    robot_id: int,
    *,
    old: str | None,
    old_version: int,
    new: str | None,
    first_version: int,
    reason: str | None,
    actor: str,
    now: datetime,
) -> None:
    """End the robot's current session (``old``, its map at ``old_version``; nothing to keep at version 0)
    and open ``new`` at ``first_version``, in the caller's transaction, with an audit entry. The current
    map's rows are copied to the ended session's tables; the caller then replaces them with the new map."""
    current = conn.execute(
        select(_SESS.c.id).where(_SESS.c.robot_id == robot_id, _SESS.c.ended_at.is_(None))
    ).first()
    ended: int | None = None
    if old_version > 0 or current is not None:
        if current is None:  # the map of a robot from before sessions: give it a row now
            ended = int(
                conn.execute(
                    insert(_SESS)
                    .values(robot_id=robot_id, session_id=old, started_at=now, reason="before map sessions")
                    .returning(_SESS.c.id)
                ).scalar_one()
            )
        else:
            ended = int(current[0])
        cols = ("segment_id", "x0_m", "y0_m", "x1_m", "y1_m", "version")
        conn.execute(
            insert(_ARCH_SEG).from_select(
                ["session_pk", *cols],
                select(literal(ended, _ARCH_SEG.c.session_pk.type), *(_SEG.c[c] for c in cols)).where(
                    _SEG.c.robot_id == robot_id
                ),
            )
        )
        tcols = ("version", "stamp_s", "x_m", "y_m", "theta_rad")
        conn.execute(
            insert(_ARCH_TRAJ).from_select(
                ["session_pk", *tcols],
                select(literal(ended, _ARCH_TRAJ.c.session_pk.type), *(_TRAJ.c[c] for c in tcols))
                .where(_TRAJ.c.robot_id == robot_id)
                .order_by(_TRAJ.c.id),
            )
        )
        walls = conn.execute(select(func.count()).select_from(_SEG).where(_SEG.c.robot_id == robot_id))
        st = conn.execute(
            select(
                _STATE.c.stamp_s, _STATE.c.pose, _STATE.c.centroids, _STATE.c.wall_time_s, _STATE.c.updated_at
            ).where(_STATE.c.robot_id == robot_id)
        ).first()
        state = (
            {"stamp_s": st[0], "pose": st[1], "centroids": st[2], "wall_time_s": st[3]}
            if st is not None
            else None
        )
        conn.execute(
            update(_SESS)
            .where(_SESS.c.id == ended)
            .values(
                ended_at=now,
                last_version=old_version,
                last_upload_at=st[4] if st is not None else None,
                wall_count=int(walls.scalar_one()),
                state=state,
            )
        )
    conn.execute(
        insert(_SESS).values(
            robot_id=robot_id, session_id=new, started_at=now, first_version=first_version, reason=reason
        )
    )
    conn.execute(
        insert(_AUDIT).values(
            at=now,
            actor=actor,
            action="map.session.start",
            target=f"robot:{robot_id}",
            detail={
                "session": new,
                "first_version": first_version,
                "reason": reason,
                "previous_session": old,
                "previous_version": old_version,
            },
        )
    )


def list_sessions(s: Session, robot_id: int) -> list[MapSessionOut]:
    """The robot's sessions, newest first: the current one's figures read live, ended ones' as stored.
    O(sessions) plus one count of the current map's walls."""
    robot = s.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    rows = list(
        s.scalars(select(MapSession).where(MapSession.robot_id == robot_id).order_by(MapSession.id.desc()))
    )
    out: list[MapSessionOut] = []
    open_seen = False
    for r in rows:
        if r.ended_at is None:
            open_seen = True
            out.append(_live(s, robot, r.session_id, r.started_at, r.first_version, r.reason))
        else:
            out.append(
                MapSessionOut(
                    map_session=r.session_id,
                    current=False,
                    first_version=r.first_version,
                    last_version=r.last_version,
                    started_at=r.started_at,
                    last_upload_at=r.last_upload_at,
                    ended_at=r.ended_at,
                    wall_count=r.wall_count or 0,
                    reason=r.reason,
                )
            )
    if not open_seen and robot.map_version > 0:  # a robot from before sessions, still on its first map
        out.insert(0, _live(s, robot, robot.map_session, None, None, "before map sessions"))
    return out


def _live(
    s: Session,
    robot: Robot,
    session_id: str | None,
    started: datetime | None,
    first: int | None,
    reason: str | None,
) -> MapSessionOut:
    walls = s.scalar(select(func.count()).select_from(MapSegment).where(MapSegment.robot_id == robot.id))
    state = s.get(MapState, robot.id)
    return MapSessionOut(
        map_session=session_id,
        current=True,
        first_version=first,
        last_version=robot.map_version,
        started_at=started,
        last_upload_at=state.updated_at if state else None,
        ended_at=None,
        wall_count=int(walls or 0),
        reason=reason,
    )


def read_session_map(s: Session, robot_id: int, session_id: str, trajectory_tail: int | None) -> MapOut:
    """An ended session's map as it was when the session ended (404 naming the sessions held otherwise).
    O(walls + poses)."""
    row = s.scalars(
        select(MapSession)
        .where(MapSession.robot_id == robot_id, MapSession.session_id == session_id)
        .order_by(MapSession.id.desc())
    ).first()
    if row is None:
        held = [
            x for x in s.scalars(select(MapSession.session_id).where(MapSession.robot_id == robot_id)) if x
        ]
        raise NotFoundError(
            f"robot {robot_id} has no map session {session_id}"
            + (f" (its sessions: {', '.join(held)})" if held else " (it has no sessions yet)")
        )
    segs = s.execute(
        select(
            MapSessionSegment.segment_id,
            MapSessionSegment.x0_m,
            MapSessionSegment.y0_m,
            MapSessionSegment.x1_m,
            MapSessionSegment.y1_m,
        )
        .where(MapSessionSegment.session_pk == row.id)
        .order_by(MapSessionSegment.segment_id)
    )
    tq = select(
        MapSessionTrajectoryPoint.stamp_s,
        MapSessionTrajectoryPoint.x_m,
        MapSessionTrajectoryPoint.y_m,
        MapSessionTrajectoryPoint.theta_rad,
    ).where(MapSessionTrajectoryPoint.session_pk == row.id)
    if trajectory_tail is not None:
        traj = list(s.execute(tq.order_by(MapSessionTrajectoryPoint.id.desc()).limit(trajectory_tail)))[::-1]
    else:
        traj = list(s.execute(tq.order_by(MapSessionTrajectoryPoint.id)))
    st = row.state or {}
    pose = st.get("pose") or {"x_m": 0.0, "y_m": 0.0, "theta_rad": 0.0}
    return MapOut(
        robot_id=robot_id,
        version=row.last_version or 0,
        map_session=row.session_id,
        stamp_s=float(st.get("stamp_s", 0.0)),
        segments=[[float(i), x0, y0, x1, y1] for i, x0, y0, x1, y1 in segs],
        centroids=list((st.get("centroids") or {}).get("xy", [])),
        pose=[pose["x_m"], pose["y_m"], pose["theta_rad"]],
        trajectory=[list(t) for t in traj],
        wall_time_s=st.get("wall_time_s"),
    )
