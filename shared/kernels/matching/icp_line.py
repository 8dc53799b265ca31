"""2D point-to-line ICP between consecutive scans (paper §6.2.2, after Censi's PLICP, ICRA 2008).

Point-to-point ICP (:mod:`shared.kernels.matching.icp`) pulls each current point onto a reference *point*,
so the beam spacing of the reference becomes a bias; point-to-line ICP instead minimises the distance of
each current point to the reference surface through its nearest reference point. It converges in a few
Gauss-Newton steps and stays accurate on sparse far walls.

1. Reference lines (:mod:`shared.kernels.matching._local_lines`): every reference point gets the
   total-least-squares line of its scan-order neighbours on the same surface (ABD breakpoint test, within
   ``normal_radius_m`` but always the first neighbour on each side); corners use a one-sided fit;
   isolated points and poor fits get no line.
2. Each iteration maps the current points with the estimate, pairs each one with its exact nearest
   reference point within ``max_correspondence_m`` (the compiled grid of
   :mod:`shared.kernels.matching._grid`) and skips pairs whose reference point has no line. The residual
   of a pair is its signed distance to the line, ``r = n . (R p + t) - c``.
3. Trimming: only the best ``trim_ratio`` share of the pairs (smallest ``|r|``) take part in the step.
4. The step ``(dx, dy, dtheta)``, applied on the left of the estimate, solves the linearised least squares
   ``sum (r + n_x dx + n_y dy + (n x p') dtheta)^2`` through its 3x3 normal equations, in the scaled
   unknowns ``(dx, dy, s dtheta)`` with ``s`` the RMS radius of the pairs. Directions of the normal matrix
   whose eigenvalue is below ``degeneracy_ratio`` times the largest get no update: along a featureless
   corridor the estimate stays at the initial guess instead of drifting on noise.
5. Two phases like ``icp``: once the step falls below ten times the tolerances with
   ``max_correspondence_m``, the search radius drops to ``refine_correspondence_m`` (if smaller) until the
   step falls below ``tolerance_m`` and ``tolerance_rad`` (``converged``); ``max_iterations`` bounds both.

Conventions and edge cases (as ``icp``):

* ``pose`` maps current points into the reference frame: ``reference ~ pose.transform_points(current)``;
  ``initial`` (default identity) is the first estimate. The reference must be in its scanner's frame and
  in beam order (the lines come from scan neighbours); the current points may be in any order.
* Non-finite rows are ignored. At most ``max_points`` current points are used (even stride).
* ``rmse_m`` is the RMS point-to-line distance of the pairs that took part in the last step, under the
  returned pose; ``inlier_ratio`` the share of the used current points that had a pair (within the search
  radius of the last phase, reference line known) in the last iteration, before trimming.
* Fewer than 3 pairs at any iteration: ``initial`` is returned with ``converged=False``, ``rmse_m=inf``
  and ``inlier_ratio=0``.

Complexity: O(M * max_side) for the lines and the grid, then O(K N' log N') for K iterations over
N' = min(N, max_points) points (the log from trimming).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.kernels.base import ScanMatchingKernel
from shared.kernels.matching._grid import _MAX_CELLS_PER_AXIS, _grid_build, _grid_nearest
from shared.kernels.matching._local_lines import _local_lines
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Match
from shared.types import FloatArray, Pose2D, as_points

__all__ = ["IcpLine", "IcpLineParams"]

#: grid cell side of the nearest-neighbour search relative to the correspondence radius (speed only)
_CELL_PER_RADIUS = 0.25
#: the first (wide) phase stops at this multiple of the tolerances
_COARSE_TOLERANCE = 10.0
#: most scan neighbours per side in a reference point's line fit (speed bound; the radius decides)
_MAX_SIDE = 8
#: estimates remembered to detect a limit cycle of the correspondences
_HISTORY = 4


class IcpLineParams(KernelParams):
    """Parameters of :class:`IcpLine`."""

    max_iterations: int = param(
        30, description="Most ICP iterations (both phases) before giving up", ge=1, le=1000, paper="§6.2.2"
    )
    max_correspondence_m: float = param(
        0.5,
        description="A current point pairs with its nearest reference point only within this distance",
        unit="m",
        gt=0.0,
        le=10.0,
        paper="§6.2.2",
    )
    refine_correspondence_m: float = param(
        0.25,
        description="Search radius of the second phase, once converged coarsely with max_correspondence_m "
        "(no second phase when >= max_correspondence_m)",
        unit="m",
        gt=0.0,
        le=10.0,
    )
    trim_ratio: float = param(
        0.9,
        description="Share of the pairs, those nearest their lines, that take part in each step",
        gt=0.0,
        le=1.0,
    )
    tolerance_m: float = param(
        1e-4, description="Converged when the translation step is below this", unit="m", gt=0.0, le=1.0
    )
    tolerance_rad: float = param(
        1e-4, description="Converged when the rotation step is below this", unit="rad", gt=0.0, le=1.0
    )
    degeneracy_ratio: float = param(
        1e-2,
        description="Directions of the 3x3 normal equations weaker than this share of the strongest "
        "(translation and rotation times the RMS radius) are not updated",
        ge=0.0,
        lt=1.0,
    )
    normal_radius_m: float = param(
        0.2,
        description="Scan neighbours of a reference point within this distance fit its local line (the "
        "first neighbour on each side always does)",
        unit="m",
        gt=0.0,
        le=10.0,
    )
    lambda_deg: float = param(
        10.0,
        description="ABD auxiliary angle: scan neighbours on a wall seen more obliquely than this are not "
        "on the same surface",
        unit="deg",
        gt=0.0,
        lt=90.0,
        paper="§3.1 eq. 15",
    )
    sigma_r_m: float = param(
        0.01,
        description="Range noise; 3 sigma is added to the ABD breakpoint distance",
        unit="m",
        ge=0.0,
        le=1.0,
        paper="§3.1 eq. 15",
    )
    line_max_ratio: float = param(
        0.3,
        description="A local line fit is kept when the RMS distance of its points to the line is at most "
        "this share of their RMS spread along it",
        gt=0.0,
        le=1.0,
    )
    max_points: int = param(
        400,
        description="Most current-scan points used (even stride over the scan); bounds the time per step",
        ge=3,
        le=1_000_000,
    )


@njit
def _step(h: FloatArray, g: FloatArray, degeneracy: float) -> tuple[float, float, float]:
    """Solve ``h d = -g`` (3x3 symmetric) over the eigen-directions stronger than ``degeneracy`` x max."""
    w, v = np.linalg.eigh(h)
    top = w[2]
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    if not top > 0.0:
        return d0, d1, d2
    for k in range(3):
        if w[k] > degeneracy * top and w[k] > 0.0:
            a = -(v[0, k] * g[0] + v[1, k] * g[1] + v[2, k] * g[2]) / w[k]
            d0 += a * v[0, k]
            d1 += a * v[1, k]
            d2 += a * v[2, k]
    return d0, d1, d2


@njit
def _plicp(
    reference: FloatArray,
    current: FloatArray,
    x: float,
    y: float,
    theta: float,
    max_d: float,
    fine_d: float,
    trim: float,
    tol_m: float,
    tol_rad: float,
    degeneracy: float,
    max_iter: int,
    radius_m: float,
    lambda_rad: float,
    sigma_m: float,
    max_ratio: float,
) -> tuple[float, float, float, int, bool, int, int, float]:
    """The point-to-line ICP loop. Returns ``(x, y, theta, n_iter, converged, pairs, used, sse)``: ``pairs``
    had a line within reach in the last iteration (``< 3`` means failure), ``used`` took part in the step."""
    normals, offsets, valid = _local_lines(reference, radius_m, _MAX_SIDE, lambda_rad, sigma_m, max_ratio)
    sorted_xy, order, start, x0, y0, h, nx, ny = _grid_build(reference, max_d * _CELL_PER_RADIUS,
                                                               _MAX_CELLS_PER_AXIS)
    n = current.shape[0]
    line = np.empty(n, dtype=np.intp)
    res = np.empty(n, dtype=np.float64)
    absr = np.empty(n, dtype=np.float64)
    hm = np.empty((3, 3), dtype=np.float64)
    gv = np.empty(3, dtype=np.float64)
    # the last _HISTORY estimates: returning to one of them is a correspondence limit cycle
    hist = np.full((_HISTORY, 3), np.inf)
    converged = False
    pairs = 0
    used = 0
    cut = math.inf
    it = 0
    while it < max_iter:
        it += 1
        c = math.cos(theta)
        s = math.sin(theta)
        pairs = 0
        for i in range(n):
            qx = c * current[i, 0] - s * current[i, 1] + x
            qy = s * current[i, 0] + c * current[i, 1] + y
            j, _ = _grid_nearest(sorted_xy, order, start, x0, y0, h, nx, ny, qx, qy, max_d)
            if j >= 0 and valid[j]:
                line[i] = j
                res[i] = normals[j, 0] * qx + normals[j, 1] * qy - offsets[j]
                absr[pairs] = abs(res[i])
                pairs += 1
            else:
                line[i] = -1
        if pairs < 3:
            return x, y, theta, it, False, pairs, 0, math.inf
        keep = max(3, min(pairs, int(math.ceil(trim * pairs))))
        cut = np.sort(absr[:pairs])[keep - 1] if keep < pairs else math.inf
        # RMS radius of the pairs: scales the rotation column to metres
        r2 = 0.0
        used = 0
        for i in range(n):
            if line[i] >= 0 and abs(res[i]) <= cut:
                qx = c * current[i, 0] - s * current[i, 1] + x
                qy = s * current[i, 0] + c * current[i, 1] + y
                r2 += qx * qx + qy * qy
                used += 1
        scale = max(math.sqrt(r2 / used), 1e-3)
        hm[:] = 0.0
        gv[:] = 0.0
        for i in range(n):
            j = line[i]
            if j >= 0 and abs(res[i]) <= cut:
                qx = c * current[i, 0] - s * current[i, 1] + x
                qy = s * current[i, 0] + c * current[i, 1] + y
                jac0 = normals[j, 0]
                jac1 = normals[j, 1]
                jac2 = (normals[j, 1] * qx - normals[j, 0] * qy) / scale
                for a, ja in ((0, jac0), (1, jac1), (2, jac2)):
                    hm[a, 0] += ja * jac0
                    hm[a, 1] += ja * jac1
                    hm[a, 2] += ja * jac2
                    gv[a] += ja * res[i]
        dx, dy, ds = _step(hm, gv, degeneracy)
        dth = ds / scale
        cd = math.cos(dth)
        sd = math.sin(dth)
        hist[it % _HISTORY, 0] = x
        hist[it % _HISTORY, 1] = y
        hist[it % _HISTORY, 2] = theta
        x, y = cd * x - sd * y + dx, sd * x + cd * y + dy
        theta = theta + dth
        coarse = fine_d < max_d
        f = _COARSE_TOLERANCE if coarse else 1.0
        done = False
        for k in range(_HISTORY):
            d_rad = abs((theta - hist[k, 2] + math.pi) % (2.0 * math.pi) - math.pi)
            if math.hypot(x - hist[k, 0], y - hist[k, 1]) < f * tol_m and d_rad < f * tol_rad:
                done = True
        if done and coarse:
            max_d = fine_d  # converged coarsely: go on with the tighter search radius
            hist[:] = np.inf
        elif done:
            converged = True
            break
    c = math.cos(theta)
    s = math.sin(theta)
    sse = 0.0
    for i in range(n):
        j = line[i]
        if j >= 0 and abs(res[i]) <= cut:
            qx = c * current[i, 0] - s * current[i, 1] + x
            qy = s * current[i, 0] + c * current[i, 1] + y
            d = normals[j, 0] * qx + normals[j, 1] * qy - offsets[j]
            sse += d * d
    return x, y, theta, it, converged, pairs, used, sse


def _finite(points: ArrayLike, name: str) -> FloatArray:
    pts = as_points(points, name=name)
    keep = np.isfinite(pts).all(axis=1)
    return pts if keep.all() else np.ascontiguousarray(pts[keep])


@register
class IcpLine(ScanMatchingKernel[IcpLineParams]):
    """2D point-to-line ICP (PLICP) with local reference lines, trimming and degeneracy-aware steps."""

    name = "icp-line"
    version = "1.0.0"
    Params = IcpLineParams

    def apply(self, reference: ArrayLike, current: ArrayLike, initial: Pose2D | None = None) -> Match:
        """Pose mapping ``current`` ``(N, 2)`` onto ``reference`` ``(M, 2)`` (metres, beam order), from
        ``initial``."""
        p = self.params
        start = Pose2D() if initial is None else initial
        failed = Match(pose=start, rmse_m=math.inf, inlier_ratio=0.0, n_iter=0, converged=False)
        ref = _finite(reference, "reference")
        cur = _finite(current, "current")
        if ref.shape[0] < 3 or cur.shape[0] < 3:
            return failed
        if cur.shape[0] > p.max_points:
            cur = np.ascontiguousarray(cur[(np.arange(p.max_points) * cur.shape[0]) // p.max_points])
        x, y, theta, n_iter, converged, pairs, used, sse = _plicp(
            np.ascontiguousarray(ref),
            np.ascontiguousarray(cur),
            start.x_m,
            start.y_m,
            start.theta_rad,
            p.max_correspondence_m,
            p.refine_correspondence_m,
            p.trim_ratio,
            p.tolerance_m,
            p.tolerance_rad,
            p.degeneracy_ratio,
            p.max_iterations,
            p.normal_radius_m,
            math.radians(p.lambda_deg),
            p.sigma_r_m,
            p.line_max_ratio,
        )
        if pairs < 3:
            return Match(pose=start, rmse_m=math.inf, inlier_ratio=0.0, n_iter=n_iter, converged=False)
        return Match(
            pose=Pose2D(x, y, theta),
            rmse_m=math.sqrt(sse / used),
            inlier_ratio=pairs / cur.shape[0],
            n_iter=n_iter,
            converged=converged,
        )
