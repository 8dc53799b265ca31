"""One straight line per segment by clustering in the Hough domain (paper §4, Algorithm 2, eq. 35).

For each group S^n separately:

1. every point votes into the ``(rho, theta)`` accumulator (eq. 34; layout in
   :mod:`shared.kernels.lines._common`: theta over ``[0, pi)``, rho relative to the group's centroid);
2. the highest vote ``T`` is found (its first cell in row-major order is the *peak cell*);
3. every cell with ``votes >= max(T - delta, min_votes)`` is taken (eq. 35);
4. those cells are clustered into one cluster, i.e. their unweighted centroid (k-means with one line per
   segment, as in Fig. 15 where a 6-vote and a 5-vote cell average to the midpoint);
5. the inverse transform of the centroid is the line; its segment is the span of the group's points within
   ``span_factor x rho_resolution_m`` of it, and ``support`` counts them.

The seam: ``(rho, theta)`` and ``(-rho, theta + pi)`` are the same line, so a cell more than 90 deg from
the peak cell is first moved to the representation continuous with the peak (``theta -+ pi``,
``-rho``). Without this, a near-vertical wall whose cells sit at 1 deg and 179 deg would average to a line
at 90 deg, perpendicular to the wall.

A group gets no line when it has fewer than ``min_points`` points, when ``T < min_votes``, or when no
point lies within the span tolerance of the averaged line. The paper's step 4 assumes one wall per
segment: a group holding two walls of similar length (an unsplit corner) averages into a line between them.

Complexity: O(n x n_theta) voting plus O(G x cells) scanning; all groups run in one numba call.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.kernels.base import StraightLineKernel
from shared.kernels.lines._common import (
    _accumulator_setup,
    _clear,
    _peak,
    _vote,
    build_lines,
    group_points,
    theta_grid,
)
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Lines
from shared.types import BoolArray, FloatArray, IntArray

__all__ = ["HoughCluster", "HoughClusterParams"]


class HoughClusterParams(KernelParams):
    """Parameters of :class:`HoughCluster`; the defaults suit raw URG-04LX points in segments."""

    theta_resolution_deg: float = param(
        1.0,
        description="Accumulator theta cell size over [0, 180) deg",
        unit="deg",
        ge=0.05,
        le=10.0,
        paper="§4 Algorithm 2",
    )
    rho_resolution_m: float = param(
        0.02,
        description="Accumulator rho cell size",
        unit="m",
        ge=0.001,
        le=1.0,
        paper="§4 Algorithm 2",
    )
    delta: int = param(
        1,
        description="Cells with at least (highest vote - delta) votes are clustered",
        ge=0,
        le=2,
        paper="§4 eq. 35",
    )
    min_votes: int = param(
        2,
        description="Clustered cells need at least this many votes (a 1-vote cell fits any line through "
        "one point)",
        ge=1,
        le=100_000,
    )
    min_points: int = param(
        2,
        description="Groups with fewer points give no line",
        ge=2,
        le=100_000,
    )
    span_factor: float = param(
        3.0,
        description="Points within span_factor x rho_resolution_m of the line define its segment",
        ge=0.5,
        le=100.0,
    )


@njit
def _cluster_lines(
    pts: FloatArray,
    starts: IntArray,
    cos_t: FloatArray,
    sin_t: FloatArray,
    res: float,
    delta: int,
    min_votes: int,
    min_points: int,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """``(rho, theta, found)`` per group: the inverse transform of the centroid of the top cells."""
    n_groups = starts.shape[0] - 1
    n_theta = cos_t.shape[0]
    step = math.pi / n_theta
    inv_res = 1.0 / res
    rho = np.zeros(n_groups)
    theta = np.zeros(n_groups)
    found = np.zeros(n_groups, dtype=np.bool_)
    cx, cy, half, active, acc, rows = _accumulator_setup(pts, starts, n_theta, inv_res, min_points)
    for g in range(n_groups):
        if not active[g]:
            continue
        h = half[g]
        _vote(pts, np.arange(starts[g], starts[g + 1]), cx[g], cy[g], h, cos_t, sin_t, inv_res, acc, rows)
        kp, _, top = _peak(acc, rows)
        if top >= min_votes:
            threshold = max(top - delta, min_votes)
            theta_peak = kp * step
            sum_t = 0.0
            sum_r = 0.0
            count = 0
            for k in range(n_theta):
                if rows[k, 0] < threshold:
                    continue
                th = k * step
                sign = 1.0
                if th - theta_peak > 0.5 * math.pi:  # across the seam: (rho, th) == (-rho, th - pi)
                    th -= math.pi
                    sign = -1.0
                elif theta_peak - th > 0.5 * math.pi:
                    th += math.pi
                    sign = -1.0
                for j in range(rows[k, 1], rows[k, 2] + 1):
                    if acc[k, j] >= threshold:
                        sum_t += th
                        sum_r += sign * (j - h) * res
                        count += 1
            t_mean = sum_t / count
            theta[g] = t_mean
            rho[g] = sum_r / count + cx[g] * math.cos(t_mean) + cy[g] * math.sin(t_mean)
            found[g] = True
        _clear(acc, rows)
    return rho, theta, found


@register
class HoughCluster(StraightLineKernel[HoughClusterParams]):
    """Clustering in the Hough domain (paper §4, Algorithm 2): one averaged top-cell line per segment."""

    name = "hough-cluster"
    version = "1.0.0"
    Params = HoughClusterParams

    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        """At most one line per group of ``points`` ``(N, 2)`` (metres), ascending group label.

        Negative groups and non-finite rows are ignored.
        """
        p = self.params
        grouped = group_points(points, groups)
        cos_t, sin_t = theta_grid(p.theta_resolution_deg)
        rho, theta, found = _cluster_lines(
            grouped.points,
            grouped.starts,
            cos_t,
            sin_t,
            p.rho_resolution_m,
            p.delta,
            p.min_votes,
            p.min_points,
        )
        line_of_group = np.cumsum(found) - 1
        point_idx = np.flatnonzero(found[grouped.group_index])
        line_idx = line_of_group[grouped.group_index[point_idx]]
        line_group = np.flatnonzero(found)
        return build_lines(
            grouped,
            point_idx,
            line_idx,
            rho[found],
            theta[found],
            line_group,
            tolerance_m=p.span_factor * p.rho_resolution_m,
        )
