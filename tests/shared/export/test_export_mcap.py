"""The map as MCAP for Foxglove: write, read back, compare; the file is one valid rosbag2 MCAP file."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from shared.errors import InvalidInputError
from shared.export import (
    MCAP_TOPICS,
    ExportIOError,
    McapMap,
    McapMapError,
    read_map_mcap,
    write_map_mcap,
)
from shared.pipeline import MapSnapshot, Pipeline
from shared.sim import default_world, simulate_run
from shared.types import FloatArray, Pose2D

MCAP_MAGIC = b"\x89MCAP0\r\n"
NONE: FloatArray = np.zeros(0)


def assert_same_map(got: McapMap, want: McapMap) -> None:
    np.testing.assert_array_equal(got.segments, want.segments)  # float64 points: exact
    np.testing.assert_array_equal(got.centroids, want.centroids)
    assert got.trajectory.shape == want.trajectory.shape
    np.testing.assert_array_equal(got.trajectory[:, 1:3], want.trajectory[:, 1:3])
    np.testing.assert_allclose(got.trajectory[:, 0], want.trajectory[:, 0], rtol=0, atol=1e-9)  # integer ns
    gap = np.abs(np.remainder(got.trajectory[:, 3] - want.trajectory[:, 3] + math.pi, math.tau) - math.pi)
    assert (gap <= 1e-12).all()  # heading through a quaternion
    assert abs(got.stamp_s - want.stamp_s) <= 1e-9 and got.frame_id == want.frame_id
    if want.pose is None:
        assert got.pose is None
    else:
        assert got.pose is not None
        assert (got.pose.x_m, got.pose.y_m) == (want.pose.x_m, want.pose.y_m)
        assert abs(math.remainder(got.pose.theta_rad - want.pose.theta_rad, math.tau)) <= 1e-12


def test_a_snapshot_round_trips(tmp_path: Path, snapshot: MapSnapshot) -> None:
    path = write_map_mcap(tmp_path / "map.mcap", snapshot)
    assert path == tmp_path / "map.mcap"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.mcap"]  # no scratch folder left behind
    data = path.read_bytes()
    assert data.startswith(MCAP_MAGIC) and data.endswith(MCAP_MAGIC)
    got = read_map_mcap(path)
    assert_same_map(got, McapMap.from_snapshot(snapshot))
    assert (
        len(got.segments) == 4 and got.pose is not None and got.pose.theta_rad == pytest.approx(math.pi / 2)
    )


def test_the_file_holds_foxglove_friendly_ros2_messages(tmp_path: Path, snapshot: MapSnapshot) -> None:
    path = write_map_mcap(tmp_path / "map.mcap", snapshot)
    with AnyReader([path]) as bag:
        assert {c.topic: c.msgtype for c in bag.connections} == MCAP_TOPICS
        msgs: dict[str, tuple[int, Any]] = {
            c.topic: (t, bag.deserialize(raw, c.msgtype)) for c, t, raw in bag.messages()
        }
    stamp_ns = round(snapshot.stamp_s * 1e9)
    assert {t for t, _ in msgs.values()} == {stamp_ns}
    walls, centroids = msgs["/linemap/map"][1].markers
    assert (walls.ns, walls.type, centroids.ns, centroids.type) == (
        "walls",
        5,
        "centroids",
        8,
    )  # LINE_LIST, POINTS
    assert len(walls.points) == 2 * len(snapshot.segments) and len(centroids.points) == len(
        snapshot.centroids
    )
    assert walls.header.frame_id == "map" and walls.scale.x > 0 and walls.color.a == 1.0
    assert walls.pose.orientation.w == 1.0
    first = walls.points[0]
    assert (first.x, first.y, first.z) == (0.0, 0.0, 0.0)
    path_msg = msgs["/linemap/trajectory"][1]
    assert [p.header.stamp.sec for p in path_msg.poses] == [90, 90, 91]
    assert [p.header.stamp.nanosec for p in path_msg.poses] == [239599000, 719599000, 321399000]
    pose = msgs["/linemap/pose"][1].pose
    assert (pose.position.x, pose.position.y) == (2.0, 1.5)
    assert pose.orientation.z == pytest.approx(math.sin(math.pi / 4))


def test_plain_arrays_and_an_empty_map(tmp_path: Path) -> None:
    empty = McapMap(np.zeros((0, 4)), np.zeros((0, 2)), np.zeros((0, 4)))
    assert_same_map(read_map_mcap(write_map_mcap(tmp_path / "empty.mcap", empty)), empty)
    plain = McapMap(
        np.array([[0.0, 0.0, 1.0, 0.0]]),
        np.array([[0.5, 0.0]]),
        np.array([[0.0, 0.0, 0.0, 3.0]]),
        Pose2D(0, 0, 3.0),
        0.0,
        "world",
    )
    got = read_map_mcap(write_map_mcap(tmp_path / "plain.mcap", plain))
    assert_same_map(got, plain)
    assert got.frame_id == "world"


def test_a_pipeline_map_round_trips(tmp_path: Path) -> None:
    run = simulate_run(default_world(), seed=0)
    pipeline = Pipeline(laser_offset=run.drive.laser_offset)
    for scan in run.scans[:40]:
        pipeline.step(scan)
    pipeline.flush()
    snap = pipeline.snapshot()
    assert len(snap.segments) > 0 and len(snap.trajectory) == 40
    got = read_map_mcap(write_map_mcap(tmp_path / "run.mcap", snap))
    assert_same_map(got, McapMap.from_snapshot(snap))


def test_an_existing_file_is_replaced_whole(tmp_path: Path, snapshot: MapSnapshot) -> None:
    path = tmp_path / "map.mcap"
    path.write_bytes(b"old")
    write_map_mcap(path, snapshot)
    smaller = McapMap(snapshot.segments[:1], snapshot.centroids[:1], snapshot.trajectory[:1])
    write_map_mcap(path, smaller)
    assert_same_map(read_map_mcap(path), smaller)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.mcap"]


segment_rows = arrays(np.float64, st.tuples(st.integers(0, 30), st.just(4)), elements=st.floats(-1e4, 1e4))
traj_rows = st.lists(
    st.tuples(st.floats(0, 2e9), st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-math.pi, math.pi)),
    max_size=20,
)


@settings(max_examples=10, deadline=None)
@given(segment_rows, traj_rows)
def test_any_finite_map_round_trips(segments: FloatArray, trajectory: list[tuple[float, ...]]) -> None:
    layers = McapMap(segments, segments[:, :2], np.array(trajectory).reshape(-1, 4), None, 12.5)
    with tempfile.TemporaryDirectory() as folder:
        got = read_map_mcap(write_map_mcap(Path(folder) / "m.mcap", layers))
    assert_same_map(got, layers)


def test_bad_inputs_and_files_are_clear_errors(tmp_path: Path, snapshot: MapSnapshot) -> None:
    with pytest.raises(McapMapError, match=r"suffix '\.bag': expected \.mcap"):
        write_map_mcap(tmp_path / "map.bag", snapshot)
    with pytest.raises(ExportIOError, match="does not exist"):
        write_map_mcap(tmp_path / "absent" / "map.mcap", snapshot)
    with pytest.raises(InvalidInputError, match=r"segments has shape \(2, 3\): expected \(N, 4\)"):
        McapMap(np.zeros((2, 3)), NONE, NONE)
    with pytest.raises(InvalidInputError, match="centroids holds non-finite values"):
        McapMap(NONE, np.array([[math.nan, 0.0]]), NONE)
    with pytest.raises(InvalidInputError, match=r"expected 0 <= stamp < 2\^31 s"):
        McapMap(NONE, NONE, np.array([[-1.0, 0.0, 0.0, 0.0]]))
    with pytest.raises(ExportIOError, match="no such file"):
        read_map_mcap(tmp_path / "missing.mcap")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    with pytest.raises(McapMapError, match="cannot read it as an MCAP map"):
        read_map_mcap(garbage)


def test_an_mcap_without_a_map_is_refused(tmp_path: Path) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(tmp_path / "other", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        msg = ts.types["std_msgs/msg/String"](data="hello")
        writer.write(conn, 1, ts.serialize_cdr(msg, "std_msgs/msg/String"))
    with pytest.raises(McapMapError, match="expected a map written by linemap"):
        read_map_mcap(tmp_path / "other" / "other.mcap")
