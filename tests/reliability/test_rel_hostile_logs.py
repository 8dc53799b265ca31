"""Fuzzed laser logs (docs/reliability.md): CARMEN and BreezySLAM text logs (plain and gzip) and ROS bags (ROS
1, rosbag2 SQLite3 and MCAP) built from valid seeds and mutated (truncation, byte flips, garbage lines, huge
numbers, NaN/inf text, non-ASCII digits, corrupt gzip): reading them may fail only with the readers' own
:class:`shared.io.LogError` family, whose message says what is wrong; never IndexError, ValueError & co.
"""

from __future__ import annotations

import functools
import gzip
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import strategies as st
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from shared.io import CarmenReader, LogError, open_log
from tests.reliability.hostiletools import (
    assert_only,
    fast_examples,
    mutated_bytes,
    mutated_text,
    run_fuzz,
    soak_examples,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
NS = 1_000_000_000
#: Latest stamp both ROS 1 (uint32 seconds) and ROS 2 (int32 seconds) can carry.
MAX_STAMP_NS = (2**31 - 1) * NS


# ------------------------------------------------------------------------------------------ text seeds


def _carmen_seed() -> str:
    r8 = " ".join(f"{1.0 + 0.25 * i:.3f}" for i in range(8))
    r6 = " ".join(f"{2.0 + 0.5 * i:.3f}" for i in range(6))
    rem = " ".join(str(10 * i) for i in range(6))
    return "\n".join(
        [
            "# CARMEN Logfile",
            "PARAM robot_front_laser_max 50.0 0.0 host 0.0",
            "PARAM laser_front_laser_resolution 1.0 0.0 host 0.0",
            "PARAM robot_frontlaser_offset 0.1 0.0 host 0.0",
            "ODOM 0.0 0.0 0.0 0.0 0.0 0.0 1.0 host 1.0",
            f"FLASER 8 {r8} 0.1 0.0 0.0 0.0 0.0 0.0 1.1 host 1.1",
            f"RLASER 8 {r8} 0.1 0.0 3.14 0.0 0.0 0.0 1.1 host 1.1",
            "TRUEPOS 0.0 0.0 0.0 0.0 0.0 0.0 1.2 host 1.2",
            f"ROBOTLASER1 0 -1.5708 3.1416 0.0175 50.0 0.01 0 6 {r6} 6 {rem} 0.2 0.1 0.05 0.1 0.1 0.05 "
            "0.0 0.0 0.5 0.3 0.0 1.3 host 1.3",
            f"ROBOTLASER2 99 -2.0 4.0 0.5 5.6 0.001 0 6 {r6} 0 0.2 0.1 0.05 0.1 0.1 0.05 "
            "0.0 0.0 0.5 0.3 0.0 1.4 host 1.4",
            f"FLASER 8 {r8} 0.2 0.0 0.1 0.1 0.0 0.1 1.5 host 1.5",
        ]
    )


def _breezy_seed() -> str:
    lines = []
    for k in range(3):
        head = [str(1_000_000 * k), str(k), str(100 * k), str(120 * k)] + ["0"] * 20
        ranges = [str(500 + (i * 7 + k) % 3000) for i in range(682)]
        lines.append(" ".join([*head, *ranges, "0"]))
    return "\n".join(lines)


def _real_seed(path: Path, lines: int) -> str | None:
    if not path.is_file():
        return None
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        return "".join(fh.readline() for _ in range(lines))


CARMEN_GARBAGE = (
    "FLASER", "FLASER 3", "FLASER -1 1 2 3", "FLASER 99999999999999999999 1", "ROBOTLASER1 0",
    "ROBOTLASER1 0 0 0 0 0 0 0 2 1 1 \u00b2 1", "ROBOTLASER1 0 nan 1 0 50 0 0 1 1 0 " + "0 " * 14,
    "PARAM", "PARAM robot_front_laser_max nan", "PARAM laser_front_laser_resolution -1",
    "ODOM nan inf", "123 456", "\x00\x00\x00", "#", "FLASER 1 1 1e308 -1e308 0 -1e308 1e308 0 1 h 1",
)  # fmt: skip
BREEZY_GARBAGE = ("1 2 3", "x" * 100, " ".join(["1e308"] * 707), " ".join(["-1.7976931348623157e308"] * 707))


@st.composite
def text_logs(draw: st.DrawFn, seeds: list[str], garbage: tuple[str, ...]) -> tuple[bytes, str]:
    """``(file bytes, how it was written)``: a mutated seed, as text, as gzip, or byte-mutated either way."""
    text = draw(mutated_text(draw(st.sampled_from(seeds)), garbage))
    raw = text.encode("utf-8", "surrogatepass")
    how = draw(st.sampled_from(["text", "gzip", "bytes", "gzip-bytes"]))
    if how.startswith("gzip"):
        raw = gzip.compress(raw, compresslevel=1, mtime=0)
    if how.endswith("bytes"):
        raw = draw(mutated_bytes(raw))
    return raw, how


def _read_all(path: Path, **kwargs: Any) -> int:
    with open_log(path, **kwargs) as reader:
        assert reader.info is not None
        return sum(1 for _ in reader)


def _carmen_check(tmp: Path) -> Any:
    def check(case: tuple[tuple[bytes, str], str, bool]) -> None:
        (raw, _how), laser, by_name = case
        path = tmp / ("log.clf" if by_name else "log.unknown")
        path.write_bytes(raw)

        def read() -> None:
            if laser == "front":
                _read_all(path)
            else:
                with CarmenReader(path, laser=laser) as reader:
                    sum(1 for _ in reader)

        assert_only((LogError,), read)

    return check


def _breezy_check(tmp: Path) -> Any:
    def check(case: tuple[bytes, str]) -> None:
        path = tmp / "log.dat"
        path.write_bytes(case[0])
        assert_only((LogError,), lambda: _read_all(path))

    return check


def _carmen_cases() -> st.SearchStrategy[Any]:
    seeds = [_carmen_seed()]
    for name, n in (("aces/aces.clf.gz", 40), ("fr-clinic/fr-clinic_robotlaser.clf.gz", 30)):
        real = _real_seed(DATA / name, n)
        if real is not None:
            seeds.append(real)
    return st.tuples(text_logs(seeds, CARMEN_GARBAGE), st.sampled_from(["front", "rear"]), st.booleans())


def _breezy_cases() -> st.SearchStrategy[Any]:
    seeds = [_breezy_seed()]
    real = _real_seed(DATA / "breezyslam-urg04lx" / "exp1.dat.gz", 3)
    if real is not None:
        seeds.append(real)
    return text_logs(seeds, BREEZY_GARBAGE)


def test_seeds_are_valid(tmp_path: Path) -> None:
    """The seeds read cleanly, so the fuzzing starts from valid input and the mutations are what fails."""
    (tmp_path / "a.clf").write_text(_carmen_seed(), encoding="utf-8")
    assert _read_all(tmp_path / "a.clf") == 3
    with CarmenReader(tmp_path / "a.clf", laser="rear") as rear:
        assert sum(1 for _ in rear) == 2
    (tmp_path / "b.dat").write_text(_breezy_seed(), encoding="utf-8")
    assert _read_all(tmp_path / "b.dat") == 3


def _breezy_line(stamp: int, q1: str, q2: str) -> str:
    return " ".join([str(stamp), "0", q1, q2] + ["0"] * 20 + ["1000"] * 682 + ["0"])


@pytest.mark.parametrize(
    ("name", "text", "fragment"),
    [
        ("poses.clf", "FLASER 1 1.0 1e308 -1e308 0 -1e308 1e308 0 1 h 1\n", "offset is not a finite number"),
        (
            "angles.clf",
            "ROBOTLASER1 0 1e308 0 1e308 50 0 0 3 1 1 1 0 0 0 0 0 0 0 0 0 0 0 0 1 h 1\n",
            "expected beam angles that are finite numbers",
        ),
        ("remissions.clf", "ROBOTLASER1 0 0 0 1 50 0 0 1 1 \u00b2 " + "0 " * 14 + "\n", "remission count"),
        (
            "ticks.dat",
            _breezy_line(0, "1.7e308", "-1.7e308") + "\n" + _breezy_line(1, "-1.7e308", "1.7e308") + "\n",
            "the odometry step is not a finite number",
        ),
    ],
    ids=["flaser-poses", "robotlaser-angles", "remission-count", "breezyslam-ticks"],
)
def test_huge_numbers_are_log_format_errors(tmp_path: Path, name: str, text: str, fragment: str) -> None:
    """Findings of the fuzzing, kept as cases: finite fields whose arithmetic overflows, a non-ASCII digit."""
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    err = assert_only((LogError,), lambda: _read_all(path))
    assert err is not None and fragment in str(err), err


def test_corrupt_gzip_without_suffix_is_a_log_error(tmp_path: Path) -> None:
    raw = bytearray(gzip.compress(_carmen_seed().encode(), compresslevel=1, mtime=0))
    raw[len(raw) // 2] ^= 0xFF
    (tmp_path / "log").write_bytes(bytes(raw))
    assert assert_only((LogError,), lambda: _read_all(tmp_path / "log")) is not None


def test_carmen_fuzz(tmp_path: Path) -> None:
    run_fuzz(_carmen_check(tmp_path), _carmen_cases(), fast_examples(300))


def test_breezyslam_fuzz(tmp_path: Path) -> None:
    run_fuzz(_breezy_check(tmp_path), _breezy_cases(), fast_examples(200))


@pytest.mark.soak
def test_text_logs_soak(tmp_path: Path) -> None:
    run_fuzz(_carmen_check(tmp_path), _carmen_cases(), soak_examples())
    run_fuzz(_breezy_check(tmp_path), _breezy_cases(), soak_examples())


# ------------------------------------------------------------------------------------------- ROS bags


@functools.cache
def _store(kind: str) -> Typestore:
    if kind != "ros1":
        return get_typestore(Stores.ROS2_HUMBLE)
    store = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        tf = get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        store.register(tf)
    return store


def _header(ts: Typestore, stamp_ns: int, frame: str) -> Any:
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS)
    if "seq" in dict(ts.fielddefs["std_msgs/msg/Header"][1]):
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


@st.composite
def bag_values(draw: st.DrawFn) -> dict[str, Any]:
    """Field values of a small bag, finite and sane or hostile (NaN, inf, huge, zero spacing, bad frames)."""
    anyf = st.floats(allow_nan=True, allow_infinity=True, width=64)
    sane = st.floats(-10.0, 10.0) | st.sampled_from([1.7e308, -1.7e308])
    f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
    stamps = st.integers(0, MAX_STAMP_NS)
    quat = st.tuples(anyf, anyf, anyf, anyf) | st.just((0.0, 0.0, 0.0, 1.0))
    return {
        "angle_min": draw(st.sampled_from([-1.5]) | f32),
        "angle_increment": draw(st.sampled_from([0.01]) | f32),
        "range_min": draw(st.sampled_from([0.02]) | f32),
        "range_max": draw(st.sampled_from([5.6]) | f32),
        "scan_time": draw(st.sampled_from([0.1]) | f32),
        "ranges": draw(st.lists(f32, min_size=0, max_size=12)),
        "intensities": draw(st.lists(f32, max_size=12)),
        "scan_stamps": draw(st.lists(stamps, min_size=1, max_size=4)),
        "odom": draw(st.lists(st.tuples(stamps, sane | anyf, sane | anyf, quat), max_size=5)),
        "static": draw(st.sampled_from([(0.1, 0.0, 0.0)]) | st.tuples(anyf, anyf, anyf)),
        "laser_frame": draw(st.sampled_from(["laser", "base_link", "/laser", ""]) | st.text(max_size=6)),
        "child_frame": draw(st.sampled_from(["base_link", ""]) | st.text(max_size=6)),
    }


def _messages(ts: Typestore, v: dict[str, Any]) -> Iterator[tuple[int, str, str, Any]]:
    t = ts.types
    for k, stamp in enumerate(v["scan_stamps"]):
        msg = t["sensor_msgs/msg/LaserScan"](
            header=_header(ts, stamp, v["laser_frame"]), angle_min=v["angle_min"],
            angle_max=v["angle_min"] + 1.0, angle_increment=v["angle_increment"], time_increment=0.0,
            scan_time=v["scan_time"], range_min=v["range_min"], range_max=v["range_max"],
            ranges=np.asarray(v["ranges"], dtype=np.float32),
            intensities=np.asarray(v["intensities"], dtype=np.float32),
        )  # fmt: skip
        yield k + 10, "/scan", "sensor_msgs/msg/LaserScan", msg
    vec = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    for k, (stamp, x, y, (qx, qy, qz, qw)) in enumerate(v["odom"]):
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )
        msg = t["nav_msgs/msg/Odometry"](
            header=_header(ts, stamp, "odom"), child_frame_id=v["child_frame"],
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=np.zeros(36)
            ),
        )  # fmt: skip
        yield k + 11, "/odom", "nav_msgs/msg/Odometry", msg
    sx, sy, sz = v["static"]
    tr = t["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, 0, "base_link"), child_frame_id="laser",
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=sx, y=sy, z=sz),
            rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )  # fmt: skip
    yield 1, "/tf_static", "tf2_msgs/msg/TFMessage", t["tf2_msgs/msg/TFMessage"](transforms=[tr])


def write_bag(path: Path, kind: str, values: dict[str, Any]) -> Path:
    """A bag of ``kind`` (``ros1`` file, ``sqlite3`` / ``mcap`` rosbag2 folder) at ``path``."""
    ts = _store(kind)
    msgs = sorted(_messages(ts, values), key=lambda m: m[0])
    if kind == "ros1":
        with Writer1(path) as w1:
            conns1: dict[str, Any] = {}
            for t_ns, topic, msgtype, msg in msgs:
                if topic not in conns1:
                    conns1[topic] = w1.add_connection(topic, msgtype, typestore=ts)
                w1.write(conns1[topic], t_ns, ts.serialize_ros1(msg, msgtype))
        return path
    plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
    with Writer2(path, version=9, storage_plugin=plugin) as w2:
        conns2: dict[str, Any] = {}
        for t_ns, topic, msgtype, msg in msgs:
            if topic not in conns2:
                conns2[topic] = w2.add_connection(topic, msgtype, typestore=ts)
            w2.write(conns2[topic], t_ns, ts.serialize_cdr(msg, msgtype))
    return path


SANE = {
    "angle_min": -1.5, "angle_increment": 0.01, "range_min": 0.02, "range_max": 5.6, "scan_time": 0.1,
    "ranges": [1.0, 2.0, 3.0], "intensities": [], "scan_stamps": [2 * NS, 3 * NS, 4 * NS],
    "odom": [(1 * NS, 0.0, 0.0, (0.0, 0.0, 0.0, 1.0)), (5 * NS, 1.0, 0.5, (0.0, 0.0, 0.1, 0.995))],
    "static": (0.1, 0.0, 0.0), "laser_frame": "laser", "child_frame": "base_link",
}  # fmt: skip
KINDS = ("ros1", "sqlite3", "mcap")


def _bag_path(tmp: Path, kind: str, name: str) -> Path:
    return tmp / (f"{name}.bag" if kind == "ros1" else name)


def _storage(path: Path) -> Path:
    if path.is_file():
        return path
    (file,) = [f for f in path.iterdir() if f.suffix in (".db3", ".mcap")]
    return file


def test_bag_seeds_are_valid(tmp_path: Path) -> None:
    for kind in KINDS:
        assert _read_all(write_bag(_bag_path(tmp_path, kind, f"seed-{kind}"), kind, SANE)) == 3


@pytest.mark.parametrize("kind", KINDS)
def test_rosbag_odometry_interpolation_overflow_is_a_log_error(tmp_path: Path, kind: str) -> None:
    """A finding of the fuzzing: two finite odometry poses whose interpolation overflows."""
    q = (0.0, 0.0, 0.0, 1.0)
    values = {**SANE, "odom": [(1 * NS, 1.7e308, 0.0, q), (5 * NS, -1.7e308, 0.0, q)]}
    path = write_bag(_bag_path(tmp_path, kind, "overflow"), kind, values)
    err = assert_only((LogError,), lambda: _read_all(path))
    assert err is not None and "odometry interpolated at its stamp is not finite" in str(err), err


def _values_check(tmp: Path) -> Any:
    counter = [0]

    def check(case: tuple[str, dict[str, Any]]) -> None:
        kind, values = case
        counter[0] += 1
        path = _bag_path(tmp, kind, f"v{counter[0]}")
        write_bag(path, kind, values)
        try:
            assert_only((LogError,), lambda: _read_all(path))
        finally:
            shutil.rmtree(path) if path.is_dir() else path.unlink()

    return check


def _bytes_check(tmp: Path, seeds: dict[str, Path]) -> Any:
    def check(case: tuple[str, bytes, bool]) -> None:
        kind, raw, in_metadata = case
        target = _bag_path(tmp, kind, "mutated")
        if target.exists():
            shutil.rmtree(target) if target.is_dir() else target.unlink()
        if kind == "ros1":
            target.write_bytes(raw)
        else:
            shutil.copytree(seeds[kind], target)
            (target / "metadata.yaml" if in_metadata else _storage(target)).write_bytes(raw)
        assert_only((LogError,), lambda: _read_all(target))

    return check


def _bytes_cases(seeds: dict[str, Path]) -> st.SearchStrategy[Any]:
    def one(kind: str) -> st.SearchStrategy[Any]:
        if kind == "ros1":
            return st.tuples(st.just(kind), mutated_bytes(seeds[kind].read_bytes()), st.just(False))
        meta = (seeds[kind] / "metadata.yaml").read_bytes()
        store = _storage(seeds[kind]).read_bytes()
        return st.booleans().flatmap(
            lambda in_meta: st.tuples(
                st.just(kind), mutated_bytes(meta if in_meta else store), st.just(in_meta)
            )
        )

    return st.sampled_from(KINDS).flatmap(one)


@pytest.fixture
def bag_seeds(tmp_path: Path) -> dict[str, Path]:
    return {kind: write_bag(_bag_path(tmp_path, kind, f"seed-{kind}"), kind, SANE) for kind in KINDS}


def test_rosbag_field_fuzz(tmp_path: Path) -> None:
    run_fuzz(_values_check(tmp_path), st.tuples(st.sampled_from(KINDS), bag_values()), fast_examples(40))


def test_rosbag_byte_fuzz(tmp_path: Path, bag_seeds: dict[str, Path]) -> None:
    run_fuzz(_bytes_check(tmp_path, bag_seeds), _bytes_cases(bag_seeds), fast_examples(200))


@pytest.mark.soak
def test_rosbag_soak(tmp_path: Path, bag_seeds: dict[str, Path]) -> None:
    run_fuzz(_values_check(tmp_path), st.tuples(st.sampled_from(KINDS), bag_values()), soak_examples())
    run_fuzz(_bytes_check(tmp_path, bag_seeds), _bytes_cases(bag_seeds), soak_examples())
