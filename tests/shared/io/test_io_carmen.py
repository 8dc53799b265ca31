"""CARMEN reader: record layouts, beam geometry, no-return handling, PARAMs, error paths (known answers)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from shared.errors import InvalidInputError, LinemapError
from shared.io import CarmenReader, LogError, LogFormatError
from shared.types import Pose2D, Scan

DEG = math.pi / 180.0


def flaser(
    ranges: Sequence[float | str],
    laser: Sequence[float | str] = (0.0, 0.0, 0.0),
    robot: Sequence[float | str] = (0.0, 0.0, 0.0),
    stamp: float | str = 1.0,
    count: int | str | None = None,
    name: str = "FLASER",
) -> str:
    n = len(ranges) if count is None else count
    parts = [name, str(n), *map(str, ranges), *map(str, laser), *map(str, robot), str(stamp), "host", "0.5"]
    return " ".join(parts)


def robotlaser(
    ranges: Sequence[float | str],
    *,
    start: float = -math.pi / 2,
    res: float = DEG,
    max_range: float | str = 81.9,
    laser_type: int = 0,
    remissions: Sequence[float] = (),
    laser: Sequence[float] = (0.22, 0.0, 0.0),
    robot: Sequence[float] = (0.0, 0.0, 0.0),
    stamp: float = 5.0,
    count: int | None = None,
    rem_count: int | None = None,
    name: str = "ROBOTLASER1",
) -> str:
    n = len(ranges) if count is None else count
    m = len(remissions) if rem_count is None else rem_count
    parts = [
        name, str(laser_type), repr(start), repr(math.pi), repr(res), str(max_range), "0.01", "0",
        str(n), *map(str, ranges), str(m), *map(str, remissions), *map(str, laser), *map(str, robot),
        "0", "0", "0", "0", "0", str(stamp), "host", "0.1",
    ]  # fmt: skip
    return " ".join(parts)


def write(tmp_path: Path, *lines: str, name: str = "log.clf") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def read_all(path: Path, max_range_m: float | None = None) -> list[Scan]:
    with CarmenReader(path, max_range_m=max_range_m) as reader:
        return list(reader)


def test_flaser_geometry_odometry_and_no_return(tmp_path: Path) -> None:
    ranges = [1.5] * 180
    ranges[0], ranges[1], ranges[2] = 50.0, 0.0, 49.91
    path = write(
        tmp_path,
        "# CARMEN Logfile",
        "PARAM robot_use_laser on nohost 0",
        "ODOM 1 2 1.570796 0 0 0 0.9 host 0",
        flaser(ranges, laser=(1.0, 2.3, math.pi / 2), robot=(1.0, 2.0, math.pi / 2), stamp=70.2899),
    )
    with CarmenReader(path) as reader:
        scans = list(reader)
        info = reader.info
        counts = reader.record_counts
    assert len(scans) == 1
    s = scans[0]
    assert s.stamp_s == 70.2899
    assert s.angle_min_rad == -math.pi / 2 and s.angle_increment_rad == pytest.approx(DEG, abs=1e-15)
    assert s.beam_count == 180 and s.angles_rad[-1] == pytest.approx(89 * DEG)
    assert s.range_min_m == 0.0 and s.range_max_m == 50.0  # DEFAULT_FLASER_MAX_RANGE_M
    assert np.isnan(s.ranges_m[0]) and np.isnan(s.ranges_m[1])  # 50.00 = no return, 0 = no return
    assert s.ranges_m[2] == 49.91 and np.all(s.ranges_m[3:] == 1.5)
    assert s.odometry is not None and s.odometry.as_tuple() == pytest.approx((1.0, 2.0, math.pi / 2))
    assert info.format == "carmen" and info.geometry is not None
    assert info.geometry.beam_count == 180 and info.geometry.range_max_m == 50.0
    assert info.laser_offset.as_tuple() == pytest.approx((0.3, 0.0, 0.0), abs=1e-9)
    assert info.params == {"robot_use_laser": "on"}
    assert counts == {"PARAM": 1, "ODOM": 1, "FLASER": 1}


@pytest.mark.parametrize(
    ("n", "inc_deg", "last_deg"), [(181, 1.0, 90.0), (360, 0.5, 89.5), (361, 0.5, 90.0), (91, 2.0, 90.0)]
)
def test_flaser_carmen_beam_spacing(tmp_path: Path, n: int, inc_deg: float, last_deg: float) -> None:
    (s,) = read_all(write(tmp_path, flaser([2.0] * n)))
    assert s.angle_increment_rad == pytest.approx(inc_deg * DEG, rel=1e-12)
    assert math.degrees(s.angles_rad[-1]) == pytest.approx(last_deg)


def test_params_set_max_range_resolution_and_offset(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "PARAM robot_front_laser_max 80.99 1.0 magnum 0.0",
        "PARAM laser_front_laser_resolution 1.0 1.0 magnum 0.0",
        "PARAM robot_frontlaser_offset -0.04 1.0 magnum 0.0",
        flaser([81.91, 60.0, 80.99, 3.0], laser=(-0.04, 0.0, 0.0)),
    )
    with CarmenReader(path) as reader:
        (s,) = list(reader)
        assert reader.params["robot_front_laser_max"] == "80.99"
        assert reader.info.laser_offset.as_tuple() == pytest.approx((-0.04, 0.0, 0.0))
    assert s.range_max_m == 80.99
    np.testing.assert_array_equal(s.ranges_m, [np.nan, 60.0, np.nan, 3.0])
    assert s.angle_increment_rad == pytest.approx(DEG)  # PARAM 1.0 deg, not 180 / 3


def test_explicit_max_range_overrides(tmp_path: Path) -> None:
    (s,) = read_all(write(tmp_path, flaser([49.0, 30.0, 10.0])), max_range_m=40.0)
    np.testing.assert_array_equal(s.ranges_m, [np.nan, 30.0, 10.0])


def test_offset_from_param_when_no_laser_record(tmp_path: Path) -> None:
    path = write(tmp_path, "PARAM robot_frontlaser_offset 0.15 nohost 0", "ODOM 0 0 0 0 0 0 1 h 0")
    with CarmenReader(path) as reader:
        assert list(reader) == []
        assert reader.info.geometry is None
        assert reader.info.laser_offset == Pose2D(0.15, 0.0, 0.0)


def test_robotlaser_layout_interlaced_and_sick_codes(tmp_path: Path) -> None:
    start = -1.566433
    path = write(
        tmp_path,
        robotlaser(
            [14.12, 81.91, 81.83, 7.0],
            start=start,
            res=0.017453,
            laser=(0.78, 0, math.pi),
            robot=(1, 0, math.pi),
        ),
        robotlaser([1.0, 81.83], laser_type=99, laser=(0.0, 0.0, 0.0), stamp=6.0),
    )
    with CarmenReader(path) as reader:
        a, b = list(reader)
        assert reader.info.laser_offset.as_tuple() == pytest.approx((0.22, 0.0, 0.0), abs=1e-9)
        assert reader.info.geometry is not None and reader.info.geometry.angle_min_rad == start
    assert a.angle_min_rad == start and a.angle_increment_rad == 0.017453 and a.range_max_m == 81.9
    np.testing.assert_array_equal(a.ranges_m, [14.12, np.nan, np.nan, 7.0])  # SICK: 81.83 is an error code
    assert a.odometry == Pose2D(1.0, 0.0, math.pi) and a.stamp_s == 5.0 and a.intensities is None
    np.testing.assert_array_equal(b.ranges_m, [1.0, 81.83])  # not a SICK (laser_type 99): a distance


def test_robotlaser_remissions_become_intensities(tmp_path: Path) -> None:
    (s,) = read_all(write(tmp_path, robotlaser([1.0, 2.0], remissions=[0.5, 0.25])))
    assert s.intensities is not None
    np.testing.assert_array_equal(s.intensities, [0.5, 0.25])
    (t,) = read_all(write(tmp_path, robotlaser([1.0, 2.0], remissions=[0.5]), name="b.clf"))
    assert t.intensities is None  # a remission count that is not one per beam is dropped (logged)


def test_comments_unknown_records_and_rear_laser(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "# comment",
        "",
        "SYNC tag 1 h 0",
        "TRUEPOS 1 2 3 4 5 6 1.0 h 0",
        flaser([1.0, 2.0], stamp=1.0),
        flaser([3.0, 4.0], laser=(-0.2, 0.0, math.pi), stamp=1.1, name="RLASER"),
        flaser([5.0, 6.0], stamp=1.2),
    )
    front = read_all(path)
    assert [s.stamp_s for s in front] == [1.0, 1.2]
    with CarmenReader(path, laser="rear") as reader:
        rear = list(reader)
        assert reader.info.laser_offset.as_tuple() == pytest.approx((-0.2, 0.0, math.pi))
    assert [s.stamp_s for s in rear] == [1.1]
    with pytest.raises(InvalidInputError, match="'front' or 'rear'"):
        CarmenReader(path, laser="left")


def test_streams_lazily(tmp_path: Path) -> None:
    path = write(tmp_path, flaser([1.0]), flaser([2.0]), "FLASER 1 oops")
    with CarmenReader(path) as reader:
        it = iter(reader)
        assert next(it).ranges_m[0] == 1.0
        assert next(it).ranges_m[0] == 2.0  # the bad third line is not read yet
        assert reader.scans_read == 2
        with pytest.raises(LogFormatError) as err:
            next(it)
    assert err.value.line_no == 3


# --- error paths -----------------------------------------------------------------------------------------

GOOD = flaser([1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("bad_line", "message"),
    [
        (flaser([1.0] * 179, count=180), "FLASER declares 180 ranges but has 179 values"),
        (flaser([1.0] * 181, count=180), "FLASER declares 180 ranges but has 181 values"),
        ("FLASER 180 1.0 2.0 3.0", "FLASER record is truncated: 5 fields, expected 191"),
        ("FLASER", "FLASER record is truncated: it ends before field 1 (num_readings)"),
        (flaser([1.0, 2.0], count="two"), "FLASER field 1 (num_readings) = 'two': expected a non-negative"),
        (flaser([1.0, 2.0], count=-2), "FLASER field 1 (num_readings) = '-2'"),
        (flaser([1.0, "abc", 3.0]), "FLASER field 3 (r_2) = 'abc': expected a number"),
        (flaser([1.0], robot=(0, "y?", 0)), "FLASER field 7 (odom_y) = 'y?': expected a number"),
        (flaser([1.0], stamp="noon"), "FLASER field 9 (ipc_timestamp) = 'noon': expected a number"),
        (flaser([1.0], laser=("nan", 0, 0)), "FLASER field 3 (x) = 'nan': expected a finite number"),
        ("ODOM 1 2 3 0 0 0 1.0 host", "ODOM has 9 fields: expected 10"),
        ("ODOM 1 2 x 0 0 0 1.0 host 0", "ODOM field 3 (theta) = 'x': expected a number"),
        ("PARAM robot_front_laser_max", "PARAM has 1 fields: expected a name and a value"),
        (
            "PARAM robot_front_laser_max far nohost 0",
            "PARAM robot_front_laser_max = 'far': expected a positive",
        ),
        ("PARAM robot_front_laser_max -5 nohost 0", "PARAM robot_front_laser_max = '-5'"),
        ("1.0 2.0 3.0", "line starts with '1.0': expected a CARMEN message name"),
        (robotlaser([1.0, 2.0], count=3), "ROBOTLASER1 declares 3 ranges but field 12, the remission count"),
        (robotlaser([1, 2], count=1), "ROBOTLASER1 declares 1 ranges and 2 remissions but has 2 values"),
        (
            robotlaser([1.0, 2.0], rem_count=2),
            "ROBOTLASER1 declares 2 ranges and 2 remissions but has 2 values",
        ),
        (robotlaser([1.0, 2.0], res=0.0), "ROBOTLASER1 field 4 (angular_res) = '0.0': expected a non-zero"),
        (robotlaser([1.0], max_range="-1"), "ROBOTLASER1 field 5 (max_range) = '-1': expected a positive"),
        (robotlaser([1.0, "x"]), "ROBOTLASER1 field 10 (r_2) = 'x': expected a number"),
        ("ROBOTLASER1 0 -1.5 3.1 0.01 80 0.01 0 5 1 2", "ROBOTLASER1 declares 5 ranges but has 2 values"),
    ],
)
def test_malformed_record_names_line_and_field(tmp_path: Path, bad_line: str, message: str) -> None:
    path = write(tmp_path, "# header", GOOD, bad_line, GOOD, name="aces.clf")
    with pytest.raises(LogFormatError) as err:
        read_all(path)
    assert err.value.line_no == 3 and err.value.path == path
    assert str(err.value).startswith(f"aces.clf line 3: {message}")
    assert isinstance(err.value, LogError) and isinstance(err.value, LinemapError)


def test_malformed_first_record_fails_at_open(tmp_path: Path) -> None:
    path = write(tmp_path, "PARAM a b", flaser([1.0, 2.0], count=3))
    with pytest.raises(LogFormatError, match="line 2: FLASER declares 3 ranges but has 2 values"):
        CarmenReader(path)


def test_error_pickles_with_its_fields() -> None:
    import pickle

    err = LogFormatError(Path("/x/aces.clf"), 12, "FLASER bad")
    back = pickle.loads(pickle.dumps(err))
    assert (back.path, back.line_no, back.reason, str(back)) == (err.path, 12, "FLASER bad", str(err))
