"""A robot's mapping sessions (docs/reliability/identity.md): one map per (robot, session).

The current session's map lives in ``map_segments`` / ``trajectory_points`` / ``map_states`` (the hot
upload path, :mod:`server.mapstore`, is unchanged by sessions); when a snapshot of a new session arrives
:func:`start_session` moves that map into ``map_session_segments`` / ``map_session_trajectory`` under the
ended session's ``map_sessions`` row (one ``INSERT ... SELECT`` each: O(walls + poses) in the database, no
rows through Python) and opens a row for the new session. :mod:`server.mapread` reads them back. An ended
session is never reopened: an upload of it is refused (:class:`~server.errors.MapSessionEndedError`), so
two maps are never mixed.
"""

from __future__ import annotations

import logging
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, Table, func, insert, literal, select, update

from server.errors import MapSessionEndedError
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

__all__ = ["check_not_ended", "start_session"]

log = logging.getLogger(__name__)

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
                _STATE.c.stamp_s,
                _STATE.c.pose,
                _STATE.c.centroids,
                _STATE.c.wall_time_s,
                _STATE.c.updated_at,
                _STATE.c.keyframes,
                _STATE.c.loop_closures,
                _STATE.c.pose_covariance,
            ).where(_STATE.c.robot_id == robot_id)
        ).first()
        state = (
            {
                "stamp_s": st[0],
                "pose": st[1],
                "centroids": st[2],
                "wall_time_s": st[3],
                "keyframes": st[5],
                "loop_closures": st[6],
                "pose_covariance": st[7],
            }
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
    log.warning(
        "robot %d started map session %s at version %d (was %s at version %d): %s",
        robot_id,
        new,
        first_version,
        old,
        old_version,
        reason or "no reason given",
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
