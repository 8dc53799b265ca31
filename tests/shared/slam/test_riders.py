"""Riders (shared.slam.riders): an edge carried onto the nodes its ends ride on says what it said before
(to first order: its residual under any small move is the same), inversion likewise, covariance
intersection is consistent and never worse than the better edge, and the reduced edges keep nothing
that joins a node to itself or that the robust kernel outvoted. Then the pose graph: riders leave the
solver at its rebuild, follow their anchors, the graph stays where the full one was, and a graph copied
as a state is copied goes on bit for bit."""

from __future__ import annotations

import copy
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.slam import PoseGraph, riders
from shared.slam.graph import RESOLVE_EVERY_UPDATES
from shared.slam.riders import (
    CARRIED,
    EDGE_WIDTH,
    LOOP,
    RIDE_WIDTH,
    carry,
    compose_many,
    fuse,
    inverse_edge,
    reduce_edges,
    remainder_tau,
    residual_sigmas,
    take_riders,
)
from shared.types import Pose2D

coord = st.floats(-3.0, 3.0)
angle = st.floats(-math.pi, math.pi)
pose = st.tuples(coord, coord, angle)


def _edge(i: int, j: int, z: tuple[float, float, float], info: np.ndarray, loop: bool = False) -> np.ndarray:
    row = np.zeros(EDGE_WIDTH)
    row[:6] = [i, j, *z, float(loop)]
    row[6:] = info.ravel()
    return row


def _info(seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(3, 3))
    return a @ a.T + np.diag([50.0, 5000.0, 200.0])  # a corridor: sure across, unsure along


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    p = Pose2D(*a.tolist()) @ Pose2D(*b.tolist())
    return np.array(p.as_tuple())


def _residual(row: np.ndarray, xi: np.ndarray, xj: np.ndarray) -> float:
    est = np.zeros((max(int(row[0]), int(row[1])) + 1, 3))
    est[int(row[0])], est[int(row[1])] = xi, xj
    return residual_sigmas(row, est)


@settings(max_examples=60, deadline=None)
@given(pose, pose, pose, pose, pose, st.integers(0, 1000), st.tuples(coord, coord, angle))
def test_a_carried_edge_has_the_residual_of_the_edge_it_came_from(
    a_i: tuple[float, ...],
    a_j: tuple[float, ...],
    o_i: tuple[float, ...],
    o_j: tuple[float, ...],
    z: tuple[float, ...],
    seed: int,
    move: tuple[float, float, float],
) -> None:
    """Ends i, j riding on anchors 0, 1 at offsets: under the anchors' poses moved a little, the carried
    edge's residual equals the original's with the riders moved along (first order: within 2 %)."""
    o_i_ = np.array(o_i) * 0.1  # riders sit near their anchors (25 cm, 20 degrees at most)
    o_j_ = np.array(o_j) * 0.1
    anchors = [np.array(a_i), np.array(a_j)]
    truth_i, truth_j = _compose(anchors[0], o_i_), _compose(anchors[1], o_j_)
    z_true = np.array(Pose2D(*truth_i.tolist()).between(Pose2D(*truth_j.tolist())).as_tuple())
    z_meas = z_true + np.array(z) * 0.002
    row = _edge(2, 3, tuple(z_meas.tolist()), _info(seed) * 100.0)  # about 1 cm, 0.5 degrees
    carried = carry(row, o_i_, o_j_, 0, 1)
    assert carried[:2].tolist() == [0.0, 1.0]
    moved_j = _compose(anchors[1], np.array(move) * 0.001)
    before = _residual(row, truth_i, _compose(moved_j, o_j_))
    after = _residual(carried, anchors[0], moved_j)
    assert math.isclose(before, after, rel_tol=0.02, abs_tol=0.005)


def test_a_node_no_closure_ties_to_its_place_stays_in_the_solver() -> None:
    est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.05, 0.0, 0.0], [1.0, 0.02, 0.0]])
    info = np.diag([1e4, 1e4, 4e4])
    edges = np.vstack(
        [
            _edge(0, 1, (1.0, 0.0, 0.0), info),
            _edge(1, 2, (0.05, 0.0, 0.0), info),
            _edge(2, 3, (-0.05, 0.02, 0.0), info),
            _edge(1, 3, (0.0, 0.02, 0.0), info, loop=True),  # ties 1 to 3, nothing ties 2 to 3
        ]
    )
    rides = np.zeros((4, RIDE_WIDTH))
    rides[:, 0] = -1
    out, reduced = take_riders(rides, [(1, 3), (2, 3)], est, edges, 3.0)
    assert out[1, 0] == 3 and out[2, 0] == -1 and out[3, 0] == -1
    np.testing.assert_allclose(out[1, 1:4], [0.0, -0.02, 0.0], atol=1e-12)
    assert {(int(r[0]), int(r[1])) for r in reduced} == {(0, 3), (2, 3)}


def test_an_exact_edge_carries_to_the_anchors_relative_pose() -> None:
    a0, a1 = np.array([1.0, 2.0, 0.3]), np.array([4.0, -1.0, 2.0])
    o0, o1 = np.array([0.1, -0.05, 0.2]), np.array([-0.2, 0.1, -0.3])
    x0, x1 = _compose(a0, o0), _compose(a1, o1)
    z = Pose2D(*x0.tolist()).between(Pose2D(*x1.tolist())).as_tuple()
    carried = carry(_edge(5, 6, z, np.eye(3)), o0, o1, 0, 1)
    expected = Pose2D(*a0.tolist()).between(Pose2D(*a1.tolist())).as_tuple()
    np.testing.assert_allclose(carried[2:5], expected, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(pose, pose, st.integers(0, 1000), st.tuples(coord, coord, angle))
def test_an_inverted_edge_says_the_same(
    xi: tuple[float, ...], xj: tuple[float, ...], seed: int, move: tuple[float, float, float]
) -> None:
    a, b = np.array(xi), np.array(xj)
    z = Pose2D(*a.tolist()).between(Pose2D(*b.tolist())).as_tuple()
    row = _edge(0, 1, z, _info(seed) * 100.0)
    inv = inverse_edge(row)
    np.testing.assert_allclose(inverse_edge(inv), row, atol=1e-9)
    moved = _compose(b, np.array(move) * 0.001)
    assert math.isclose(_residual(row, a, moved), _residual(inv, moved, a), rel_tol=0.02, abs_tol=0.005)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 1000), st.integers(0, 1000), st.tuples(coord, coord, angle))
def test_covariance_intersection_is_no_worse_than_the_better_edge_and_no_more_certain_than_both(
    seed_a: int, seed_b: int, shift: tuple[float, float, float]
) -> None:
    la, lb = _info(seed_a), _info(seed_b) * 0.3
    a = _edge(0, 1, (1.0, 0.0, 0.1), la)
    b = _edge(0, 1, tuple((np.array([1.0, 0.0, 0.1]) + 0.01 * np.array(shift)).tolist()), lb)
    f = fuse(a, b)
    lf = f[6:].reshape(3, 3)
    det = np.linalg.det
    assert det(lf) >= max(det(la), det(lb)) * (1 - 1e-9)
    # consistent whatever the correlation: never more certain than the sum of the two (the independent case)
    assert np.linalg.eigvalsh(la + lb - lf).min() >= -1e-6 * np.abs(la + lb).max()
    # the mean lies between the two measurements
    for k in range(3):
        lo, hi = sorted((a[2 + k], b[2 + k]))
        assert lo - 1e-9 <= f[2 + k] <= hi + 1e-9


def test_fusing_an_edge_with_itself_gives_it_back() -> None:
    a = _edge(0, 1, (1.0, 0.5, 0.2), _info(3))
    np.testing.assert_allclose(fuse(a, a), a, rtol=1e-9, atol=1e-9)


def test_the_reduced_edges_drop_self_joins_and_outvoted_closures_and_fuse_parallel_carried_ones() -> None:
    """Nodes 0..3 on a line 1 m apart; node 2 rides on node 1 at offset (1, 0, 0). Edges: 1->2 (now
    1 -> 1: dropped), 2->3 twice (both carried to 1->3 and fused into one), 1->3 (between two nodes in the
    solver: kept apart from the carried), a loop 0->2 that fits (carried to 0->1) and a loop 0->2 3 m off
    (outvoted: dropped)."""
    est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    info = np.diag([100.0, 100.0, 400.0])
    rows = np.vstack(
        [
            _edge(1, 2, (1.0, 0.0, 0.0), info),
            _edge(2, 3, (1.0, 0.0, 0.0), info),
            _edge(2, 3, (1.0, 0.01, 0.0), info * 2),
            _edge(1, 3, (2.0, 0.0, 0.0), info * 2),
            _edge(0, 2, (2.0, 0.0, 0.0), info, loop=True),
            _edge(0, 2, (5.0, 0.0, 0.0), info, loop=True),
        ]
    )
    anchor = np.array([0, 1, 1, 3])
    offset = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    out = reduce_edges(rows, anchor, offset, est, robust_sigmas=3.0)
    kinds = [(int(r[0]), int(r[1]), int(r[5])) for r in out]
    assert kinds == [(1, 3, CARRIED), (1, 3, 0), (0, 1, LOOP | CARRIED)]
    np.testing.assert_allclose(out[1], rows[3])  # the solver's own edge untouched
    np.testing.assert_allclose(out[2, 2:5], [1.0, 0.0, 0.0], atol=1e-12)
    # the fused carried 1->3: at least the stronger edge's information, at most both together
    fused = out[0, 6:].reshape(3, 3)
    assert np.linalg.det(fused) >= np.linalg.det(info * 2) * (1 - 1e-9)
    assert np.linalg.eigvalsh(info * 3 - fused).min() >= -1e-6
    assert 0.0 <= out[0, 3] <= 0.01  # between the two (here the stronger one alone)


# ---------------------------------------------------------------------------------------------- the graph
SEQ = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.01**2])
LOOP_INFO = np.diag([1.0 / 0.01**2, 1.0 / 0.01**2, 1.0 / 0.005**2])


def _laps(graph: PoseGraph, laps: int, ride: bool) -> list[Pose2D]:
    """``laps`` laps of a 40-node circle of 5 m radius, motions turning 0.3 degrees too far, each node
    from the second lap on closing a loop with the node at its place one lap back (which, with ``ride``,
    then rides on it). One update a node. Returns the true poses."""
    per_lap, radius = 40, 5.0
    truth = [
        Pose2D(
            radius * math.cos(2 * math.pi * k / per_lap),
            radius * math.sin(2 * math.pi * k / per_lap),
            2 * math.pi * k / per_lap + math.pi / 2,
        )
        for k in range(per_lap * laps + 1)
    ]
    graph.add_node(truth[0])
    graph.update()
    for k in range(1, len(truth)):
        m = truth[k - 1].between(truth[k])
        measured = Pose2D(m.x_m, m.y_m, m.theta_rad + math.radians(0.3))
        graph.add_node(graph.pose(k - 1) @ measured)
        graph.add_edge(k - 1, k, measured, SEQ, loop=False)
        if k >= per_lap:
            graph.add_edge(k - per_lap, k, truth[k - per_lap].between(truth[k]), LOOP_INFO, loop=True)
            if ride:
                graph.ride(k - per_lap, k)
        graph.update()
    return truth


def test_riders_leave_the_solver_follow_their_anchors_and_the_graph_stays_where_it_was() -> None:
    laps = 1 + 2 * RESOLVE_EVERY_UPDATES // 40  # past two rebuilds from scratch
    full, reduced = PoseGraph(), PoseGraph()
    truth = _laps(full, laps, ride=False)
    _laps(reduced, laps, ride=True)
    n = len(truth)
    assert full.solved_nodes == n
    assert reduced.solved_nodes < 3 * 40 + RESOLVE_EVERY_UPDATES  # bounded by the places and the rebuild
    assert len(reduced.edges) < len(full.edges) / 2
    est = reduced.pose_array()
    for k in range(n):
        a = reduced.riding_on(k)
        if a != k:  # a rider sits where its anchor and offset put it, next to the anchor
            assert abs(est[k, 0] - est[a, 0]) < 0.1 and abs(est[k, 1] - est[a, 1]) < 0.1
    # the newest lap (in the solver) within 1 cm of the full graph's and of the truth
    for k in range(n - 40, n):
        p, q, t = reduced.pose(k), full.pose(k), truth[k]
        assert math.hypot(p.x_m - q.x_m, p.y_m - q.y_m) < 0.01
        assert math.hypot(p.x_m - t.x_m, p.y_m - t.y_m) < 0.03


def test_a_graph_with_riders_copied_as_a_state_goes_on_bit_for_bit() -> None:
    """A copy without its solver (as shared.slam.onlinestate saves one), reattached, then both given the
    same further nodes and edges: the same estimate bit for bit, riders and pending rides included."""
    graph = PoseGraph()
    _laps(graph, 4, ride=True)
    skip = {"_params", "_isam", "_new_factors", "_new_values"}
    copied = object.__new__(PoseGraph)
    copied.__dict__.update({k: copy.deepcopy(v) for k, v in graph.__dict__.items() if k not in skip})
    copied.reattach()
    for g in (graph, copied):
        n = len(g)
        for k in range(n, n + RESOLVE_EVERY_UPDATES + 5):
            g.add_node(g.pose(k - 1) @ Pose2D(0.3, 0.0, 0.05))
            g.add_edge(k - 1, k, Pose2D(0.3, 0.0, 0.05), SEQ, loop=False)
            if k % 7 == 0:
                g.ride(k - 40, k)
            g.update()
    assert np.array_equal(graph.pose_array(), copied.pose_array())
    assert graph.solved_nodes == copied.solved_nodes


def test_an_edge_to_a_rider_goes_to_its_anchor() -> None:
    """A loop search begun before its candidate retired may still close on it: the edge is carried."""
    graph = PoseGraph()
    _laps(graph, 4, ride=True)
    rider = next(k for k in range(1, len(graph)) if graph.riding_on(k) != k)
    before = len(graph.edges)
    k = len(graph) - 1
    graph.add_edge(rider, k, graph.pose(rider).between(graph.pose(k)), LOOP_INFO, loop=True)
    graph.update()
    last = graph.edges[-1]
    assert len(graph.edges) == before + 1
    assert {last.i, last.j} == {graph.riding_on(rider), k}
    assert graph.residual_sigmas(last) < 1.0


_heading = st.one_of(
    st.floats(-math.pi, math.pi), st.sampled_from([math.pi, -math.pi]), st.floats(-20.0, 20.0)
)
_pose_rows = st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), _heading)


@settings(max_examples=200, deadline=None)
@given(_pose_rows, st.lists(_pose_rows, min_size=1, max_size=30))
def test_riders_handed_on_in_one_pass_are_composed_as_one_by_one(
    a: tuple[float, float, float], bs: list[tuple[float, float, float]]
) -> None:
    """compose_many, which hands a leaving node's riders on, against _compose on each: the headings are
    the same IEEE remainder bit for bit, the positions the same to rounding (a 2x2 product in BLAS)."""
    row, rows = np.array(a), np.array(bs)
    got = compose_many(row, rows)
    want = np.array([riders._compose(row, b) for b in rows])
    assert np.array_equal(got[:, 2], want[:, 2])
    np.testing.assert_allclose(got[:, :2], want[:, :2], rtol=1e-12, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.one_of(st.floats(-100.0, 100.0), st.sampled_from([math.pi, -math.pi, math.tau, -math.tau, 0.0])),
        max_size=40,
    )
)
def test_the_vectorised_remainder_is_math_remainder_bit_for_bit(values: list[float]) -> None:
    theta = np.array(values, dtype=np.float64)
    remainder_tau(theta)
    assert theta.tolist() == [math.remainder(v, math.tau) for v in values]
