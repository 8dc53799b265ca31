"""The multi-lap benchmark (shared.bench.laps): lap ends where the true path has gone round once more, the
map measured at each lap's end is the one the robot showed then, and the position error is the believed
position's distance from the true one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.bench.laps import LapFigures, lap_ends, run_laps
from shared.bench.worlds import measure_map
from shared.pipeline import Pipeline, PipelineConfig
from shared.sim.worlds import simulate_case


@pytest.fixture(scope="module")
def two_laps():  # type: ignore[no-untyped-def]
    return simulate_case("loop-block", 1, laps=2)


def test_lap_ends_are_where_the_path_comes_round_again(two_laps) -> None:  # type: ignore[no-untyped-def]
    ends = lap_ends(two_laps, 2)
    truth = two_laps.run.trajectory("true")
    assert ends[-1] == len(truth)
    start = truth[0, 1:3]
    # at the first lap's end the robot is back at the start (within one step at 0.4 m/s and 10 Hz)
    assert np.hypot(*(truth[ends[0] - 1, 1:3] - start)) < 0.1
    # and half-way round it is far from it
    assert np.hypot(*(truth[ends[0] // 2, 1:3] - start)) > 3.0
    assert lap_ends(two_laps, 1) == [len(truth)]  # one lap asked for: it ends with the run


def test_front_end_run_measures_what_the_pipeline_showed(two_laps) -> None:  # type: ignore[no-untyped-def]
    run = run_laps(two_laps, 2, None)
    assert run.variant == "front end" and [f.lap for f in run.laps] == [1, 2]
    pipe = Pipeline(PipelineConfig(), laser_offset=two_laps.run.drive.laser_offset)
    for scan in two_laps.run.scans:
        pipe.step(scan)
    pipe.flush()
    snap = pipe.snapshot()
    expected = measure_map(two_laps, snap.segments, snap.trajectory)
    last = run.laps[-1]
    assert last.mean_error_m == pytest.approx(expected["mean_error_m"])
    assert last.walls_mapped == expected["walls_mapped"]
    assert last.ate_m == pytest.approx(expected["ate_m"])
    truth = two_laps.run.trajectory("true")
    np.testing.assert_allclose(run.position_error_m, np.hypot(*(snap.trajectory[:, 1:3] - truth[:, 1:3]).T))
    assert run.closures == 0 and run.optimise_ms == ()
    assert len(run.step_ms) == len(truth)


def test_lap_targets() -> None:
    good = LapFigures(1, 100, 0.015, 0.03, 0.97, 0.01, 30, 24, 0.02)
    assert good.meets_targets() and good.wall_ratio == 1.25
    assert not LapFigures(1, 100, 0.025, 0.03, 0.97, 0.01, 30, 24, 0.02).meets_targets()
    assert not LapFigures(1, 100, 0.015, 0.03, 0.90, 0.01, 30, 24, 0.02).meets_targets()
    assert not LapFigures(1, 100, 0.015, 0.03, 0.97, 0.05, 30, 24, 0.02).meets_targets()
    assert not LapFigures(1, 100, 0.015, 0.03, 0.97, 0.01, 40, 24, 0.02).meets_targets()
    assert math.isnan(LapFigures(1, 100, 0.015, 0.03, 0.97, 0.01, 4, 0, 0.02).wall_ratio)
