"""The pose graph: a true loop closure takes out the drift of a lap; false closures, injected, do not wreck
it (their Cauchy kernel outvotes them), while the same false closures without the kernel do."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.slam import OptimisationError, PoseGraph
from shared.types import Pose2D

SEQ_INFO = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.01**2])
LOOP_INFO = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.005**2])


def square_lap(steps_per_side: int = 10, side_m: float = 4.0, sides: int = 4) -> list[Pose2D]:
    """True poses round a square: ``sides`` sides (5: once round and along the first side again)."""
    poses = []
    for k in (n % 4 for n in range(sides)):
        corner = [(0.0, 0.0), (side_m, 0.0), (side_m, side_m), (0.0, side_m)][k]
        heading = k * math.pi / 2
        for i in range(steps_per_side):
            d = side_m * i / steps_per_side
            poses.append(
                Pose2D(corner[0] + d * math.cos(heading), corner[1] + d * math.sin(heading), heading)
            )
    poses.append(
        Pose2D(*[(0.0, 0.0), (side_m, 0.0), (side_m, side_m), (0.0, side_m)][sides % 4], sides * math.pi / 2)
    )
    return poses


def closed_laps(truth: list[Pose2D], *, robust_sigmas: float = 3.0) -> tuple[PoseGraph, float]:
    """A chain whose measured motions turn 0.6 degrees too far each step (worn wheels), with a true loop
    closure at every step from the 41st on (the first side seen again); returns the graph and the worst
    drift before a closure took effect."""
    graph = PoseGraph(robust_sigmas=robust_sigmas)
    graph.add_node(truth[0])
    drifted = 0.0
    for i in range(1, len(truth)):
        true_motion = truth[i - 1].between(truth[i])
        measured = Pose2D(true_motion.x_m, true_motion.y_m, true_motion.theta_rad + math.radians(0.6))
        graph.add_node(graph.pose(i - 1) @ measured)
        graph.add_edge(i - 1, i, measured, SEQ_INFO, loop=False)
        if i >= 40:  # back on the first side: the place of node i - 40 seen again
            error = math.hypot(graph.pose(i).x_m - truth[i].x_m, graph.pose(i).y_m - truth[i].y_m)
            drifted = max(drifted, error)
            graph.add_edge(i - 40, i, truth[i - 40].between(truth[i]), LOOP_INFO, loop=True)
        graph.update()
    return graph, drifted


def worst_error(graph: PoseGraph, truth: list[Pose2D]) -> float:
    return max(math.hypot(p.x_m - t.x_m, p.y_m - t.y_m) for p, t in zip(graph.poses(), truth, strict=True))


def test_loop_closures_take_out_the_drift_of_a_lap() -> None:
    """Round the square and along its first side again, closing a loop at each step of that side: the
    first closures lie far outside their own covariance (the drift of a lap) and are outvoted at first,
    then together they pull the lap into place."""
    truth = square_lap(sides=5)
    graph, drifted = closed_laps(truth)
    assert drifted > 0.5
    graph.optimise_batch()
    assert worst_error(graph, truth) < 0.2 * drifted
    assert max(graph.residual_sigmas(e) for e in graph.edges if e.loop) < 3.0


@pytest.mark.parametrize("batch", [False, True])
def test_false_loop_closures_do_not_wreck_the_map(batch: bool) -> None:
    truth = square_lap(sides=5)
    robust, _ = closed_laps(truth)
    plain, _ = closed_laps(truth, robust_sigmas=1e9)  # a kernel so wide it is plain least squares
    reference = worst_error(robust, truth)
    # three false closures: places 2-3 m apart claimed to be one (a repeating corridor)
    for i, j in ((2, 25), (5, 31), (12, 35)):
        wrong = truth[i].between(truth[j]) @ Pose2D(2.0, 0.5, 0.3)
        for graph in (robust, plain):
            graph.add_edge(i, j, wrong, LOOP_INFO, loop=True)
    for graph in (robust, plain):
        graph.update()
        if batch:
            graph.optimise_batch()
    assert worst_error(robust, truth) < reference + 0.05
    assert worst_error(plain, truth) > reference + 0.3
    outvoted = [robust.residual_sigmas(e) for e in robust.edges[-3:]]
    assert min(outvoted) > 10.0


def test_an_edge_without_positive_information_is_refused() -> None:
    graph = PoseGraph()
    graph.add_node(Pose2D())
    graph.add_node(Pose2D(1.0, 0.0, 0.0))
    with pytest.raises(OptimisationError, match="positive definite"):
        graph.add_edge(0, 1, Pose2D(1.0, 0.0, 0.0), np.zeros((3, 3)), loop=False)
    with pytest.raises(OptimisationError, match="positive definite"):
        graph.add_edge(0, 1, Pose2D(1.0, 0.0, 0.0), np.full((3, 3), np.nan), loop=True)


def _saved_and_restored(graph: PoseGraph) -> PoseGraph:
    """``graph`` through a mapping state's bytes (as the robot's Robot DB keeps it), solver rebuilt."""
    from shared.pipeline.state import MapperState, decode_tree, encode_tree
    from shared.slam.onlinestate import _SKIP

    tree, arrays = encode_tree(graph, _SKIP)
    restored = decode_tree(MapperState.from_bytes(MapperState("graph", tree, arrays).to_bytes()))
    assert isinstance(restored, PoseGraph)
    restored.reattach()
    return restored


def _grow(graphs: list[PoseGraph], truth: list[Pose2D], start: int, rng: np.random.Generator) -> None:
    """Nodes ``start..`` on every graph alike: a chain with noisy motions, a loop edge now and then."""
    for k in range(start, len(truth)):
        motion = truth[k - 1].between(truth[k])
        noisy = Pose2D(motion.x_m + rng.normal(0, 0.01), motion.y_m, motion.theta_rad + rng.normal(0, 0.005))
        loop = k >= 41 and k % 3 == 0
        for g in graphs:
            g.add_node(g.pose(k - 1) @ noisy)
            g.add_edge(k - 1, k, noisy, SEQ_INFO, loop=False)
            if loop:
                g.add_edge(k - 40, k, truth[k - 40].between(truth[k]), LOOP_INFO, loop=True)
            g.update()


@pytest.mark.parametrize("split", [1, 30, 99, 100, 101, 130])
def test_a_restored_graph_goes_on_exactly_as_the_saved_one(split: int) -> None:
    """Saved after ``split`` updates (before, at and after the solver is built from scratch at update
    100), restored and grown on alike: the very same estimate, bit for bit, at every update after."""
    truth = square_lap(sides=20)  # 201 nodes: two rebuilds from scratch on the way
    rng = np.random.default_rng(split)
    graph = PoseGraph()
    graph.add_node(truth[0])
    graph.update()
    _grow([graph], truth[: split + 1], 1, rng)
    restored = _saved_and_restored(graph)
    assert restored.poses() == graph.poses()
    _grow([graph, restored], truth, split + 1, rng)
    assert restored.poses() == graph.poses()
    assert len(restored) == len(truth)


def test_a_history_that_does_not_replay_falls_back_to_the_saved_estimate(caplog) -> None:  # type: ignore[no-untyped-def]
    truth = square_lap(sides=6)
    graph = PoseGraph()
    graph.add_node(truth[0])
    graph.update()
    _grow([graph], truth, 1, np.random.default_rng(0))
    graph._guesses = graph._guesses[:-5]  # a damaged history: the last nodes' guesses are missing
    restored = _saved_and_restored(graph)
    assert restored.poses() == graph.poses()
    assert "did not replay" in caplog.text
    restored.add_node(restored.pose(len(restored) - 1))
    restored.add_edge(len(restored) - 2, len(restored) - 1, Pose2D(), SEQ_INFO, loop=False)
    restored.update()
    assert math.dist(restored.pose(len(restored) - 1).as_tuple()[:2], graph.poses()[-1].as_tuple()[:2]) < 1e-3
