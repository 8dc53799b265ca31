"""BreezySLAM URG-04LX .dat reader: field layout, mm -> m with error codes as NaN, encoder odometry."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from shared.io import BreezySlamReader, LogFormatError
from shared.odometry import MINES_ROVER
from shared.types import URG04LX, Pose2D


def dat_line(
    stamp_us: int | str,
    q1: int | str,
    q2: int | str,
    ranges_mm: Sequence[int | str] | None = None,
    trailing: bool = True,
) -> str:
    ranges = list(ranges_mm) if ranges_mm is not None else [1000] * 682
    telemetry = ["0"] * 20
    tail = ["3"] if trailing else []
    return " ".join([str(stamp_us), "14710", str(q1), str(q2), *telemetry, *map(str, ranges), *tail])


def write(tmp_path: Path, *lines: str) -> Path:
    path = tmp_path / "exp.dat"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_ranges_geometry_and_stamp(tmp_path: Path) -> None:
    ranges = [0, 19, 20, 5000, 1234] + [2000] * 677
    with BreezySlamReader(write(tmp_path, dat_line(212387282, 29221, 25178, ranges))) as reader:
        (s,) = list(reader)
        info = reader.info
    assert s.stamp_s == pytest.approx(212.387282, abs=1e-12)
    np.testing.assert_array_equal(s.ranges_m[:5], [np.nan, np.nan, 0.02, 5.0, 1.234])
    assert (s.angle_min_rad, s.angle_increment_rad, s.beam_count) == (
        URG04LX.angle_min_rad,
        URG04LX.angle_increment_rad,
        682,
    )
    assert math.degrees(s.angles_rad[0]) == pytest.approx(-119.53125)
    assert s.odometry == Pose2D()
    assert info.format == "breezyslam" and info.robot is MINES_ROVER and info.geometry is URG04LX
    assert info.laser_offset == Pose2D(0.145, 0.0, 0.0)


def test_encoder_odometry_known_answers(tmp_path: Path) -> None:
    # 1000 ticks = half a turn of a 154 mm wheel = 0.077 pi m; then only the right wheel: a turn of
    # 0.077 pi / 0.330 rad about the left wheel (eq. 9-11, mid-step heading).
    path = write(
        tmp_path,
        dat_line(1_000_000, 500, 700),
        dat_line(1_100_000, 1500, 1700),
        dat_line(1_200_000, 1500, 2700),
    )
    with BreezySlamReader(path) as reader:
        a, b, c = list(reader)
    half_turn = 0.077 * math.pi
    assert a.odometry == Pose2D()
    assert b.odometry is not None and b.odometry.as_tuple() == pytest.approx((half_turn, 0.0, 0.0))
    dtheta = half_turn / 0.330
    expected = (
        half_turn + 0.5 * half_turn * math.cos(dtheta / 2),
        0.5 * half_turn * math.sin(dtheta / 2),
        dtheta,
    )
    assert c.odometry is not None and c.odometry.as_tuple() == pytest.approx(expected)
    assert [s.stamp_s for s in (a, b, c)] == pytest.approx([1.0, 1.1, 1.2])


@pytest.mark.parametrize(
    ("bad_line", "message"),
    [
        (dat_line(1, 2, 3, [1000] * 681), "BreezySLAM scan has 706 fields: expected 707"),
        (dat_line(1, 2, 3, trailing=False), "BreezySLAM scan has 706 fields: expected 707"),
        ("1 2 3", "BreezySLAM scan has 3 fields: expected 707"),
        (dat_line(1, "x", 3), "BreezySLAM field 2 (left_ticks_Q1) = 'x': expected a number"),
        (dat_line("t", 2, 3), "BreezySLAM field 0 (timestamp_us) = 't': expected a number"),
        (dat_line(1, 2, "inf"), "BreezySLAM field 3 (right_ticks_Q2) = 'inf': expected a finite number"),
        (
            dat_line(1, 2, 3, ["5", "?", *["1"] * 680]),
            "BreezySLAM field 25 (range_2_mm) = '?': expected a number",
        ),
    ],
)
def test_malformed_line_names_line_and_field(tmp_path: Path, bad_line: str, message: str) -> None:
    path = write(tmp_path, dat_line(1, 0, 0), "", bad_line)
    with BreezySlamReader(path) as reader, pytest.raises(LogFormatError) as err:
        list(reader)
    assert err.value.line_no == 3
    assert str(err.value).startswith(f"exp.dat line 3: {message}")
