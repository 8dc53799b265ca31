"""Reading a robot's maps back (docs/reliability/identity.md): the current map and its (session, version),
a version this process read lately (:mod:`server.recentmaps`), an ended mapping session's map as it was
when it ended, and the list of the robot's maps, one per session. Reads only; the writes are
:mod:`server.mapstore` and :mod:`server.mapsessions`. Each read is O(walls + poses) of the map read.
"""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.errors import ConflictError, NotFoundError
from server.mapgraph import graph_fields
from server.maphistory import read_version
from server.models import (
    MapSegment,
    MapSession,
    MapSessionSegment,
    MapSessionTrajectoryPoint,
    MapState,
    Robot,
    TrajectoryPoint,
)
from server.schemas import MapOut, MapSessionOut

if TYPE_CHECKING:
    from server.deps import AppState

__all__ = ["list_sessions", "map_version", "read_held", "read_map", "read_session_map"]


def map_version(s: Session, robot_id: int) -> tuple[str | None, int]:
    """The robot's current (map session, map version)."""
    robot = s.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    return robot.map_session, robot.map_version


def read_map(s: Session, robot_id: int, trajectory_tail: int | None = None) -> MapOut:
    """The robot's whole current map (version 0 and empty before its first upload). O(walls + poses)."""
    session, version = map_version(s, robot_id)
    segs = s.execute(
        select(MapSegment.segment_id, MapSegment.x0_m, MapSegment.y0_m, MapSegment.x1_m, MapSegment.y1_m)
        .where(MapSegment.robot_id == robot_id)
        .order_by(MapSegment.segment_id)
    )
    tq = select(
        TrajectoryPoint.stamp_s, TrajectoryPoint.x_m, TrajectoryPoint.y_m, TrajectoryPoint.theta_rad
    ).where(TrajectoryPoint.robot_id == robot_id)
    if trajectory_tail is not None:
        traj = list(s.execute(tq.order_by(TrajectoryPoint.id.desc()).limit(trajectory_tail)))[::-1]
    else:
        traj = list(s.execute(tq.order_by(TrajectoryPoint.id)))
    state = s.get(MapState, robot_id)
    return MapOut(
        robot_id=robot_id,
        version=version,
        map_session=session,
        stamp_s=state.stamp_s if state else 0.0,
        segments=[[float(i), x0, y0, x1, y1] for i, x0, y0, x1, y1 in segs],
        centroids=list(state.centroids.get("xy", [])) if state else [],
        pose=[state.pose["x_m"], state.pose["y_m"], state.pose["theta_rad"]] if state else [0.0, 0.0, 0.0],
        trajectory=[list(t) for t in traj],
        wall_time_s=state.wall_time_s if state else None,
        **graph_fields(
            {
                "keyframes": state.keyframes,
                "loop_closures": state.loop_closures,
                "pose_covariance": state.pose_covariance,
            }
            if state
            else {}
        ),
    )


def list_sessions(s: Session, robot_id: int) -> list[MapSessionOut]:
    """The robot's sessions, newest first: the current one's figures read live, ended ones' as stored.
    O(sessions); the current map's wall count is the one kept with its state (:mod:`server.mapcounts`)."""
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
    state = s.get(MapState, robot.id)
    walls = state.n_walls if state is not None else 0  # kept with every upload (server.mapcounts)
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
        **graph_fields(st),
    )


def _current_session(state: AppState, robot_id: int) -> str | None:
    with state.db.read() as s:
        return map_version(s, robot_id)[0]


def read_held(
    state: AppState, robot_id: int, tail: int | None, version: int | None = None, session: str | None = None
) -> MapOut:
    """The current map (``version`` None) or version ``version``: one this process read lately
    (:mod:`server.recentmaps`), else rebuilt from the delta log (:mod:`server.maphistory`: 409 for a
    version above the current one, 410 for one older than the replayable range, 404 for a number the robot
    skipped, each naming the range). ``tail``: only the
    last N trajectory poses. ``session``: that mapping session's map (an ended one as it ended; 404 naming
    the robot's sessions when it has no such session)."""
    if session is not None:
        with state.db.read() as s:
            current, _v = map_version(s, robot_id)
            if session != current:
                m = read_session_map(s, robot_id, session, tail)
                if version is not None and m.version != version:
                    raise ConflictError(
                        f"map session {session} of robot {robot_id} ended at version {m.version}, "
                        f"not {version}",
                        current_version=m.version,
                    )
                return m
    if version is not None:
        kept = state.recent_maps.get(robot_id, version)
        # versions count anew in each map session: a kept map serves only while its session is current
        # (another server process may have started a new one)
        if kept is not None and _current_session(state, robot_id) == kept.map_session:
            return _tail_of(kept, tail)
        # rebuilt from the current map and the delta log's undo records (server.maphistory): 409 / 410 /
        # 404 naming the replayable versions when it cannot be
        with state.db.read() as s:
            m = read_version(s, robot_id, version, tail)
    else:
        with state.db.read() as s:
            m = read_map(s, robot_id, tail)
    if tail is None and version is None:
        state.recent_maps.put(m)
    return m


def _tail_of(m: MapOut, tail: int | None) -> MapOut:
    if tail is None or tail >= len(m.trajectory):
        return m
    return m.model_copy(update={"trajectory": m.trajectory[len(m.trajectory) - tail :] if tail else []})
