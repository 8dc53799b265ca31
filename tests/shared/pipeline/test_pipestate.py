"""A pipeline's state round-trips exactly: stepped N scans, saved to bytes, restored and stepped M more, it
equals one stepped N + M scans (poses, walls and their ids, centroids), in every mode; a damaged or
newer state is refused with an error that says so."""

from __future__ import annotations

import itertools
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shared.errors import StateError
from shared.pipeline import MapperState, Pipeline, PipelineConfig
from shared.pipeline.state import STATE_FORMAT
from shared.sim import default_world, simulate_run
from shared.types import Pose2D, Scan

OFFSET = Pose2D(0.1, 0.0, 0.0)


@cache
def _scans() -> tuple[Scan, ...]:
    return tuple(itertools.islice(simulate_run(default_world(), seed=3).scans, 160))


def _config(mode: str) -> PipelineConfig:
    return PipelineConfig.parse({"mode": mode})


def _stepped(config: PipelineConfig, scans: tuple[Scan, ...]) -> Pipeline:
    pipe = Pipeline(config, laser_offset=OFFSET)
    for scan in scans:
        pipe.step(scan)
    return pipe


def _assert_same(a: Pipeline, b: Pipeline) -> None:
    sa, sb = a.snapshot(), b.snapshot()
    assert sa.version == sb.version
    np.testing.assert_array_equal(sa.trajectory, sb.trajectory)
    np.testing.assert_array_equal(sa.segment_ids, sb.segment_ids)
    np.testing.assert_array_equal(sa.segments, sb.segments)
    np.testing.assert_array_equal(sa.centroids, sb.centroids)
    assert a.pose == b.pose


@pytest.mark.parametrize("mode", ["online", "offline", "mixed"])
def test_saved_restored_and_stepped_on_equals_stepped_through(mode: str) -> None:
    scans = _scans()
    config = _config(mode)
    through = _stepped(config, scans)
    first = _stepped(config, scans[:70])
    restored = Pipeline(config, laser_offset=OFFSET)
    restored.restore(MapperState.from_bytes(first.state().to_bytes()))
    for scan in scans[70:]:
        restored.step(scan)
    _assert_same(through, restored)
    assert len(through.walls()[0]) > 5


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(split=st.integers(0, 60), more=st.integers(1, 25))
def test_any_split_round_trips_exactly(split: int, more: int) -> None:
    scans = _scans()[: split + more]
    config = _config("offline")  # pending batches at the split are part of the state
    first = _stepped(config, scans[:split])
    restored = Pipeline(config, laser_offset=OFFSET)
    restored.restore(MapperState.from_bytes(first.state().to_bytes()))
    for scan in scans[split:]:
        first.step(scan)
        restored.step(scan)
    _assert_same(first, restored)


def test_a_saved_state_does_not_change_as_the_pipeline_steps_on() -> None:
    scans = _scans()[:40]
    pipe = _stepped(PipelineConfig(), scans[:20])
    blob = pipe.state().to_bytes()
    for scan in scans[20:]:
        pipe.step(scan)
    again = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    again.restore(MapperState.from_bytes(blob))
    assert again.version == 20


def test_a_stepped_pipeline_cannot_be_restored_over() -> None:
    pipe = _stepped(PipelineConfig(), _scans()[:3])
    with pytest.raises(StateError, match="only before its first step"):
        pipe.restore(pipe.state())


def test_damaged_bytes_are_refused() -> None:
    blob = _stepped(PipelineConfig(), _scans()[:10]).state().to_bytes()
    with pytest.raises(StateError, match="first bytes are wrong"):
        MapperState.from_bytes(b"not a state" + blob)
    with pytest.raises(StateError, match="does not parse"):
        MapperState.from_bytes(blob[:-20])
    with pytest.raises(StateError, match="does not parse"):
        MapperState.from_bytes(blob[:8] + bytes(b ^ 0x5A for b in blob[8:]))


def test_a_newer_format_is_refused() -> None:
    state = _stepped(PipelineConfig(), _scans()[:5]).state()
    newer = MapperState(state.kind, state.tree, state.arrays, STATE_FORMAT + 1)
    with pytest.raises(
        StateError, match=f"format {STATE_FORMAT + 1}: this agent reads format {STATE_FORMAT}"
    ):
        MapperState.from_bytes(newer.to_bytes())


def test_an_unregistered_class_is_refused_on_both_sides() -> None:
    state = _stepped(PipelineConfig(), _scans()[:5]).state()
    forged = MapperState(state.kind, {"n": 0, "o": "os.system", "x": {}}, ())
    with pytest.raises(StateError, match=r"'os\.system': not a registered state class"):
        Pipeline(PipelineConfig()).restore(MapperState.from_bytes(forged.to_bytes()))


def test_another_kind_of_state_is_refused() -> None:
    state = _stepped(PipelineConfig(), _scans()[:5]).state()
    with pytest.raises(StateError, match="a 'graph' state: expected a 'pipeline' state"):
        Pipeline(PipelineConfig()).restore(MapperState("graph", state.tree, state.arrays))
