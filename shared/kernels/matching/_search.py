"""Correlative coarse pose search (after Olson 2009, "Real-time correlative scan matching"), in numba.

ICP only finds the local minimum nearest its start; when the odometry prediction is off by more than a few
degrees (fast turns, wheel slip, a stalled or lagging odometry stream) it converges to a wrong pose or not
at all. This search scores every pose of a grid around the prediction, rotations ``theta0 + k dtheta`` for
``|k dtheta| <= rot_half_rad`` and translations in steps of one cell for ``|dx|, |dy| <= xy_half_m``,
against a look-up table of the reference scan: each cell holds ``max(0, 1 - (d / radius_m)^2)`` for the
distance ``d`` from its centre to the nearest reference point (0 beyond ``radius_m``). A pose's score is the
mean table value of the current points it maps (points off the table score 0), in ``[0, 1]``; the best
pose is a start for ICP, not a result: it is only as fine as the cell and the angular step.

Complexity: O(M (radius / cell)^2) to fill the table, O(R T N) to search R rotations, T translations and N
current points (each a table look-up); the table covers the reference's bounding box plus the translation
window, at most ``_MAX_CELLS`` cells per axis (farther reference points are left out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.types import FloatArray, Pose2D, as_points

__all__ = ["CoarseMatch", "correlative_search"]

_MAX_CELLS = 600


@dataclass(frozen=True, slots=True)
class CoarseMatch:
    """The best pose of the search grid and its score (mean look-up value of the current points, 0..1)."""

    pose: Pose2D
    score: float


@njit
def _table(ref: FloatArray, x0: float, y0: float, cell: float, nx: int, ny: int, radius: float) -> FloatArray:
    """The look-up table: ``1 - (d / radius)^2`` clipped at 0 for the distance d to the nearest point."""
    table = np.zeros((nx, ny))
    reach = math.ceil(radius / cell)
    r2 = radius * radius
    for i in range(ref.shape[0]):
        cx = int((ref[i, 0] - x0) / cell)
        cy = int((ref[i, 1] - y0) / cell)
        for a in range(max(cx - reach, 0), min(cx + reach + 1, nx)):
            dx = x0 + (a + 0.5) * cell - ref[i, 0]
            for b in range(max(cy - reach, 0), min(cy + reach + 1, ny)):
                dy = y0 + (b + 0.5) * cell - ref[i, 1]
                v = 1.0 - (dx * dx + dy * dy) / r2
                if v > table[a, b]:
                    table[a, b] = v
    return table


@njit
def _search(
    table: FloatArray,
    x0: float,
    y0: float,
    cell: float,
    cur: FloatArray,
    x: float,
    y: float,
    theta: float,
    n_rot: int,
    rot_step: float,
    n_xy: int,
) -> tuple[float, float, float, float]:
    """Best ``(x, y, theta, score)`` over ``2 n_rot + 1`` rotations and ``(2 n_xy + 1)^2`` cell shifts."""
    nx, ny = table.shape
    n = cur.shape[0]
    cx = np.empty(n, dtype=np.int64)
    cy = np.empty(n, dtype=np.int64)
    side = 2 * n_xy + 1
    sums = np.empty(side * side)
    best = (x, y, theta, -1.0)
    best_rank = -1.0
    for k in range(-n_rot, n_rot + 1):
        th = theta + k * rot_step
        c = math.cos(th)
        s = math.sin(th)
        for i in range(n):
            cx[i] = math.floor((c * cur[i, 0] - s * cur[i, 1] + x - x0) / cell)
            cy[i] = math.floor((s * cur[i, 0] + c * cur[i, 1] + y - y0) / cell)
        sums[:] = 0.0
        for i in range(n):
            for a in range(side):
                u = cx[i] + a - n_xy
                if u < 0 or u >= nx:
                    continue
                for b in range(side):
                    v = cy[i] + b - n_xy
                    if 0 <= v < ny:
                        sums[a * side + b] += table[u, v]
        for a in range(side):
            for b in range(side):
                score = sums[a * side + b] / n
                # ties (flat corridors) go to the shift and rotation nearest the prediction
                rank = score - 1e-6 * (abs(k) + abs(a - n_xy) + abs(b - n_xy))
                if rank > best_rank:
                    best_rank = rank
                    best = (x + (a - n_xy) * cell, y + (b - n_xy) * cell, th, score)
    return best


def correlative_search(
    reference: ArrayLike,
    current: ArrayLike,
    initial: Pose2D,
    *,
    rot_half_rad: float = 0.35,
    rot_step_rad: float = 0.0175,
    xy_half_m: float = 0.2,
    cell_m: float = 0.05,
    radius_m: float = 0.15,
    max_points: int = 200,
) -> CoarseMatch:
    """Best pose mapping ``current`` ``(N, 2)`` onto ``reference`` ``(M, 2)`` (metres) on a grid around
    ``initial`` (module docstring). Non-finite rows are ignored; at most ``max_points`` current points are
    used (even stride). With no usable points the score is 0 and ``initial`` is returned."""
    ref = as_points(reference, name="reference")
    cur = as_points(current, name="current")
    ref = ref[np.isfinite(ref).all(axis=1)]
    cur = cur[np.isfinite(cur).all(axis=1)]
    if len(ref) == 0 or len(cur) == 0:
        return CoarseMatch(initial, 0.0)
    if len(cur) > max_points:
        cur = cur[(np.arange(max_points) * len(cur)) // max_points]
    margin = xy_half_m + radius_m + cell_m
    lo = ref.min(axis=0) - margin
    hi = ref.max(axis=0) + margin
    centre = np.array([initial.x_m, initial.y_m])
    half = 0.5 * _MAX_CELLS * cell_m  # keep the table bounded: clip it to a box around the prediction
    lo = np.maximum(lo, centre - half)
    hi = np.minimum(hi, centre + half)
    nx, ny = (int(v) for v in np.maximum(np.ceil((hi - lo) / cell_m), 1))
    table = _table(np.ascontiguousarray(ref), float(lo[0]), float(lo[1]), cell_m, nx, ny, radius_m)
    x, y, th, score = _search(
        table,
        float(lo[0]),
        float(lo[1]),
        cell_m,
        np.ascontiguousarray(cur),
        initial.x_m,
        initial.y_m,
        initial.theta_rad,
        int(rot_half_rad / rot_step_rad),
        rot_step_rad,
        round(xy_half_m / cell_m),
    )
    return CoarseMatch(Pose2D(x, y, th), max(score, 0.0))
