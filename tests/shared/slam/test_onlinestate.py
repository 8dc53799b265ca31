"""The loop-closure graph mapper's state round-trips: stepped N scans of two laps round a block, saved to
bytes, restored and stepped to the end, it closes the same loops and ends within 1 cm and 0.1 degrees of
one stepped through at every keyframe, with the same walls (the solver is rebuilt, so not bit for bit);
pending loop searches are not lost with a worker; a pipeline's state is refused."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from shared.errors import StateError
from shared.pipeline import MapperState, Pipeline, PipelineConfig
from shared.sim.worlds import simulate_case
from shared.slam import OnlineGraphMapper


@cache
def _case():  # type: ignore[no-untyped-def]
    return simulate_case("loop-block", 2)


def _mapper(worker: bool = False) -> OnlineGraphMapper:
    offset = _case().run.drive.laser_offset
    return OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), PipelineConfig(), worker=worker)


def _keyframe_poses(online: OnlineGraphMapper) -> np.ndarray:
    traj = online.trajectory()
    steps = [k.step for k in online._mapper.keyframes]
    return traj[steps, 1:]


@cache
def _through() -> OnlineGraphMapper:
    online = _mapper()
    for scan in _case().run.scans:
        online.step(scan)
    return online


@pytest.mark.parametrize("split", [1, 240, 520])
def test_saved_restored_and_stepped_on_keeps_the_keyframes_and_walls(split: int) -> None:
    scans = _case().run.scans
    through = _through()
    first = _mapper()
    for scan in scans[:split]:
        first.step(scan)
    restored = _mapper()
    restored.restore(MapperState.from_bytes(first.state().to_bytes()))
    for scan in scans[split:]:
        restored.step(scan)
    assert restored.version == through.version == len(scans)
    assert restored.closures == through.closures > 0
    a, b = _keyframe_poses(through), _keyframe_poses(restored)
    assert a.shape == b.shape
    assert np.abs(a[:, :2] - b[:, :2]).max() <= 0.01
    turn = np.abs(np.remainder(a[:, 2] - b[:, 2] + math.pi, 2 * math.pi) - math.pi)
    assert math.degrees(turn.max()) <= 0.1
    ids_a, walls_a = through.walls()
    ids_b, walls_b = restored.walls()
    np.testing.assert_array_equal(ids_a, ids_b)
    assert np.abs(walls_a - walls_b).max() <= 0.01


def test_pending_loop_searches_are_taken_up_after_a_restore() -> None:
    """With the worker, the state taken while searches are pending names them and a restore submits them
    again; the restored mapper ends with the keyframes of one stepped through in the step (the worker's
    timing changes which closures it finds, not where the graph settles)."""
    scans = _case().run.scans
    first = _mapper(worker=True)
    try:
        for scan in scans[:300]:
            first.step(scan)
        state = first.state()
        closed_then = first.closures
    finally:
        first.close()
    restored = _mapper(worker=True)
    try:
        restored.restore(MapperState.from_bytes(state.to_bytes()))
        for scan in scans[300:]:
            restored.step(scan)
        restored.flush()
        assert restored._searches == set()
        assert restored.closures > closed_then
        a, b = _keyframe_poses(_through()), _keyframe_poses(restored)
        assert a.shape == b.shape
        assert np.abs(a[:, :2] - b[:, :2]).max() <= 0.01
        turn = np.abs(np.remainder(a[:, 2] - b[:, 2] + math.pi, 2 * math.pi) - math.pi)
        assert math.degrees(turn.max()) <= 0.1
    finally:
        restored.close()


def test_a_pipeline_state_is_refused_by_the_graph_mapper() -> None:
    pipe = Pipeline(PipelineConfig())
    pipe.step(_case().run.scans[0])
    with pytest.raises(StateError, match="a 'pipeline' state: expected a 'graph' state"):
        _mapper().restore(pipe.state())
