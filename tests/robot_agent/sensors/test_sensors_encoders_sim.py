"""The simulated encoder bridge: the run's ticks and odometry come back through the protocol decoder."""

from __future__ import annotations

import itertools
import math

import pytest

from robot_agent.sensors.encoder_emulator import SimOdometry
from robot_agent.sensors.encoders import parse_line
from shared.errors import InvalidInputError
from shared.sim import NO_SLIP, SimRun, default_world, simulate_run
from shared.types import Pose2D


@pytest.fixture(scope="module")
def run() -> SimRun:
    return simulate_run(default_world(), seed=2)


def test_one_reading_per_scan_is_the_simulators_odometry_exactly(run: SimRun) -> None:
    readings = list(SimOdometry(run))
    assert [r.pose for r in readings] == list(run.odometry_poses)
    assert [(r.left_ticks, r.right_ticks) for r in readings] == [tuple(t) for t in run.ticks.tolist()]
    assert [r.stamp_s for r in readings] == [s.stamp_s for s in run.scans]
    assert [r.pose for r in readings] == [s.odometry for s in run.scans]


@pytest.mark.parametrize("substeps", [2, 5, 10])
def test_faster_bridge_agrees_at_the_scans_to_the_tick(run: SimRun, substeps: int) -> None:
    sim = SimOdometry(run, substeps=substeps, device_epoch_ms=2**32 - 1234, tick_origin=(-(2**31), 2**31 - 1))
    readings = list(sim)
    assert len(readings) == (len(run) - 1) * substeps + 1
    at_scans = readings[::substeps]
    assert [r.stamp_s for r in at_scans] == [s.stamp_s for s in run.scans]
    assert [(r.left_ticks, r.right_ticks) for r in at_scans] == [tuple(t) for t in run.ticks.tolist()]
    tick_m = run.drive.metres_per_tick
    for r, p in zip(at_scans, run.odometry_poses, strict=True):
        assert math.hypot(r.pose.x_m - p.x_m, r.pose.y_m - p.y_m) <= tick_m
        assert abs(math.remainder(r.pose.theta_rad - p.theta_rad, math.tau)) <= tick_m / run.drive.tread_m
    steps = [b.stamp_s - a.stamp_s for a, b in itertools.pairwise(readings)]
    assert min(steps) == pytest.approx(0.1 / substeps) and max(steps) == pytest.approx(0.1 / substeps)
    # between two scans the counts move from one scan's count to the next
    for i, (t0, t1) in enumerate(itertools.pairwise(run.ticks.tolist())):
        for r in readings[i * substeps : (i + 1) * substeps + 1]:
            assert min(t0[0], t1[0]) <= r.left_ticks <= max(t0[0], t1[0])
            assert min(t0[1], t1[1]) <= r.right_ticks <= max(t0[1], t1[1])


def test_sub_readings_sample_the_same_motion() -> None:
    run = simulate_run(default_world(), seed=0, slip=NO_SLIP)
    readings = list(SimOdometry(run, substeps=4))
    tol = run.drive.metres_per_tick
    # halfway between two scans the pose lies between the scans' poses (straight legs, turns in place)
    for i in range(len(run) - 1):
        a, mid, b = (readings[4 * i + k].pose for k in (0, 2, 4))
        assert min(a.x_m, b.x_m) - tol <= mid.x_m <= max(a.x_m, b.x_m) + tol
        assert min(a.y_m, b.y_m) - tol <= mid.y_m <= max(a.y_m, b.y_m) + tol
        turn = math.remainder(b.theta_rad - a.theta_rad, math.tau)
        half = math.remainder(mid.theta_rad - a.theta_rad, math.tau)
        assert abs(half - turn / 2) <= tol / run.drive.tread_m


def test_the_lines_are_what_a_bridge_sends(run: SimRun) -> None:
    sim = SimOdometry(run, substeps=3, device_epoch_ms=5, tick_origin=(7, -7), origin=Pose2D(1.0, 2.0, 3.0))
    records = [rec for _, rec in sim.records()]
    assert [parse_line(line, require_checksum=True) for line in sim.lines()] == records
    assert [parse_line(line) for line in sim.lines(with_checksum=False)] == records
    assert (records[0].device_ms, records[0].left_ticks, records[0].right_ticks) == (5, 7, -7)
    first = next(iter(sim))
    assert first.pose == Pose2D(1.0, 2.0, 3.0) and (first.left_ticks, first.right_ticks) == (0, 0)
    assert sim.info.to_drive().metres_per_tick == pytest.approx(run.drive.metres_per_tick)
    sim.close()


@pytest.mark.parametrize("substeps", [0, -1, 101, 2.5, True])
def test_bad_substeps_are_refused(run: SimRun, substeps: object) -> None:
    with pytest.raises(InvalidInputError, match="substeps"):
        SimOdometry(run, substeps=substeps)  # type: ignore[arg-type]
