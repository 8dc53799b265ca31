"""Pairing scans with wheel odometry by time stamp: interpolation (endpoints, between-ness, heading wrap),
waiting for a newer reading, the maximum gap (drop or flag), and the simulator end to end."""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.sensors.encoder_emulator import SimOdometry
from robot_agent.sensors.encoders import OdometryReading
from robot_agent.sensors.pairing import (
    PairingStats,
    PoseTrack,
    ScanPairer,
    interpolate_pose,
    paired_scans,
)
from shared.errors import InvalidInputError
from shared.sim import SimRun, default_world, simulate_run
from shared.types import Pose2D, Scan, wrap_angle

coord = st.floats(-1e4, 1e4)
angle = st.floats(-math.pi, math.pi)
poses = st.builds(Pose2D, coord, coord, angle)


def arc(a: float, b: float) -> float:
    """Signed shortest turn from heading a to heading b, in (-pi, pi]."""
    return wrap_angle(b - a)


@dataclass(frozen=True)
class Reading:
    stamp_s: float
    pose: Pose2D


def scan_at(stamp_s: float) -> Scan:
    return Scan(stamp_s, -1.0, 0.5, 0.02, 5.6, np.array([1.0, 2.0, 3.0, 4.0, 5.0]))


@given(poses, poses, st.floats(-1e3, 1e3), st.floats(1e-3, 1e3), st.floats(0.0, 1.0))
def test_interpolation_lies_between_and_is_exact_at_the_ends(
    p0: Pose2D, p1: Pose2D, t0: float, span: float, f: float
) -> None:
    t1 = t0 + span
    t = min(max(t0 + f * span, t0), t1)
    assert interpolate_pose(t0, p0, t1, p1, t0) == p0
    assert interpolate_pose(t0, p0, t1, p1, t1) == p1
    p = interpolate_pose(t0, p0, t1, p1, t)
    assert min(p0.x_m, p1.x_m) <= p.x_m <= max(p0.x_m, p1.x_m)
    assert min(p0.y_m, p1.y_m) <= p.y_m <= max(p0.y_m, p1.y_m)
    # the heading is on the shorter arc, at the time's share of it
    turn = arc(p0.theta_rad, p1.theta_rad)
    g = (t - t0) / (t1 - t0)
    assert abs(arc(p0.theta_rad, p.theta_rad) - g * turn) < 1e-9
    assert abs(arc(p0.theta_rad, p.theta_rad)) + abs(arc(p.theta_rad, p1.theta_rad)) == pytest.approx(
        abs(turn), abs=1e-9
    )


@given(st.floats(0.01, 1.0), st.floats(0.01, 1.0), st.floats(0.0, 1.0))
def test_heading_interpolates_across_the_pi_seam(a: float, b: float, f: float) -> None:
    p0, p1 = Pose2D(0.0, 0.0, math.pi - a), Pose2D(0.0, 0.0, -math.pi + b)
    p = interpolate_pose(0.0, p0, 1.0, p1, f)
    assert abs(p.theta_rad) >= math.pi - max(a, b) - 1e-12  # near +-pi, never through 0
    assert arc(p0.theta_rad, p.theta_rad) == pytest.approx(f * (a + b), abs=1e-9)


def test_interpolation_outside_its_interval_is_refused() -> None:
    with pytest.raises(InvalidInputError, match=r"t = 2.0 s: expected a time between 0.0 s and 1.0 s"):
        interpolate_pose(0.0, Pose2D(), 1.0, Pose2D(), 2.0)


@given(st.lists(st.tuples(st.floats(0.001, 1.0), poses), min_size=1, max_size=30), st.data())
def test_track_returns_each_reading_exactly_at_its_time(
    steps: list[tuple[float, Pose2D]], data: st.DataObject
) -> None:
    track = PoseTrack()
    stamps = list(itertools.accumulate(dt for dt, _ in steps))
    for t, (_, pose) in zip(stamps, steps, strict=True):
        assert track.append(t, pose)
    assert not track.append(stamps[-1], Pose2D())  # not newer: ignored
    for t, (_, pose) in zip(stamps, steps, strict=True):
        assert track.pose_at(t) == (pose, 0.0)
    assert track.pose_at(stamps[-1] + 1e-6) is None  # newer than the newest: wait
    before = track.pose_at(stamps[0] - 0.5)
    assert before is not None and before[0] == steps[0][1] and before[1] == pytest.approx(0.5)
    cut = data.draw(st.sampled_from(stamps))
    track.prune_before(cut)
    assert track.first_stamp_s == cut
    for t, (_, pose) in zip(stamps, steps, strict=True):
        if t >= cut:
            assert track.pose_at(t) == (pose, 0.0)


def reference(readings: list[Reading], t: float, max_gap_s: float) -> Pose2D | None:
    """Pairing by brute force, knowing every reading."""
    before = [r for r in readings if r.stamp_s <= t]
    after = [r for r in readings if r.stamp_s >= t]
    if before and after:
        a, b = before[-1], after[0]
        gap = min(t - a.stamp_s, b.stamp_s - t)
        return interpolate_pose(a.stamp_s, a.pose, b.stamp_s, b.pose, t) if gap <= max_gap_s else None
    nearest = before[-1] if before else after[0] if after else None
    if nearest is None or abs(nearest.stamp_s - t) > max_gap_s:
        return None
    return nearest.pose


@given(
    st.lists(st.tuples(st.floats(0.005, 0.3), poses), min_size=0, max_size=40),
    st.lists(st.floats(0.01, 0.3), min_size=1, max_size=20),
    st.randoms(use_true_random=False),
)
def test_online_pairing_equals_pairing_with_hindsight_in_any_arrival_order(
    steps: list[tuple[float, Pose2D]], scan_steps: list[float], rnd: random.Random
) -> None:
    readings = [
        Reading(t, p) for t, (_, p) in zip(itertools.accumulate(d for d, _ in steps), steps, strict=True)
    ]
    scans = [scan_at(t) for t in itertools.accumulate(scan_steps)]
    events: list[Reading | Scan] = []
    r_iter, s_iter = iter(readings), iter(scans)
    r_next, s_next = next(r_iter, None), next(s_iter, None)
    while r_next is not None or s_next is not None:  # a random interleaving of the two ordered streams
        if r_next is not None and (s_next is None or rnd.random() < 0.5):
            events.append(r_next)
            r_next = next(r_iter, None)
        elif s_next is not None:
            events.append(s_next)
            s_next = next(s_iter, None)
    pairer = ScanPairer(max_gap_s=0.1, max_pending=1000)
    out = []
    for event in events:
        if isinstance(event, Reading):
            out += pairer.add_reading(event.stamp_s, event.pose)
        else:
            out += pairer.add_scan(event)
    out += pairer.finish()
    assert [p.scan for p in out] == scans
    for p in out:
        want = reference(readings, p.scan.stamp_s, 0.1)
        assert (p.pose is None) == (want is None)
        if want is not None and p.pose is not None:
            assert p.pose.as_tuple() == pytest.approx(want.as_tuple(), abs=1e-9)
    s = pairer.stats
    assert s.paired + s.held + s.unpaired == len(scans) and s.readings == len(readings)


def test_a_scan_newer_than_the_newest_reading_waits() -> None:
    pairer = ScanPairer(max_gap_s=0.1)
    assert pairer.add_scan(scan_at(1.0)) == [] and pairer.pending == 1
    assert pairer.add_reading(0.95, Pose2D(0.0, 0.0, 0.0)) == []
    assert pairer.add_scan(scan_at(1.02)) == [] and pairer.pending == 2
    out = pairer.add_reading(1.05, Pose2D(1.0, 0.0, 0.1))
    assert [p.scan.stamp_s for p in out] == [1.0, 1.02] and pairer.pending == 0
    assert out[0].pose is not None and out[0].pose.x_m == pytest.approx(0.5)
    assert out[0].pose.theta_rad == pytest.approx(0.05) and out[0].gap_s == pytest.approx(0.05)
    assert out[1].pose is not None and out[1].pose.x_m == pytest.approx(0.7)
    held = pairer.add_scan(scan_at(1.08))
    assert held == [] and pairer.finish()[0].pose == Pose2D(1.0, 0.0, 0.1)  # held after the last reading
    assert pairer.stats == PairingStats(paired=2, held=1, unpaired=0, readings=2, ignored_readings=0)
    (late,) = pairer.add_scan(scan_at(1.3))  # after finish: settled at once, too far from any reading
    assert late.pose is None and late.gap_s == pytest.approx(0.25)


def test_too_many_waiting_scans_are_settled_with_what_is_known() -> None:
    pairer = ScanPairer(max_gap_s=0.1, max_pending=2)
    pairer.add_reading(0.0, Pose2D())
    assert pairer.add_scan(scan_at(0.05)) == [] and pairer.add_scan(scan_at(0.5)) == []
    (first,) = pairer.add_scan(scan_at(0.6))
    assert first.scan.stamp_s == 0.05 and first.pose == Pose2D() and pairer.pending == 2


def test_bad_settings_are_refused() -> None:
    with pytest.raises(InvalidInputError, match="max_gap_s"):
        ScanPairer(max_gap_s=-1.0)
    with pytest.raises(InvalidInputError, match="on_gap = 'skip'"):
        next(paired_scans([scan_at(0.0)], [], on_gap="skip"))  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def run() -> SimRun:
    return simulate_run(default_world(), seed=3)


def bare(run: SimRun, shift_s: float = 0.0) -> list[Scan]:
    """The run's scans without their odometry (as the laser gives them), shifted in time."""
    return [replace(s, stamp_s=s.stamp_s + shift_s, odometry=None) for s in run.scans]


def test_scans_get_the_simulators_odometry(run: SimRun) -> None:
    stats = PairingStats()
    out = list(paired_scans(bare(run), SimOdometry(run, substeps=5), stats=stats))
    assert [s.stamp_s for s in out] == [s.stamp_s for s in run.scans]
    tick_m = run.drive.metres_per_tick
    for s, p in zip(out, run.odometry_poses, strict=True):
        assert s.odometry is not None
        assert math.hypot(s.odometry.x_m - p.x_m, s.odometry.y_m - p.y_m) <= tick_m
        assert abs(arc(s.odometry.theta_rad, p.theta_rad)) <= tick_m / run.drive.tread_m
    assert stats.paired == len(run) and stats.unpaired == 0
    assert all(
        np.array_equal(a.ranges_m, b.ranges_m, equal_nan=True) for a, b in zip(out, run.scans, strict=True)
    )


def test_scans_between_readings_are_interpolated(run: SimRun) -> None:
    # 50 Hz readings, scans 10 ms after each reading: compare with a 100 Hz bridge's reading at that time
    fine = list(SimOdometry(run, substeps=10))[1::10]
    out = list(paired_scans(bare(run, 0.01)[:-1], SimOdometry(run, substeps=5)))
    assert len(out) == len(fine) == len(run) - 1
    tick_m = run.drive.metres_per_tick
    for s, r in zip(out, fine, strict=True):
        assert s.odometry is not None and s.stamp_s == pytest.approx(r.stamp_s)
        assert math.hypot(s.odometry.x_m - r.pose.x_m, s.odometry.y_m - r.pose.y_m) <= 2 * tick_m
        assert abs(arc(s.odometry.theta_rad, r.pose.theta_rad)) <= 2 * tick_m / run.drive.tread_m


def test_odometry_is_read_only_as_far_as_each_scan_needs(run: SimRun) -> None:
    pulled: list[OdometryReading] = []

    def readings() -> Iterator[OdometryReading]:
        for r in SimOdometry(run, substeps=4):
            pulled.append(r)
            yield r

    for scan in itertools.islice(paired_scans(bare(run, 0.001), readings()), 50):
        # the newest reading read is the first one at or after the scan: nothing read ahead
        assert pulled[-1].stamp_s >= scan.stamp_s > pulled[-2].stamp_s


@pytest.mark.parametrize("on_gap", ["drop", "flag"])
def test_scans_in_an_odometry_stall_are_dropped_or_flagged(run: SimRun, on_gap: str) -> None:
    readings = [r for r in SimOdometry(run, substeps=2) if not 10.0 < r.stamp_s < 12.0]  # 2 s silent
    stats = PairingStats()
    out = list(paired_scans(bare(run), readings, max_gap_s=0.15, on_gap=on_gap, stats=stats))  # type: ignore[arg-type]
    lost = [s.stamp_s for s in run.scans if 10.15 < s.stamp_s < 11.85]
    assert stats.unpaired == len(lost) and stats.paired == len(run) - len(lost)
    if on_gap == "drop":
        assert [s.stamp_s for s in out] == [s.stamp_s for s in run.scans if s.stamp_s not in lost]
    else:
        assert [s.stamp_s for s in out] == [s.stamp_s for s in run.scans]
        assert [s.stamp_s for s in out if s.odometry is None] == lost


def test_scans_after_the_odometry_ended(run: SimRun) -> None:
    readings = list(SimOdometry(run))[:10]
    out = list(paired_scans(bare(run)[:14], readings, max_gap_s=0.25, on_gap="flag"))
    assert [s.odometry is not None for s in out] == [True] * 12 + [False] * 2
    assert out[10].odometry == out[11].odometry == readings[-1].pose  # held within the gap
