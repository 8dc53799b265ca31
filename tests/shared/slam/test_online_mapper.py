"""Loop closure on the robot (OnlineGraphMapper): the same corrected map whether the search and the
rebuild run in the step or on the worker, however late the worker is (bit for bit); the step's pose is
the corrected one; a bad configuration is refused with the old one kept; a failing worker leaves the
robot mapping on the front end."""

from __future__ import annotations

import numpy as np
import pytest

from shared.bench.worlds import measure_map
from shared.pipeline import Pipeline, PipelineConfig
from shared.sim.worlds import simulate_case
from shared.slam import LoopClosureSettings, OnlineGraphMapper
from tests.shared.slam.slamcheck import assert_same_map


def _mapper(case_run, worker: bool) -> OnlineGraphMapper:  # type: ignore[no-untyped-def]
    offset = case_run.drive.laser_offset
    return OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), PipelineConfig(), worker=worker)


@pytest.fixture(scope="module")
def loop_block():  # type: ignore[no-untyped-def]
    return simulate_case("loop-block", 2)


@pytest.fixture(scope="module")
def in_step(loop_block):  # type: ignore[no-untyped-def]
    """The two laps through the front end alone and through the online mapper in its in-step mode."""
    run = loop_block.run
    front = Pipeline(PipelineConfig(), laser_offset=run.drive.laser_offset)
    online = _mapper(run, worker=False)
    poses = []
    for scan in run.scans:
        front.step(scan)
        poses.append(online.step(scan).pose)
    front.flush()
    online.flush()
    return front, online, poses


def test_in_the_step_two_laps_close_their_loop(loop_block, in_step) -> None:  # type: ignore[no-untyped-def]
    front, online, poses = in_step
    before = measure_map(loop_block, front.snapshot().segments, front.snapshot().trajectory)
    snap = online.snapshot()
    after = measure_map(loop_block, snap.segments, snap.trajectory)
    assert online.closures >= 3 and online.rebuilds >= 1
    assert after["mean_error_m"] < 0.7 * before["mean_error_m"]
    assert after["ate_m"] < before["ate_m"]
    assert poses[-1] == snap.pose  # the step answers with the corrected pose
    ids, segments = online.walls()
    np.testing.assert_array_equal(segments, snap.segments)
    assert len(ids) == len(segments)


def test_on_the_worker_the_map_is_corrected_too(loop_block) -> None:  # type: ignore[no-untyped-def]
    run = loop_block.run
    online = _mapper(run, worker=True)
    try:
        for scan in run.scans:
            online.step(scan)
        assert online.wait_idle(300)
        online.flush()
        snap = online.snapshot()
        after = measure_map(loop_block, snap.segments, snap.trajectory)
        assert online.closures >= 3 and online.rebuilds >= 1
        assert online.failure is None
        assert after["mean_error_m"] < 0.02
        assert len(snap.trajectory) == len(run.scans)
    finally:
        online.close()


def test_however_late_the_worker_the_graph_and_the_map_are_the_same(loop_block, in_step, late_worker) -> None:  # type: ignore[no-untyped-def]
    """The worker held back to the last moment (each search until the step before its closures are due,
    each rebuild 9 steps): every keyframe, closure and wall equals the in-step run's exactly."""
    _front, reference, _poses = in_step
    online = _mapper(loop_block.run, worker=True)
    late = late_worker(online)
    try:
        for scan in loop_block.run.scans:
            late.step(scan)
        late.release()
        online.flush()
        assert online.failure is None
        assert online.closures >= 3
        assert_same_map(online, reference)
    finally:
        online.close()


def test_a_new_configuration_reaches_the_front_end_and_the_shown_map(loop_block, in_step) -> None:  # type: ignore[no-untyped-def]
    run = loop_block.run
    _front, online, _poses = in_step
    assert online.rebuilds >= 1  # a shown map of its own
    offline = PipelineConfig(mode="offline", n_smax=5)
    online.reconfigure(offline)
    assert online.config == offline
    assert online._mapper.front.config == offline and online._shown is not None
    assert online._shown.config == offline
    online.step(run.scans[0])


def test_a_failing_search_leaves_the_robot_mapping(loop_block, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    run = loop_block.run
    online = _mapper(run, worker=True)

    def broken(k: int, *args: object) -> list[object]:
        raise RuntimeError("search exploded")

    monkeypatch.setattr(online._mapper, "find_closures", broken)
    try:
        for scan in run.scans[:120]:
            online.step(scan)
        assert online.wait_idle(60)
        assert online.failure is not None and "search exploded" in online.failure
        assert online.version == 120
        assert len(online.walls()[1]) > 0
    finally:
        online.close()


def test_loop_closure_off_is_the_front_end(loop_block) -> None:  # type: ignore[no-untyped-def]
    run = loop_block.run
    offset = run.drive.laser_offset
    off = OnlineGraphMapper(
        lambda c: Pipeline(c, laser_offset=offset),
        PipelineConfig(),
        LoopClosureSettings(enabled=False),
        worker=False,
    )
    front = Pipeline(PipelineConfig(), laser_offset=offset)
    for scan in run.scans[:300]:
        off.step(scan)
        front.step(scan)
    np.testing.assert_array_equal(off.walls()[1], front.walls()[1])
    assert off.closures == 0


def test_switched_on_while_mapping_it_corrects_what_comes_after(loop_block) -> None:  # type: ignore[no-untyped-def]
    """Loop closure switched on a third of the way round the first lap: the front end goes on under the
    graph, the map drawn so far stays (its walls keep their ids), the versions go on, and the second lap
    closes the loop."""
    run = loop_block.run
    offset = run.drive.laser_offset
    third = len(run.scans) // 6  # two laps: a third of the first
    front = Pipeline(PipelineConfig(), laser_offset=offset)
    alone = Pipeline(PipelineConfig(), laser_offset=offset)
    for scan in run.scans[:third]:
        front.step(scan)
        alone.step(scan)
    before_ids = set(front.walls()[0].tolist())
    config = PipelineConfig(loop_closure={})
    online = OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), config, worker=False, front=front)
    assert online.step(run.scans[third]).version == third + 1
    for scan in run.scans[third + 1 :]:
        online.step(scan)
    for scan in run.scans[third:]:
        alone.step(scan)
    online.flush()
    alone.flush()
    snap = online.snapshot()
    assert online.closures >= 3 and online.rebuilds >= 1
    assert len(snap.trajectory) == len(run.scans)
    assert before_ids & set(snap.segment_ids.tolist()), "walls drawn before the switch keep their ids"
    after = measure_map(loop_block, snap.segments, snap.trajectory)
    plain = measure_map(loop_block, alone.snapshot().segments, alone.snapshot().trajectory)
    assert after["mean_error_m"] < plain["mean_error_m"]
    assert after["ate_m"] < plain["ate_m"]


def test_switched_off_the_search_stops_and_the_map_stays(loop_block) -> None:  # type: ignore[no-untyped-def]
    run = loop_block.run
    online = _mapper(run, worker=False)
    half = len(run.scans) // 2
    for scan in run.scans[:half]:
        online.step(scan)
    online.reconfigure(PipelineConfig(loop_closure={"search_radius_m": 6.0}))
    assert online.settings.enabled and online.settings.search_radius_m == 6.0
    online.reconfigure(PipelineConfig())
    assert not online.settings.enabled
    closures, rebuilds = online.closures, online.rebuilds
    for scan in run.scans[half:]:  # the second lap: the first lap's places again, and no search
        online.step(scan)
    online.flush()
    assert online.closures == closures
    assert online.rebuilds == rebuilds  # the map is not redrawn either
    assert len(online.snapshot().trajectory) == len(run.scans)


def test_redraws_keep_a_scan_per_10_cm_and_none_standing_still(loop_block) -> None:  # type: ignore[no-untyped-def]
    """The scans kept for redraws: one each REDRAW_SPACING of motion (a fraction of those at 0.4 m/s and
    10 Hz), none more while the robot stands still (the same scan again and again)."""
    from dataclasses import replace

    from shared.slam.online import REDRAW_SPACING

    run = loop_block.run
    online = _mapper(run, worker=False)
    for scan in run.scans[:300]:
        online.step(scan)
    kept = online._mapper.stepped()
    steps = [k[0] for k in kept]
    assert steps == sorted(steps) and steps[0] == 0
    assert 300 // 6 < len(kept) < 300 // 2
    poses = online._mapper.front.snapshot().trajectory
    gaps = np.hypot(*np.diff(poses[steps, 1:3], axis=0).T)
    turns = np.abs(np.diff(poses[steps, 3]))
    assert ((gaps >= REDRAW_SPACING[0] - 1e-9) | (turns >= REDRAW_SPACING[1] - 1e-9)).all()
    last = run.scans[299]
    for i in range(50):  # standing still
        online.step(replace(last, stamp_s=last.stamp_s + 0.1 * (i + 1)))
    assert len(online._mapper.stepped()) <= len(kept) + 1


def test_standing_still_the_state_does_not_grow(loop_block) -> None:  # type: ignore[no-untyped-def]
    """With a bounded history (the agent's), a robot standing still adds nothing to the mapper's state:
    no kept scan, no keyframe, and the trajectory thinned to the bound."""
    from dataclasses import replace

    run = loop_block.run
    offset = run.drive.laser_offset
    online = OnlineGraphMapper(
        lambda c: Pipeline(c, laser_offset=offset, history=200), PipelineConfig(), worker=False, history=200
    )
    for scan in run.scans[:300]:
        online.step(scan)
    last = run.scans[299]

    def stand(n: int, start: int) -> int:
        for i in range(start, start + n):
            online.step(replace(last, stamp_s=last.stamp_s + 0.1 * (i + 1)))
        online.flush()
        return len(online.state().to_bytes())

    after_300 = stand(300, 0)
    keyframes, kept = len(online._mapper.keyframes), len(online._mapper.stepped())
    after_1800 = stand(1500, 300)
    assert len(online._mapper.keyframes) == keyframes and len(online._mapper.stepped()) == kept
    assert len(online.trajectory()) <= 200
    assert after_1800 <= 1.01 * after_300, (after_300, after_1800)
