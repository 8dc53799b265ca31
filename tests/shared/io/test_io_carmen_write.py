"""write_carmen -> open_log round trips (hypothesis), record choice, gzip, and the writer's error paths."""

from __future__ import annotations

import gzip
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.io import open_log, write_carmen
from shared.types import URG04LX, Pose2D, Scan, wrap_angle

RANGE_TOL_M = 1.0e-3 + 1e-9  # 3 decimals, and a valid reading at range_max is written 1 mm below it
POSE_TOL = 1.0e-6  # 6 decimals


def _scan(
    ranges: list[float], geometry: tuple[float, float, float, float], stamp: float, pose: Pose2D
) -> Scan:
    angle_min, inc, rmin, rmax = geometry
    return Scan(stamp, angle_min, inc, rmin, rmax, np.array(ranges), odometry=pose)


@st.composite
def scans(draw: st.DrawFn) -> list[Scan]:
    """1..6 scans sharing a geometry: FLASER-like (beam 0 at -90 deg, CARMEN spacing) or arbitrary."""
    if draw(st.booleans()):
        n = draw(st.sampled_from([180, 181, 360, 361]))
        inc = math.pi / (180.0 if n < 200 else 360.0)
        angle_min = -math.pi / 2
    else:
        n = draw(st.integers(1, 40))
        angle_min = draw(st.floats(-math.pi, math.pi))
        inc = draw(st.floats(1e-4, 0.1)) * draw(st.sampled_from([1.0, -1.0]))
    rmax = draw(st.floats(0.5, 120.0))
    rmin = draw(st.floats(0.001, 0.3))  # CARMEN: a reading of 0 is no return
    value = st.one_of(
        st.floats(0.01, rmax * 1.2),
        st.sampled_from([math.nan, math.inf, rmax, rmin, 0.0]),
    )
    count = draw(st.integers(1, 6))
    t0 = draw(st.floats(0.0, 2.0e9))
    out = []
    for k in range(count):
        ranges = draw(st.lists(value, min_size=n, max_size=n))
        pose = Pose2D(
            draw(st.floats(-1e4, 1e4)), draw(st.floats(-1e4, 1e4)), draw(st.floats(-math.pi, math.pi))
        )
        out.append(_scan(ranges, (angle_min, inc, rmin, rmax), t0 + 0.1 * k, pose))
    return out


def assert_same(written: list[Scan], read: list[Scan]) -> None:
    assert len(read) == len(written)
    for a, b in zip(written, read, strict=True):
        assert b.stamp_s == pytest.approx(a.stamp_s, abs=POSE_TOL)
        assert (b.angle_min_rad, b.angle_increment_rad, b.range_max_m) == (
            a.angle_min_rad,
            a.angle_increment_rad,
            a.range_max_m,
        )
        assert a.odometry is not None and b.odometry is not None
        assert b.odometry.x_m == pytest.approx(a.odometry.x_m, abs=POSE_TOL)
        assert b.odometry.y_m == pytest.approx(a.odometry.y_m, abs=POSE_TOL)
        assert abs(wrap_angle(b.odometry.theta_rad - a.odometry.theta_rad)) <= POSE_TOL
        valid = a.valid_mask()
        np.testing.assert_array_equal(np.isnan(b.ranges_m), ~valid)
        np.testing.assert_allclose(b.ranges_m[valid], a.ranges_m[valid], rtol=0, atol=RANGE_TOL_M)
        assert b.valid_mask()[valid].all()


@settings(max_examples=60, deadline=None)
@given(scans(), st.booleans(), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi))
def test_round_trip_preserves_ranges_stamps_odometry(
    batch: list[Scan], gz: bool, offset_x: float, offset_theta: float
) -> None:
    offset = Pose2D(offset_x, 0.1, offset_theta)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / ("run.clf.gz" if gz else "run.clf")
        assert write_carmen(path, iter(batch), laser_offset=offset) == len(batch)
        with open_log(path) as reader:
            read = list(reader)
            info = reader.info
            counts = reader.record_counts  # type: ignore[attr-defined]
    assert_same(batch, read)
    assert info.format == "carmen" and info.compressed == gz
    assert info.laser_offset.x_m == pytest.approx(offset.x_m, abs=2e-5)
    assert info.laser_offset.y_m == pytest.approx(offset.y_m, abs=2e-5)
    assert abs(wrap_angle(info.laser_offset.theta_rad - offset.theta_rad)) <= 2e-5
    assert counts["ODOM"] == len(batch)


def test_flaser_for_carmen_layouts_robotlaser_otherwise(tmp_path: Path) -> None:
    pose = Pose2D(1.0, 2.0, 0.5)
    sick = Scan(1.0, -math.pi / 2, math.pi / 180, 0.0, 50.0, np.full(180, 3.0), odometry=pose)
    urg = Scan.from_geometry(URG04LX, np.full(682, 2.5), stamp_s=1.1, odometry=pose)
    with_intensity = Scan(1.2, -math.pi / 2, math.pi / 180, 0.0, 50.0, np.ones(180), np.arange(180.0), pose)
    path = tmp_path / "mixed.clf"
    assert write_carmen(path, [sick, urg, with_intensity], odometry_records=False) == 3
    kinds = [line.split()[0] for line in path.read_text().splitlines() if not line.startswith("#")]
    assert kinds == ["PARAM", "PARAM", "FLASER", "ROBOTLASER1", "ROBOTLASER1"]
    with open_log(path) as reader:
        first, b, c = list(reader)
        assert "ODOM" not in reader.record_counts  # type: ignore[attr-defined]
        assert reader.info.geometry is not None and reader.info.geometry.beam_count == 180
    assert first.beam_count == 180 and first.intensities is None
    assert (b.angle_min_rad, b.angle_increment_rad, b.beam_count) == (
        URG04LX.angle_min_rad,
        URG04LX.angle_increment_rad,
        682,
    )
    assert c.intensities is not None
    np.testing.assert_allclose(c.intensities, np.arange(180.0))


def test_gzip_output_is_gzip_and_no_temporary_file_left(tmp_path: Path) -> None:
    scans = [
        Scan.from_geometry(URG04LX, np.full(682, 1.234), stamp_s=0.1 * i, odometry=Pose2D(i, 0, 0))
        for i in range(3)
    ]
    path = tmp_path / "sim.clf.gz"
    assert write_carmen(path, scans, laser_offset=Pose2D(0.145, 0.0, 0.0)) == 3
    with gzip.open(path, "rt") as fh:
        assert fh.readline().startswith("# CARMEN Logfile")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.clf.gz"]
    with open_log(path) as reader:
        read = list(reader)
        assert reader.info.laser_offset.as_tuple() == pytest.approx((0.145, 0.0, 0.0))
    assert_same(scans, read)


def test_empty_input_writes_a_header_only(tmp_path: Path) -> None:
    path = tmp_path / "empty.clf"
    assert write_carmen(path, []) == 0
    with open_log(path) as reader:
        assert list(reader) == []


def test_scan_without_odometry_is_refused_and_leaves_no_file(tmp_path: Path) -> None:
    good = Scan.from_geometry(URG04LX, np.ones(682), odometry=Pose2D())
    bad = Scan.from_geometry(URG04LX, np.ones(682), stamp_s=0.1)
    path = tmp_path / "x.clf"
    with pytest.raises(InvalidInputError, match=r"scan 1 \(stamp 0.1 s\) has no odometry"):
        write_carmen(path, [good, bad])
    assert list(tmp_path.iterdir()) == []


def test_reading_at_range_max_stays_valid_and_below_min_is_no_return(tmp_path: Path) -> None:
    scan = Scan(0.0, -1.0, 0.01, 0.1, 5.6, np.array([5.6, 5.5996, 0.05, 5.7, 1.0]), odometry=Pose2D())
    path = tmp_path / "edge.clf"
    write_carmen(path, [scan])
    with open_log(path) as reader:
        (back,) = list(reader)
    np.testing.assert_allclose(back.ranges_m, [5.599, 5.599, np.nan, np.nan, 1.0])
