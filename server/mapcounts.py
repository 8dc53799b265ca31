"""How many walls and poses a robot's map holds (``map_states.n_walls``, ``map_states.n_poses``), kept
with every write of ``map_segments`` and ``trajectory_points`` in the same transaction, so that an upload's
wall cap (:mod:`server.wallcap`) and trajectory cap (:func:`server.maprows.thin_trajectory`) read two
numbers with the robot row instead of counting rows.

Why: counting cost O(rows) at every upload, and grew with the run. On PostgreSQL with 100 robots the
trajectory probe (the id with ``MAX_TRAJECTORY_POSES`` newer poses) took 6.3 ms of the database's time per
upload once trajectories were full, twice the rest of the upload; counting the walls, 0.1 ms at 240 walls
and O(walls) beyond.

The arithmetic (:func:`walls_after_delta`, :func:`walls_of_snapshot`) is exact from what an upload reads
already (a delta's touched walls that exist: :class:`server.maphistory.UndoReads`). :func:`reconcile`
counts the rows now and then (every :data:`server.mapstore._TRIM_EVERY` versions) and corrects the numbers
with a warning should they ever differ (a row written behind the server's back, a bug): a drift is seen and
bounded, never silent.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

from sqlalchemy import Connection, Table, func, select, update

from server.models import MapSegment, MapState, TrajectoryPoint
from server.schemas import MapUpload

__all__ = ["Counts", "count_rows", "reconcile", "walls_after_delta", "walls_of_snapshot"]

log = logging.getLogger(__name__)

_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
_STATE: Table = MapState.__table__  # type: ignore[assignment]


@dataclass(frozen=True, slots=True)
class Counts:
    """A robot's stored walls and poses (both 0 before its first upload)."""

    walls: int = 0
    poses: int = 0


def walls_after_delta(before: int, up: MapUpload, present: Iterable[int]) -> int:
    """The walls stored after delta ``up`` is applied to a map of ``before`` walls, of which the ids
    ``present`` are among those the delta touches (sends or removes). The delta's removed walls go first,
    then its walls are inserted or replaced (:func:`server.maprows.write_rows`): a wall both removed and
    sent stays. O(walls in the delta)."""
    sent = {int(r[0]) for r in up.segments}
    stored = {int(i) for i in present}
    gone = len(stored.intersection(up.removed) - sent)
    return before - gone + len(sent - stored)


def walls_of_snapshot(up: MapUpload) -> int:
    """The walls stored after snapshot ``up`` (it replaces the map, whether written whole or as a diff):
    its distinct ids. O(walls)."""
    return len({int(r[0]) for r in up.segments})


def count_rows(conn: Connection, robot_id: int) -> Counts:
    """The robot's rows counted (O(walls + poses) on the robot's indexes)."""
    walls = conn.execute(select(func.count()).select_from(_SEG).where(_SEG.c.robot_id == robot_id)).scalar()
    poses = conn.execute(select(func.count()).select_from(_TRAJ).where(_TRAJ.c.robot_id == robot_id)).scalar()
    return Counts(int(walls or 0), int(poses or 0))


def reconcile(conn: Connection, robot_id: int, kept: Counts) -> Counts:
    """Count the robot's rows and, where ``kept`` (the numbers just written) differs, write the counted
    ones and log a warning; the counted numbers. O(walls + poses)."""
    counted = count_rows(conn, robot_id)
    if counted != kept:
        log.warning(
            "robot %d's stored counts were %d walls and %d poses, but %d walls and %d poses are stored: "
            "corrected",
            robot_id,
            kept.walls,
            kept.poses,
            counted.walls,
            counted.poses,
        )
        conn.execute(
            update(_STATE)
            .where(_STATE.c.robot_id == robot_id)
            .values(n_walls=counted.walls, n_poses=counted.poses)
        )
    return counted
