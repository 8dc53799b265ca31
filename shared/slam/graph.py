"""A 2D pose graph on gtsam: keyframe poses as nodes, relative-pose edges with their information.

Sequential edges (the front end's motion between consecutive keyframes) are Gaussian; loop-closure edges
carry a Cauchy kernel (``robust_sigmas`` wide, in standard deviations of the edge): a closure whose
residual is far beyond its covariance, as a false one is, pulls with a weight ``1 / (1 + (r / k)^2)`` and
cannot drag the map after it. The graph is solved incrementally with iSAM2 (Kaess et al. 2012) as nodes and
edges arrive; :meth:`PoseGraph.optimise_batch` re-solves the whole graph with Levenberg-Marquardt (the
offline final pass). gtsam's ``Pose2`` tangent order ``(x, y, theta)`` is the order of every information
matrix here (per m^2, m rad, rad^2).

**Riders** (:mod:`shared.slam.riders`): a node handed to :meth:`PoseGraph.ride` (a keyframe retired at a
place an older one holds, :mod:`shared.slam.places`) that a loop edge ties directly to that one (a
closure, or the tie the mapper measures at retirement) leaves the solver at its next rebuild from scratch
and is carried by it at a fixed offset; its edges are carried onto the anchor and fused. The solver then
grows with the places and with the few retired nodes whose tie failed, not with every keyframe.

An update that gtsam refuses (an indeterminate system, a non-finite value) raises
:class:`~shared.slam.errors.OptimisationError`; the estimate from before it stays in force.

Cost: iSAM2's update is O(affected nodes) per keyframe; a loop closure re-solves the nodes of the loop.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import gtsam
import numpy as np

from shared.slam.errors import OptimisationError
from shared.slam.ridepose import RiderPoses
from shared.slam.riders import (
    EDGE_WIDTH,
    LOOP,
    RIDE_WIDTH,
    carry,
    inverse_edge,
    residual_sigmas,
    take_riders,
)
from shared.slam.rows import Rows
from shared.types import FloatArray, Pose2D

__all__ = ["RESOLVE_EVERY_UPDATES", "Edge", "PoseGraph"]

log = logging.getLogger(__name__)

#: the solver is built from scratch at the estimate after this many updates (a keyframe or a batch of
#: closures each): a restored graph replays at most these to be the very solver it was saved from
RESOLVE_EVERY_UPDATES = 100


@dataclass(frozen=True, slots=True)
class Edge:
    """A relative-pose measurement ``j`` in the frame of ``i``, its information ``(3, 3)``, and whether it
    closes a loop (robust) or follows the chain (Gaussian)."""

    i: int
    j: int
    measurement: Pose2D
    information: FloatArray
    loop: bool


def _pose2(p: Pose2D) -> gtsam.Pose2:
    return gtsam.Pose2(p.x_m, p.y_m, p.theta_rad)


#: an edge as a row of :attr:`PoseGraph._edges`: i, j, the measurement (x, y, theta), its kind (bits:
#: a loop closure 1, carried from a rider 2; shared.slam.riders) and the information's 9 entries (row-major)
_EDGE_WIDTH = EDGE_WIDTH


def _edge_row(e: Edge) -> list[float]:
    m = e.measurement
    return [float(e.i), float(e.j), m.x_m, m.y_m, m.theta_rad, float(e.loop), *e.information.ravel().tolist()]


def _edge_of(row: FloatArray) -> Edge:
    i, j, x, y, th, loop = row[:6].tolist()
    info = np.array(row[6:15], dtype=np.float64).reshape(3, 3)
    return Edge(int(i), int(j), Pose2D(x, y, th), info, bool(int(loop) & LOOP))


def _poses_of(values: gtsam.Values, riders: RiderPoses, rows: Rows, n: int) -> FloatArray:
    """Nodes ``0..n-1`` as read-only rows ``(n, 3)`` ``[x_m, y_m, theta_rad]``: those in the solver read
    off ``values`` in key order (one C++ call: the per-node ``atPose2``, and a ``Pose2D`` per node, took a
    third of an update's time on long graphs), the riders composed from their anchors (``rows``: the
    rider table, :data:`~shared.slam.riders.RIDE_WIDTH`; :class:`~shared.slam.ridepose.RiderPoses`).
    O(n), vectorised; trigonometry O(nodes in the solver)."""
    arr = np.array(gtsam.utilities.extractPose2(values), dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(arr).all():
        raise OptimisationError("the solution holds a pose that is not finite")
    try:
        out = riders.compose(arr, rows, n)
    except ValueError as exc:
        raise OptimisationError(f"the solution does not fit the graph: {exc}") from exc
    return _frozen(out)


def _frozen(arr: FloatArray) -> FloatArray:
    arr.setflags(write=False)
    return arr


def _row(p: Pose2D) -> FloatArray:
    return np.array([[p.x_m, p.y_m, p.theta_rad]], dtype=np.float64)


def _local(information: FloatArray, measurement: Pose2D) -> FloatArray:
    """``information`` over a relative pose's coordinates in the frame of its first node, expressed in the
    measurement's own frame (gtsam's tangent space of ``Pose2``): ``B^T I B`` with ``B = diag(R, 1)``,
    ``R`` the measurement's rotation (to first order). O(1)."""
    c, s = math.cos(measurement.theta_rad), math.sin(measurement.theta_rad)
    b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out: FloatArray = b.T @ information @ b
    return 0.5 * (out + out.T)


class PoseGraph:
    """Keyframe poses ``0..n-1`` (world frame) under sequential and loop-closure edges."""

    def __init__(self, *, robust_sigmas: float = 3.0, extra_iterations: int = 2) -> None:
        self._robust_sigmas = robust_sigmas
        self._extra = extra_iterations
        # the estimate as read-only (n, 3) rows; replaced, never written in place, so an array handed out
        # (pose_array) stays what it was
        self._estimate: FloatArray = _frozen(np.zeros((0, 3)))
        self._first: Pose2D | None = None
        # every edge as a row (_EDGE_WIDTH): a state copies one array, not an object per edge
        self._edges = Rows(_EDGE_WIDTH)
        self._loop_pending = False
        # the solver's history since it was last built from scratch (RESOLVE_EVERY_UPDATES): the graph
        # then (node and edge counts, the estimate), then each update's node count, edge count and
        # whether a loop edge came, and the first guess of each node added since; enough to rebuild the
        # very same iSAM2 after a restore
        self._base: tuple[int, int, FloatArray] = (0, 0, np.zeros((0, 3)))
        self._log: list[tuple[int, int, bool]] = []
        self._guesses: list[Pose2D] = []
        # per node: the node it rides on (-1: in the solver) and its offset there (x, y, theta); and the
        # nodes handed to ride() for the next rebuild from scratch, with their anchors
        self._rides = Rows(RIDE_WIDTH)
        self._queued: list[tuple[int, int]] = []
        self._fresh_solver()

    def _all_poses(self, values: gtsam.Values) -> FloatArray:
        """Every node's pose from the solver's ``values`` (:func:`_poses_of`), its plan kept across updates
        (not part of a saved state: made again on first use after a restore)."""
        riders: RiderPoses | None = self.__dict__.get("_rider_poses")
        if riders is None:
            riders = self._rider_poses = RiderPoses()
        return _poses_of(values, riders, self._rides, len(self._estimate))

    def _solved_indices(self, n: int) -> list[int]:
        """Nodes ``0..n-1`` that are in the solver (not riding), ascending. O(n) numpy."""
        out: list[int] = np.flatnonzero(self._rides.view()[:n, 0] < 0).tolist()
        return out

    def _fresh_solver(self) -> None:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self._params = params
        self._isam = gtsam.ISAM2(params)
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()

    def _prior(self) -> None:
        assert self._first is not None
        anchor = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))
        self._new_factors.add(gtsam.PriorFactorPose2(0, _pose2(self._first), anchor))

    def _queue_edges(self, rows: FloatArray) -> None:
        """The edges of ``rows`` (rows of ``_edges``) queued as factors. O(len(rows))."""
        for row in rows:
            e = _edge_of(row)
            noise = self._noise(_local(e.information, e.measurement), e.loop)
            self._new_factors.add(gtsam.BetweenFactorPose2(e.i, e.j, _pose2(e.measurement), noise))

    def _solve(self, loops: bool) -> gtsam.Values:
        """The queued nodes and edges into iSAM2 (a few relinearisations more after a loop edge)."""
        try:
            self._isam.update(self._new_factors, self._new_values)
            for _ in range(self._extra if loops else 0):
                self._isam.update()
            return self._isam.calculateEstimate()
        except RuntimeError as exc:
            raise OptimisationError(f"iSAM2 refused the update: {exc}") from exc
        finally:
            self._new_factors = gtsam.NonlinearFactorGraph()
            self._new_values = gtsam.Values()

    def _queue_graph(self, estimate: FloatArray, edges: FloatArray) -> None:
        """The anchor, every node in the solver at ``estimate`` (rows) and ``edges``, queued for one
        update."""
        self._prior()
        for k in self._solved_indices(len(estimate)):  # the riders are not in the solver: O(solved) inserts
            x, y, th = estimate[k].tolist()
            self._new_values.insert(k, gtsam.Pose2(x, y, th))
        self._queue_edges(edges)

    def _resolve(self, take_riders: bool = True) -> None:
        """Build the solver from scratch: the nodes handed to :meth:`ride` leave it, then every node in it
        at its estimate, every edge, one update (the estimate stays); the history starts again here.
        O(graph)."""
        if self._queued and take_riders:
            self._take_riders()
        self._fresh_solver()
        self._base = (len(self._estimate), len(self._edges), self.pose_array())
        self._log, self._guesses = [], []
        if len(self._estimate):
            self._queue_graph(self._estimate, self._edges.view())
            self._solve(False)

    def reattach(self) -> None:
        """Rebuild the solver of a graph restored from a saved state (:mod:`shared.slam.onlinestate`),
        which holds the nodes, the edges, the estimate and the solver's history but no gtsam objects:
        the solver as it was last built from scratch, then every update since, replayed, so it is the
        very solver that was saved and later updates give what they would have given. If the replay
        does not arrive at the saved estimate (a state from another gtsam), the solver is built from
        the saved estimate instead (within its relinearisation of it). O(graph + updates since)."""
        saved, history, guesses = _frozen(np.array(self._estimate)), list(self._log), list(self._guesses)
        nodes, edges, base = self._base
        self._fresh_solver()
        try:
            self._estimate = _frozen(np.array(base, dtype=np.float64).reshape(-1, 3))
            if nodes:
                self._queue_graph(self._estimate, self._edges.view()[:edges])
                self._solve(False)
            self._estimate = self._estimate[:nodes]
            for n_after, e_after, loops in history:
                for k in range(len(self._estimate), n_after):
                    guess = guesses[k - nodes]
                    self._new_values.insert(k, _pose2(guess))
                    if k == 0:
                        self._prior()
                    self._estimate = np.vstack([self._estimate, _row(guess)])
                self._queue_edges(self._edges.view()[edges:e_after])
                edges = e_after
                self._estimate = self._all_poses(self._solve(loops))
        except (OptimisationError, IndexError) as exc:
            log.warning("the pose graph's solver did not replay (%s); rebuilt from the saved estimate", exc)
        exact = self._estimate.shape == saved.shape and bool(np.array_equal(self._estimate, saved))
        self._estimate = saved
        if not exact:
            log.warning("the pose graph's solver replayed to another estimate; rebuilt from the saved one")
            self._resolve(take_riders=False)
        else:
            self._log, self._guesses = history, guesses

    # ------------------------------------------------------------------ building
    def __len__(self) -> int:
        return len(self._estimate)

    @property
    def solved_nodes(self) -> int:
        """How many nodes are in the solver (the others ride on them). O(n)."""
        return int(np.count_nonzero(self._rides.view()[:, 0] < 0))

    def riding_on(self, index: int) -> int:
        """The node that node ``index`` rides on, or ``index`` itself while it is in the solver. O(1)."""
        anchor = int(self._rides.row(index)[0])
        return index if anchor < 0 else anchor

    @property
    def edges(self) -> tuple[Edge, ...]:
        """The edges, in order: each as added, but those of riders carried onto their anchors and fused at
        each rebuild from scratch (:mod:`shared.slam.riders`). O(edges)."""
        return tuple(_edge_of(row) for row in self._edges.view())

    def add_node(self, guess: Pose2D) -> int:
        """A new node at ``guess`` (world frame); the first is anchored there. Returns its index."""
        index = len(self._estimate)
        self._new_values.insert(index, _pose2(guess))
        if index == 0:
            self._first = guess
            self._prior()
        self._estimate = _frozen(np.vstack([self._estimate, _row(guess)]))
        self._guesses.append(guess)
        self._rides.append((-1.0, *[0.0] * (RIDE_WIDTH - 1)))
        return index

    def ride(self, index: int, anchor: int) -> None:
        """From the next rebuild from scratch, node ``index`` leaves the solver and rides on node ``anchor``
        (the node holding its place) at their relative estimate then, if a loop closure joins the two
        directly; its edges are carried onto the anchor (:mod:`shared.slam.riders`). The first node (the
        graph's anchor) and a node already riding stay as they are. O(1)."""
        if not 0 < index < len(self._estimate) or not 0 <= anchor < len(self._estimate) or index == anchor:
            return
        self._queued.append((index, anchor))

    def _take_riders(self) -> None:
        """The queued riders out of the solver and every edge carried and fused
        (:func:`~shared.slam.riders.take_riders`). O(graph)."""
        est = self._estimate
        rides, edges = take_riders(
            self._rides.view()[: len(est)], self._queued, est, self._edges.view(), self._robust_sigmas
        )
        self._queued = []
        self._rides, self._edges = Rows.of(rides), Rows.of(edges)

    def add_edge(self, i: int, j: int, measurement: Pose2D, information: FloatArray, *, loop: bool) -> None:
        """Measurement of node ``j`` in the frame of node ``i`` with ``information`` (positive definite)
        over its coordinates ``(x, y, theta)`` in that frame (as a scan match gives it). gtsam's error of
        a between factor is taken in the measurement's own frame; the information is rotated into it."""
        info = np.asarray(information, dtype=np.float64)
        if info.shape != (3, 3) or not np.isfinite(info).all() or np.linalg.eigvalsh(info)[0] <= 0.0:
            raise OptimisationError(f"edge {i}->{j}: information {info.tolist()} is not positive definite")
        row = np.array(_edge_row(Edge(i, j, measurement, info, loop)))
        a_i, a_j = self.riding_on(i), self.riding_on(j)
        if (a_i, a_j) != (i, j):  # an end rides on another node: the edge goes to it (riders.carry)
            if a_i == a_j:
                return
            rides = self._rides.view()
            off_i = rides[i, 1:4] if a_i != i else np.zeros(3)
            off_j = rides[j, 1:4] if a_j != j else np.zeros(3)
            row = carry(row, off_i, off_j, a_i, a_j)
            if a_i > a_j:
                row = inverse_edge(row)
        self._edges.append(row.tolist())
        e = _edge_of(row)
        self._loop_pending = self._loop_pending or loop
        self._new_factors.add(
            gtsam.BetweenFactorPose2(
                e.i, e.j, _pose2(e.measurement), self._noise(_local(e.information, e.measurement), loop)
            )
        )

    def _noise(self, info: FloatArray, loop: bool) -> gtsam.noiseModel.Base:
        gaussian = gtsam.noiseModel.Gaussian.Information(info)
        if not loop:
            return gaussian
        kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(self._robust_sigmas)
        return gtsam.noiseModel.Robust.Create(kernel, gaussian)

    # ------------------------------------------------------------------ solving
    def update(self) -> None:
        """Take the new nodes and edges into the incremental solution (iSAM2), a few relinearisations
        more when a loop edge arrived; every ``RESOLVE_EVERY_UPDATES`` updates the solver is built from
        scratch at the estimate (O(graph)), which bounds the history a restore replays."""
        if self._new_factors.size() == 0 and self._new_values.size() == 0:
            return
        loops, self._loop_pending = self._loop_pending, False
        self._log.append((len(self._estimate), len(self._edges), loops))
        self._estimate = self._all_poses(self._solve(loops))
        if len(self._log) >= RESOLVE_EVERY_UPDATES:
            self._resolve()

    def optimise_batch(self, max_iterations: int = 100) -> None:
        """Re-solve the whole graph with Levenberg-Marquardt from the current estimate (offline)."""
        self.update()
        if not len(self._estimate):
            return
        graph = gtsam.NonlinearFactorGraph()
        assert self._first is not None
        anchor = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))
        graph.add(gtsam.PriorFactorPose2(0, _pose2(self._first), anchor))
        for e in map(_edge_of, self._edges.view()):
            graph.add(
                gtsam.BetweenFactorPose2(
                    e.i, e.j, _pose2(e.measurement), self._noise(_local(e.information, e.measurement), e.loop)
                )
            )
        initial = gtsam.Values()
        for k in self._solved_indices(len(self._estimate)):
            x, y, th = self._estimate[k].tolist()
            initial.insert(k, gtsam.Pose2(x, y, th))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
        except RuntimeError as exc:
            raise OptimisationError(f"batch optimisation failed: {exc}") from exc
        poses = self._all_poses(result)
        if np.isfinite(poses).all():
            self._estimate = poses
            self._resolve()

    # ------------------------------------------------------------------ reading
    def pose(self, index: int) -> Pose2D:
        """The current estimate of node ``index`` (world frame). O(1)."""
        x, y, th = self._estimate[index].tolist()
        return Pose2D(x, y, th)

    def poses(self) -> list[Pose2D]:
        """Every node's current estimate, in order. O(n)."""
        return [Pose2D(x, y, th) for x, y, th in self._estimate.tolist()]

    def pose_array(self) -> FloatArray:
        """Every node's current estimate as read-only rows ``(n, 3)`` ``[x_m, y_m, theta_rad]``; the same
        array until the estimate changes, and never changed in place (a copy-free snapshot for work off
        the step). O(1)."""
        return self._estimate

    def covariance(self, index: int) -> FloatArray:
        """The marginal covariance of node ``index`` ``(3, 3)`` over world-frame ``(x_m, y_m, theta_rad)``
        (iSAM2's, in the node's own frame, rotated into the world's). Cost: a Bayes tree marginal, small
        for recent nodes (they sit near the root). A rider's is its anchor's (its offset is held fixed)."""
        index = self.riding_on(index)
        try:
            local = np.asarray(self._isam.marginalCovariance(index), dtype=np.float64)
        except RuntimeError as exc:
            raise OptimisationError(f"no marginal covariance of node {index}: {exc}") from exc
        th = float(self._estimate[index, 2])
        c, s = math.cos(th), math.sin(th)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        out: FloatArray = rot @ local @ rot.T
        return 0.5 * (out + out.T)

    def residual_sigmas(self, edge: Edge) -> float:
        """How far the current estimate is from ``edge``'s measurement, in the edge's standard deviations
        (Mahalanobis distance; :func:`shared.slam.riders.residual_sigmas`). A loop edge far beyond
        ``robust_sigmas`` is one the kernel outvoted."""
        return residual_sigmas(np.array(_edge_row(edge)), self._estimate)
