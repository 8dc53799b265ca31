"""Differential-drive odometry (paper §2, eq. 9-11) against hand-computed cases."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER, DiffDrive, integrate
from shared.types import Pose2D


def test_straight_line() -> None:
    p = integrate(Pose2D(1.0, 2.0, math.pi / 2), 0.3, 0.3, tread_m=0.4)
    assert (
        p.x_m == pytest.approx(1.0)
        and p.y_m == pytest.approx(2.3)
        and p.theta_rad == pytest.approx(math.pi / 2)
    )


def test_turn_in_place() -> None:
    # right wheel forward 0.1 m, left back 0.1 m, tread 0.4 m -> +0.5 rad, no translation (eq. 9)
    p = integrate(Pose2D(), -0.1, 0.1, tread_m=0.4)
    assert p.as_tuple() == pytest.approx((0.0, 0.0, 0.5))


def test_paper_form_uses_start_heading() -> None:
    # dD_l = 0.1, dD_r = 0.3, w = 0.4: dtheta = 0.5 rad, forward 0.2 m along theta0 = 0 (eq. 10-11)
    p = integrate(Pose2D(), 0.1, 0.3, tread_m=0.4, midpoint=False)
    assert p.as_tuple() == pytest.approx((0.2, 0.0, 0.5))
    q = integrate(Pose2D(), 0.1, 0.3, tread_m=0.4, midpoint=True)
    assert q.as_tuple() == pytest.approx((0.2 * math.cos(0.25), 0.2 * math.sin(0.25), 0.5))


def test_full_circle_returns_home() -> None:
    # constant curvature: 100 small steps around a circle of radius 1 m come back to the start
    drive = DiffDrive(wheel_diameter_m=0.1, tread_m=0.5, ticks_per_turn=1000)
    pose = Pose2D()
    arc = 2 * math.pi / 100
    for _ in range(100):
        pose = drive.step(pose, arc * (1.0 - 0.25), arc * (1.0 + 0.25))
    assert math.hypot(pose.x_m, pose.y_m) < 2e-3 and abs(pose.theta_rad) < 1e-9


def test_mines_rover_matches_its_source_model() -> None:
    # SOURCE.md: d = r (pi/2000) (dQ1 + dQ2) mm, dtheta = (r/R) (pi/2000) (dQ2 - dQ1), r = 77, R = 165
    dq1, dq2 = 120.0, 180.0
    pose = MINES_ROVER.step_ticks(Pose2D(), dq1, dq2, midpoint=False)
    d = 0.077 * math.pi / 2000 * (dq1 + dq2)
    dtheta = (77 / 165) * math.pi / 2000 * (dq2 - dq1)
    assert pose.x_m == pytest.approx(d) and pose.theta_rad == pytest.approx(dtheta)
    assert MINES_ROVER.laser_pose(Pose2D(0, 0, math.pi / 2)).y_m == pytest.approx(0.145)


@given(st.floats(-1, 1), st.floats(-1, 1))
def test_reverse_undoes_forward(d_l: float, d_r: float) -> None:
    there = integrate(Pose2D(0.5, -0.2, 0.3), d_l, d_r, 0.4)
    back = integrate(there, -d_l, -d_r, 0.4)
    assert back.theta_rad == pytest.approx(0.3, abs=1e-9)
    assert math.hypot(back.x_m - 0.5, back.y_m + 0.2) < 1e-9


def test_bad_geometry_rejected() -> None:
    with pytest.raises(InvalidInputError, match="tread_m"):
        DiffDrive(wheel_diameter_m=0.1, tread_m=0.0, ticks_per_turn=100)
