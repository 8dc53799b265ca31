"""The loop-closure graph mapper's state round-trips: stepped N scans of two laps round a block, saved to
bytes, restored and stepped to the end, it ends exactly where one stepped through ends (every keyframe,
closure, wall and pose, bit for bit: the solver's history since it was last built is replayed); pending
loop searches and a pending rebuild are not lost with a worker; a pipeline's state is refused."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from shared.errors import StateError
from shared.pipeline import MapperState, Pipeline, PipelineConfig
from shared.sim.worlds import simulate_case
from shared.slam import OnlineGraphMapper
from tests.shared.slam.slamcheck import assert_same_map, state_when


@cache
def _case():  # type: ignore[no-untyped-def]
    return simulate_case("loop-block", 2)


def _mapper(worker: bool = False) -> OnlineGraphMapper:
    offset = _case().run.drive.laser_offset
    return OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), PipelineConfig(), worker=worker)


@cache
def _through() -> OnlineGraphMapper:
    online = _mapper()
    for scan in _case().run.scans:
        online.step(scan)
    return online


def _assert_same(through: OnlineGraphMapper, restored: OnlineGraphMapper) -> None:
    """Both flushed: the same keyframes, closures, walls (ids and end points) and trajectory, exactly."""
    through.flush()
    restored.flush()
    assert restored.version == through.version == len(_case().run.scans)
    assert_same_map(through, restored)


@pytest.mark.parametrize("split", [1, 240, 520, 1100])
def test_saved_restored_and_stepped_on_ends_where_one_stepped_through_does(split: int) -> None:
    scans = _case().run.scans
    first = _mapper()
    for scan in scans[:split]:
        first.step(scan)
    restored = _mapper()
    state = first.state()
    restored.restore(MapperState.from_bytes(state.to_bytes()))
    _assert_same_records(first, restored)
    held = _layout(state.tree, {})
    assert not {"shared.slam.mapper.Keyframe", "shared.slam.mapper.LoopClosure"} & set(held), "saved as rows"
    for scan in scans[split:]:
        restored.step(scan)
    _assert_same(_through(), restored)


def _assert_same_records(a: OnlineGraphMapper, b: OnlineGraphMapper) -> None:
    """The keyframes, closures and kept scans a restore made again from rows are those saved, field by field
    (returns, poses and odometry bit for bit)."""
    ga, gb = a._mapper, b._mapper
    assert len(ga.keyframes) == len(gb.keyframes) and len(ga._scans) == len(gb._scans)
    for x, y in zip(ga.keyframes, gb.keyframes, strict=True):
        assert (x.step, x.frontend, x.odometry, x.travelled_m, x.stamp_s) == (
            y.step,
            y.frontend,
            y.odometry,
            y.travelled_m,
            y.stamp_s,
        )
        assert np.array_equal(x.points, y.points) and np.array_equal(x.scan, y.scan)
    assert [(c.current, c.candidate, c.pose, float(c.inlier_share)) for c in ga.closures] == [
        (c.current, c.candidate, c.pose, float(c.inlier_share)) for c in gb.closures
    ]
    for (sa, scan_a, oa), (sb, scan_b, ob) in zip(ga._scans, gb._scans, strict=True):
        assert (sa, oa) == (sb, ob) and (scan_a is None) == (scan_b is None)
        assert (
            scan_a is None
            or scan_b is None
            or np.array_equal(scan_a.ranges_m, scan_b.ranges_m, equal_nan=True)
        )


def test_pending_searches_and_rebuild_are_taken_up_after_a_restore(late_worker) -> None:  # type: ignore[no-untyped-def]
    """The state taken while loop searches are unfinished and a rebuild is not shown yet (the worker held
    back) keeps them as their inputs; a restore submits them again, and the restored mapper ends exactly
    where one stepped through in the step ends."""
    scans = _case().run.scans
    first = _mapper(worker=True)

    def pending(split: int) -> bool:  # a search and a rebuild pending
        searching = any(j.matches is None for j in first._searches)
        return split >= 300 and searching and bool(first._redraws) and not first._redraws[-1].done

    state, split = state_when(first, late_worker(first), scans, pending)
    restored = _mapper(worker=True)
    try:
        restored.restore(MapperState.from_bytes(state.to_bytes()))
        assert restored._searches and restored._redraws
        for scan in scans[split:]:
            restored.step(scan)
        _assert_same(_through(), restored)
        assert restored._searches == [] and restored._redraws == []
    finally:
        restored.close()


def test_a_pipeline_state_is_refused_by_the_graph_mapper() -> None:
    pipe = Pipeline(PipelineConfig())
    pipe.step(_case().run.scans[0])
    with pytest.raises(StateError, match="a 'pipeline' state: expected a 'graph' state"):
        _mapper().restore(pipe.state())


def _layout(tree: object, out: dict[str, set[str]]) -> dict[str, set[str]]:
    """Every class in a state's tree with the attribute names it is kept with."""
    if isinstance(tree, dict):
        if "o" in tree:
            out.setdefault(tree["o"], set()).update(tree["x"])
        for value in tree.values():
            _layout(value, out)
    elif isinstance(tree, list):
        for value in tree:
            _layout(value, out)
    return out


def test_the_state_format_names_the_layout() -> None:
    """What a graph mapper's state holds (its classes and their attributes) is pinned to STATE_FORMAT: a
    state of an older layout must be refused by its format number with a clear error, not half read (a
    missing attribute would surface as an AttributeError in the agent). If this fails, bump
    shared.pipeline.state.STATE_FORMAT and pin the new layout's digest here."""
    import hashlib
    import json

    from shared.pipeline.state import STATE_FORMAT

    online = _mapper()
    for scan in _case().run.scans[:400]:
        online.step(scan)
    layout = {k: sorted(v) for k, v in _layout(online.state().tree, {}).items()}
    digest = hashlib.sha256(json.dumps(layout, sort_keys=True).encode()).hexdigest()[:16]
    assert (STATE_FORMAT, digest) == (6, "37bd59e394a6b02a"), layout


def test_records_of_another_shape_are_refused_by_name() -> None:
    """A state whose saved returns are not (index, points, scan) rows is refused as a StateError, not a
    TypeError the agent would report as a bug."""
    online = _mapper()
    for scan in _case().run.scans[:60]:
        online.step(scan)
    state = online.state()
    tree = dict(state.tree)
    tree["d"] = [
        [k, {"n": 10**6, "l": [{"n": 10**6 + 1, "l": [1]}]} if k == "returns" else v] for k, v in tree["d"]
    ]
    with pytest.raises(StateError, match="records do not parse"):
        _mapper().restore(MapperState(state.kind, tree, state.arrays))
