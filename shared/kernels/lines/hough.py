"""Straight lines by the Hough transform of the points, peak after peak (paper §3.4.2, Algorithm 1).

Within each group (segment S^n; for centroids, the segment of each centroid):

1. every remaining point votes into the ``(rho, theta)`` accumulator (eq. 34; layout in
   :mod:`shared.kernels.lines._common`: theta over ``[0, pi)``, rho relative to the group's centroid);
2. the highest cell is found (ties: the first in row-major order, i.e. smallest theta, then smallest rho
   relative to the group centroid);
   if it has fewer than ``min_votes`` votes the group is done;
3. its inverse transform (the cell centre) is a line through the largest number of points;
4. the points within ``rho_resolution_m`` of that line (always including the cell's voters) are its
   inliers and are removed; the segment is the line's span over them.

Steps 1-4 repeat while at least ``min_points`` points remain, up to ``max_lines_per_group`` lines, because
the paper's maps have several lines per segment (Fig. 22e). The reported line is the cell centre, so it is
exact to within half a cell: ``theta_resolution_deg / 2`` and ``rho_resolution_m / 2``.

Complexity: O(lines x n_g x n_theta) voting per group plus O(lines x cells); the whole loop is one numba
call.
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
    _rho_cell,
    _vote,
    build_lines,
    group_points,
    theta_grid,
)
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Lines
from shared.types import FloatArray, IntArray

__all__ = ["Hough", "HoughParams"]


class HoughParams(KernelParams):
    """Parameters of :class:`Hough`; the defaults suit cluster centroids (a line needs two of them)."""

    theta_resolution_deg: float = param(
        1.0,
        description="Accumulator theta cell size over [0, 180) deg",
        unit="deg",
        ge=0.05,
        le=10.0,
        paper="§3.4.2 Algorithm 1",
    )
    rho_resolution_m: float = param(
        0.02,
        description="Accumulator rho cell size; also the inlier distance of a found line",
        unit="m",
        ge=0.001,
        le=1.0,
        paper="§3.4.2 Algorithm 1",
    )
    min_points: int = param(
        2,
        description="Look for another line in a group while at least this many points remain",
        ge=2,
        le=100_000,
    )
    min_votes: int = param(
        2,
        description="A peak needs at least this many votes to become a line",
        ge=1,
        le=100_000,
    )
    max_lines_per_group: int = param(
        10,
        description="At most this many lines per group",
        ge=1,
        le=1000,
    )


@njit
def _hough_lines(
    pts: FloatArray,
    starts: IntArray,
    cos_t: FloatArray,
    sin_t: FloatArray,
    res: float,
    min_points: int,
    min_votes: int,
    max_lines: int,
) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
    """Lines ``(rho, theta, group)`` of every group and the line each point was removed by (-1: none)."""
    n = pts.shape[0]
    n_theta = cos_t.shape[0]
    step = math.pi / n_theta
    inv_res = 1.0 / res
    rho = np.empty(n)
    theta = np.empty(n)
    line_group = np.empty(n, dtype=np.intp)
    line_of = np.full(n, -1, dtype=np.intp)
    n_lines = 0
    cx, cy, half, active, acc, rows = _accumulator_setup(pts, starts, n_theta, inv_res, min_points)
    for g in range(starts.shape[0] - 1):
        if not active[g]:
            continue
        members = np.arange(starts[g], starts[g + 1])
        n_left = members.shape[0]
        for _ in range(max_lines):
            if n_left < min_points:
                break
            _vote(pts, members[:n_left], cx[g], cy[g], half[g], cos_t, sin_t, inv_res, acc, rows)
            kp, jp, votes = _peak(acc, rows)
            _clear(acc, rows)
            if votes < min_votes:
                break
            c = cos_t[kp]
            sn = sin_t[kp]
            r_rel = (jp - half[g]) * res
            keep = 0
            for q in range(n_left):
                m = members[q]
                dx = pts[m, 0] - cx[g]
                dy = pts[m, 1] - cy[g]
                voter = _rho_cell(dx, dy, c * inv_res, sn * inv_res, half[g] + 0.5) == jp
                if voter or abs(dx * c + dy * sn - r_rel) <= res:
                    line_of[m] = n_lines
                else:
                    members[keep] = m
                    keep += 1
            n_left = keep
            rho[n_lines] = r_rel + cx[g] * c + cy[g] * sn
            theta[n_lines] = kp * step
            line_group[n_lines] = g
            n_lines += 1
    return rho[:n_lines], theta[:n_lines], line_group[:n_lines], line_of


@register
class Hough(StraightLineKernel[HoughParams]):
    """Hough transform lines (paper §3.4.2, Algorithm 1): peak, inverse transform, remove inliers, repeat."""

    consumes = "centroids"

    name = "hough"
    version = "1.0.0"
    Params = HoughParams

    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        """Lines of ``points`` ``(N, 2)`` (metres) per group; negative groups and non-finite rows ignored.

        Lines come group by group (ascending label), in the order they were found; ``support`` is the
        number of inliers each removed.
        """
        p = self.params
        grouped = group_points(points, groups)
        cos_t, sin_t = theta_grid(p.theta_resolution_deg)
        rho, theta, line_group, line_of = _hough_lines(
            grouped.points,
            grouped.starts,
            cos_t,
            sin_t,
            p.rho_resolution_m,
            p.min_points,
            p.min_votes,
            p.max_lines_per_group,
        )
        point_idx = np.flatnonzero(line_of >= 0)
        return build_lines(grouped, point_idx, line_of[point_idx], rho, theta, line_group)
