"""Every node's pose from the solver's (shared.slam.ridepose): bit for bit the straightforward composition,
whatever the riders, headings and offsets; the plan follows nodes added to the solver and a replaced
rider table; a rider on a node that is not in the solver is refused."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.slam.ridepose import RiderPoses, compose_reference
from shared.slam.riders import RIDE_WIDTH
from shared.slam.rows import Rows
from shared.types import wrap_angle

_angle = st.one_of(
    st.floats(-math.pi, math.pi),
    st.sampled_from([math.pi, -math.pi, math.nextafter(math.pi, 0), math.nextafter(-math.pi, 0)]),
)
_offset_angle = st.one_of(_angle, st.floats(-7.0, 7.0))  # beyond 2 pi too: the per-value path


@st.composite
def _graphs(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """A rider table ``(n, RIDE_WIDTH)`` and the solved nodes' poses ``(k, 3)``."""
    n = draw(st.integers(1, 60))
    riding = [False] + [draw(st.booleans()) for _ in range(n - 1)]  # node 0 is always in the solver
    solved = [i for i in range(n) if not riding[i]]
    table = np.zeros((n, RIDE_WIDTH))
    table[:, 0] = -1.0
    for i in range(n):
        if riding[i]:
            table[i, 0] = draw(st.sampled_from(solved))
            table[i, 1] = draw(st.floats(-50, 50))
            table[i, 2] = draw(st.floats(-50, 50))
            table[i, 3] = draw(_offset_angle)
    coord = st.floats(-1e4, 1e4)
    poses = np.array([[draw(coord), draw(coord), draw(_angle)] for _ in solved]).reshape(-1, 3)
    return table, poses


@settings(max_examples=300, deadline=None)
@given(_graphs())
def test_the_composition_is_the_straightforward_one_bit_for_bit(graph: tuple[np.ndarray, np.ndarray]) -> None:
    table, poses = graph
    got = RiderPoses().compose(poses, Rows.of(table), len(table))
    want = compose_reference(poses, table)
    assert got.shape == (len(table), 3) and got.flags.c_contiguous
    assert np.array_equal(got, want)
    assert all(-math.pi < t <= math.pi for t in got[:, 2])
    assert all(wrap_angle(float(t)) == t for t in got[:, 2])


@settings(max_examples=100, deadline=None)
@given(_graphs(), st.integers(1, 5), st.floats(-math.pi, math.pi))
def test_nodes_added_to_the_solver_extend_the_plan(
    graph: tuple[np.ndarray, np.ndarray], added: int, heading: float
) -> None:
    table, poses = graph
    rows, riders = Rows.of(table), RiderPoses()
    riders.compose(poses, rows, len(table))
    for k in range(added):  # as PoseGraph.add_node does: a row in the solver at the end
        rows.append((-1.0, *[0.0] * (RIDE_WIDTH - 1)))
        poses = np.vstack([poses, [float(k), -float(k), heading]])
    got = riders.compose(poses, rows, len(rows))
    assert np.array_equal(got, compose_reference(poses, rows.view()))


def test_a_replaced_rider_table_gets_a_new_plan() -> None:
    table = np.zeros((3, RIDE_WIDTH))
    table[:, 0] = -1.0
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [2.0, 0.0, 1.0]])
    riders = RiderPoses()
    assert np.array_equal(riders.compose(poses, Rows.of(table), 3), poses)
    table[2] = (1.0, 0.5, 0.0, 0.1, *[0.0] * (RIDE_WIDTH - 4))  # node 2 now rides on node 1
    got = riders.compose(poses[:2], Rows.of(table), 3)
    assert np.array_equal(got, compose_reference(poses[:2], table))
    assert got[2, 0] == pytest.approx(1.0 + 0.5 * math.cos(0.5))


def test_a_rider_on_a_node_outside_the_solver_or_a_wrong_count_is_refused() -> None:
    table = np.zeros((3, RIDE_WIDTH))
    table[:, 0] = (-1.0, 2.0, 1.0)  # node 2 rides on node 1, which rides itself
    with pytest.raises(ValueError, match="not in the solver"):
        RiderPoses().compose(np.zeros((1, 3)), Rows.of(table), 3)
    table[:, 0] = (-1.0, -1.0, 0.0)
    with pytest.raises(ValueError, match="3 poses for 2 nodes"):
        RiderPoses().compose(np.zeros((3, 3)), Rows.of(table), 3)
