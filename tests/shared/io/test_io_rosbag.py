"""ROS bags without ROS: bags are written here with rosbags' own writers (rosbag2 SQLite3 and MCAP, ROS 1),
from simulated scans and a cut of a real CARMEN log, then read back through ``open_log``.

Acceptance: a bag maps like the equivalent CARMEN log.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from itertools import islice, pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from shared.io import (
    LogError,
    LogNotFoundError,
    RosbagError,
    RosbagMessageError,
    RosbagReader,
    RosbagTopicError,
    UnknownLogFormatError,
    detect_format,
    open_log,
    write_carmen,
)
from shared.io.rosbag_pose import interpolate_pose, quaternion_from_yaw
from shared.pipeline import Pipeline
from shared.sim import default_world, simulate_run
from shared.types import FloatArray, Pose2D, Scan

ROOT = Path(__file__).resolve().parents[3]
FR079 = ROOT.parent / "shared" / "data" / "fr079" / "fr079.clf.gz"
KINDS = ("sqlite3", "mcap", "ros1")
NS = 1_000_000_000


# -- writing bags ---------------------------------------------------------------------------------------


def to_ns(stamp_s: float) -> int:
    """The nearest integer nanosecond to a float stamp (exact rational arithmetic)."""
    return round(Fraction(stamp_s) * NS)


def typestore_for(kind: str) -> Typestore:
    if kind == "ros1":
        store = get_typestore(Stores.ROS1_NOETIC)
        store.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        )
        return store
    return get_typestore(Stores.ROS2_HUMBLE)


@dataclass
class Bag:
    """What to write: scans per topic, odometry samples, static and dynamic transforms."""

    scans: dict[str, Sequence[Scan]]
    odometry: Sequence[tuple[int, Pose2D]] = ()
    odom_topic: str = "/odom"
    static_tf: Sequence[tuple[str, str, Pose2D]] = ()
    tf_odometry: Sequence[tuple[int, Pose2D]] = ()
    laser_frame: str = "laser"
    odom_delay_ns: int = 1_000_000  # bag (receive) time minus header stamp


def _header(ts: Typestore, stamp_ns: int, frame: str) -> Any:
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS)
    if "seq" in dict(ts.fielddefs["std_msgs/msg/Header"][1]):
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _pose_msg(ts: Typestore, pose: Pose2D) -> Any:
    t = ts.types
    qx, qy, qz, qw = quaternion_from_yaw(pose.theta_rad)
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=pose.x_m, y=pose.y_m, z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )


def _transform_stamped(ts: Typestore, stamp_ns: int, parent: str, child: str, pose: Pose2D) -> Any:
    t = ts.types
    p = _pose_msg(ts, pose)
    return t["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, stamp_ns, parent),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=p.position.x, y=p.position.y, z=0.1),
            rotation=p.orientation,
        ),
    )


def scan_msg(ts: Typestore, scan: Scan, frame: str) -> Any:
    n = scan.beam_count
    return ts.types["sensor_msgs/msg/LaserScan"](
        header=_header(ts, to_ns(scan.stamp_s), frame),
        angle_min=scan.angle_min_rad,
        angle_max=scan.angle_min_rad + (n - 1) * scan.angle_increment_rad,
        angle_increment=scan.angle_increment_rad,
        time_increment=0.0,
        scan_time=0.1,
        range_min=scan.range_min_m,
        range_max=scan.range_max_m,
        ranges=np.asarray(scan.ranges_m, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def odometry_msg(ts: Typestore, stamp_ns: int, pose: Pose2D) -> Any:
    t = ts.types
    vec = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=_header(ts, stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=_pose_msg(ts, pose), covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=np.zeros(36)
        ),
    )


def _tf_msg(ts: Typestore, transforms: list[Any]) -> Any:
    return ts.types["tf2_msgs/msg/TFMessage"](transforms=transforms)


def _messages(ts: Typestore, bag: Bag) -> Iterator[tuple[int, str, str, Any]]:
    """``(bag time ns, topic, msgtype, message)``; scans arrive 3 ms after their stamp."""
    for topic, scans in bag.scans.items():
        for scan in scans:
            yield (
                to_ns(scan.stamp_s) + 3_000_000,
                topic,
                "sensor_msgs/msg/LaserScan",
                scan_msg(ts, scan, bag.laser_frame),
            )
    for stamp_ns, pose in bag.odometry:
        yield (
            stamp_ns + bag.odom_delay_ns,
            bag.odom_topic,
            "nav_msgs/msg/Odometry",
            odometry_msg(ts, stamp_ns, pose),
        )
    if bag.static_tf:
        transforms = [_transform_stamped(ts, 0, p, c, pose) for p, c, pose in bag.static_tf]
        yield 0, "/tf_static", "tf2_msgs/msg/TFMessage", _tf_msg(ts, transforms)
    for stamp_ns, pose in bag.tf_odometry:
        tr = _transform_stamped(ts, stamp_ns, "odom", "base_link", pose)
        yield stamp_ns, "/tf", "tf2_msgs/msg/TFMessage", _tf_msg(ts, [tr])


def write_bag(path: Path, kind: str, bag: Bag) -> Path:
    """Write ``bag`` as a rosbag2 folder (``sqlite3`` / ``mcap``) or a ROS 1 ``.bag`` at ``path``."""
    ts = typestore_for(kind)
    msgs = sorted(_messages(ts, bag), key=lambda m: m[0])
    if kind == "ros1":
        writer1 = Writer1(path)
        with writer1:
            conns1: dict[str, Any] = {}
            for t_ns, topic, msgtype, msg in msgs:
                if topic not in conns1:
                    conns1[topic] = writer1.add_connection(topic, msgtype, typestore=ts)
                writer1.write(conns1[topic], t_ns, ts.serialize_ros1(msg, msgtype))
        return path
    plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
    with Writer2(path, version=9, storage_plugin=plugin) as writer2:
        conns2: dict[str, Any] = {}
        for t_ns, topic, msgtype, msg in msgs:
            if topic not in conns2:
                conns2[topic] = writer2.add_connection(topic, msgtype, typestore=ts)
            writer2.write(conns2[topic], t_ns, ts.serialize_cdr(msg, msgtype))
    return path


def bag_path(tmp_path: Path, kind: str, name: str = "run") -> Path:
    return tmp_path / (f"{name}.bag" if kind == "ros1" else name)


def storage_file(folder: Path) -> Path:
    """The single .db3 / .mcap file inside a rosbag2 folder."""
    (file,) = [f for f in folder.iterdir() if f.suffix in (".db3", ".mcap")]
    return file


# -- sources --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim_scans() -> list[Scan]:
    """150 simulated URG-04LX scans at 10 Hz with their odometry; ranges already on the mm grid, so the
    bag (float32) and a CARMEN log (mm text) carry the same numbers."""
    run = simulate_run(default_world(), seed=0)
    out = []
    for s in run.scans[:150]:
        mm: FloatArray = np.asarray(s.ranges_m, dtype=np.float64).round(3)
        out.append(
            Scan(
                s.stamp_s,
                s.angle_min_rad,
                s.angle_increment_rad,
                s.range_min_m,
                s.range_max_m,
                mm,
                odometry=s.odometry,
            )
        )
    return out


SIM_OFFSET = Pose2D(0.145, 0.0, 0.0)


def odometry_at_scans(scans: Sequence[Scan]) -> list[tuple[int, Pose2D]]:
    out = []
    for s in scans:
        assert s.odometry is not None
        out.append((to_ns(s.stamp_s), s.odometry))
    return out


def odometry_twice_per_scan(scans: Sequence[Scan]) -> list[tuple[int, Pose2D]]:
    """Odometry at 20 Hz for 10 Hz scans: at each scan's stamp and half-way to the next (interpolated)."""
    at = odometry_at_scans(scans)
    out = []
    for (t0, p0), (t1, p1) in pairwise(at):
        out.append((t0, p0))
        out.append(((t0 + t1) // 2, interpolate_pose(t0, p0, t1, p1, (t0 + t1) // 2)))
    out.append(at[-1])
    return out


def sim_bag(scans: Sequence[Scan]) -> Bag:
    return Bag(
        {"/scan": scans},
        odometry=odometry_twice_per_scan(scans),
        static_tf=[
            ("base_link", "laser_mount", Pose2D(0.1, 0.0, 0.0)),
            ("laser_mount", "laser", Pose2D(0.045)),
        ],
    )


def read_all(path: Path, **kwargs: Any) -> tuple[list[Scan], RosbagReader]:
    with open_log(path, **kwargs) as reader:
        assert isinstance(reader, RosbagReader)
        return list(reader), reader


def assert_same_scans(got: Sequence[Scan], want: Sequence[Scan]) -> None:
    """Ranges bit-exact (as float32 widened), stamps within 1 ns, geometry as float32."""
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        f32 = np.asarray(w.ranges_m, dtype=np.float32).astype(np.float64)
        np.testing.assert_array_equal(g.ranges_m, f32)  # NaN == NaN here
        assert abs(g.stamp_s - w.stamp_s) <= 1e-9 * max(1.0, abs(w.stamp_s) / 1e6)
        assert g.stamp_s == to_ns(w.stamp_s) / NS
        assert g.angle_min_rad == float(np.float32(w.angle_min_rad))
        assert g.angle_increment_rad == float(np.float32(w.angle_increment_rad))
        assert g.range_max_m == float(np.float32(w.range_max_m))
        assert g.intensities is None


def pose_error(a: Pose2D | None, b: Pose2D | None) -> tuple[float, float]:
    assert a is not None and b is not None
    return math.hypot(a.x_m - b.x_m, a.y_m - b.y_m), abs(math.remainder(a.theta_rad - b.theta_rad, math.tau))


# -- reading back ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_bag_reads_back_the_scans_stamps_odometry_and_laser_offset(
    tmp_path: Path, kind: str, sim_scans: list[Scan]
) -> None:
    path = write_bag(bag_path(tmp_path, kind), kind, sim_bag(sim_scans))
    assert detect_format(path) == "rosbag"
    got, reader = read_all(path)
    assert_same_scans(got, sim_scans)
    for g, w in zip(got, sim_scans, strict=True):
        dist, turn = pose_error(g.odometry, w.odometry)
        assert dist <= 1e-9 and turn <= 1e-9  # odometry at 20 Hz hits every scan stamp
    info = reader.info
    assert info.format == "rosbag"
    assert max(pose_error(info.laser_offset, SIM_OFFSET)) <= 1e-12  # base_link -> laser_mount -> laser
    assert info.geometry is not None and info.geometry.beam_count == sim_scans[0].beam_count
    assert info.geometry.rate_hz == pytest.approx(10.0)
    storage = {"sqlite3": "sqlite3", "mcap": "mcap", "ros1": "rosbag1"}[kind]
    assert info.params["storage"] == storage and info.params["ros_version"] == (
        "1" if kind == "ros1" else "2"
    )
    assert info.params["scan_topic"] == "/scan" and info.params["odometry"].startswith("/odom")
    assert reader.clamped_scans == 0 and reader.scans_read == len(sim_scans)
    assert reader.progress() == 1.0  # the share of the bag's scan messages read (its message counts)


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_the_storage_file_alone_opens_too(tmp_path: Path, kind: str, sim_scans: list[Scan]) -> None:
    folder = write_bag(tmp_path / "run", kind, sim_bag(sim_scans[:10]))
    alone = tmp_path / f"alone{storage_file(folder).suffix}"
    shutil.copy(storage_file(folder), alone)
    got, _ = read_all(alone)
    assert_same_scans(got, sim_scans[:10])


@pytest.mark.skipif(not FR079.is_file(), reason=f"real log not found at {FR079}")
@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_a_cut_of_a_real_carmen_log_round_trips(tmp_path: Path, kind: str) -> None:
    with open_log(FR079) as carmen:
        scans = list(islice(carmen, 60))
        offset = carmen.info.laser_offset
    bag = Bag(
        {"/base_scan": scans}, odometry=odometry_at_scans(scans), static_tf=[("base_link", "laser", offset)]
    )
    got, reader = read_all(write_bag(bag_path(tmp_path, kind), kind, bag))
    assert_same_scans(got, scans)  # stamps ~1211 s: exact to the nanosecond
    for g, w in zip(got, scans, strict=True):
        dist, turn = pose_error(g.odometry, w.odometry)
        assert dist <= 1e-3 and turn <= 1e-3  # the bound when the rates match
        assert dist <= 1e-12 and turn <= 1e-12  # and in fact exact: the stamps coincide
        assert np.isnan(g.ranges_m).sum() == np.isnan(w.ranges_m).sum()  # no return stays no return
    assert max(pose_error(reader.info.laser_offset, offset)) <= 1e-12
    assert reader.info.laser_offset.x_m == pytest.approx(-0.04)


def analytic_pose(t_s: float) -> Pose2D:
    """A robot driving a gentle curve while spinning through +-pi (x linear, y smooth, heading linear)."""
    return Pose2D(0.3 * t_s, 0.1 * math.sin(0.5 * t_s), 2.5 + 1.2 * t_s)


@pytest.mark.parametrize("kind", KINDS)
def test_odometry_at_another_rate_is_interpolated_at_each_scan_stamp(
    tmp_path: Path, kind: str, sim_scans: list[Scan]
) -> None:
    scans = sim_scans[:60]
    odo_t = [0.05 + i / 23.0 for i in range(int(6.2 * 23))]  # 23 Hz, starting after the first scan
    odometry = [(to_ns(t), analytic_pose(t)) for t in odo_t]
    got, reader = read_all(
        write_bag(bag_path(tmp_path, kind), kind, Bag({"/scan": scans}, odometry=odometry))
    )
    assert reader.clamped_scans == 1  # the scan at t = 0 precedes the odometry
    assert got[0].odometry == odometry[0][1]
    for g in got[1:]:
        dist, turn = pose_error(g.odometry, analytic_pose(g.stamp_s))
        assert dist <= 1e-5  # y's curvature over 1/23 s: <= 0.1 * 0.25 / 23^2 / 8
        assert turn <= 1e-9  # heading is linear in time, and interpolated across +-pi the short way
    assert reader.info.laser_offset == Pose2D()  # no tf at all: identity


def test_odometry_recorded_late_still_pairs_with_the_right_scans(
    tmp_path: Path, sim_scans: list[Scan]
) -> None:
    """Odometry messages reach the bag 0.8 s after their stamps: each scan waits in a short queue for the
    odometry message that brackets it."""
    scans = sim_scans[:40]
    bag = Bag({"/scan": scans}, odometry=odometry_at_scans(scans), odom_delay_ns=800_000_000)
    got, reader = read_all(write_bag(tmp_path / "late", "mcap", bag))
    assert reader.clamped_scans == 0
    for g, w in zip(got, scans, strict=True):
        assert max(pose_error(g.odometry, w.odometry)) <= 1e-12


@pytest.mark.parametrize("kind", KINDS)
def test_without_an_odometry_topic_the_odom_to_base_link_transforms_are_used(
    tmp_path: Path, kind: str, sim_scans: list[Scan]
) -> None:
    scans = sim_scans[:30]
    tf_t = [i / 30.0 for i in range(95)]
    bag = Bag(
        {"/scan": scans},
        tf_odometry=[(to_ns(t), analytic_pose(t)) for t in tf_t],
        static_tf=[("base_link", "laser", SIM_OFFSET)],
    )
    got, reader = read_all(write_bag(bag_path(tmp_path, kind), kind, bag))
    assert reader.info.params["odometry"] == "tf odom -> base_link"
    for g in got:
        dist, turn = pose_error(g.odometry, analytic_pose(g.stamp_s))
        assert dist <= 1e-5 and turn <= 1e-9
    assert max(pose_error(reader.info.laser_offset, SIM_OFFSET)) <= 1e-12


def test_a_bag_without_any_odometry_gives_scans_without_odometry(
    tmp_path: Path, sim_scans: list[Scan]
) -> None:
    got, reader = read_all(write_bag(tmp_path / "bare", "sqlite3", Bag({"/scan": sim_scans[:5]})))
    assert [g.odometry for g in got] == [None] * 5
    assert reader.info.params["odometry"] == "none"


# -- the acceptance criterion ---------------------------------------------------------------------------


def map_segments(scans: Sequence[Scan], offset: Pose2D) -> FloatArray:
    pipeline = Pipeline(laser_offset=offset)
    for scan in scans:
        pipeline.step(scan)
    pipeline.flush()
    return pipeline.snapshot().segments


def wall_points(segments: FloatArray, step_m: float = 0.02) -> FloatArray:
    """Points every ``step_m`` along each segment (both ends included)."""
    parts = []
    for x0, y0, x1, y1 in segments.tolist():
        t = np.linspace(0.0, 1.0, max(2, int(math.hypot(x1 - x0, y1 - y0) / step_m) + 1))
        parts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(parts)


def share_within(segments: FloatArray, walls: FloatArray, tol_m: float) -> float:
    """The share of ``segments``' length (sampled every 2 cm) within ``tol_m`` of one of ``walls``."""
    p = wall_points(segments)[:, None, :]
    a, d = walls[None, :, :2], walls[None, :, 2:] - walls[None, :, :2]
    t = np.clip(((p - a) * d).sum(2) / np.maximum((d * d).sum(2), 1e-18), 0.0, 1.0)
    return float((np.sqrt(((p - a - t[..., None] * d) ** 2).sum(2)).min(1) <= tol_m).mean())


def assert_same_walls(got: FloatArray, want: FloatArray) -> None:
    """The same walls up to the pipeline's tipping points. The scans read are the same to float32 (the
    tests above); the maps are a discontinuous function of them: float32 ranges and angles in the bag, mm
    ranges and 6-decimal poses in the CARMEN text can split, merge or extend a wall differently (one short
    piece joined in one map and not the other moved a wall's end by 37-40 cm, 2-3 % of the map's length).
    So compare the wall sets as geometry: 95 % of each map's length within 2 cm of the other and about as
    many segments. A reading error (an offset, a flipped angle, a unit) moves every wall (the test below
    checks that a missing laser offset fails this).
    """
    assert abs(len(got) - len(want)) <= max(1, len(want) // 10)
    assert share_within(got, want, 0.02) >= 0.95 and share_within(want, got, 0.02) >= 0.95


@pytest.fixture(scope="module")
def carmen_walls(sim_scans: list[Scan], tmp_path_factory: pytest.TempPathFactory) -> FloatArray:
    log = tmp_path_factory.mktemp("carmen") / "run.clf"
    write_carmen(log, sim_scans, laser_offset=SIM_OFFSET)
    with open_log(log) as reader:
        assert reader.info.laser_offset == SIM_OFFSET
        walls = map_segments(list(reader), reader.info.laser_offset)
    assert len(walls) >= 10
    return walls


@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_maps_like_the_equivalent_carmen_log(
    tmp_path: Path, kind: str, sim_scans: list[Scan], carmen_walls: FloatArray
) -> None:
    path = write_bag(bag_path(tmp_path, kind), kind, sim_bag(sim_scans))
    with open_log(path) as reader:
        walls = map_segments(list(reader), reader.info.laser_offset)
    assert_same_walls(walls, carmen_walls)


@pytest.mark.skipif(not FR079.is_file(), reason=f"real log not found at {FR079}")
def test_a_bag_of_a_real_log_maps_like_that_log(tmp_path: Path) -> None:
    with open_log(FR079) as source:
        scans = list(islice(source, 100))
        offset = source.info.laser_offset
    log = tmp_path / "cut.clf"
    write_carmen(log, scans, laser_offset=offset)
    with open_log(log) as carmen:
        want = map_segments(list(carmen), carmen.info.laser_offset)
    bag = Bag(
        {"/base_scan": scans}, odometry=odometry_at_scans(scans), static_tf=[("base_link", "laser", offset)]
    )
    bag_file = write_bag(tmp_path / "cut", "mcap", bag)
    with open_log(bag_file) as reader:
        got = map_segments(list(reader), reader.info.laser_offset)
    # the same tipping points as the simulated run's (assert_same_walls): at 0494ebe one wall of the bag's
    # map ended 17 cm further on (0.6 % of the map's length), all else within 1 cm
    assert len(want) >= 10
    assert_same_walls(got, want)
    with open_log(bag_file) as reader:
        shifted = map_segments(list(reader), Pose2D())  # the laser offset left out: every wall moves
    with pytest.raises(AssertionError):
        assert_same_walls(shifted, want)


def test_the_wall_comparison_notices_a_wrong_laser_offset(
    tmp_path: Path, sim_scans: list[Scan], carmen_walls: FloatArray
) -> None:
    path = write_bag(tmp_path / "run", "mcap", sim_bag(sim_scans))
    with open_log(path) as reader:
        shifted = map_segments(list(reader), Pose2D())  # the tf offset (14.5 cm) left out
    with pytest.raises(AssertionError):
        assert_same_walls(shifted, carmen_walls)


# -- choosing topics, bad bags --------------------------------------------------------------------------


def test_two_laser_topics_need_a_choice(tmp_path: Path, sim_scans: list[Scan]) -> None:
    scans = sim_scans[:5]
    path = write_bag(tmp_path / "two", "mcap", Bag({"/front": scans, "/rear": scans[:3]}))
    with pytest.raises(
        RosbagTopicError, match=r"2 sensor_msgs/msg/LaserScan topics \(/front, /rear\)"
    ) as err:
        open_log(path)
    assert err.value.candidates == ("/front", "/rear")
    assert "scan_topic" in str(err.value)
    got, reader = read_all(path, scan_topic="rear")  # the leading / may be left out
    assert len(got) == 3 and reader.info.params["scan_topic"] == "/rear"
    with pytest.raises(
        RosbagTopicError,
        match=r"no topic '/side': sensor_msgs/msg/LaserScan topics in the bag: "
        r"/front, /rear",
    ):
        open_log(path, scan_topic="/side")


def test_a_topic_of_the_wrong_type_is_refused(tmp_path: Path, sim_scans: list[Scan]) -> None:
    bag = Bag({"/scan": sim_scans[:5]}, odometry=odometry_at_scans(sim_scans[:5]))
    path = write_bag(tmp_path / "typed", "sqlite3", bag)
    with pytest.raises(
        RosbagTopicError,
        match=r"topic /odom carries nav_msgs/msg/Odometry: expected "
        r"sensor_msgs/msg/LaserScan",
    ):
        open_log(path, scan_topic="/odom")
    with pytest.raises(
        RosbagTopicError,
        match=r"topic /scan carries sensor_msgs/msg/LaserScan: expected "
        r"nav_msgs/msg/Odometry",
    ):
        open_log(path, odom_topic="/scan")


@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_without_laser_scans_is_refused_naming_its_topics(tmp_path: Path, kind: str) -> None:
    bag = Bag({}, odometry=[(0, Pose2D()), (NS, Pose2D(1.0))])
    path = write_bag(bag_path(tmp_path, kind), kind, bag)
    with pytest.raises(
        RosbagTopicError,
        match=r"no sensor_msgs/msg/LaserScan topic: topics in the bag: "
        r"/odom \(nav_msgs/msg/Odometry\)",
    ):
        open_log(path)


def write_odometry_topics(path: Path, scans: Sequence[Scan], topics: Sequence[str]) -> Path:
    """An MCAP bag of ``scans`` on /scan plus one Odometry topic per name (topic i at x = i m)."""
    ts = typestore_for("mcap")
    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        scan_conn = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        odom_conns = [writer.add_connection(t, "nav_msgs/msg/Odometry", typestore=ts) for t in topics]
        for s in scans:
            t_ns = to_ns(s.stamp_s)
            writer.write(
                scan_conn, t_ns, ts.serialize_cdr(scan_msg(ts, s, "laser"), "sensor_msgs/msg/LaserScan")
            )
            for i, conn in enumerate(odom_conns):
                msg = odometry_msg(ts, t_ns, Pose2D(float(i)))
                writer.write(conn, t_ns, ts.serialize_cdr(msg, "nav_msgs/msg/Odometry"))
    return path


def test_several_odometry_topics_prefer_odom_else_need_a_choice(
    tmp_path: Path, sim_scans: list[Scan]
) -> None:
    scans = sim_scans[:5]
    path = write_odometry_topics(tmp_path / "odoms", scans, ["/wheel_odom", "/visual_odom"])
    with pytest.raises(
        RosbagTopicError,
        match=r"2 nav_msgs/msg/Odometry topics \(/visual_odom, /wheel_odom\): "
        r"choose one with --odom-topic \(odom_topic\)",
    ):
        open_log(path)
    got, _ = read_all(path, odom_topic="visual_odom")
    assert all(g.odometry == Pose2D(1.0) for g in got)
    got, reader = read_all(write_odometry_topics(tmp_path / "rep105", scans, ["/odometry/filtered", "/odom"]))
    assert reader.info.params["odometry"] == "/odom (nav_msgs/msg/Odometry)"
    assert all(g.odometry == Pose2D(1.0) for g in got)


def test_scans_after_the_odometry_stops_keep_its_last_pose(tmp_path: Path, sim_scans: list[Scan]) -> None:
    scans = sim_scans[:30]
    bag = Bag({"/scan": scans}, odometry=odometry_at_scans(scans[:10]))
    got, reader = read_all(write_bag(tmp_path / "stops", "sqlite3", bag))
    assert reader.clamped_scans == 20
    for g, w in zip(got, scans[:10] + [scans[9]] * 20, strict=True):
        assert max(pose_error(g.odometry, w.odometry)) <= 1e-12


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("keep", [0.5, 0.97])
def test_a_truncated_bag_is_a_clear_error(
    tmp_path: Path, kind: str, keep: float, sim_scans: list[Scan]
) -> None:
    written = write_bag(bag_path(tmp_path, kind), kind, sim_bag(sim_scans[:20]))
    file = written if kind == "ros1" else storage_file(written)
    cut = tmp_path / f"cut{file.suffix}"
    data = file.read_bytes()
    cut.write_bytes(data[: int(len(data) * keep)])
    with (
        pytest.raises(RosbagError, match=r"cut\.(bag|db3|mcap): cannot open it as a ROS bag") as err,
        open_log(cut) as reader,
    ):
        list(reader)
    assert isinstance(err.value, LogError)
    garbage = tmp_path / f"garbage{file.suffix}"
    garbage.write_bytes(b"not a bag at all\n" * 40)
    with pytest.raises(RosbagError, match="garbage"):
        open_log(garbage)


def test_a_bad_message_names_topic_and_message_number(tmp_path: Path, sim_scans: list[Scan]) -> None:
    ts = typestore_for("mcap")
    path = tmp_path / "bad"
    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        for i, s in enumerate(sim_scans[:4]):
            msg = scan_msg(ts, s, "laser")
            if i == 2:
                msg.range_max = -1.0
            writer.write(conn, to_ns(s.stamp_s), ts.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
    with open_log(path) as reader:
        assert next(reader).stamp_s == sim_scans[0].stamp_s
        with pytest.raises(
            RosbagMessageError, match=r"bad: /scan message 3: Scan range window .* expected 0 <= min"
        ):
            list(reader)


def test_open_log_tells_folders_files_and_names_apart(tmp_path: Path, sim_scans: list[Scan]) -> None:
    folder = tmp_path / "plain"
    folder.mkdir()
    with pytest.raises(LogError, match=r"is a directory without metadata\.yaml"):
        open_log(folder)
    with pytest.raises(LogNotFoundError):
        open_log(tmp_path / "absent.mcap")
    written = write_bag(tmp_path / "run", "mcap", sim_bag(sim_scans[:3]))
    disguised = tmp_path / "run.bin"
    shutil.copy(storage_file(written), disguised)
    with pytest.raises(UnknownLogFormatError, match=r"holds a MCAP file .* rename it to end in \.mcap"):
        open_log(disguised)
    ros1 = write_bag(tmp_path / "r.bag", "ros1", sim_bag(sim_scans[:3]))
    shutil.copy(ros1, tmp_path / "r1")
    with pytest.raises(UnknownLogFormatError, match=r"ROS 1 bag .* \.bag"):
        open_log(tmp_path / "r1")
    with pytest.raises(RosbagError, match=r"suffix '\.bin'"):
        open_log(disguised, format="rosbag")
    log = tmp_path / "run.clf"
    write_carmen(log, sim_scans[:3])
    with pytest.raises(LogError, match="ROS bags only"):
        open_log(log, scan_topic="/scan")
