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
