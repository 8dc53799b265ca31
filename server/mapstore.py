"""The server's copy of each robot's temporary map: apply snapshot and delta uploads, read the whole map.

Walls are rows keyed by (robot, segment id), so a delta costs O(changed walls), not O(map). An upload's
idempotency key is recorded in the same transaction as its changes: a retry finds the key and changes
nothing. A delta must start from the version the server has (``base_version`` == current) or it is
refused with 409 and the server's version, and the robot sends a snapshot instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, func, insert, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from server.errors import ConflictError, NotFoundError
from server.models import MapSegment, MapState, MapUploadRecord, Robot, TrajectoryPoint, utcnow
from server.schemas import MapOut, MapUpload, MapUploadOut

__all__ = ["AppliedUpload", "apply_upload", "map_version", "read_map"]


@dataclass(frozen=True, slots=True)
class AppliedUpload:
    """What the upload returned, and the event for stream subscribers (``None`` for a retry)."""

    out: MapUploadOut
    event: dict[str, Any] | None


def _upsert_segments(s: Session, robot_id: int, version: int, rows: list[list[float]]) -> None:
    if not rows:
        return
    values = [
        {
            "robot_id": robot_id,
            "segment_id": int(r[0]),
            "x0_m": r[1],
            "y0_m": r[2],
            "x1_m": r[3],
            "y1_m": r[4],
            "version": version,
        }
        for r in rows
    ]
    dialect = s.get_bind().dialect.name
    if dialect == "postgresql":
        pg = postgresql.insert(MapSegment)
        stmt: Any = pg.on_conflict_do_update(
            index_elements=["robot_id", "segment_id"],
            set_={c: getattr(pg.excluded, c) for c in ("x0_m", "y0_m", "x1_m", "y1_m", "version")},
        )
    elif dialect == "sqlite":
        lite = sqlite.insert(MapSegment)
        stmt = lite.on_conflict_do_update(
            index_elements=["robot_id", "segment_id"],
            set_={c: getattr(lite.excluded, c) for c in ("x0_m", "y0_m", "x1_m", "y1_m", "version")},
        )
    else:  # other backends: delete then insert
        ids = [v["segment_id"] for v in values]
        s.execute(delete(MapSegment).where(MapSegment.robot_id == robot_id, MapSegment.segment_id.in_(ids)))
        stmt = insert(MapSegment)
    s.execute(stmt, values)


def _add_trajectory(s: Session, robot_id: int, version: int, rows: list[list[float]]) -> None:
    if rows:
        s.execute(
            insert(TrajectoryPoint),
            [
                {
                    "robot_id": robot_id,
                    "version": version,
                    "stamp_s": r[0],
                    "x_m": r[1],
                    "y_m": r[2],
                    "theta_rad": r[3],
                }
                for r in rows
            ],
        )


def apply_upload(s: Session, robot_id: int, up: MapUpload, key: str) -> AppliedUpload:
    """Apply one upload in the caller's transaction. O(rows in the upload)."""
    # Lock the robot's row first: concurrent uploads of one robot (a retry racing its original) queue here,
    # so the idempotency check below sees every upload committed before it.
    robot = s.scalars(select(Robot).where(Robot.id == robot_id).with_for_update()).first()
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    seen = s.scalars(
        select(MapUploadRecord).where(
            MapUploadRecord.robot_id == robot_id, MapUploadRecord.idempotency_key == key
        )
    ).first()
    if seen is not None:
        return AppliedUpload(
            MapUploadOut(version=seen.version, segments=_count(s, robot_id), duplicate=True), None
        )
    current = robot.map_version
    if up.base_version is None:
        if up.version <= current:
            raise ConflictError(
                f"snapshot version {up.version} is not newer than the server's map version {current}",
                current_version=current,
            )
        s.execute(delete(MapSegment).where(MapSegment.robot_id == robot_id))
        s.execute(delete(TrajectoryPoint).where(TrajectoryPoint.robot_id == robot_id))
    else:
        if up.base_version != current:
            raise ConflictError(
                f"delta from version {up.base_version}, but the server's map is at version {current}: "
                "send a snapshot (base_version null)",
                current_version=current,
            )
        if up.removed:
            s.execute(
                delete(MapSegment).where(
                    MapSegment.robot_id == robot_id, MapSegment.segment_id.in_(up.removed)
                )
            )
    _upsert_segments(s, robot_id, up.version, up.segments)
    _add_trajectory(s, robot_id, up.version, up.trajectory)
    pose = {"x_m": up.pose[0], "y_m": up.pose[1], "theta_rad": up.pose[2]}
    state = s.get(MapState, robot_id)
    if state is None:
        s.add(
            MapState(
                robot_id=robot_id,
                version=up.version,
                stamp_s=up.stamp_s,
                centroids={"xy": up.centroids},
                pose=pose,
            )
        )
    else:
        state.version, state.stamp_s, state.centroids, state.pose = (
            up.version,
            up.stamp_s,
            {"xy": up.centroids},
            pose,
        )
        state.updated_at = utcnow()
    robot.map_version = up.version
    if up.status is not None:
        if up.status.mode is not None:
            robot.mode = up.status.mode
        if up.status.active_kernels is not None:
            robot.active_kernels = dict(up.status.active_kernels)
        if up.status.step_ms is not None:
            robot.step_ms = up.status.step_ms
        robot.last_error = up.status.last_error
    s.add(
        MapUploadRecord(
            robot_id=robot_id,
            idempotency_key=key,
            version=up.version,
            base_version=up.base_version,
            n_segments=len(up.segments),
            n_removed=len(up.removed),
        )
    )
    event = {
        "kind": "snapshot" if up.base_version is None else "delta",
        "robot_id": robot_id,
        "version": up.version,
        "base_version": up.base_version,
        "stamp_s": up.stamp_s,
        "segments": up.segments,
        "removed": up.removed,
        "centroids": up.centroids,
        "pose": up.pose,
        "trajectory": up.trajectory,
    }
    return AppliedUpload(
        MapUploadOut(version=up.version, segments=_count(s, robot_id), duplicate=False), event
    )


def _count(s: Session, robot_id: int) -> int:
    return int(
        s.scalar(select(func.count()).select_from(MapSegment).where(MapSegment.robot_id == robot_id)) or 0
    )


def map_version(s: Session, robot_id: int) -> int:
    robot = s.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    return robot.map_version


def read_map(s: Session, robot_id: int, trajectory_tail: int | None = None) -> MapOut:
    """The robot's whole current map (version 0 and empty before its first upload). O(walls + poses)."""
    version = map_version(s, robot_id)
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
        stamp_s=state.stamp_s if state else 0.0,
        segments=[[float(i), x0, y0, x1, y1] for i, x0, y0, x1, y1 in segs],
        centroids=list(state.centroids.get("xy", [])) if state else [],
        pose=[state.pose["x_m"], state.pose["y_m"], state.pose["theta_rad"]] if state else [0.0, 0.0, 0.0],
        trajectory=[list(t) for t in traj],
    )
