"""Line-segment EKF-SLAM baseline: a square room with a known answer, the measurement model's Jacobians,
gating (new landmark vs update), the rho sign flip, degenerate scans and parameter validation."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from shared.baselines import (
    BaselineParameterError,
    EkfLineSlam,
    EkfLineSlamParams,
    line_difference,
    lines_to_world,
    normalise_lines,
    predict_lines,
)
from shared.errors import InvalidInputError
from shared.metrics import line_accuracy
from shared.sim import RangeNoise, SimRun, World, plan_path, polygon_walls, simulate_run, simulate_scan
from shared.types import URG04LX, FloatArray, Pose2D, Scan

ROOM = World(polygon_walls([(0.0, 0.0), (6.0, 0.0), (6.0, 6.0), (0.0, 6.0)]), 36.0, "square")
# true walls as normalised (rho, alpha): y = 0, x = 6, y = 6, x = 0
ROOM_LINES = np.array([[0.0, -math.pi / 2], [6.0, 0.0], [6.0, math.pi / 2], [0.0, math.pi]])
OFFSET = Pose2D(0.145, 0.0, 0.0)  # MINES_ROVER's laser, as in simulate_run


@pytest.fixture(scope="module")
def square_run() -> tuple[SimRun, EkfLineSlam]:
    """The square room driven once round (~35 s at 0.4 m/s) with the default noise, 5 % clutter, 2 % slip."""
    path = plan_path([(1.5, 1.5), (4.5, 1.5), (4.5, 4.5), (1.5, 4.5), (1.5, 2.0)])
    run = simulate_run(ROOM, path, seed=0)
    slam = EkfLineSlam(laser_offset=run.drive.laser_offset)
    for scan in run.scans:
        slam.step(scan)
    return run, slam


def test_square_room_has_exactly_its_four_walls(square_run: tuple[SimRun, EkfLineSlam]) -> None:
    _, slam = square_run
    # one-off fits (a corner, lined-up clutter) are pruned; what stays is one landmark per wall
    assert slam.n_landmarks == 4
    lm = slam.landmarks
    for rho, alpha in ROOM_LINES:
        d_rho, d_alpha, _ = line_difference(lm[:, 0], lm[:, 1], rho, alpha)
        j = int(np.argmin(np.abs(d_rho) + np.abs(d_alpha)))
        assert abs(d_rho[j]) < 0.03  # 3 cm
        assert abs(math.degrees(d_alpha[j])) < 1.0  # 1 deg
    assert np.all(slam.observation_counts > 100)
    assert slam.covariance.shape == (11, 11)


def test_square_room_pose_and_map(square_run: tuple[SimRun, EkfLineSlam]) -> None:
    run, slam = square_run
    truth, est = run.true_poses[-1], slam.pose
    err_m = math.hypot(est.x_m - truth.x_m, est.y_m - truth.y_m)
    assert err_m < 0.05
    assert abs(math.degrees(est.theta_rad - truth.theta_rad)) < 1.0
    odo = run.odometry_poses[-1]
    assert err_m < math.hypot(odo.x_m - truth.x_m, odo.y_m - truth.y_m)  # better than dead reckoning
    traj = slam.trajectory
    assert len(traj) == len(run) == len(slam.step_ms) == len(slam.extract_ms)
    assert all(0.0 <= e <= s for e, s in zip(slam.extract_ms, slam.step_ms, strict=True))
    assert [t for t, _ in traj] == [s.stamp_s for s in run.scans]
    errors = [
        math.hypot(p.x_m - q.x_m, p.y_m - q.y_m) for (_, p), q in zip(traj, run.true_poses, strict=True)
    ]
    assert max(errors) < 0.05
    walls = slam.walls()
    assert walls.shape == (4, 4)
    acc = line_accuracy(walls, ROOM.walls)
    assert acc.completeness > 0.95
    assert acc.mean_distance_m < 0.02
    assert acc.spurious_share < 0.05
    assert acc.mean_angle_error_deg < 0.5


def _numeric_jacobian(f: Callable[[FloatArray], FloatArray], x: FloatArray, eps: float = 1e-6) -> FloatArray:
    cols = []
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx[k] = eps
        cols.append((f(x + dx) - f(x - dx)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("offset", [Pose2D(), OFFSET, Pose2D(0.1, -0.05, 0.3)])
def test_measurement_jacobians_match_finite_differences(offset: Pose2D) -> None:
    robot = np.array([1.2, -0.7, 0.4])
    line = np.array([3.0, 2.5])
    h, H_r, H_l = predict_lines(robot, offset, line[:1], line[1:])
    num_r = _numeric_jacobian(lambda r: predict_lines(r, offset, line[:1], line[1:])[0][0], robot)
    num_l = _numeric_jacobian(lambda q: predict_lines(robot, offset, q[:1], q[1:])[0][0], line)
    np.testing.assert_allclose(H_r[0], num_r, atol=1e-7)
    np.testing.assert_allclose(H_l[0], num_l, atol=1e-7)
    # inverse model: g(x, h(x, l)) = l, and its Jacobians
    g, G_r, G_z = lines_to_world(robot, offset, h[:, 0], h[:, 1])
    np.testing.assert_allclose(g[0], line, atol=1e-12)
    z = h[0]
    num_gr = _numeric_jacobian(lambda r: lines_to_world(r, offset, z[:1], z[1:])[0][0], robot)
    num_gz = _numeric_jacobian(lambda q: lines_to_world(robot, offset, q[:1], q[1:])[0][0], z)
    np.testing.assert_allclose(G_r[0], num_gr, atol=1e-7)
    np.testing.assert_allclose(G_z[0], num_gz, atol=1e-7)


def test_the_two_forms_of_a_line_have_no_difference() -> None:
    d_rho, d_alpha, sign = line_difference(0.02, 0.1, -0.02, 0.1 + math.pi)
    assert float(d_rho) == pytest.approx(0.0, abs=1e-12)
    assert float(d_alpha) == pytest.approx(0.0, abs=1e-12)
    assert float(sign) == -1.0
    rho, alpha, s = normalise_lines(np.array([-1.0, 2.0]), np.array([0.5, 3.5]))
    np.testing.assert_allclose(rho, [1.0, 2.0])
    np.testing.assert_allclose(alpha, [0.5 - math.pi, 3.5 - 2 * math.pi])
    np.testing.assert_allclose(s, [-1.0, 1.0])


def _scan(world: World, pose: Pose2D, seed: int, stamp_s: float = 0.0) -> Scan:
    noise = RangeNoise(outlier_rate=0.0)
    return simulate_scan(world, pose, np.random.default_rng(seed), noise, stamp_s=stamp_s, odometry=pose)


def test_gating_updates_a_near_landmark_and_adds_a_far_one() -> None:
    pose = Pose2D(0.0, 0.0, math.pi / 2)  # facing +y
    one = World(np.array([[-3.0, 2.0, 3.0, 2.0]]), 1.0)
    two = World(np.array([[-3.0, 2.0, 3.0, 2.0], [1.5, -1.5, 1.5, 1.5]]), 1.0)
    slam = EkfLineSlam(EkfLineSlamParams(prune_after_steps=0))
    slam.step(_scan(one, pose, 1))
    assert slam.n_landmarks == 1
    assert slam.landmarks[0] == pytest.approx([2.0, math.pi / 2], abs=0.02)
    var_before = np.diag(slam.covariance)[3:5].copy()
    slam.step(_scan(two, pose, 2, 0.1))
    # the wall y = 2 gated with landmark 0 and updated it; the wall x = 1.5 gated with nothing: new landmark
    assert slam.n_landmarks == 2
    assert slam.observation_counts.tolist() == [2, 1]
    assert np.all(np.diag(slam.covariance)[3:5] < var_before)
    assert slam.landmarks[1] == pytest.approx([1.5, 0.0], abs=0.02)
    assert slam.matched == 1
    # a third look at both: two updates, no new landmark
    slam.step(_scan(two, pose, 3, 0.2))
    assert slam.n_landmarks == 2
    assert slam.observation_counts.tolist() == [3, 2]


def test_a_line_through_the_origin_survives_the_rho_sign_flip(monkeypatch: pytest.MonkeyPatch) -> None:
    # the wall x = -0.6 mm has world rho ~ 0: updates push the estimate across 0, where the normalised
    # (rho, alpha) jumps from alpha ~ 0 to ~ pi; P's rho row and the extents must flip with it
    flips = []
    normalise = EkfLineSlam._normalise_landmarks

    def counting(self: EkfLineSlam) -> None:
        flips.append(int(np.sum(self.landmarks[:, 0] < 0.0)))
        normalise(self)

    monkeypatch.setattr(EkfLineSlam, "_normalise_landmarks", counting)
    wall = World(np.array([[-0.0006, -3.0, -0.0006, 3.0]]), 1.0)
    slam = EkfLineSlam(EkfLineSlamParams(prune_after_steps=0))
    for k in range(40):
        pose = Pose2D(1.5, -0.5 + 0.03 * k, math.pi)
        slam.step(_scan(wall, pose, k, 0.1 * k))
    assert sum(flips) >= 1
    assert slam.n_landmarks == 1
    rho, alpha = slam.landmarks[0]
    assert 0.0 <= rho < 0.01
    assert abs(math.sin(alpha)) < 0.01  # alpha ~ 0 or ~ pi: the line x = 0
    assert slam.pose.as_tuple() == pytest.approx((1.5, -0.5 + 0.03 * 39, math.pi), abs=0.01)
    (seg,) = slam.walls()
    assert np.abs(seg[[0, 2]]).max() < 0.01
    assert abs(seg[3] - seg[1]) > 4.0  # the extent survived the flips


def test_spurious_landmarks_are_pruned_and_kept_without_pruning() -> None:
    world = World(np.array([[-3.0, 2.0, 3.0, 2.0]]), 1.0)
    blank = Scan.from_geometry(URG04LX, np.full(URG04LX.beam_count, np.nan), odometry=Pose2D())
    for prune, expected in ((3, 0), (0, 1)):
        slam = EkfLineSlam(EkfLineSlamParams(prune_after_steps=prune, min_observations=2))
        slam.step(_scan(world, Pose2D(0.0, 0.0, math.pi / 2), 1))  # seen once...
        for k in range(5):
            slam.step(
                Scan(
                    0.1 * (k + 1),
                    blank.angle_min_rad,
                    blank.angle_increment_rad,
                    0.02,
                    5.6,
                    blank.ranges_m,
                    odometry=Pose2D(),
                )
            )
        assert slam.n_landmarks == expected  # ...never again
        assert slam.walls().shape == (0, 4)  # below min_observations either way


def test_empty_scans_and_missing_odometry_do_not_crash() -> None:
    start = Pose2D(2.0, -1.0, 0.5)
    slam = EkfLineSlam(initial_pose=start)
    nan = np.full(URG04LX.beam_count, np.nan)
    for k in range(3):
        pose = slam.step(Scan.from_geometry(URG04LX, nan, stamp_s=0.1 * k))  # no odometry at all
        assert pose == start
    assert slam.n_landmarks == 0
    assert slam.walls().shape == (0, 4)
    assert len(slam.trajectory) == 3
    # without initial_pose the first scan's odometry is the start
    first = EkfLineSlam().step(Scan.from_geometry(URG04LX, nan, odometry=Pose2D(1.0, 2.0, 3.0)))
    assert first == Pose2D(1.0, 2.0, 3.0)
    # the pose grows uncertain while nothing is seen
    assert np.all(np.diag(slam.covariance) > 0.0)


def test_odometry_increments_drive_the_prediction() -> None:
    nan = np.full(URG04LX.beam_count, np.nan)
    slam = EkfLineSlam(initial_pose=Pose2D(10.0, 0.0, math.pi / 2))
    odo = [
        Pose2D(0.0, 0.0, 0.0),
        Pose2D(1.0, 0.0, 0.0),
        Pose2D(1.0, 0.0, math.pi / 2),
        Pose2D(1.0, 2.0, math.pi / 2),
    ]
    poses = [slam.step(Scan.from_geometry(URG04LX, nan, stamp_s=k, odometry=o)) for k, o in enumerate(odo)]
    # relative motion re-applied from the initial pose: 1 m forward (+y), turn left, 2 m forward (-x)
    assert poses[-1].as_tuple() == pytest.approx((8.0, 1.0, math.pi), abs=1e-9)
    var = np.diag(slam.covariance)
    assert var[0] > 1e-4 and var[1] > 1e-4  # the motion noise entered P


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gate_chi2", 0.0),
        ("gate_chi2", math.inf),
        ("trans_noise_per_m", -0.1),
        ("rot_noise_per_rad", math.nan),
        ("min_observations", 0),
        ("prune_after_steps", -1),
        ("prune_after_steps", 2.5),
        ("extent_gap_m", 0.0),
        ("new_landmark_chi2", 5.0),  # below gate_chi2
        ("extraction", "split-and-merge"),
    ],
)
def test_params_errors_name_the_field(field: str, value: object) -> None:
    with pytest.raises(BaselineParameterError, match=f"EkfLineSlamParams.{field}") as info:
        EkfLineSlamParams(**{field: value})  # type: ignore[arg-type]
    assert info.value.parameter == field
    assert isinstance(info.value, InvalidInputError)
