"""A robot's map (:class:`~shared.foxbridge.mapstate.MapState`) as Foxglove messages (``foxglove.messages``
of the foxglove-sdk package): pure functions, one per message, the same input giving the same message.

The map lies in the plane z = 0 of frame ``map`` (metres); the robot's frame is ``base_link``, placed by
the pose ``(x_m, y_m, theta_rad)``: a translation ``(x, y, 0)`` and a rotation by ``theta`` about z, the
quaternion ``(0, 0, sin(theta/2), cos(theta/2))``. Each message is stamped with the version's time
(:func:`stamp_of`). Costs: O(walls) for the walls, O(poses) for the trajectory, O(1) for the pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from foxglove.messages import (
    Color,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from shared.foxbridge.mapstate import MapState

__all__ = [
    "BASE_FRAME",
    "CENTROIDS_ID",
    "MAP_FRAME",
    "TRAJECTORY_ID",
    "WALLS_ID",
    "MapMessages",
    "base_transform",
    "centroids_update",
    "map_messages",
    "pose_in_frame",
    "stamp_of",
    "trajectory_update",
    "walls_update",
    "yaw_quaternion",
]

MAP_FRAME = "map"
BASE_FRAME = "base_link"
WALLS_ID = "walls"
TRAJECTORY_ID = "trajectory"
CENTROIDS_ID = "centroids"

#: Line widths (m) and the centroid marker's diameter (m): drawn in metres, so they scale with the map.
WALL_THICKNESS_M = 0.04
TRAJECTORY_THICKNESS_M = 0.02
CENTROID_SIZE_M = 0.05

_WALL_COLOR = (0.1, 0.45, 0.9, 1.0)
_TRAJECTORY_COLOR = (0.95, 0.55, 0.1, 1.0)
_CENTROID_COLOR = (0.5, 0.5, 0.5, 0.8)


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def stamp_of(state: MapState, now_s: float) -> Timestamp:
    """The time of a version's messages: when the robot made it (``wall_time_s``) or, when it did not
    say, ``now_s`` (Unix seconds, the bridge's clock when the version arrived)."""
    seconds = state.wall_time_s if state.wall_time_s is not None and state.wall_time_s >= 0 else now_s
    return Timestamp.from_epoch_secs(max(seconds, 0.0))


def yaw_quaternion(theta_rad: float) -> Quaternion:
    """The rotation by ``theta_rad`` about z, as a unit quaternion (x, y, z, w)."""
    half = 0.5 * theta_rad
    return Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def walls_update(state: MapState, stamp: Timestamp) -> SceneUpdate:
    """The walls as one scene entity (id ``walls``, frame ``map``) with one LINE_LIST primitive: two points
    per wall, in the order of the wall ids. Publishing it replaces the entity of the previous version."""
    points: list[Point3] = []
    for wall_id in sorted(state.segments):
        x0, y0, x1, y1 = state.segments[wall_id]
        points += [Point3(x=x0, y=y0, z=0.0), Point3(x=x1, y=y1, z=0.0)]
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineList,
        thickness=WALL_THICKNESS_M,
        points=points,
        color=_color(_WALL_COLOR),
    )
    entity = SceneEntity(timestamp=stamp, frame_id=MAP_FRAME, id=WALLS_ID, lines=[line])
    return SceneUpdate(entities=[entity])


def trajectory_update(state: MapState, stamp: Timestamp) -> SceneUpdate:
    """The kept trajectory as one entity (id ``trajectory``, frame ``map``) with a LINE_STRIP through the
    poses' positions, oldest first."""
    points = [Point3(x=row[1], y=row[2], z=0.0) for row in state.trajectory]
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineStrip,
        thickness=TRAJECTORY_THICKNESS_M,
        points=points,
        color=_color(_TRAJECTORY_COLOR),
    )
    entity = SceneEntity(timestamp=stamp, frame_id=MAP_FRAME, id=TRAJECTORY_ID, lines=[line])
    return SceneUpdate(entities=[entity])


def centroids_update(state: MapState, stamp: Timestamp) -> SceneUpdate:
    """The cluster centroids as one entity (id ``centroids``, frame ``map``): a small sphere each (the
    size, colour and orientation objects shared by all: they are most of the cost)."""
    size = Vector3(x=CENTROID_SIZE_M, y=CENTROID_SIZE_M, z=CENTROID_SIZE_M)
    color, upright = _color(_CENTROID_COLOR), yaw_quaternion(0.0)
    spheres = [
        SpherePrimitive(
            pose=Pose(position=Vector3(x=x, y=y, z=0.0), orientation=upright), size=size, color=color
        )
        for x, y in state.centroids
    ]
    entity = SceneEntity(timestamp=stamp, frame_id=MAP_FRAME, id=CENTROIDS_ID, spheres=spheres)
    return SceneUpdate(entities=[entity])


def _pose(pose: tuple[float, float, float]) -> Pose:
    x, y, theta = pose
    return Pose(position=Vector3(x=x, y=y, z=0.0), orientation=yaw_quaternion(theta))


def pose_in_frame(state: MapState, stamp: Timestamp) -> PoseInFrame | None:
    """The robot's pose in frame ``map`` (None before the map has one)."""
    if state.pose is None:
        return None
    return PoseInFrame(timestamp=stamp, frame_id=MAP_FRAME, pose=_pose(state.pose))


def base_transform(state: MapState, stamp: Timestamp) -> FrameTransform | None:
    """The transform ``map`` -> ``base_link`` of the robot's pose (None before the map has one)."""
    if state.pose is None:
        return None
    x, y, theta = state.pose
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=MAP_FRAME,
        child_frame_id=BASE_FRAME,
        translation=Vector3(x=x, y=y, z=0.0),
        rotation=yaw_quaternion(theta),
    )


@dataclass(frozen=True)
class MapMessages:
    """Every message of one map version (``pose``/``transform`` None before the map has a pose)."""

    walls: SceneUpdate
    trajectory: SceneUpdate
    centroids: SceneUpdate
    pose: PoseInFrame | None
    transform: FrameTransform | None


def map_messages(state: MapState, now_s: float) -> MapMessages:
    """All of one version's messages, stamped by :func:`stamp_of`. O(walls + poses + centroids)."""
    stamp = stamp_of(state, now_s)
    return MapMessages(
        walls=walls_update(state, stamp),
        trajectory=trajectory_update(state, stamp),
        centroids=centroids_update(state, stamp),
        pose=pose_in_frame(state, stamp),
        transform=base_transform(state, stamp),
    )
