"""Total-least-squares lines by singular value decomposition (paper §3.4.1, eq. 27-32).

For each group the points (or centroids) ``c_1..c_n`` minus their mean form the matrix ``A`` (eq. 27).
``A = U S V^T`` (eq. 28-31); setting the smaller singular value to zero gives the rank-1 reconstruction
``A_new = U S_new V^T = A v_1 v_1^T`` (eq. 32), the points projected on the regression line through the
mean with direction ``v_1``. The line's normal is ``v_2``, so ``theta = atan2(v_2)`` and
``rho = mean . v_2``; the segment spans the projections (the extreme rows of ``A_new``).

As the paper notes, ``V`` holds the eigenvectors of ``A^T A``: the kernel takes the SVD of every group's
2 x 2 scatter matrix ``A^T A = V S^2 V^T`` in one batched ``numpy.linalg.svd`` call, so the cost does
not grow with the number of groups' Python overhead. The scatter is summed from mean-centred points
(two passes), so it stays accurate far from the origin.

Groups with fewer than ``min_points`` points, or whose points all coincide, give no line.
Complexity: O(N + G).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels.base import StraightLineKernel
from shared.kernels.lines._common import build_lines, empty_lines, group_points
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Lines

__all__ = ["Svd", "SvdParams"]


class SvdParams(KernelParams):
    """Parameters of :class:`Svd`."""

    min_points: int = param(
        2,
        description="Groups with fewer points give no line",
        ge=2,
        le=100_000,
        paper="§3.4.1",
    )


@register
class Svd(StraightLineKernel[SvdParams]):
    """SVD regression line per group (paper §3.4.1, eq. 27-32): total least squares, rank-1 reconstruction."""

    consumes = "centroids"

    name = "svd"
    version = "1.0.0"
    Params = SvdParams

    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        """One line per group of ``points`` ``(N, 2)`` (metres), ascending group label; ``support`` is the
        group's point count. Negative groups and non-finite rows are ignored."""
        grouped = group_points(points, groups)
        counts = grouped.counts
        found = counts >= self.params.min_points
        if not found.any():
            return empty_lines()
        pts, gi, first = grouped.points, grouped.group_index, grouped.starts[:-1]
        mean = np.add.reduceat(pts, first, axis=0) / counts[:, None]
        a = pts - mean[gi]
        scatter = np.empty((counts.size, 2, 2))
        scatter[:, 0, 0] = np.add.reduceat(a[:, 0] * a[:, 0], first)
        scatter[:, 1, 1] = np.add.reduceat(a[:, 1] * a[:, 1], first)
        scatter[:, 0, 1] = scatter[:, 1, 0] = np.add.reduceat(a[:, 0] * a[:, 1], first)
        _, _, vt = np.linalg.svd(scatter[found])
        normal = vt[:, 1, :]  # right singular vector of the smallest singular value
        theta = np.arctan2(normal[:, 1], normal[:, 0])
        rho = np.einsum("ij,ij->i", mean[found], normal)
        line_of_group = np.cumsum(found) - 1
        point_idx = np.flatnonzero(found[gi])
        line_idx = line_of_group[gi[point_idx]]
        return build_lines(grouped, point_idx, line_idx, rho, theta, np.flatnonzero(found))
