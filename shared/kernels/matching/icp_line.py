"""2D point-to-line ICP between consecutive scans (paper §6.2.2, after Censi's PLICP, ICRA 2008).

Point-to-point ICP (:mod:`shared.kernels.matching.icp`) pulls each current point onto a reference *point*,
so the beam spacing of the reference becomes a bias; point-to-line ICP instead minimises the distance of
each current point to the reference surface through its nearest reference point. It converges in a few
Gauss-Newton steps and stays accurate on sparse far walls, but its basin of convergence is narrower (a
point may slide along a wrong line), so a coarse point-to-point phase comes first.

1. Reference lines (:mod:`shared.kernels.matching._local_lines`): every reference point gets the
   total-least-squares line of its scan-order neighbours on the same surface (ABD breakpoint test, within
   ``normal_radius_m`` but always the first neighbour on each side); next to corners a one-sided fit;
   isolated points and poor fits get no line.
2. Each iteration maps the current points with the estimate and pairs each one with its exact nearest
   reference point within the search radius (the compiled grid of :mod:`shared.kernels.matching._grid`).
3. Trimming: only the best ``trim_ratio`` share of the pairs (smallest residuals) take part in the step.
4. Point-to-point phase: search radius ``max_correspondence_m``, every other current point of a large
   scan, residual = distance to the partner, closed-form rigid alignment (2D Kabsch). It ends when the
   estimate moves less than ``50 x tolerance_m`` and ``50 x tolerance_rad`` (5 mm, 5 mrad by default).
5. Point-to-line phase: search radius ``refine_correspondence_m``, all current points, pairs whose
   reference point has no line are skipped; residual = signed distance to the line,
   ``r = n . (R p + t) - c``. The step ``(dx, dy, dtheta)``, applied on the left of the estimate,
   solves the linearised least squares ``sum (r + n_x dx + n_y dy + (n x p') dtheta)^2`` through its 3x3
   normal equations, in the unknowns ``(dx, dy, s dtheta)`` with ``s`` the RMS radius of the pairs.
   Directions of the normal matrix whose eigenvalue is below ``degeneracy_ratio`` times the largest get no
   update: along a featureless corridor the estimate stays at the guess instead of drifting on noise.
   ``converged`` once the estimate moves less than ``tolerance_m`` and ``tolerance_rad``.
6. Either phase also ends when the estimate returns to within the tolerances of one of the last
   ``_HISTORY`` estimates: a limit cycle of the correspondences (pairs flipping between two reference
   points), which otherwise burns the iterations moving back and forth by a millimetre.
   ``max_iterations`` bounds both phases together.

Conventions and edge cases (as ``icp``):

* ``pose`` maps current points into the reference frame: ``reference ~ pose.transform_points(current)``;
  ``initial`` (default identity) is the first estimate. The reference must be in its scanner's frame and
  in beam order (the lines come from scan neighbours); the current points may be in any order.
* Non-finite rows are ignored. At most ``max_points`` current points are used (even stride).
* ``rmse_m`` is the RMS residual (point-to-line distance; point-to-point if the first phase ran out of
  iterations) of the pairs that took part in the last step, under the returned pose; ``inlier_ratio`` the
  share of the used current points that had a pair in the last iteration (within its search radius, with
  a reference line in the second phase), before trimming.
* Fewer than 3 pairs at any iteration: ``initial`` is returned with ``converged=False``, ``rmse_m=inf``
  and ``inlier_ratio=0``.

Complexity: O(M * max_side) for the lines, O(M + cells) for the grid, then O(K N') for K iterations over
N' = min(N, max_points) points (each query visits a few cells; trimming is a linear-time selection).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.kernels.base import ScanMatchingKernel
from shared.kernels.matching._grid import _MAX_CELLS_PER_AXIS, _grid_build, _grid_nearest
from shared.kernels.matching._local_lines import _local_lines
from shared.kernels.matching._solve import _line_step, _point_align
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Match
from shared.types import FloatArray, Pose2D, as_points

__all__ = ["IcpLine", "IcpLineParams"]

#: grid cell side of the nearest-neighbour search relative to the correspondence radius (speed only)
_CELL_PER_RADIUS = 0.25
#: the point-to-point phase stops at this multiple of the tolerances
_COARSE_TOLERANCE = 50.0
#: most scan neighbours per side in a reference point's line fit (speed bound; the radius decides)
_MAX_SIDE = 8
#: the point-to-point phase thins the current scan to every other point when it keeps at least this many
_POINT_PHASE_MIN = 100
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
        description="Search radius of the point-to-line phase (the point-to-point phase uses "
        "max_correspondence_m)",
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
        300,
        description="Most current-scan points used (even stride over the scan); bounds the time per step",
        ge=3,
        le=1_000_000,
    )


@njit
def _plicp(
    reference: FloatArray,
    current: FloatArray,
    x: float,
    y: float,
    theta: float,
    max_d: float,
    line_d: float,
    trim: float,
    tol_m: float,
    tol_rad: float,
    degeneracy: float,
    max_iter: int,
    radius_m: float,
    lambda_rad: float,
    sigma_m: float,
    max_ratio: float,
) -> tuple[float, float, float, int, bool, int, int, int, float]:
    """The ICP loop: point-to-point within ``max_d`` until coarsely converged, then point-to-line within
    ``line_d``. Returns ``(x, y, theta, n_iter, converged, queried, pairs, used, sse)``: of the ``queried``
    current points of the last iteration, ``pairs`` had a partner (``< 3`` means failure) and ``used`` took
    part in its step; ``sse`` is their sum of squared residuals under the returned pose."""
    normals, offsets, valid = _local_lines(reference, radius_m, _MAX_SIDE, lambda_rad, sigma_m, max_ratio)
    sorted_xy, order, start, x0, y0, h, nx, ny = _grid_build(
        reference, max_d * _CELL_PER_RADIUS, _MAX_CELLS_PER_AXIS
    )
    n = current.shape[0]
    pair = np.empty(n, dtype=np.intp)
    res = np.empty(n, dtype=np.float64)
    px = np.empty(n, dtype=np.float64)
    py = np.empty(n, dtype=np.float64)
    absr = np.empty(n, dtype=np.float64)
    # the estimates before the last _HISTORY steps: returning to one of them is a limit cycle of the pairs
    hist = np.full((_HISTORY, 3), np.inf)
    lines = False  # the point-to-point phase comes first
    search = max_d
    converged = False
    pairs = 0
    used = 0
    queried = n
    cut = math.inf
    it = 0
    while it < max_iter:
        it += 1
        c = math.cos(theta)
        s = math.sin(theta)
        pairs = 0
        r2 = 0.0
        # the coarse point-to-point phase uses every other point of a large scan (speed)
        stride = 1 if lines or n < 2 * _POINT_PHASE_MIN else 2
        queried = (n + stride - 1) // stride
        pair[:] = -1
        for i in range(0, n, stride):
            qx = c * current[i, 0] - s * current[i, 1] + x
            qy = s * current[i, 0] + c * current[i, 1] + y
            j, d2 = _grid_nearest(sorted_xy, order, start, x0, y0, h, nx, ny, qx, qy, search)
            if j < 0 or (lines and not valid[j]):
                continue
            pair[i] = j
            px[i] = qx
            py[i] = qy
            res[i] = normals[j, 0] * qx + normals[j, 1] * qy - offsets[j] if lines else math.sqrt(d2)
            absr[pairs] = abs(res[i])
            r2 += qx * qx + qy * qy
            pairs += 1
        if pairs < 3:
            return x, y, theta, it, False, queried, pairs, 0, math.inf
        keep = max(3, math.ceil(trim * pairs))
        cut = np.partition(absr[:pairs], keep - 1)[keep - 1] if keep < pairs else math.inf
        used = 0
        for i in range(n):
            if pair[i] >= 0 and abs(res[i]) <= cut:
                used += 1
        hist[it % _HISTORY, 0] = x
        hist[it % _HISTORY, 1] = y
        hist[it % _HISTORY, 2] = theta
        if lines:
            # the rotation unknown is scaled by the RMS radius of the pairs to a length
            scale = max(math.sqrt(r2 / pairs), 1e-3)
            dx, dy, dth = _line_step(px, py, normals, pair, res, cut, scale, degeneracy)
            cd = math.cos(dth)
            sd = math.sin(dth)
            x, y = cd * x - sd * y + dx, sd * x + cd * y + dy
            theta = theta + dth
        else:
            x, y, theta = _point_align(current, reference, pair, res, cut)
        f = 1.0 if lines else _COARSE_TOLERANCE
        done = False
        for k in range(_HISTORY):
            d_rad = abs((theta - hist[k, 2] + math.pi) % (2.0 * math.pi) - math.pi)
            if math.hypot(x - hist[k, 0], y - hist[k, 1]) < f * tol_m and d_rad < f * tol_rad:
                done = True
        if done and not lines:
            lines = True  # coarsely aligned: go on point-to-line
            search = line_d
            hist[:] = np.inf
        elif done:
            converged = True
            break
    c = math.cos(theta)
    s = math.sin(theta)
    sse = 0.0
    for i in range(n):
        j = pair[i]
        if j >= 0 and abs(res[i]) <= cut:
            qx = c * current[i, 0] - s * current[i, 1] + x
            qy = s * current[i, 0] + c * current[i, 1] + y
            if lines:
                d = normals[j, 0] * qx + normals[j, 1] * qy - offsets[j]
                sse += d * d
            else:
                sse += (qx - reference[j, 0]) ** 2 + (qy - reference[j, 1]) ** 2
    return x, y, theta, it, converged, queried, pairs, used, sse


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
        x, y, theta, n_iter, converged, queried, pairs, used, sse = _plicp(
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
            inlier_ratio=pairs / queried,
            n_iter=n_iter,
            converged=converged,
        )
