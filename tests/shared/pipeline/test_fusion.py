"""Scan matches fused with odometry by their information: the scan decides across walls, odometry along a
corridor whose ends are out of range, and a pipeline tracks a short corridor exactly and a long one with
no shrinking (docs/worlds.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline import IcpGate, Pipeline
from shared.pipeline.fusion import fuse_gated, hold_unseen_directions
from shared.pipeline.fusion_solve import fuse_with_odometry, odometry_information
from shared.pipeline.rangenoise import NO_RANGE_NOISE, URG04LX_RANGE_NOISE
from shared.sim import NO_SLIP, RangeNoise, SlipNoise, World, plan_path, simulate_run, simulate_scan
from shared.sim.world import polygon_walls
from shared.types import Pose2D

FUSED = IcpGate(fuse_odometry=True)
STRONG_ODOMETRY = odometry_information(
    Pose2D(), sigma_m=0.01, sigma_ratio=0.0, sigma_rad=0.01, sigma_rad_per_rad=0.0
)


def corridor(length_m: float, width_m: float = 1.6) -> World:
    """A closed corridor from x = 0 to ``length_m``, centred on y = 0, path along its middle."""
    h = 0.5 * width_m
    outline = [(0.0, -h), (length_m, -h), (length_m, h), (0.0, h)]
    return World(
        polygon_walls(outline), length_m * width_m, "corridor", np.array([[0.5, 0.0], [length_m - 0.5, 0.0]])
    )


def points(world: World, at: Pose2D, seed: int) -> np.ndarray:
    scan = simulate_scan(world, at, np.random.default_rng(seed), RangeNoise())
    return scan.to_points()[0]


@settings(max_examples=15, deadline=None)
@given(st.floats(-0.05, 0.05), st.floats(-0.01, 0.01), st.floats(-0.01, 0.01))
def test_across_the_walls_the_scan_decides_along_them_odometry(
    along: float, across: float, turn: float
) -> None:
    world = corridor(40.0)  # both ends far beyond the 5.6 m range
    ref = points(world, Pose2D(20.0, 0.0, 0.0), 0)
    true = Pose2D(0.3, 0.1, 0.02)  # current scanner in the reference frame
    cur = points(world, Pose2D(20.3, 0.1, 0.02), 1)
    odo = Pose2D(true.x_m + along, true.y_m + across, true.theta_rad + turn)  # odometry off in every way
    # a matcher that slid back along the corridor (point-to-point ICP's bias) but is right across it
    matched = Pose2D(0.2, 0.1, 0.02)
    pose = fuse_gated(FUSED, ref, cur, matched, odo)
    # along: odometry, not the slid match (the scan's nearest-point objective still moves it 2-3 cm there)
    assert abs(pose.x_m - odo.x_m) < 0.04 and abs(pose.x_m - odo.x_m) < abs(pose.x_m - matched.x_m)
    assert pose.y_m == pytest.approx(true.y_m, abs=0.01)  # across: the scan (odometry up to 1 cm off)
    assert pose.theta_rad == pytest.approx(true.theta_rad, abs=0.005)  # odometry up to 0.01 rad off
    scan = fuse_with_odometry(ref, cur, true, odo, STRONG_ODOMETRY, scan_only=True)
    assert scan is not None and scan.weakest_sigma_m > 0.003  # it knows the corridor axis is weak


def test_an_end_wall_in_range_fixes_the_along_track_position() -> None:
    world = corridor(4.0)
    ref = points(world, Pose2D(1.5, 0.0, 0.0), 0)
    cur = points(world, Pose2D(1.8, 0.05, 0.0), 1)
    odo = Pose2D(0.36, 0.0, 0.0)  # 6 cm long, 5 cm to the side
    gate = IcpGate()
    info = odometry_information(
        odo,
        sigma_m=gate.odom_sigma_m,
        sigma_ratio=gate.odom_sigma_ratio,
        sigma_rad=gate.odom_sigma_rad,
        sigma_rad_per_rad=gate.odom_sigma_rad_per_rad,
    )
    fused = fuse_with_odometry(ref, cur, odo, odo, info)
    assert fused is not None
    assert fused.pose.x_m == pytest.approx(0.3, abs=0.015)  # the end wall 2.2 m ahead decides
    assert fused.pose.y_m == pytest.approx(0.05, abs=0.01)
    assert fused.weakest_sigma_m < 0.01


def test_too_few_pairs_keep_the_match() -> None:
    far = np.array([[50.0, 0.0], [50.0, 0.1], [50.0, 0.2], [50.0, 0.3]])
    assert fuse_with_odometry(far, far + 10.0, Pose2D(), Pose2D(), STRONG_ODOMETRY) is None


def along_track_errors(world: World, gate: IcpGate = FUSED, slip: SlipNoise | None = None) -> np.ndarray:
    """Pipeline pose minus true pose along x (the corridor axis) per step, for a drive along the world's
    path with the simulated robot (its scanner offset given)."""
    path = plan_path(np.asarray(world.knots))
    run = simulate_run(world, path, seed=2) if slip is None else simulate_run(world, path, seed=2, slip=slip)
    pipe = Pipeline(laser_offset=run.drive.laser_offset, icp_gate=gate)
    errs = []
    for scan, truth in zip(run.scans, run.true_poses, strict=True):
        pose = pipe.step(scan).pose
        errs.append(
            (
                pose.x_m - truth.x_m,
                pose.y_m - truth.y_m,
                math.remainder(pose.theta_rad - truth.theta_rad, math.tau),
            )
        )
    return np.asarray(errs)


def test_a_corridor_shorter_than_the_range_is_tracked_exactly() -> None:
    err = along_track_errors(corridor(5.0))
    assert np.abs(err[:, :2]).max() < 0.03  # the end walls are in range all the way
    assert np.abs(err[:, 2]).max() < math.radians(0.5)


def test_a_corridor_beyond_the_range_follows_odometry_without_shrinking() -> None:
    err = along_track_errors(corridor(20.0), slip=NO_SLIP)  # the wheels are right: odometry = truth
    # along the corridor the pose stays with odometry: no shrinking (before: pulled back along it)
    # (without fusion: 0.79 m short at the end)
    assert abs(err[-1, 0]) < 0.05 and np.abs(err[:, 0]).mean() < 0.04
    assert np.abs(err[:, 1]).max() < 0.02


def test_the_wall_refinement_prior_alone_keeps_most_of_the_corridor() -> None:
    world = corridor(20.0)
    plain = along_track_errors(world, gate=IcpGate(fuse_odometry=False), slip=NO_SLIP)
    refine_only = IcpGate(fuse_odometry=False, refine_with_odometry=True)
    refined = along_track_errors(world, gate=refine_only, slip=NO_SLIP)
    # the plain pipeline comes out metres short (point-to-point ICP under-estimates the motion along it)
    assert plain[-1, 0] < -1.0
    assert abs(refined[-1, 0]) < 0.2 * abs(plain[-1, 0])


def test_by_default_a_corridor_beyond_the_range_is_no_worse_than_slipping_wheels() -> None:
    world = corridor(20.0)
    path = plan_path(np.asarray(world.knots))
    run = simulate_run(world, path, seed=3)  # the default slip model: odometry drifts a little
    pipe = Pipeline(laser_offset=run.drive.laser_offset)  # default gate: fusion with learned noise
    poses = np.array([pipe.step(scan).pose.as_tuple() for scan in run.scans])
    truth = run.trajectory("true")[:, 1:]
    odometry = run.trajectory("odometry")[:, 1:]
    ours = np.hypot(*(poses[:, :2] - truth[:, :2]).T)
    wheels = np.hypot(*(odometry[:, :2] - odometry[0, :2] - (truth[:, :2] - truth[0, :2])).T)
    assert pipe.odometry_noise.samples[0] > 20  # it learned from the matches
    assert np.sqrt(np.mean(ours**2)) <= np.sqrt(np.mean(wheels**2)) + 0.02


def test_a_second_chance_match_keeps_odometry_along_a_corridor_and_the_scan_across() -> None:
    world = corridor(40.0)
    ref = points(world, Pose2D(20.0, 0.0, 0.0), 0)
    cur = points(world, Pose2D(20.3, 0.1, 0.02), 1)
    odo = Pose2D(0.3, 0.06, 0.0)  # right along the corridor, 4 cm and 0.02 rad off across it
    searched = Pose2D(0.5, 0.1, 0.02)  # the search's pick: right across, 20 cm off along the axis
    pose = hold_unseen_directions(IcpGate(), ref, cur, searched, odo, range_noise=URG04LX_RANGE_NOISE)
    assert pose.x_m == pytest.approx(odo.x_m, abs=0.01)
    assert pose.y_m == pytest.approx(searched.y_m, abs=0.005)
    assert pose.theta_rad == pytest.approx(searched.theta_rad, abs=0.005)


def test_a_second_chance_match_the_scan_fixes_everywhere_stands() -> None:
    world = corridor(4.0)  # both end walls in range
    ref = points(world, Pose2D(1.5, 0.0, 0.0), 0)
    cur = points(world, Pose2D(1.8, 0.05, 0.1), 1)
    searched = Pose2D(0.3, 0.05, 0.1)
    pose = hold_unseen_directions(
        IcpGate(), ref, cur, searched, Pose2D(0.2, 0.0, 0.0), range_noise=URG04LX_RANGE_NOISE
    )
    assert (pose.x_m, pose.y_m, pose.theta_rad) == (searched.x_m, searched.y_m, searched.theta_rad)
    off = hold_unseen_directions(IcpGate(fuse_odometry=False), ref, cur, searched, Pose2D())
    assert off == searched


def test_clutter_returns_beside_a_wall_give_no_information_along_it() -> None:
    world = corridor(40.0, width_m=1.83)
    infos = {}
    for name, model in (("none", NO_RANGE_NOISE), ("urg", URG04LX_RANGE_NOISE)):
        along = []
        for k in range(4):
            ref = points(world, Pose2D(20.0, 0.0, 0.0), 2 * k)  # 5 % clutter returns (the simulator's)
            cur = points(world, Pose2D(20.15, 0.0, 0.0), 2 * k + 1)
            fit = fuse_with_odometry(
                ref,
                cur,
                Pose2D(0.15, 0, 0),
                Pose2D(0.15, 0, 0),
                STRONG_ODOMETRY,
                scan_only=True,
                range_noise=model,
            )
            assert fit is not None
            along.append(fit.information[0, 0])
        infos[name] = float(np.median(along))
    # without the direction test the short windows between clutter returns beside the scanner get lines at
    # any angle (about 12,000-23,000 m^-2 along the corridor); with it about what the walls alone give
    assert infos["none"] > 5000.0
    assert infos["urg"] < 2000.0
