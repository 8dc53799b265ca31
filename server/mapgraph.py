"""The pose graph's part of a robot's stored map (keyframes, loop closures, the pose covariance) and how an
upload changes it, in the upload's own transaction (:func:`server.mapstore.apply_upload`).

A snapshot replaces all three. A delta merges its keyframes by id (new ones and those an optimisation
moved), adds its loop closures, and sets the covariance of its pose (absent: the pose has none). When a
delta moves stored keyframes (a loop closure's correction), the stored trajectory poses recorded after
each moved keyframe move with it (:func:`shared.protocol.posegraph.correct_trajectory`), so
``/maps/latest`` returns the corrected trajectory and the rows a viewer corrects in place match it. The
correction costs O(poses after the earliest moved keyframe); a delta without graph rows costs nothing here.

Bounded whatever the run's length (issue 21): when the stored trajectory is thinned,
:func:`prune_graph` drops the keyframes that own none of the poses left and the loop closures reaching
them (:func:`shared.protocol.keyframes_in_use`); a delta's row for a keyframe dropped so (not stored, older
than the newest stored) moves nothing and is left out, as is a loop closure to one. So the stored rows, and
``/maps/latest``, hold at most about one keyframe per kept pose.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from sqlalchemy import Connection, Table, bindparam, select, update

from server.models import MapState, TrajectoryPoint
from server.schemas import MapUpload
from shared.protocol import correct_trajectory, keyframes_in_use

__all__ = ["GRAPH_COLUMNS", "graph_columns", "graph_fields", "prune_graph"]

log = logging.getLogger(__name__)

_STATE: Table = MapState.__table__  # type: ignore[assignment]
_TRAJ: Table = TrajectoryPoint.__table__  # type: ignore[assignment]
#: the map state's columns this module writes
GRAPH_COLUMNS = ("keyframes", "loop_closures", "pose_covariance")
#: a keyframe counts as moved when it moved more than this (m, rad): float noise of a re-solve is not a
#: correction worth rewriting poses for
_MOVED_M, _MOVED_RAD = 1e-6, 1e-7


def _rows(value: dict[str, Any] | None) -> list[list[float]]:
    return list((value or {}).get("rows", []))


def graph_fields(st: dict[str, Any]) -> dict[str, Any]:
    """The pose graph's fields of a map (``keyframes``, ``loop_closures``, ``pose_covariance`` of
    :class:`server.schemas.MapOut`) from a stored state's columns (a dict of :data:`GRAPH_COLUMNS`)."""
    kf, lc = st.get("keyframes"), st.get("loop_closures")
    return {
        "keyframes": None if kf is None else kf.get("rows", []),
        "loop_closures": None if lc is None else [[int(a), int(b)] for a, b in lc.get("rows", [])],
        "pose_covariance": st.get("pose_covariance"),
    }


def graph_columns(conn: Connection, robot_id: int, up: MapUpload, whole: bool) -> dict[str, Any]:
    """The map state's pose-graph columns after ``up`` (``whole``: it replaces the map: a snapshot or a new
    session's first upload). For a delta that moves stored keyframes, the stored trajectory is corrected
    here (before the delta's own poses are inserted). Only the columns that change are returned."""
    cov = up.pose_covariance
    out: dict[str, Any] = {"pose_covariance": cov}
    if whole:
        out["keyframes"] = None if up.keyframes is None else {"rows": up.keyframes}
        out["loop_closures"] = None if up.loop_closures is None else {"rows": up.loop_closures}
        return out
    if up.keyframes is None and up.loop_closures is None:
        return out
    stored = conn.execute(
        select(_STATE.c.keyframes, _STATE.c.loop_closures).where(_STATE.c.robot_id == robot_id)
    ).first()
    old_kf = _rows(stored[0]) if stored is not None else []
    old_lc = _rows(stored[1]) if stored is not None else []
    before = {int(r[0]): r[1:] for r in old_kf}
    newest = max(before, default=-1)
    if up.keyframes is not None:
        # a row of a keyframe dropped with the poses it owned (prune_graph) moves nothing: left out
        after = {int(r[0]): r[1:] for r in up.keyframes if int(r[0]) in before or int(r[0]) > newest}
        moved = {k: v for k, v in after.items() if k in before and _moved(before[k], v)}
        if moved:
            _correct_stored(conn, robot_id, before, moved)
        merged = {**before, **after}
        out["keyframes"] = {
            "rows": [[float(k), *merged[k]] for k in sorted(merged, key=lambda k: merged[k][0])]
        }
    if up.loop_closures is not None:
        seen = {(int(a), int(b)) for a, b in old_lc}
        new = [
            [int(a), int(b)]
            for a, b in up.loop_closures
            if (int(a), int(b)) not in seen
            and not _dropped(int(a), before, newest)
            and not _dropped(int(b), before, newest)
        ]
        out["loop_closures"] = {"rows": [*old_lc, *new]}
    return out


def _dropped(k: int, held: dict[int, list[float]], newest: int) -> bool:
    """Whether keyframe ``k`` was dropped by :func:`prune_graph` (not held, older than the newest held)."""
    return k not in held and k < newest


def prune_graph(conn: Connection, robot_id: int) -> int:
    """Drop the robot's stored keyframes that own none of its stored poses, and the loop closures that
    reach them (:func:`shared.protocol.keyframes_in_use`); the keyframes dropped. Called after the
    trajectory is thinned (once per ~max poses / 4 poses stored). O(poses + keyframes)."""
    stored = conn.execute(
        select(_STATE.c.keyframes, _STATE.c.loop_closures).where(_STATE.c.robot_id == robot_id)
    ).first()
    if stored is None or stored[0] is None:
        return 0
    keyframes = _rows(stored[0])
    stamps = conn.execute(select(_TRAJ.c.stamp_s).where(_TRAJ.c.robot_id == robot_id)).scalars().all()
    used = keyframes_in_use(keyframes, stamps)
    if len(used) == len(keyframes):
        return 0
    values: dict[str, Any] = {"keyframes": {"rows": [r for r in keyframes if int(r[0]) in used]}}
    if stored[1] is not None:
        values["loop_closures"] = {
            "rows": [[a, b] for a, b in _rows(stored[1]) if int(a) in used and int(b) in used]
        }
    conn.execute(update(_STATE).where(_STATE.c.robot_id == robot_id).values(**values))
    return len(keyframes) - len(used)


def _moved(old: list[float], new: list[float]) -> bool:
    return (
        abs(old[1] - new[1]) > _MOVED_M
        or abs(old[2] - new[2]) > _MOVED_M
        or abs(float(np.remainder(old[3] - new[3] + np.pi, 2 * np.pi) - np.pi)) > _MOVED_RAD
    )


def _correct_stored(
    conn: Connection, robot_id: int, before: dict[int, list[float]], moved: dict[int, list[float]]
) -> None:
    """Move the stored poses recorded after each moved keyframe with it. O(poses after the earliest)."""
    since = min(float(before[k][0]) for k in moved)
    rows = list(
        conn.execute(
            select(_TRAJ.c.id, _TRAJ.c.stamp_s, _TRAJ.c.x_m, _TRAJ.c.y_m, _TRAJ.c.theta_rad).where(
                _TRAJ.c.robot_id == robot_id, _TRAJ.c.stamp_s >= since
            )
        )
    )
    if not rows:
        return
    ids = [int(r[0]) for r in rows]
    traj = np.asarray([r[1:] for r in rows], dtype=np.float64)
    fixed = correct_trajectory(traj, before, moved)
    stmt = (
        update(_TRAJ)
        .where(_TRAJ.c.id == bindparam("pk"))
        .values(x_m=bindparam("x"), y_m=bindparam("y"), theta_rad=bindparam("th"))
    )
    conn.execute(
        stmt,
        [
            {"pk": i, "x": float(r[1]), "y": float(r[2]), "th": float(r[3])}
            for i, r in zip(ids, fixed, strict=True)
        ],
    )
    log.info(
        "robot %d: %d keyframes corrected, %d stored poses moved with them", robot_id, len(moved), len(ids)
    )
