"""Every node's pose from the solver's: the nodes in the solver as solved, the riders composed from their
anchors (:mod:`shared.slam.riders`), in time that grows slowly with the riders.

After each update the pose graph needs every node's pose; on a long patrol nearly all of them ride
(a day's 70,000 keyframes on ~160 in the solver). Composing them afresh each time took ~7 ms at 70,000
(gathering each rider's anchor pose and offset from the whole table, a cosine and a sine per rider, and a
Python-level wrap of the headings past +-pi). :class:`RiderPoses` keeps a *plan* made once per rider table
(which nodes are solved, which ride, each rider's anchor as a position among the solved ones, the offsets
as contiguous columns), extended in O(new nodes) when nodes are added to the solver, and composes with
one cosine and sine per solved node, gathers from the small solved arrays and one scatter: ~4x less.
The result is the same, bit for bit, as composing each rider on its own
(``tests/shared/slam/test_ridepose.py``, against the straightforward composition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.slam.riders import remainder_tau
from shared.slam.rows import Rows
from shared.types import FloatArray, IntArray

__all__ = ["RiderPoses", "compose_reference"]


@dataclass(frozen=True, slots=True)
class _Plan:
    rows: Rows  # the rider table the plan was made from (held: its identity is the plan's key)
    n: int  # nodes covered
    solved: IntArray  # nodes in the solver, ascending (the solver's key order)
    riders: IntArray  # riding nodes, ascending
    at: IntArray  # each rider's anchor as a position in ``solved``
    off: FloatArray  # (3, riders) the offsets x, y, theta, one contiguous row each


class RiderPoses:
    """The composition of :func:`compose_reference`, with its plan kept across calls (module docstring).
    Not thread-safe: one per pose graph, used under the graph's own discipline."""

    __slots__ = ("_plan",)

    def __init__(self) -> None:
        self._plan: _Plan | None = None

    def compose(self, solved_poses: FloatArray, rows: Rows, n: int) -> FloatArray:
        """Rows ``(n, 3)`` ``[x_m, y_m, theta_rad]`` of nodes ``0..n-1``, headings in (-pi, pi]:
        ``solved_poses`` ``(k, 3)`` are the nodes in the solver in index order, the others composed from
        ``rows`` (the rider table, :data:`~shared.slam.riders.RIDE_WIDTH` wide, at least ``n`` rows).
        Raises ``ValueError`` when ``solved_poses`` does not hold one pose per solved node.
        O(n) numpy, O(k) trigonometry; the plan O(n) when the table was replaced."""
        plan = self._plan_for(rows, n)
        if len(solved_poses) != len(plan.solved):
            raise ValueError(f"{len(solved_poses)} poses for {len(plan.solved)} nodes in the solver")
        cols = np.empty((3, n))  # x, y, theta: column by column, contiguous, then one transposing copy
        cols[:, plan.solved] = solved_poses.T
        if len(plan.riders):
            x, y, theta = (np.ascontiguousarray(v) for v in solved_poses.T)
            at = plan.at
            c, s = np.cos(theta).take(at), np.sin(theta).take(at)
            ox, oy, ot = plan.off
            cols[0, plan.riders] = x.take(at) + c * ox - s * oy
            cols[1, plan.riders] = y.take(at) + s * ox + c * oy
            cols[2, plan.riders] = theta.take(at) + ot
        _wrap_headings(cols[2])
        return np.ascontiguousarray(cols.T)

    def _plan_for(self, rows: Rows, n: int) -> _Plan:
        plan = self._plan
        if plan is not None and plan.rows is rows and plan.n <= n:
            if plan.n == n:
                return plan
            new = rows.view()[plan.n : n, 0]
            if bool((new < 0).all()):  # nodes added to the solver since: append them, nothing else moves
                grown = np.concatenate([plan.solved, np.arange(plan.n, n, dtype=np.intp)])
                plan = _Plan(rows, n, grown, plan.riders, plan.at, plan.off)
                self._plan = plan
                return plan
        self._plan = plan = _make_plan(rows, n)
        return plan


def _make_plan(rows: Rows, n: int) -> _Plan:
    table = rows.view()[:n]
    anchor = table[:, 0].astype(np.intp)
    solved = np.flatnonzero(anchor < 0)
    riders = np.flatnonzero(anchor >= 0)
    at = np.searchsorted(solved, anchor[riders])
    if len(riders) and (
        not len(solved)
        or (at >= len(solved)).any()
        or (solved[np.minimum(at, len(solved) - 1)] != anchor[riders]).any()
    ):
        raise ValueError("a node rides on a node that is not in the solver")
    off = np.ascontiguousarray(table[riders, 1:4].T)
    return _Plan(rows, n, solved, riders, at.astype(np.intp), off)


def _wrap_headings(theta: FloatArray) -> None:
    """Headings wrapped to (-pi, pi] in place, as :func:`shared.types.wrap_angle` does, bit for bit: the
    IEEE remainder by 2 pi (:func:`~shared.slam.riders.remainder_tau`), -pi made pi. O(n)."""
    remainder_tau(theta)
    theta[theta == -math.pi] = math.pi


def compose_reference(solved_poses: FloatArray, table: FloatArray) -> FloatArray:
    """The straightforward composition (the reference :class:`RiderPoses` is tested against): each rider
    of ``table`` ``(n, RIDE_WIDTH)`` from its anchor's pose, each heading wrapped on its own. O(n)."""
    anchor = table[:, 0].astype(np.intp)
    out = np.empty((len(table), 3))
    out[np.flatnonzero(anchor < 0)] = solved_poses
    riders = np.flatnonzero(anchor >= 0)
    if len(riders):
        base, off = out[anchor[riders]], table[riders, 1:4]
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        out[riders, 0] = base[:, 0] + c * off[:, 0] - s * off[:, 1]
        out[riders, 1] = base[:, 1] + s * off[:, 0] + c * off[:, 1]
        out[riders, 2] = base[:, 2] + off[:, 2]
    th = out[:, 2]
    for i in np.flatnonzero((th <= -math.pi) | (th > math.pi)).tolist():
        wrapped = math.remainder(float(th[i]), 2 * math.pi)
        th[i] = math.pi if wrapped == -math.pi else wrapped
    return out
