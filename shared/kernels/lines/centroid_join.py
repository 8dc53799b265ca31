"""Map lines by joining consecutive centroids (CJ; paper §3.3-§3.4, "joining the centroids", Fig. 22d).

Within each group the points (cluster centroids, in scan order) are joined into a polyline: each pair of
consecutive points becomes one segment, unless they are farther apart than ``max_gap_m`` (a door or an
unseen stretch lies between them) or coincide. A group with one point gives no line. Each segment's Hesse
form comes from its end points (:func:`shared.types.hesse_from_endpoints`); ``support`` is 2.

Complexity: O(N), vectorised.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels.base import StraightLineKernel
from shared.kernels.lines._common import MIN_LENGTH_M, build_lines, group_points
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Lines
from shared.types import hesse_from_endpoints

__all__ = ["CentroidJoin", "CentroidJoinParams"]


class CentroidJoinParams(KernelParams):
    """Parameters of :class:`CentroidJoin`."""

    max_gap_m: float = param(
        3.0,
        description="Consecutive points farther apart than this are not joined",
        unit="m",
        gt=0.0,
        le=1000.0,
        paper="§3.4",
    )


@register
class CentroidJoin(StraightLineKernel[CentroidJoinParams]):
    """Centroid joining (CJ, paper §3.4): a polyline through each group's points in scan order."""

    consumes = "centroids"

    name = "centroid-join"
    version = "1.0.0"
    Params = CentroidJoinParams

    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        """Segments between consecutive points of each group of ``points`` ``(N, 2)`` (metres).

        Lines come by ascending group label, then in scan order. Negative groups and non-finite rows are
        ignored (a dropped row does not break the polyline: its neighbours are joined).
        """
        grouped = group_points(points, groups)
        pts, gi = grouped.points, grouped.group_index
        gap = np.hypot(*(pts[1:] - pts[:-1]).T)
        first = np.flatnonzero((gi[1:] == gi[:-1]) & (gap <= self.params.max_gap_m) & (gap > MIN_LENGTH_M))
        segments = np.concatenate([pts[first], pts[first + 1]], axis=1)
        rho, theta = hesse_from_endpoints(segments)
        point_idx = np.stack([first, first + 1], axis=1).ravel()
        line_idx = np.repeat(np.arange(first.size), 2)
        return build_lines(grouped, point_idx, line_idx, rho, theta, gi[first])
