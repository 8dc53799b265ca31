"""The map -> Foxglove conversion (shared/foxbridge/convert.py), each message decoded with the protobuf
schema a Foxglove client would use: walls as one LINE_LIST of two points per wall, the trajectory as a
LINE_STRIP, the pose and the map -> base_link transform with the heading as a yaw quaternion."""

from __future__ import annotations

import math
from types import MappingProxyType

from hypothesis import given
from hypothesis import strategies as st

from shared.foxbridge.convert import (
    BASE_FRAME,
    MAP_FRAME,
    map_messages,
    stamp_of,
)
from shared.foxbridge.mapstate import MapState
from tests.shared.foxbridge.fxwire import decode, yaw_of

LINE_STRIP, LINE_LIST = 0, 2  # foxglove.LinePrimitive.Type

coord = st.floats(-1e4, 1e4, allow_nan=False)
angle = st.floats(-math.pi + 1e-9, math.pi, allow_nan=False)


@st.composite
def states(draw: st.DrawFn) -> MapState:
    ids = draw(st.lists(st.integers(0, 2**40), unique=True, max_size=30))
    segments = {i: tuple(draw(coord) for _ in range(4)) for i in ids}
    trajectory = draw(st.lists(st.tuples(st.floats(0, 1e6), coord, coord, angle), max_size=30))
    return MapState(
        robot_id=draw(st.integers(1, 1000)),
        version=draw(st.integers(0, 10**9)),
        map_session=None,
        stamp_s=draw(st.floats(0, 1e6)),
        segments=MappingProxyType(segments),  # type: ignore[arg-type]
        centroids=tuple(draw(st.lists(st.tuples(coord, coord), max_size=20))),
        pose=draw(st.none() | st.tuples(coord, coord, angle)),
        trajectory=tuple(trajectory),
        wall_time_s=draw(st.none() | st.floats(1e9, 2e9)),
    )


def _xy(points: object) -> list[tuple[float, float, float]]:
    return [(p.x, p.y, p.z) for p in points]  # type: ignore[attr-defined]


@given(states())
def test_walls_are_one_line_list_of_two_points_per_wall(state: MapState) -> None:
    update = decode(map_messages(state, 1.7e9).walls)
    assert len(update.entities) == 1
    entity = update.entities[0]
    assert (entity.id, entity.frame_id) == ("walls", MAP_FRAME)
    assert len(entity.lines) == 1 and entity.lines[0].type == LINE_LIST
    expected = []
    for wall_id in sorted(state.segments):
        x0, y0, x1, y1 = state.segments[wall_id]
        expected += [(x0, y0, 0.0), (x1, y1, 0.0)]
    assert _xy(entity.lines[0].points) == expected


@given(states())
def test_trajectory_is_a_line_strip_through_the_poses(state: MapState) -> None:
    entity = decode(map_messages(state, 1.7e9).trajectory).entities[0]
    assert (entity.id, entity.frame_id, entity.lines[0].type) == ("trajectory", MAP_FRAME, LINE_STRIP)
    assert _xy(entity.lines[0].points) == [(x, y, 0.0) for _, x, y, _ in state.trajectory]


@given(states())
def test_centroids_are_spheres_at_their_positions(state: MapState) -> None:
    entity = decode(map_messages(state, 1.7e9).centroids).entities[0]
    assert entity.id == "centroids"
    assert [(s.pose.position.x, s.pose.position.y) for s in entity.spheres] == list(state.centroids)


@given(states())
def test_pose_and_transform_place_base_link_at_the_pose(state: MapState) -> None:
    messages = map_messages(state, 1.7e9)
    if state.pose is None:
        assert messages.pose is None and messages.transform is None
        return
    x, y, theta = state.pose
    pose = decode(messages.pose)
    tf = decode(messages.transform)
    assert pose.frame_id == MAP_FRAME
    assert (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z) == (x, y, 0.0)
    assert (tf.parent_frame_id, tf.child_frame_id) == (MAP_FRAME, BASE_FRAME)
    assert (tf.translation.x, tf.translation.y) == (x, y)
    for q in (pose.pose.orientation, tf.rotation):
        assert q.x == 0.0 and q.y == 0.0
        assert math.isclose(q.z**2 + q.w**2, 1.0, abs_tol=1e-12)
        assert math.isclose(math.remainder(yaw_of(q) - theta, math.tau), 0.0, abs_tol=1e-9)


@given(states(), st.floats(1e9, 2e9))
def test_every_message_of_a_version_has_its_time(state: MapState, now_s: float) -> None:
    messages = map_messages(state, now_s)
    seconds = state.wall_time_s if state.wall_time_s is not None else now_s
    stamp = stamp_of(state, now_s)
    assert math.isclose(stamp.sec + stamp.nsec * 1e-9, seconds, abs_tol=1e-6)
    stamps = [decode(u).entities[0].timestamp for u in (messages.walls, messages.trajectory)]
    if messages.pose is not None:
        stamps.append(decode(messages.pose).timestamp)
    assert all((s.seconds, s.nanos) == (stamp.sec, stamp.nsec) for s in stamps)
