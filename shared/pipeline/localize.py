"""Scan-to-map pose refinement: point-to-line least squares against the walls already in the map.

Scan-to-scan ICP drifts a little with every keyframe; the walls of the map are long-lived references, so
once a few walls are confirmed, each scan's pose is refined against them (the paper's "map correction",
§6.3.1). Each scan point is associated with the nearest wall segment within ``max_distance_m``; the pose
update ``(dx, dy, dtheta)`` minimises the squared point-to-line distances (linearised about the current
pose, Gauss-Newton, a few iterations with re-association), with a small damping term so directions the
walls do not constrain (along a corridor) stay where odometry and ICP put them. The damping alone is too
weak when the walls are a few degrees off parallel: their across-wall residuals then echo, amplified by
1 / sin(angle), into a large along-corridor step (on the ACES log the pose crept backwards several cm per
scan). With ``degeneracy_ratio > 0`` the step is solved in the eigenbasis of the normal matrix, in the
unknowns ``(dx, dy, s dtheta)`` (``s`` the RMS lever of the pairs, so all three are lengths), and
directions whose eigenvalue is at most that share of the largest get no update. Residuals beyond
``trim_m`` are dropped as outliers. Complexity O(iterations x N x W_near).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.kernels._jit import njit
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.types import FloatArray, Pose2D

__all__ = ["WallFit", "refine_to_walls"]


@dataclass(frozen=True, slots=True)
class WallFit:
    """The refined scanner pose, how many points matched a wall and their RMS distance (m), both as the
    last Gauss-Newton step was solved on: after the iterations ran out that is the pose before that step
    (measuring the returned pose again would cost one more association per step for a figure the
    pipeline does not read)."""

    pose: Pose2D
    matched: int
    rmse_m: float


@njit
def _normal_equations(
    points: FloatArray,
    x_m: float,
    y_m: float,
    theta_rad: float,
    walls: FloatArray,
    max_distance_m: float,
    trim_m: float,
    weights: FloatArray,
) -> tuple[int, FloatArray, FloatArray, float, float]:
    """One Gauss-Newton linearisation at the scanner pose ``(x_m, y_m, theta_rad)``: each point (scanner
    frame) is paired with its nearest wall segment within ``max_distance_m`` whose line it is within
    ``trim_m`` of; with the rows ``a = (n_x, n_y, n . J lever)`` (``J`` the 90 deg rotation, ``lever`` the
    point less the scanner position) and residuals ``r = n . p - n . a`` returns the pair count,
    ``sum w a a^T`` (3x3), ``sum w a r`` (3), ``sum r^2`` and ``sum |lever|^2``, ``w`` the point's
    ``weights`` entry (its inverse variance relative to the nominal residual's). O(N W)."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    n, w = points.shape[0], walls.shape[0]
    nx = np.empty(w)
    ny = np.empty(w)
    off = np.empty(w)
    ex = np.empty(w)
    ey = np.empty(w)
    len2 = np.empty(w)
    box = np.empty((w, 4))  # each wall's bounding box grown by max_distance_m: a cheap test first
    for j in range(w):
        box[j, 0] = min(walls[j, 0], walls[j, 2]) - max_distance_m
        box[j, 1] = max(walls[j, 0], walls[j, 2]) + max_distance_m
        box[j, 2] = min(walls[j, 1], walls[j, 3]) - max_distance_m
        box[j, 3] = max(walls[j, 1], walls[j, 3]) + max_distance_m
        ex[j], ey[j] = walls[j, 2] - walls[j, 0], walls[j, 3] - walls[j, 1]
        length = max(math.hypot(ex[j], ey[j]), 1e-12)
        nx[j], ny[j] = -ey[j] / length, ex[j] / length
        off[j] = nx[j] * walls[j, 0] + ny[j] * walls[j, 1]
        len2[j] = max(ex[j] * ex[j] + ey[j] * ey[j], 1e-12)
    h = np.zeros((3, 3))
    g = np.zeros(3)
    r2 = 0.0
    lever2 = 0.0
    count = 0
    max2 = max_distance_m * max_distance_m
    trim = max(trim_m, 1e-6)
    for i in range(n):
        lx = c * points[i, 0] - s * points[i, 1]
        ly = s * points[i, 0] + c * points[i, 1]
        wx, wy = lx + x_m, ly + y_m
        best, which = np.inf, -1
        for j in range(w):
            # a wall whose grown box misses the point is beyond max_distance_m: never the pair
            if wx < box[j, 0] or wx > box[j, 1] or wy < box[j, 2] or wy > box[j, 3]:
                continue
            px, py = wx - walls[j, 0], wy - walls[j, 1]
            t = min(max((px * ex[j] + py * ey[j]) / len2[j], 0.0), 1.0)
            dx, dy = px - t * ex[j], py - t * ey[j]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, which = d2, j
        if which < 0 or best > max2:
            continue
        r = nx[which] * wx + ny[which] * wy - off[which]
        if abs(r) > trim:
            continue
        a0, a1 = nx[which], ny[which]
        a2 = -a0 * ly + a1 * lx
        wt = weights[i]
        h[0, 0] += wt * a0 * a0
        h[0, 1] += wt * a0 * a1
        h[0, 2] += wt * a0 * a2
        h[1, 1] += wt * a1 * a1
        h[1, 2] += wt * a1 * a2
        h[2, 2] += wt * a2 * a2
        g[0] += wt * a0 * r
        g[1] += wt * a1 * r
        g[2] += wt * a2 * r
        r2 += r * r
        lever2 += lx * lx + ly * ly
        count += 1
    h[1, 0], h[2, 0], h[2, 1] = h[0, 1], h[0, 2], h[1, 2]
    return count, h, g, r2, lever2


def _step(
    h0: FloatArray,
    g0: FloatArray,
    mean_lever2: float,
    damping: float,
    ratio: float,
    prior: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[float, float, float]:
    """The damped Gauss-Newton step ``(dx, dy, dtheta)`` from the normal equations ``h0 = sum a a^T``,
    ``g0 = sum a r`` (rows ``a = (n_x, n_y, d r / d theta)``); with ``ratio > 0`` only along the
    eigen-directions of the normal matrix (in ``(dx, dy, s dtheta)``, ``s`` the RMS lever, from
    ``mean_lever2``) whose eigenvalue exceeds ``ratio`` times the largest: directions the walls barely
    constrain get no update, or with a ``prior`` ``(e, P)`` (the pose minus the prior pose as ``(dx, dy,
    dtheta)`` and its information, in units of the residuals' variance) move towards the prior by its
    share of the information along them. O(1)."""
    if ratio <= 0.0:  # the plain damped step
        h = h0 + damping * np.diag([1.0, 1.0, 4.0])
        dx, dy, dth = (float(v) for v in np.linalg.solve(h, -g0))
        return dx, dy, dth
    scale = max(math.sqrt(mean_lever2), 1e-3)
    unscale = np.array([1.0, 1.0, 1.0 / scale])
    # unknowns (dx, dy, scale dtheta): all lengths; the same damping as above
    h = h0 * np.outer(unscale, unscale) + damping * np.diag([1.0, 1.0, 4.0 / scale**2])
    w, v = np.linalg.eigh(h)
    strong = w > ratio * w[-1]
    keep = v[:, strong]
    lam = w[strong]
    step = keep @ ((keep.T @ -(g0 * unscale)) / lam)
    if prior is not None:
        e, info = prior
        e_s = e * np.array([1.0, 1.0, scale])
        info_s = info * np.outer(unscale, unscale)
        for k in np.flatnonzero(~strong):
            u = v[:, k]
            pe = float(u @ info_s @ u)
            step = step - u * float(u @ e_s) * pe / (pe + max(float(w[k]), 0.0))
    return float(step[0]), float(step[1]), float(step[2]) / scale


def refine_to_walls(
    points: FloatArray,
    scanner_pose: Pose2D,
    walls: FloatArray,
    *,
    max_distance_m: float = 0.15,
    trim_m: float = 0.08,
    iterations: int = 5,
    damping: float = 1.0,
    min_matches: int = 30,
    range_m: float = 8.0,
    degeneracy_ratio: float = 0.0,
    prior: Pose2D | None = None,
    prior_information: FloatArray | None = None,
    range_noise: RangeNoise = NO_RANGE_NOISE,
    sigma_m: float = 0.02,
) -> WallFit | None:
    """Refine ``scanner_pose`` so the scan ``points`` (scanner frame) lie on ``walls`` (world frame).

    ``degeneracy_ratio`` (0: off, the plain damped step) leaves out poorly constrained directions (module
    docstring); with a ``prior`` scanner pose (odometry's) and its ``prior_information`` (3x3, per m^2
    and rad^2, already scaled to the residuals' variance) those directions follow the prior by information
    instead of keeping ``scanner_pose``'s value (a corridor's axis follows the wheels). Each point's
    residual counts by ``sigma_m^2 / (sigma_m^2 + sigma_r^2)``, ``sigma_r`` the scanner's ``range_noise``
    at its range (:mod:`shared.pipeline.rangenoise`; 1 for every point without one).
    Returns ``None`` when fewer than ``min_matches`` points find a wall (then keep the unrefined pose).
    """
    if len(points) < min_matches or len(walls) == 0:
        return None
    centre = np.array([scanner_pose.x_m, scanner_pose.y_m])
    mid = 0.5 * (walls[:, :2] + walls[:, 2:])
    half = 0.5 * np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    near = np.linalg.norm(mid - centre, axis=1) <= range_m + half
    walls = walls[near]
    if len(walls) == 0:
        return None
    pose = scanner_pose
    matched, rmse = 0, math.inf
    points = np.ascontiguousarray(points, dtype=np.float64)
    walls = np.ascontiguousarray(walls, dtype=np.float64)
    sr = np.maximum(range_noise.near_m, range_noise.ratio * np.hypot(points[:, 0], points[:, 1]))
    weights = sigma_m**2 / (sigma_m**2 + sr * sr)
    for _ in range(iterations):
        matched, h0, g0, r2, lever2 = _normal_equations(
            points, pose.x_m, pose.y_m, pose.theta_rad, walls, max_distance_m, trim_m, weights
        )
        if matched < min_matches:
            return None
        pr = None
        if prior is not None and prior_information is not None:
            e = np.array(
                [
                    pose.x_m - prior.x_m,
                    pose.y_m - prior.y_m,
                    math.remainder(pose.theta_rad - prior.theta_rad, math.tau),
                ]
            )
            pr = (e, prior_information)
        dx, dy, dth = _step(h0, g0, lever2 / matched, damping, degeneracy_ratio, pr)
        # a rotation about the scanner position, then a translation
        pose = Pose2D(pose.x_m + dx, pose.y_m + dy, pose.theta_rad + dth)
        rmse = math.sqrt(r2 / matched)
        if math.hypot(dx, dy) < 1e-4 and abs(dth) < 1e-4:
            break
    return WallFit(pose, matched, rmse)
