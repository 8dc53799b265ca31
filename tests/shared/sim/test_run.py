"""Simulated runs: encoder ticks from the true motion, odometry from the ticks, scans from the true pose."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER, DiffDrive
from shared.sim import (
    NO_SLIP,
    RangeNoise,
    SimRun,
    SlipNoise,
    World,
    default_world,
    plan_path,
    simulate_run,
    wheel_displacements_between,
)
from shared.types import FloatArray, Pose2D, wrap_angle

CLEAN = RangeNoise(near_accuracy_m=0.0, far_accuracy_ratio=0.0, outlier_rate=0.0)


@pytest.fixture(scope="module")
def world() -> World:
    return default_world()


@pytest.fixture(scope="module")
def run(world: World) -> SimRun:
    return simulate_run(world, seed=3)


def _wall_distance(world: World, pts: FloatArray) -> FloatArray:
    a, b = world.walls[:, :2], world.walls[:, 2:]
    ab = b - a
    t = np.clip(((pts[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    return np.asarray(np.linalg.norm(pts[:, None, :] - (a + t[..., None] * ab), axis=-1).min(axis=1))


def _final_drift(run: SimRun) -> float:
    truth, odo = run.true_poses[-1], run.odometry_poses[-1]
    return math.hypot(truth.x_m - odo.x_m, truth.y_m - odo.y_m)


@settings(max_examples=100, deadline=None)
@given(
    start=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-math.pi, math.pi)),
    d_left=st.floats(-0.5, 0.5),
    d_right=st.floats(-0.5, 0.5),
    tread=st.floats(0.1, 1.0),
)
def test_wheel_displacements_invert_the_step(
    start: tuple[float, float, float], d_left: float, d_right: float, tread: float
) -> None:
    drive = DiffDrive(0.15, tread, 1000.0)
    assume(abs(d_right - d_left) / tread < 3.0)  # dtheta inside (-pi, pi]: wrapping is unambiguous
    a = Pose2D(*start)
    b = drive.step(a, d_left, d_right)
    got_left, got_right = wheel_displacements_between(a, b, tread)
    assert got_left == pytest.approx(d_left, abs=1e-9)
    assert got_right == pytest.approx(d_right, abs=1e-9)


def test_known_wheel_travel() -> None:
    # a quarter turn left in place with a 0.33 m tread: right wheel +w pi/4, left wheel -w pi/4
    left, right = wheel_displacements_between(Pose2D(1, 1, 0), Pose2D(1, 1, math.pi / 2), 0.33)
    assert (left, right) == pytest.approx((-0.33 * math.pi / 4, 0.33 * math.pi / 4))
    left, right = wheel_displacements_between(Pose2D(0, 0, math.pi), Pose2D(-0.04, 0, math.pi), 0.33)
    assert (left, right) == pytest.approx((0.04, 0.04))


def test_run_shapes_stamps_and_odometry_tags(run: SimRun) -> None:
    n = len(run)
    assert n == len(run.true_poses) == len(run.odometry_poses) and n > 450
    assert run.ticks.shape == (n, 2) and run.ticks.dtype == np.int64 and not run.ticks.flags.writeable
    assert run.ticks[0].tolist() == [0, 0]
    np.testing.assert_allclose(run.stamps_s, np.arange(n) / 10.0)
    assert all(s.odometry == o for s, o in zip(run.scans, run.odometry_poses, strict=True))
    assert run.odometry_poses[0] == run.true_poses[0]
    traj = run.trajectory("odometry")
    assert traj.shape == (n, 4) and traj[-1, 1] == run.odometry_poses[-1].x_m
    # forward travel in ticks: about the path length (17.8 m) over 0.242 mm per tick, on both wheels
    path_m = float(np.mean(run.ticks[-1])) * MINES_ROVER.metres_per_tick
    assert path_m == pytest.approx(5.0 + math.hypot(3, 2) + math.hypot(4.8, 2) + 4.0, rel=0.05)


def test_no_slip_odometry_is_truth_up_to_quantisation(world: World) -> None:
    run = simulate_run(world, seed=1, slip=NO_SLIP)
    drive = run.drive
    # cumulative ticks are rounded, so the heading error never exceeds two ticks' worth of differential travel
    heading_bound = 2 * drive.metres_per_tick / drive.tread_m
    for truth, odo in zip(run.true_poses, run.odometry_poses, strict=True):
        assert abs(wrap_angle(truth.theta_rad - odo.theta_rad)) <= heading_bound + 1e-12
        assert math.hypot(truth.x_m - odo.x_m, truth.y_m - odo.y_m) < 0.005
    # and the ticks are the wheel travel over the tick length, rounded
    d = np.array(
        [wheel_displacements_between(a, b, drive.tread_m) for a, b in itertools.pairwise(run.true_poses)]
    )
    expected = np.rint(np.cumsum(d, axis=0) / drive.metres_per_tick)
    assert np.abs(run.ticks[1:] - expected).max() <= 1


def test_drift_grows_with_slip(world: World) -> None:
    drifts = [
        np.mean([_final_drift(simulate_run(world, seed=s, slip=SlipNoise(sigma))) for s in range(3)])
        for sigma in (0.0, 0.01, 0.04)
    ]
    assert drifts[0] < 0.005 < drifts[1] < drifts[2]
    # a systematic 1 % larger right wheel curls the odometry to the left: a large, one-sided drift
    biased = simulate_run(world, slip=SlipNoise(0.0, scale_right=1.01))
    assert _final_drift(biased) > 0.2


def test_scans_come_from_the_true_laser_pose(world: World) -> None:
    run = simulate_run(world, seed=2, noise=CLEAN, slip=SlipNoise(0.05))
    i = len(run) - 5
    scan = run.scans[i]
    pts, _ = scan.to_points()
    laser_true = run.drive.laser_pose(run.true_poses[i])
    laser_odo = run.drive.laser_pose(run.odometry_poses[i])
    assert _wall_distance(world, laser_true.transform_points(pts)).max() < 1e-9
    assert np.median(_wall_distance(world, laser_odo.transform_points(pts))) > 0.02  # drifted odometry


def test_slip_does_not_change_the_scans(world: World) -> None:
    path = plan_path(np.array([[1.0, 3.0], [3.0, 3.0]]))
    a = simulate_run(world, path, seed=7, slip=SlipNoise(0.0))
    b = simulate_run(world, path, seed=7, slip=SlipNoise(0.05))
    assert all(
        np.array_equal(x.ranges_m, y.ranges_m, equal_nan=True) for x, y in zip(a.scans, b.scans, strict=True)
    )
    assert a.odometry_poses != b.odometry_poses


def test_seeded_and_deterministic(world: World) -> None:
    path = plan_path(np.array([[1.0, 3.0], [2.0, 3.0], [2.0, 3.5]]))
    a, b = simulate_run(world, path, seed=11), simulate_run(world, path, seed=11)
    c = simulate_run(world, path, seed=12)
    assert a.true_poses == b.true_poses and a.odometry_poses == b.odometry_poses
    assert np.array_equal(a.ticks, b.ticks)
    assert all(
        np.array_equal(x.ranges_m, y.ranges_m, equal_nan=True) for x, y in zip(a.scans, b.scans, strict=True)
    )
    assert not np.array_equal(a.ticks, c.ticks)
    assert not np.array_equal(a.scans[0].ranges_m, c.scans[0].ranges_m, equal_nan=True)


def test_errors(world: World) -> None:
    bare = World(world.walls, world.floor_area_m2, "bare")
    with pytest.raises(InvalidInputError, match="'bare' has no path knots"):
        simulate_run(bare)
    with pytest.raises(InvalidInputError, match="non-empty sequence of Pose2D"):
        simulate_run(world, [])
    with pytest.raises(InvalidInputError, match="rate_hz"):
        simulate_run(world, rate_hz=0.0)
    with pytest.raises(InvalidInputError, match="sigma_ratio"):
        SlipNoise(-0.1)
    with pytest.raises(InvalidInputError, match="expected N of each"):
        SimRun(world, MINES_ROVER, (), (Pose2D(),), (), np.zeros((0, 2), dtype=np.int64))
