"""Patrols: lap lengths as ``patrol_lap_steps`` says, and a later lap passes the same places."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from shared.errors import InvalidInputError
from shared.sim import World, default_world, patrol_lap_steps, patrol_scans
from shared.types import Scan


def test_lap_steps_count_the_scans_of_each_lap() -> None:
    world = default_world()
    first, later = patrol_lap_steps(world)
    scans = list(patrol_scans(world, seed=3, laps=3))
    assert len(scans) == first + 2 * later
    assert later > first  # a later lap starts with the turn in place


def _range_gap_m(a: Scan, b: Scan) -> float:
    """Median absolute range difference over the beams with a return in both scans."""
    both = np.isfinite(a.ranges_m) & np.isfinite(b.ranges_m)
    return float(np.median(np.abs(a.ranges_m[both] - b.ranges_m[both])))


def test_a_step_one_later_lap_on_sees_the_same_place() -> None:
    """The scans themselves tell: one later lap on, the robot sees what it saw (noise and clutter aside);
    half a lap away it sees something else. (Wheel odometry has drifted by then, so it cannot tell.)"""
    world = default_world()
    first, later = patrol_lap_steps(world)
    scans = list(itertools.islice(patrol_scans(world, seed=0), first + 2 * later))
    steps = range(first + later, first + 2 * later, 97)
    assert all(_range_gap_m(scans[i], scans[i - later]) < 0.05 for i in steps)
    # two seconds off the same place, the view differs (median over the sampled places)
    assert np.median([_range_gap_m(scans[i], scans[i - later + 20]) for i in steps]) > 0.2


def test_a_world_without_a_path_cannot_patrol() -> None:
    base = default_world()
    pathless = World(base.walls, base.floor_area_m2, "pathless", None)
    with pytest.raises(InvalidInputError, match="pathless"):
        patrol_lap_steps(pathless)


def _off_m(scan: Scan, xy: np.ndarray) -> float:
    """How far the scan's odometry pose is from ``xy`` (m)."""
    assert scan.odometry is not None
    return float(np.hypot(scan.odometry.x_m - xy[0], scan.odometry.y_m - xy[1]))


def test_a_suite_world_patrol_runs_on_and_comes_back_each_lap() -> None:
    """Scenario-suite patrol: 10 Hz time that runs on, and with perfect wheels the odometry of the last
    scan of each lap is back on the path's first knot (out and back), chained across the laps."""
    from shared.sim import scene_patrol_scans
    from shared.sim.worlds import build_scene

    start = build_scene("corridor-doors", 1).knots[0]
    scans = list(scene_patrol_scans("corridor-doors", seed=1, laps=2, odometry="perfect"))
    assert np.allclose(np.diff([s.stamp_s for s in scans]), 0.1)
    home = [i for i, s in enumerate(scans) if _off_m(s, start) < 0.01]
    assert home[0] == 0 and home[-1] == len(scans) - 1  # starts and ends on the first knot
    assert any(abs(i - len(scans) // 2) < 60 for i in home), "and was there after the first lap"
    again = itertools.islice(scene_patrol_scans("corridor-doors", seed=1, laps=2, odometry="perfect"), 50)
    assert all(
        np.array_equal(a.ranges_m, b.ranges_m, equal_nan=True) for a, b in zip(again, scans[:50], strict=True)
    )


def test_a_closed_suite_path_is_driven_round() -> None:
    from shared.sim import scene_patrol_scans
    from shared.sim.worlds import build_scene

    first = build_scene("loop-block", 0).knots[0]
    lap = list(scene_patrol_scans("loop-block", seed=0, laps=1, odometry="perfect"))
    assert _off_m(lap[-1], first) < 0.01
    assert max(_off_m(s, first) for s in lap) > 3.0  # went round the block


def test_a_suite_patrol_gives_each_scan_with_the_true_pose() -> None:
    """``scene_patrol``: the same scans as ``scene_patrol_scans``, each with the robot's true pose; with
    perfect wheels the odometry is that pose, and with worn ones it drifts away from it."""
    from shared.sim.patrol import scene_patrol, scene_patrol_scans

    pairs = list(itertools.islice(scene_patrol("loop-block", seed=0, laps=1, odometry="perfect"), 300))
    plain = list(itertools.islice(scene_patrol_scans("loop-block", seed=0, laps=1, odometry="perfect"), 300))
    assert all(
        np.array_equal(a.ranges_m, b.ranges_m, equal_nan=True) for (a, _), b in zip(pairs, plain, strict=True)
    )
    for scan, truth in pairs:
        assert scan.odometry is not None
        assert np.allclose(scan.odometry.as_tuple(), truth.as_tuple(), atol=2e-3)
    worn = list(scene_patrol("loop-block", seed=0, laps=1, odometry="worn"))
    last, truth = worn[-1]
    assert last.odometry is not None
    assert np.hypot(last.odometry.x_m - truth.x_m, last.odometry.y_m - truth.y_m) > 0.05


def test_a_suite_patrol_refuses_unknown_names() -> None:
    from shared.sim import scene_patrol_scans

    with pytest.raises(InvalidInputError, match="corridor-long"):
        next(scene_patrol_scans("corridor-lung"))
    with pytest.raises(InvalidInputError, match="worn"):
        next(scene_patrol_scans("corridor-long", odometry="bald"))
    with pytest.raises(InvalidInputError, match="laps"):
        next(scene_patrol_scans("corridor-long", laps=-1))
