"""Mapping under the pose graph, through ``linemap map``'s own path (:func:`shared.mapping.map_scans`):
two laps round a block with worn wheels come out with the loop closed (walls and trajectory closer to the
truth than the front end's alone); once a closure ties the robot to a place its next searches there are
narrower; with loop closure off the map is the front end's, scan for scan."""

from __future__ import annotations

import numpy as np

from shared.bench.worlds import measure_map
from shared.mapping import Source, map_scans
from shared.pipeline import PipelineConfig
from shared.sim import default_world, simulate_run
from shared.sim.worlds import simulate_case
from shared.slam import LoopClosureSettings
from shared.slam.closure import verify
from shared.slam.window import MIN_WINDOW_M, MIN_WINDOW_RAD


def test_two_laps_round_a_block_close_their_loop() -> None:
    case = simulate_case("loop-block", 2)
    run = case.run
    source = Source("loop-block 2", run.scans, run.drive.laser_offset, len(run), run.world, run.trajectory())
    front = map_scans(source, PipelineConfig())
    closed = map_scans(source, PipelineConfig(), loop_closure=LoopClosureSettings())
    before = measure_map(case, front.snapshot.segments, front.snapshot.trajectory)
    after = measure_map(case, closed.snapshot.segments, closed.snapshot.trajectory)
    assert closed.loop_closures >= 3
    assert after["ate_m"] < 0.75 * before["ate_m"]
    assert after["mean_error_m"] < 0.6 * before["mean_error_m"]
    assert after["completeness"] >= before["completeness"] - 0.01
    assert after["walls_mapped"] <= 1.25 * after["walls_seen"]
    assert len(closed.snapshot.trajectory) == len(run)


def test_searches_at_a_place_already_tied_search_narrower_windows(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Two laps round a block: the first searches (nothing tied yet) cover the operator's whole window;
    once closures are accepted, searches at those places cover less, never below the floor."""
    case = simulate_case("loop-block", 2)
    run = case.run
    source = Source("loop-block 2", run.scans, run.drive.laser_offset, len(run), run.world, run.trajectory())
    windows: list[tuple[float, float] | None] = []

    def spy(*args, window=None, **kwargs):  # type: ignore[no-untyped-def]
        windows.append(window)
        return verify(*args, window=window, **kwargs)

    monkeypatch.setattr("shared.slam.mapper.verify", spy)
    settings = LoopClosureSettings()
    closed = map_scans(source, PipelineConfig(), loop_closure=settings, front_process=False)
    whole = (settings.window_m, settings.window_rad)
    assert closed.loop_closures >= 3
    assert windows[0] == whole
    narrow = [w for w in windows if w != whole]
    assert len(narrow) >= closed.loop_closures // 3
    assert all(w is not None and MIN_WINDOW_M <= w[0] < whole[0] for w in narrow)
    assert all(w is not None and MIN_WINDOW_RAD <= w[1] <= whole[1] for w in narrow)


def test_with_loop_closure_off_the_map_is_the_front_ends() -> None:
    run = simulate_run(default_world(), seed=3)
    scans = run.scans[:200]
    source = Source("room", scans, run.drive.laser_offset, len(scans))
    plain = map_scans(source, PipelineConfig())
    off = map_scans(source, PipelineConfig(), loop_closure=LoopClosureSettings(enabled=False))
    assert off.loop_closures == 0
    np.testing.assert_array_equal(off.snapshot.segments, plain.snapshot.segments)
    np.testing.assert_array_equal(off.snapshot.trajectory, plain.snapshot.trajectory)
