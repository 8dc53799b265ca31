"""The agent's scan sources: the simulated robot's patrol is one continuous drive (time and odometry)."""

from __future__ import annotations

import itertools
import math

import pytest

from robot_agent.errors import SourceError
from robot_agent.sources import open_scans
from shared.sim import default_world, simulate_run


def test_one_lap_is_the_plain_simulated_run() -> None:
    ours = [s.stamp_s for s in open_scans("sim", seed=3)]
    assert ours == [s.stamp_s for s in simulate_run(default_world(), seed=3).scans]


def test_patrol_runs_on_with_continuous_time_and_odometry() -> None:
    one_lap = len(simulate_run(default_world(), seed=0).scans)
    scans = list(itertools.islice(open_scans("sim", laps=0), 4 * one_lap))
    assert len(scans) == 4 * one_lap  # 0 laps: until stopped
    stamps = [s.stamp_s for s in scans]
    steps = [b - a for a, b in itertools.pairwise(stamps)]
    assert min(steps) == pytest.approx(0.1) and max(steps) == pytest.approx(0.1)
    odo = [s.odometry for s in scans]
    assert all(o is not None for o in odo)
    for a, b in itertools.pairwise(odo):
        assert a is not None and b is not None
        # at 0.4 m/s and 0.8 rad/s, 10 Hz: no jump between laps
        assert math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) < 0.08
        assert abs(math.remainder(b.theta_rad - a.theta_rad, math.tau)) < 0.15


def test_laps_count_is_kept() -> None:
    one_lap = len(simulate_run(default_world(), seed=0).scans)
    n = sum(1 for _ in open_scans("sim", laps=2))
    assert 3 * one_lap < n < 5 * one_lap  # a lap is out along the path and back


def test_laps_on_a_log_is_refused(tmp_path: pytest.TempPathFactory) -> None:
    with pytest.raises(SourceError, match="simulated sources"):
        next(open_scans("some.log", laps=3))
