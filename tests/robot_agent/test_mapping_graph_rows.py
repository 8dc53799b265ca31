"""What a step records of the pose graph (robot_agent.mapping.MappingLoop._with_graph): every keyframe
the first time, afterwards only those new or moved by more than 1 mm / 1 mrad; a keyframe made in this
step at the pose the step records; ids and loop closures shifted by a continued map's keyframe offset;
only the loop closures not recorded yet."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from robot_agent.mapping import MappingLoop
from robot_agent.store import StepRecord


class _Graph:
    """The graph's reading side as the agent uses it."""

    def __init__(self, rows: list[list[float]], pairs: list[list[int]]) -> None:
        self.rows = rows
        self.pairs = pairs

    def keyframe_array(self) -> np.ndarray:
        return np.array(self.rows, dtype=np.float64).reshape(-1, 5)

    def closure_pairs(self, since: int = 0) -> list[list[int]]:
        return self.pairs[since:]

    def pose_covariance(self) -> None:
        return None


def _loop(offset: int = 0) -> SimpleNamespace:
    return SimpleNamespace(_keyframe_offset=offset, _sent_keyframes=np.full((0, 3), np.nan), _prev_closures=0)


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
