"""A scan match fused with odometry by their information (docs/worlds.md), the solver: the scan decides where
it can, odometry where it cannot.

A scan match is exact across walls and blind along them: in a corridor whose ends are out of range nothing
in the scan fixes the motion along it, and point-to-point ICP there under-estimates the motion (each point
pairs with the reference return of the same beam), so the pose was pulled back along the corridor scan
after scan although odometry was right. :func:`fuse_with_odometry` re-solves the match as a maximum a
posteriori estimate: from the matcher's pose, Gauss-Newton on

    sum_i (n_i . (R p_i + t) - c_i)^2 / sigma_i^2  +  (x - x_odo)^T  Lambda_odo  (x - x_odo)

over the pose ``x = (t_x, t_y, theta)`` of the current scan in the reference scan's frame: the first term is
the point-to-line residual of each current point ``p_i`` to the local line ``(n_i, c_i)`` of its nearest
reference point (:mod:`shared.kernels.matching._local_lines`, as point-to-line ICP), its information
``J^T J / sigma_i^2`` (``sigma_i^2 = sigma_m^2 + sigma_r(|p_i|)^2``, the scanner's range noise at the
return's range, :mod:`shared.pipeline.rangenoise`) is large across walls and near zero along a
featureless corridor; the second is the odometry motion since the reference with its information
``Lambda_odo`` (:func:`odometry_information`: standard deviations growing with the distance and the turn
travelled). The solution follows the scan in
every direction the scan constrains and odometry in the others, with no threshold on what "constrains"
means; a small feature (a door recess, a cabinet corner) adds its share of information where it is seen.
Pairs farther than ``trim_m`` from their line take no part (outliers, things seen from one scan only).

Complexity: O(M) for the reference lines and grid, O(iterations x N) for the N current points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.kernels._jit import njit
from shared.kernels.matching._grid import _MAX_CELLS_PER_AXIS, _grid_build, _grid_nearest
from shared.kernels.matching._local_lines import _local_lines
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.types import BoolArray, FloatArray, IntArray, Pose2D

__all__ = [
    "Fused",
    "Reference",
    "fuse_with_odometry",
    "linear_fusion",
    "mahalanobis2",
    "odometry_information",
    "prepare_reference",
]


#: local reference lines as point-to-line ICP fits them (radius m, most neighbours a side, ABD angle rad,
#: range noise m, straightness ratio)
_LINE_RADIUS_M = 0.5
_LINE_MAX_SIDE = 16
_LINE_LAMBDA_RAD = math.radians(10.0)
_LINE_SIGMA_M = 0.01
_LINE_MAX_RATIO = 0.3
_LINE_MAX_DIRECTION_SD_RAD = 0.1


@dataclass(frozen=True, slots=True)
class Fused:
    """The fused pose (current scan in the reference frame), the pairs that took part and the posterior
    standard deviation along the least constrained direction of translation (m)."""

    pose: Pose2D
    pairs: int
    information: FloatArray  # (3, 3) posterior information of (x, y, theta)

    @property
    def weakest_sigma_m(self) -> float:
        """Posterior standard deviation along the least constrained direction of translation (m). O(1)."""
        cov = np.linalg.inv(self.information)
        return float(np.sqrt(max(np.linalg.eigvalsh(cov[:2, :2])[-1], 0.0)))


def odometry_information(
    motion: Pose2D, *, sigma_m: float, sigma_ratio: float, sigma_rad: float, sigma_rad_per_rad: float
) -> FloatArray:
    """Information matrix ``(3, 3)`` of an odometry motion: isotropic translation standard deviation
    ``sigma_m + sigma_ratio x distance``, rotation ``sigma_rad + sigma_rad_per_rad x |turn| +
    sigma_ratio x distance`` (m of travel read as rad: a slipping wheel turns the robot too). O(1)."""
    dist = math.hypot(motion.x_m, motion.y_m)
    s_xy = max(sigma_m + sigma_ratio * dist, 1e-6)
    s_th = max(sigma_rad + sigma_rad_per_rad * abs(motion.theta_rad) + sigma_ratio * dist, 1e-9)
    return np.diag([1.0 / s_xy**2, 1.0 / s_xy**2, 1.0 / s_th**2])


@dataclass(frozen=True, slots=True)
class Reference:
    """A reference scan made ready for :func:`fuse_with_odometry`: its local lines and nearest-point grid
    (for pairs up to ``max_distance_m``). Build it once per keyframe (:func:`prepare_reference`): the
    pipeline fuses several scans against one keyframe."""

    max_distance_m: float
    normals: FloatArray
    offsets: FloatArray
    valid: BoolArray
    sorted_xy: FloatArray
    order: IntArray
    start: IntArray
    x0: float
    y0: float
    h: float
    nx: int
    ny: int


def prepare_reference(
    points: FloatArray, max_distance_m: float = 0.25, range_noise: RangeNoise = NO_RANGE_NOISE
) -> Reference | None:
    """The lines and grid of ``points`` ``(M, 2)`` (scanner frame, m, beam order; non-finite rows dropped);
    ``None`` with fewer than 3 finite points. O(M).

    With a ``range_noise`` model (a scanner whose noise exceeds its beam spacing near by, the URG-04LX:
    12.5 mm against 5 mm at 1 m) a line must know its direction to :data:`_LINE_MAX_DIRECTION_SD_RAD`,
    its residual noise taken as at least the model's near sigma: a window of a few such returns (cut
    short by a clutter return) otherwise gets a line at any angle, and the match read along-track
    information from it (a simulated corridor with 5 % clutter returns: 17,000 against 800 m^-2 without
    the clutter, and the pose crept back along it). Scanners without a model (the benchmark logs' SICK
    scanners, 0.5-1 degree beams) keep every straight fit: there the test cost Freiburg 079's relation
    error 0.045 -> 0.064-0.084 m."""
    ref = np.ascontiguousarray(points[np.isfinite(points).all(axis=1)], dtype=np.float64)
    if len(ref) < 3:
        return None
    normals, offsets, valid = _local_lines(
        ref,
        _LINE_RADIUS_M,
        _LINE_MAX_SIDE,
        _LINE_LAMBDA_RAD,
        _LINE_SIGMA_M,
        _LINE_MAX_RATIO,
        _LINE_MAX_DIRECTION_SD_RAD if range_noise.near_m > 0.0 else math.inf,
        range_noise.near_m,
    )
    grid = _grid_build(ref, 0.25 * max_distance_m, _MAX_CELLS_PER_AXIS)
    return Reference(max_distance_m, normals, offsets, valid, *grid)


@njit
def _fuse(
    normals: FloatArray,
    offsets: FloatArray,
    valid: BoolArray,
    sorted_xy: FloatArray,
    order: IntArray,
    start: IntArray,
    x0: float,
    y0: float,
    h: float,
    nx: int,
    ny: int,
    cur: FloatArray,
    x: float,
    y: float,
    th: float,
    prior: FloatArray,
    info: FloatArray,
    sigma: float,
    sigma_near: float,
    sigma_ratio: float,
    max_d: float,
    trim: float,
    iterations: int,
) -> tuple[float, float, float, int, FloatArray]:
    """Gauss-Newton of the module docstring's objective from ``(x, y, th)`` against a prepared reference
    (its lines and grid); returns the pose, the pairs of the last iteration and the last normal matrix
    (the posterior information)."""
    # each pair's weight: the match noise plus the current return's own range noise (URG-04LX: the
    # larger of sigma_near and sigma_ratio x range), so far returns count for what they are worth
    n_cur = cur.shape[0]
    wts = np.empty(n_cur)
    for i in range(n_cur):
        sr = max(sigma_near, sigma_ratio * math.hypot(cur[i, 0], cur[i, 1]))
        wts[i] = 1.0 / (sigma * sigma + sr * sr)
    hm = info.copy()
    pairs = 0
    for _ in range(iterations):
        c = math.cos(th)
        s = math.sin(th)
        hm = info.copy()
        e = np.array([x - prior[0], y - prior[1], (th - prior[2] + math.pi) % (2.0 * math.pi) - math.pi])
        g = info @ e
        pairs = 0
        for i in range(cur.shape[0]):
            rx = c * cur[i, 0] - s * cur[i, 1]
            ry = s * cur[i, 0] + c * cur[i, 1]
            j, _d2 = _grid_nearest(sorted_xy, order, start, x0, y0, h, nx, ny, rx + x, ry + y, max_d)
            if j < 0 or not valid[j]:
                continue
            n0 = normals[j, 0]
            n1 = normals[j, 1]
            r = n0 * (rx + x) + n1 * (ry + y) - offsets[j]
            if abs(r) > trim:
                continue
            j2 = -n0 * ry + n1 * rx
            jac = (n0, n1, j2)
            w = wts[i]
            for a in range(3):
                g[a] += w * jac[a] * r
                for b in range(3):
                    hm[a, b] += w * jac[a] * jac[b]
            pairs += 1
        step = np.linalg.solve(hm, -g)
        x += step[0]
        y += step[1]
        th += step[2]
        if math.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-5:
            break
    return x, y, th, pairs, hm


def fuse_with_odometry(
    reference: FloatArray | Reference,
    current: FloatArray,
    matched: Pose2D,
    odometry: Pose2D,
    information: FloatArray,
    *,
    sigma_m: float = 0.02,
    max_distance_m: float = 0.25,
    trim_m: float = 0.1,
    iterations: int = 10,
    min_pairs: int = 10,
    max_points: int = 300,
    scan_only: bool = False,
    range_noise: RangeNoise = NO_RANGE_NOISE,
) -> Fused | None:
    """The pose of ``current`` in ``reference``'s frame (scanner frames, m, ``reference`` in beam order)
    that best agrees with both the scan and the ``odometry`` motion of ``information`` (module docstring),
    solved from the matcher's ``matched`` pose. ``None`` when fewer than ``min_pairs`` points find a line
    (keep the match as it is). At most ``max_points`` current points are used. ``scan_only``: without the
    odometry term (``information`` is ignored), for the scan's own information at the pose. Each pair's
    variance is ``sigma_m^2`` plus the current return's ``range_noise`` at its range
    (:mod:`shared.pipeline.rangenoise`).
    ``reference`` may be prepared already (:func:`prepare_reference`, for pairs up to ``max_distance_m``)."""
    ref = (
        reference
        if isinstance(reference, Reference)
        else prepare_reference(reference, max_distance_m, range_noise)
    )
    cur = np.ascontiguousarray(current[np.isfinite(current).all(axis=1)], dtype=np.float64)
    if len(cur) > max_points:  # an even stride keeps the scan's angular coverage (as the matchers do)
        cur = np.ascontiguousarray(cur[(np.arange(max_points) * len(cur)) // max_points])
    if ref is None or len(cur) < 3:
        return None
    if scan_only:
        information = np.eye(3) * 1e-9
    prior = np.array([odometry.x_m, odometry.y_m, odometry.theta_rad])
    x, y, th, pairs, hm = _fuse(
        ref.normals,
        ref.offsets,
        ref.valid,
        ref.sorted_xy,
        ref.order,
        ref.start,
        ref.x0,
        ref.y0,
        ref.h,
        ref.nx,
        ref.ny,
        cur,
        matched.x_m,
        matched.y_m,
        matched.theta_rad,
        prior,
        np.ascontiguousarray(information, dtype=np.float64),
        sigma_m,
        range_noise.near_m,
        range_noise.ratio,
        ref.max_distance_m,
        trim_m,
        iterations,
    )
    if pairs < min_pairs or not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
        return None
    return Fused(Pose2D(x, y, th), pairs, hm)


def linear_fusion(
    odometry: Pose2D, matched: Pose2D, odometry_information: FloatArray, scan_information: FloatArray
) -> tuple[Pose2D, FloatArray]:
    """The information-weighted mean of two estimates of one motion and its information ``(3, 3)``:
    ``odometry + (I_o + I_s)^-1 I_s (matched - odometry)``, the heading difference wrapped; in each
    eigen-direction it lies between the two. O(1)."""
    posterior = np.asarray(odometry_information, dtype=np.float64) + np.asarray(scan_information)
    e = np.array(
        [
            matched.x_m - odometry.x_m,
            matched.y_m - odometry.y_m,
            math.remainder(matched.theta_rad - odometry.theta_rad, math.tau),
        ]
    )
    step = np.linalg.solve(posterior + np.eye(3) * 1e-12, scan_information @ e)
    pose = Pose2D(odometry.x_m + step[0], odometry.y_m + step[1], odometry.theta_rad + step[2])
    return pose, posterior


def mahalanobis2(a: Pose2D, b: Pose2D, information: FloatArray) -> float:
    """Squared Mahalanobis distance of pose ``a`` from ``b`` under ``information`` ``(3, 3)`` (per m^2 and
    rad^2; the heading difference wrapped). O(1)."""
    d = np.array([a.x_m - b.x_m, a.y_m - b.y_m, math.remainder(a.theta_rad - b.theta_rad, math.tau)])
    return float(d @ np.asarray(information) @ d)
