"""A robot's map as the bridge holds it, built from the events of the server's live-map stream
(``GET /robots/{id}/maps/stream``): a ``snapshot`` replaces it, a ``delta`` changes it. Pure functions of
frozen values; every event is validated here, at the boundary, and a bad one names its field.

Rows as the stream sends them: ``segments`` ``[id, x0_m, y0_m, x1_m, y1_m]``, ``centroids`` ``[x_m, y_m]``,
``pose`` ``[x_m, y_m, theta_rad]``, ``trajectory`` ``[stamp_s, x_m, y_m, theta_rad]``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from shared.foxbridge.errors import MapEventError, OutOfStepError

__all__ = ["TRAJECTORY_KEEP", "MapState", "apply_delta", "apply_event", "from_snapshot"]

#: The trajectory poses the bridge keeps (the newest): a long run stays O(1) in memory and per message.
TRAJECTORY_KEEP = 5000

Segment = tuple[float, float, float, float]
Row = tuple[float, ...]


@dataclass(frozen=True)
class MapState:
    """One version of a robot's map. ``segments``: wall id -> ``(x0_m, y0_m, x1_m, y1_m)`` (read-only);
    ``pose`` ``(x_m, y_m, theta_rad)``; ``trajectory`` rows ``(stamp_s, x_m, y_m, theta_rad)``, oldest
    first, at most ``TRAJECTORY_KEEP``; ``wall_time_s`` the Unix time at which the robot made this version
    (None when the robot did not say)."""

    robot_id: int
    version: int
    map_session: str | None
    stamp_s: float
    segments: Mapping[int, Segment] = field(default_factory=lambda: MappingProxyType({}))
    centroids: tuple[tuple[float, float], ...] = ()
    pose: tuple[float, float, float] | None = None
    trajectory: tuple[Row, ...] = ()
    wall_time_s: float | None = None


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapEventError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _rows(event: Mapping[str, Any], name: str, width: int) -> list[Row]:
    """``event[name]`` as rows of ``width`` finite numbers (absent or null: none). O(rows)."""
    raw = event.get(name)
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise MapEventError(f"{name}: expected a list of rows, got {type(raw).__name__}")
    rows: list[Row] = []
    for i, row in enumerate(raw):
        if not isinstance(row, list) or len(row) != width:
            raise MapEventError(f"{name}[{i}]: expected a row of {width} numbers, got {row!r}")
        rows.append(tuple(_number(v, f"{name}[{i}]") for v in row))
    return rows


def _int(event: Mapping[str, Any], name: str, *, optional: bool = False) -> int | None:
    value = event.get(name)
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MapEventError(f"{name}: expected a whole number >= 0, got {value!r}")
    return value


def _segment_rows(event: Mapping[str, Any]) -> list[tuple[int, Segment]]:
    out: list[tuple[int, Segment]] = []
    for i, row in enumerate(_rows(event, "segments", 5)):
        if not row[0].is_integer():
            raise MapEventError(f"segments[{i}]: expected a whole wall id first, got {row[0]!r}")
        out.append((int(row[0]), (row[1], row[2], row[3], row[4])))
    return out


def _pose(event: Mapping[str, Any]) -> tuple[float, float, float] | None:
    raw = event.get("pose")
    if raw is None or raw == []:
        return None
    if not isinstance(raw, list) or len(raw) != 3:
        raise MapEventError(f"pose: expected [x_m, y_m, theta_rad], got {raw!r}")
    x, y, theta = (_number(v, "pose") for v in raw)
    return x, y, theta


def _optional_number(event: Mapping[str, Any], name: str) -> float | None:
    value = event.get(name)
    return None if value is None else _number(value, name)


def _session(event: Mapping[str, Any]) -> str | None:
    value = event.get("map_session")
    if value is not None and not isinstance(value, str):
        raise MapEventError(f"map_session: expected a string or null, got {value!r}")
    return value


def _keep(rows: list[Row], keep: int) -> tuple[Row, ...]:
    return tuple(rows[-keep:]) if keep > 0 else ()


def from_snapshot(event: Mapping[str, Any], keep: int = TRAJECTORY_KEEP) -> MapState:
    """The map of a ``snapshot`` event (the server's whole map). O(size of the map)."""
    robot_id = _int(event, "robot_id")
    version = _int(event, "version")
    assert robot_id is not None and version is not None
    centroids = tuple((r[0], r[1]) for r in _rows(event, "centroids", 2))
    return MapState(
        robot_id=robot_id,
        version=version,
        map_session=_session(event),
        stamp_s=_number(event.get("stamp_s", 0.0), "stamp_s"),
        segments=MappingProxyType(dict(_segment_rows(event))),
        centroids=centroids,
        pose=_pose(event),
        trajectory=_keep(_rows(event, "trajectory", 4), keep),
        wall_time_s=_optional_number(event, "wall_time_s"),
    )


def apply_delta(state: MapState, event: Mapping[str, Any], keep: int = TRAJECTORY_KEEP) -> MapState:
    """``state`` changed by a ``delta`` event: its walls set, its ``removed`` ids dropped, its centroids
    (the whole set) and pose taken, its trajectory rows appended (the newest ``keep`` kept). Raises
    :class:`OutOfStepError` when the delta's ``base_version`` is not ``state.version``. O(map + delta)."""
    base = _int(event, "base_version")
    version = _int(event, "version")
    assert version is not None
    if base != state.version:
        raise OutOfStepError(f"a delta from version {base} does not continue version {state.version}")
    removed = event.get("removed") or []
    if not isinstance(removed, list) or any(isinstance(i, bool) or not isinstance(i, int) for i in removed):
        raise MapEventError(f"removed: expected a list of wall ids, got {removed!r}")
    segments = dict(state.segments)
    for wall_id in removed:
        segments.pop(wall_id, None)
    segments.update(_segment_rows(event))
    centroids = (
        state.centroids
        if event.get("centroids") is None
        else tuple((r[0], r[1]) for r in _rows(event, "centroids", 2))
    )
    pose = _pose(event)
    wall_time = _optional_number(event, "wall_time_s")
    return MapState(
        robot_id=state.robot_id,
        version=version,
        map_session=_session(event) or state.map_session,
        stamp_s=_number(event.get("stamp_s", state.stamp_s), "stamp_s"),
        segments=MappingProxyType(segments),
        centroids=centroids,
        pose=state.pose if pose is None else pose,
        trajectory=_keep([*state.trajectory, *_rows(event, "trajectory", 4)], keep),
        wall_time_s=wall_time,
    )


def apply_event(
    state: MapState | None, kind: str, event: Mapping[str, Any], keep: int = TRAJECTORY_KEEP
) -> MapState:
    """The map after one stream event of type ``kind`` (``snapshot`` or ``delta``); a delta needs a map
    to continue (:class:`OutOfStepError` without one)."""
    if kind == "snapshot":
        return from_snapshot(event, keep)
    if kind == "delta":
        if state is None:
            raise OutOfStepError("a delta arrived before any snapshot")
        return apply_delta(state, event, keep)
    raise MapEventError(f"event type {kind!r}: expected 'snapshot' or 'delta'")
