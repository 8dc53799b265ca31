"""2D point-to-point ICP between consecutive scans (paper §6.2.2, after Besl & McKay and the 2D variant [24]).

Each iteration maps the current points with the pose estimate, pairs every one with its nearest reference
point (an exact fixed-radius search on a uniform grid built once per call on the reference,
:mod:`shared.kernels.matching._grid`; it gives the same neighbours as :class:`scipy.spatial.cKDTree` at
about a third of the cost, and the whole loop runs in one numba function), rejects pairs farther apart than
the outlier distance (the paper's threshold), and solves the rigid alignment of the surviving pairs in
closed form: with centred pairs ``p`` (current, own frame) and ``q`` (reference),
``theta = atan2(sum(p_x q_y - p_y q_x), sum(p_x q_x + p_y q_y))`` and ``t = mean(q) - R(theta) mean(p)``
(the 2D Kabsch/SVD solution). The pose is solved afresh from the original current points each time, so no
error accumulates by composing increments.

Two phases: ICP first runs with ``max_correspondence_m`` (wide enough to pull in a start that is a few
degrees off) until the change of the pose falls below ten times ``tolerance_m`` and ``tolerance_rad``;
then, if ``refine_correspondence_m`` is smaller, it goes on with that tighter outlier distance until the
change falls below the tolerances themselves (``converged``). The second phase keeps outlier returns near
walls from biasing the result. ``max_iterations`` bounds both phases together; with
``refine_correspondence_m >= max_correspondence_m`` there is one phase with the plain tolerances.

Conventions and edge cases:

* ``pose`` maps current points into the reference frame: ``reference ~ pose.transform_points(current)``;
  ``initial`` (the odometry prediction, default identity) is the first estimate.
* Non-finite rows of either input are ignored. At most ``max_points`` current points are used, taken at an
  even stride over the (finite) rows in input order, which keeps a scan's angular coverage.
* ``rmse_m`` is the root mean square distance of the inlier pairs under the returned pose;
  ``inlier_ratio`` is the share of the used current points that had an inlier pair in the last iteration
  (within the outlier distance of the last phase).
* Fewer than 3 usable pairs (too few finite points, or no reference point within reach) at any iteration:
  the match failed; ``initial`` is returned unchanged with ``converged=False``, ``rmse_m=inf`` and
  ``inlier_ratio=0``.
* Not converged within ``max_iterations``: the last estimate is returned with ``converged=False``.

Complexity: O(M + cells) for the grid, then O(K N') for K iterations over N' = min(N, max_points) points
(each query visits a few cells).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.kernels.base import ScanMatchingKernel
from shared.kernels.matching._grid import _MAX_CELLS_PER_AXIS, _grid_build, _grid_nearest
from shared.kernels.matching._solve import _point_align
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Match
from shared.types import FloatArray, IntArray, Pose2D, as_points

__all__ = ["Icp", "IcpParams"]

#: grid cell side of the nearest-neighbour search relative to the correspondence radius (speed only)
_CELL_PER_RADIUS = 0.25
#: the first (wide) phase stops at this multiple of the tolerances; the second phase does the fine work
_COARSE_TOLERANCE = 10.0


class IcpParams(KernelParams):
    """Parameters of :class:`Icp`."""

    max_iterations: int = param(
        50, description="Most ICP iterations (both phases) before giving up", ge=1, le=1000, paper="§6.2.2"
    )
    max_correspondence_m: float = param(
        0.3,
        description="Pairs farther apart than this are outliers and take no part in the alignment",
        unit="m",
        gt=0.0,
        le=10.0,
        paper="§6.2.2",
    )
    refine_correspondence_m: float = param(
        0.1,
        description="Once converged with max_correspondence_m, ICP goes on with this tighter outlier "
        "distance until it converges again (no second phase when >= max_correspondence_m)",
        unit="m",
        gt=0.0,
        le=10.0,
    )
    tolerance_m: float = param(
        3e-4, description="Converged when the translation update is below this", unit="m", gt=0.0, le=1.0
    )
    tolerance_rad: float = param(
        3e-4, description="Converged when the rotation update is below this", unit="rad", gt=0.0, le=1.0
    )
    max_points: int = param(
        300,
        description="Most current-scan points used (even stride over the scan); bounds the time per step",
        ge=3,
        le=1_000_000,
    )


@njit
def _align(current: FloatArray, reference: FloatArray, nearest: IntArray) -> tuple[float, float, float, int]:
    """Closed-form rigid alignment of pairs ``current[i] -> reference[nearest[i]]`` for ``nearest[i] >= 0``.

    Returns ``(theta, tx, ty, pairs)``; with fewer than 3 pairs the transform is meaningless (all zeros).
    """
    n = 0
    for i in range(current.shape[0]):
        if nearest[i] >= 0:
            n += 1
    if n < 3:
        return 0.0, 0.0, 0.0, n
    tx, ty, theta = _point_align(current, reference, nearest, np.zeros(current.shape[0]), np.inf)
    return theta, tx, ty, n


@njit
def _sse(
    current: FloatArray, reference: FloatArray, nearest: IntArray, c: float, s: float, tx: float, ty: float
) -> float:
    """Sum of squared distances of the pairs ``nearest[i] >= 0`` under the transform ``(c, s, tx, ty)``."""
    total = 0.0
    for i in range(current.shape[0]):
        j = nearest[i]
        if j >= 0:
            dx = c * current[i, 0] - s * current[i, 1] + tx - reference[j, 0]
            dy = s * current[i, 0] + c * current[i, 1] + ty - reference[j, 1]
            total += dx * dx + dy * dy
    return total


@njit
def _icp(
    reference: FloatArray,
    current: FloatArray,
    x: float,
    y: float,
    theta: float,
    max_d: float,
    fine_d: float,
    tol_m: float,
    tol_rad: float,
    max_iter: int,
    cell_m: float,
    coarse: float,
) -> tuple[float, float, float, int, bool, int, float]:
    """The ICP loop, first with outlier distance ``max_d``, then ``fine_d`` if smaller.

    Returns ``(x, y, theta, n_iter, converged, pairs, sse)``; ``pairs < 3`` means failure.
    """
    sorted_xy, order, start, x0, y0, h, nx, ny = _grid_build(reference, cell_m, _MAX_CELLS_PER_AXIS)
    n = current.shape[0]
    nearest = np.empty(n, dtype=np.intp)
    converged = False
    pairs = 0
    it = 0
    while it < max_iter:
        it += 1
        c = math.cos(theta)
        s = math.sin(theta)
        for i in range(n):
            px = current[i, 0]
            py = current[i, 1]
            j, _ = _grid_nearest(
                sorted_xy, order, start, x0, y0, h, nx, ny, c * px - s * py + x, s * px + c * py + y, max_d
            )
            nearest[i] = j
        new_theta, new_x, new_y, pairs = _align(current, reference, nearest)
        if pairs < 3:
            return x, y, theta, it, False, pairs, math.inf
        step_rad = abs((new_theta - theta + math.pi) % (2.0 * math.pi) - math.pi)
        step_m = math.hypot(new_x - x, new_y - y)
        x = new_x
        y = new_y
        theta = new_theta
        if fine_d < max_d:
            if step_m < coarse * tol_m and step_rad < coarse * tol_rad:
                max_d = fine_d  # converged coarsely: go on with the tighter outlier distance
        elif step_m < tol_m and step_rad < tol_rad:
            converged = True
            break
    sse = _sse(current, reference, nearest, math.cos(theta), math.sin(theta), x, y)
    return x, y, theta, it, converged, pairs, sse


def _finite(points: ArrayLike, name: str) -> FloatArray:
    pts = as_points(points, name=name)
    keep = np.isfinite(pts).all(axis=1)
    return pts if keep.all() else np.ascontiguousarray(pts[keep])


@register
class Icp(ScanMatchingKernel[IcpParams]):
    """2D point-to-point ICP with exact nearest neighbours and distance outlier rejection (paper §6.2.2)."""

    name = "icp"
    version = "1.0.0"
    Params = IcpParams

    def apply(self, reference: ArrayLike, current: ArrayLike, initial: Pose2D | None = None) -> Match:
        """Pose mapping ``current`` ``(N, 2)`` onto ``reference`` ``(M, 2)`` (metres), from ``initial``."""
        p = self.params
        start = Pose2D() if initial is None else initial
        failed = Match(pose=start, rmse_m=math.inf, inlier_ratio=0.0, n_iter=0, converged=False)
        ref = _finite(reference, "reference")
        cur = _finite(current, "current")
        if ref.shape[0] < 3 or cur.shape[0] < 3:
            return failed
        if cur.shape[0] > p.max_points:
            cur = np.ascontiguousarray(cur[(np.arange(p.max_points) * cur.shape[0]) // p.max_points])
        x, y, theta, n_iter, converged, pairs, sse = _icp(
            ref,
            cur,
            start.x_m,
            start.y_m,
            start.theta_rad,
            p.max_correspondence_m,
            p.refine_correspondence_m,
            p.tolerance_m,
            p.tolerance_rad,
            p.max_iterations,
            p.max_correspondence_m * _CELL_PER_RADIUS,
            _COARSE_TOLERANCE,
        )
        if pairs < 3:
            return Match(pose=start, rmse_m=math.inf, inlier_ratio=0.0, n_iter=n_iter, converged=False)
        return Match(
            pose=Pose2D(x, y, theta),
            rmse_m=math.sqrt(sse / pairs),
            inlier_ratio=pairs / cur.shape[0],
            n_iter=n_iter,
            converged=converged,
        )
