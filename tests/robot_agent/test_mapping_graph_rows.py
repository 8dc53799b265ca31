"""What a step records of the pose graph (robot_agent.mapping.MappingLoop._with_graph): every keyframe
the first time, afterwards only those new or moved by more than 1 mm / 1 mrad; a keyframe made in this
step at the pose the step records; ids and loop closures shifted by a continued map's keyframe offset;
only the loop closures not recorded yet; comparing only what can have moved records what comparing every
keyframe does."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from robot_agent.mapping import MappingLoop
from robot_agent.store import StepRecord
from shared.pipeline import Pipeline, PipelineConfig
from shared.sim.worlds import simulate_case
from shared.slam import OnlineGraphMapper


class _Graph:
    """The graph's reading side as the agent uses it."""

    def __init__(self, rows: list[list[float]], pairs: list[list[int]]) -> None:
        self.rows = rows
        self.pairs = pairs

    def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, np.ndarray]:
        # the rows are changed in place by the tests: a new estimate each read (every row compared)
        return object(), 0, np.array(self.rows, dtype=np.float64).reshape(-1, 5)

    def closure_pairs(self, since: int = 0) -> list[list[int]]:
        return self.pairs[since:]

    def pose_covariance(self) -> None:
        return None


def _loop(offset: int = 0) -> SimpleNamespace:
    return SimpleNamespace(
        _keyframe_offset=offset,
        _sent_keyframes=np.full((0, 3), np.nan),
        _prev_closures=0,
        _seen_estimate=None,
        _compare_from=0,
    )


def _rec(stamp: float, pose: tuple[float, float, float]) -> StepRecord:
    return StepRecord(1, stamp, 1, [], [], [stamp, *pose], [])


def _record(
    loop: SimpleNamespace, graph: _Graph, stamp: float, pose: tuple[float, float, float]
) -> StepRecord:
    return MappingLoop._with_graph(loop, _rec(stamp, pose), graph)  # type: ignore[arg-type]


def test_first_every_keyframe_then_only_the_moved_and_the_new() -> None:
    loop = _loop()
    graph = _Graph([[0, 0.0, 0.0, 0.0, 0.0], [1, 0.5, 0.5, 0.0, 0.0]], [])
    first = _record(loop, graph, 0.5, (0.501, 0.0, 0.0))
    # keyframe 1 was made in this step: recorded at the step's own pose, not the graph's
    assert first.keyframes == [[0, 0.0, 0.0, 0.0, 0.0], [1, 0.5, 0.501, 0.0, 0.0]]
    graph.rows[0][2] += 0.0005  # nudged by less than 1 mm: not again
    graph.rows[1][4] += 0.002  # turned by 2 mrad: again
    graph.rows.append([2, 1.0, 1.0, 0.0, 0.0])
    second = _record(loop, graph, 1.0, (1.0, 0.0, 0.0))
    assert [r[0] for r in second.keyframes] == [1, 2]
    assert second.keyframes[0] == [1, 0.5, 0.5, 0.0, 0.002]
    # against the last recorded pose, not the last seen one: small nudges add up to a record
    graph.rows[0][2] += 0.0006
    third = _record(loop, graph, 1.1, (1.1, 0.0, 0.0))
    assert [r[0] for r in third.keyframes] == [0]
    assert _record(loop, graph, 1.2, (1.2, 0.0, 0.0)).keyframes == []


def test_a_turn_across_pi_is_a_small_turn() -> None:
    loop = _loop()
    graph = _Graph([[0, 0.0, 0.0, 0.0, np.pi - 1e-4]], [])
    _record(loop, graph, 0.0, (0.0, 0.0, np.pi - 1e-4))
    graph.rows[0][4] = -np.pi + 1e-4  # 0.2 mrad across the wrap
    assert _record(loop, graph, 0.1, (0.0, 0.0, 0.0)).keyframes == []


def test_a_continued_maps_offset_and_only_new_closures() -> None:
    loop = _loop(offset=40)
    graph = _Graph([[0, 0.0, 0.0, 0.0, 0.0], [1, 0.5, 0.5, 0.0, 0.0]], [[0, 1]])
    first = _record(loop, graph, 0.7, (0.5, 0.0, 0.0))
    assert [r[0] for r in first.keyframes] == [40, 41] and first.loop_closures == [[40, 41]]
    graph.pairs.append([1, 0])
    second = _record(loop, graph, 0.8, (0.5, 0.0, 0.0))
    assert second.keyframes == [] and second.loop_closures == [[41, 40]]


def test_comparing_only_what_can_have_moved_records_what_comparing_all_does() -> None:
    """Two laps of loop-block through a real OnlineGraphMapper (in-step): a step whose graph estimate did
    not change since the last compares only the keyframes made since (keyframe_changes), and records
    the same rows, step by step, as comparing every keyframe each step."""
    run = simulate_case("loop-block", 2).run
    offset = run.drive.laser_offset
    online = OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), PipelineConfig(), worker=False)
    tracked, every = _loop(), _loop()
    firsts: list[int] = []

    class _Spy:
        def __getattr__(self, name: str) -> object:
            return getattr(online, name)

        def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, np.ndarray]:
            got = online.keyframe_changes(seen, since)
            firsts.append(got[1])
            return got

    class _Every:
        def __getattr__(self, name: str) -> object:
            return getattr(online, name)

        def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, np.ndarray]:
            return object(), 0, online.keyframe_array()

    closures = 0
    for scan in run.scans:
        pose = online.step(scan).pose
        rec = _rec(scan.stamp_s, (pose.x_m, pose.y_m, pose.theta_rad))
        a = MappingLoop._with_graph(tracked, rec, _Spy())  # type: ignore[arg-type]
        b = MappingLoop._with_graph(every, rec, _Every())  # type: ignore[arg-type]
        assert a.keyframes == b.keyframes and a.loop_closures == b.loop_closures
        closures += len(a.loop_closures)
    assert closures > 0 and online.optimise_ms, "the laps closed loops: the estimate moved"
    assert sum(f > 0 for f in firsts) > len(firsts) // 2, "most steps compared only the new keyframes"


class _StableGraph(_Graph):
    """A graph whose estimate changes only when :meth:`move` says so (as the online mapper's)."""

    def __init__(self, rows: list[list[float]], pairs: list[list[int]]) -> None:
        super().__init__(rows, pairs)
        self.estimate = object()

    def move(self, k: int, dy: float) -> None:
        self.rows[k][3] += dy
        self.estimate = object()

    def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, np.ndarray]:
        first = since if seen is self.estimate else 0
        return self.estimate, first, np.array(self.rows[first:], dtype=np.float64).reshape(-1, 5)


def test_a_keyframe_first_recorded_at_the_steps_pose_is_compared_again() -> None:
    """The worker had moved keyframe 1 by 5 mm when the step read it: recorded at the step's pose first,
    then, with the estimate unchanged, at the estimate's on the next step; then nothing is compared again
    until the estimate changes."""
    loop = _loop()
    graph = _StableGraph([[0, 0.0, 0.0, 0.0, 0.0], [1, 0.5, 0.505, 0.0, 0.0]], [])
    first = _record(loop, graph, 0.5, (0.5, 0.0, 0.0))
    assert first.keyframes == [[0, 0.0, 0.0, 0.0, 0.0], [1, 0.5, 0.5, 0.0, 0.0]]
    second = _record(loop, graph, 0.6, (0.6, 0.0, 0.0))
    assert second.keyframes == [[1, 0.5, 0.505, 0.0, 0.0]]
    assert _record(loop, graph, 0.7, (0.7, 0.0, 0.0)).keyframes == []
    graph.move(0, 0.002)
    assert _record(loop, graph, 0.8, (0.8, 0.0, 0.0)).keyframes == [[0, 0.0, 0.0, 0.002, 0.0]]
