"""Properties of the ROS bag reader's pose helpers: quaternion -> yaw, interpolation, tf chains."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.io.rosbag_pose import (
    OdometryTrack,
    Transform3D,
    chain_transform,
    interpolate_pose,
    quaternion_from_yaw,
    yaw_from_quaternion,
)
from shared.types import Pose2D, wrap_angle

angles = st.floats(-50.0, 50.0, allow_nan=False)
coords = st.floats(-1e3, 1e3, allow_nan=False)
poses = st.builds(Pose2D, coords, coords, angles)


def angle_gap(a: float, b: float) -> float:
    return abs(math.remainder(a - b, math.tau))


@given(angles, st.floats(1e-3, 1e3))
def test_yaw_of_a_yaw_quaternion_is_the_yaw_at_any_scale(yaw: float, scale: float) -> None:
    x, y, z, w = quaternion_from_yaw(yaw)
    assert math.isclose(x * x + y * y + z * z + w * w, 1.0, rel_tol=1e-12) and w >= 0.0
    got = yaw_from_quaternion(scale * x, scale * y, scale * z, scale * w)
    assert -math.pi < got <= math.pi
    assert angle_gap(got, yaw) <= 1e-12
    assert angle_gap(yaw_from_quaternion(-x, -y, -z, -w), yaw) <= 1e-12  # q and -q: the same rotation


def _q_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ZYX Euler angles to (x, y, z, w), written out as in REP 103 / tf."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


@given(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), angles)
def test_yaw_ignores_roll_and_pitch(roll: float, pitch: float, yaw: float) -> None:
    assert angle_gap(yaw_from_quaternion(*_q_from_euler(roll, pitch, yaw)), yaw) <= 1e-9


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0), (0.0, 0.0, math.inf, 1.0)])
def test_a_degenerate_quaternion_is_refused(q: tuple[float, float, float, float]) -> None:
    with pytest.raises(InvalidInputError, match="expected finite values, not all zero"):
        yaw_from_quaternion(*q)


@given(poses, poses, st.integers(1, 10**10), st.floats(0.0, 1.0))
def test_interpolation_is_linear_in_position_and_takes_the_short_arc(
    p0: Pose2D, p1: Pose2D, span_ns: int, f: float
) -> None:
    t0 = 1_000_000_000
    t = t0 + round(f * span_ns)
    f_exact = (t - t0) / span_ns
    mid = interpolate_pose(t0, p0, t0 + span_ns, p1, t)
    assert math.isclose(mid.x_m, p0.x_m + f_exact * (p1.x_m - p0.x_m), abs_tol=1e-9)
    assert math.isclose(mid.y_m, p0.y_m + f_exact * (p1.y_m - p0.y_m), abs_tol=1e-9)
    turn = wrap_angle(p1.theta_rad - p0.theta_rad)
    assert angle_gap(mid.theta_rad, p0.theta_rad) <= abs(turn) * f_exact + 1e-9
    assert angle_gap(mid.theta_rad, p1.theta_rad) <= abs(turn) * (1.0 - f_exact) + 1e-9
    assert angle_gap(mid.theta_rad, p0.theta_rad + f_exact * turn) <= 1e-9


@given(poses, poses, st.integers(1, 10**9))
def test_interpolation_hits_its_ends_and_clamps_outside(p0: Pose2D, p1: Pose2D, span_ns: int) -> None:
    assert interpolate_pose(0, p0, span_ns, p1, 0) == p0
    assert interpolate_pose(0, p0, span_ns, p1, span_ns) == p1
    assert interpolate_pose(0, p0, span_ns, p1, -5) == p0
    assert interpolate_pose(0, p0, span_ns, p1, span_ns + 5) == p1


def test_interpolation_across_pi_does_not_sweep_the_long_way() -> None:
    mid = interpolate_pose(0, Pose2D(0, 0, math.pi - 0.1), 10, Pose2D(0, 0, -math.pi + 0.1), 5)
    assert angle_gap(mid.theta_rad, math.pi) <= 1e-12


@given(
    st.lists(st.tuples(st.integers(0, 10**6), poses), min_size=1, max_size=20), st.integers(-10, 10**6 + 10)
)
def test_the_odometry_track_interpolates_between_its_bracketing_poses(
    samples: list[tuple[int, Pose2D]], t: int
) -> None:
    track = OdometryTrack()
    for stamp, pose in samples:
        track.add(stamp, pose)
    latest = dict(samples)  # a repeated stamp keeps the last pose given
    stamps = sorted(latest)
    assert len(track) == len(stamps) and track.latest_ns == stamps[-1]
    found = track.pose_at(t)
    assert found is not None
    pose, inside = found
    assert inside == (stamps[0] <= t <= stamps[-1])
    if t <= stamps[0]:
        assert pose == latest[stamps[0]]
    elif t >= stamps[-1]:
        assert pose == latest[stamps[-1]]
    else:
        lo = max(s for s in stamps if s <= t)
        hi = min(s for s in stamps if s >= t)
        want = latest[lo] if lo == hi else interpolate_pose(lo, latest[lo], hi, latest[hi], t)
        assert pose == want
    track.prune(t, keep_max=5)
    assert 1 <= len(track) <= 5
    if stamps[0] <= t <= stamps[-1] and len([s for s in stamps if s >= t]) < 4:
        assert track.pose_at(t) == found  # what is still needed for t survives pruning


@given(poses, poses)
def test_planar_transforms_compose_like_poses(a: Pose2D, b: Pose2D) -> None:
    def lift(p: Pose2D) -> Transform3D:
        return Transform3D((p.x_m, p.y_m, 0.0), quaternion_from_yaw(p.theta_rad))

    got = (lift(a) @ lift(b)).to_pose2d()
    want = a @ b
    assert math.isclose(got.x_m, want.x_m, abs_tol=1e-9) and math.isclose(got.y_m, want.y_m, abs_tol=1e-9)
    assert angle_gap(got.theta_rad, want.theta_rad) <= 1e-9
    assert lift(a).tilt_rad() <= 1e-6


def test_a_tf_chain_composes_up_to_the_base_and_stops_at_a_cycle() -> None:
    mount = Transform3D((0.1, 0.0, 0.2), quaternion_from_yaw(math.pi / 2))
    laser = Transform3D((0.05, 0.0, 0.0), quaternion_from_yaw(0.0))
    parents = {"mount": ("base_link", mount), "laser": ("mount", laser)}
    pose = chain_transform(parents, "base_link", "laser")
    assert pose is not None
    p2 = pose.to_pose2d()
    assert p2.as_tuple() == pytest.approx((0.1, 0.05, math.pi / 2), abs=1e-12)  # laser ahead rotated 90 deg
    assert chain_transform(parents, "base_link", "base_link") == Transform3D()
    assert chain_transform(parents, "odom", "laser") is None
    assert chain_transform({"a": ("b", laser), "b": ("a", laser)}, "base", "a") is None
    upside_down = Transform3D((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    assert upside_down.tilt_rad() == pytest.approx(math.pi)
    with pytest.raises(InvalidInputError):
        Transform3D((0.0, 0.0, math.nan))
