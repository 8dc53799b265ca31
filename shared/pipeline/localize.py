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
from shared.types import FloatArray, IntArray, Pose2D

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
def _nearest_segment(points: FloatArray, walls: FloatArray) -> tuple[FloatArray, IntArray]:
    """Distance from each point to the nearest wall segment and that wall's index. O(N W)."""
    n, w = points.shape[0], walls.shape[0]
    best = np.full(n, np.inf)
    which = np.zeros(n, dtype=np.intp)
    for j in range(w):
        ax, ay = walls[j, 0], walls[j, 1]
        ex, ey = walls[j, 2] - ax, walls[j, 3] - ay
        len2 = max(ex * ex + ey * ey, 1e-12)
        for i in range(n):
            px, py = points[i, 0] - ax, points[i, 1] - ay
            t = min(max((px * ex + py * ey) / len2, 0.0), 1.0)
            dx, dy = px - t * ex, py - t * ey
            d2 = dx * dx + dy * dy
            if d2 < best[i]:
                best[i] = d2
                which[i] = j
    return np.sqrt(best), which


def _nearest_wall(points: FloatArray, walls: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Distance to the nearest wall segment, that wall's unit normal and its offset (n . a)."""
    dist, j = _nearest_segment(np.ascontiguousarray(points), np.ascontiguousarray(walls))
    ab = walls[:, 2:] - walls[:, :2]
    length = np.maximum(np.hypot(ab[:, 0], ab[:, 1]), 1e-12)
    normal = np.column_stack([-ab[:, 1], ab[:, 0]]) / length[:, None]
    offset = (normal * walls[:, :2]).sum(axis=1)
    return dist, normal[j], offset[j]


def _step(
    n: FloatArray,
    jt: FloatArray,
    r: FloatArray,
    lever: FloatArray,
    damping: float,
    ratio: float,
    prior: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[float, float, float]:
    """The damped Gauss-Newton step ``(dx, dy, dtheta)`` for the residuals ``r`` with normals ``n`` and
    rotation derivatives ``jt``; with ``ratio > 0`` only along the eigen-directions of the normal matrix
    (in ``(dx, dy, s dtheta)``, ``s`` the RMS ``lever``) whose eigenvalue exceeds ``ratio`` times the
    largest: directions the walls barely constrain get no update, or with a ``prior`` ``(e, P)`` (the pose
    minus the prior pose as ``(dx, dy, dtheta)`` and its information, in units of the residuals' variance)
    move towards the prior by its share of the information along them. O(N)."""
    if ratio <= 0.0:  # the plain damped step
        a = np.column_stack([n, jt])
        h = a.T @ a + damping * np.diag([1.0, 1.0, 4.0])
        dx, dy, dth = (float(v) for v in np.linalg.solve(h, -(a.T @ r)))
        return dx, dy, dth
    scale = max(float(np.sqrt(np.mean(np.einsum("ij,ij->i", lever, lever)))), 1e-3)
    a = np.column_stack([n, jt / scale])  # unknowns (dx, dy, scale dtheta): all lengths
    h = a.T @ a + damping * np.diag([1.0, 1.0, 4.0 / scale**2])  # the same damping as above
    w, v = np.linalg.eigh(h)
    strong = w > ratio * w[-1]
    keep = v[:, strong]
    lam = w[strong]
    step = keep @ ((keep.T @ -(a.T @ r)) / lam)
    if prior is not None:
        e, info = prior
        unscale = np.array([1.0, 1.0, 1.0 / scale])
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
) -> WallFit | None:
    """Refine ``scanner_pose`` so the scan ``points`` (scanner frame) lie on ``walls`` (world frame).

    ``degeneracy_ratio`` (0: off, the plain damped step) leaves out poorly constrained directions (module
    docstring); with a ``prior`` scanner pose (odometry's) and its ``prior_information`` (3x3, per m^2
    and rad^2, already scaled to the residuals' variance) those directions follow the prior by information
    instead of keeping ``scanner_pose``'s value (issue 19: a corridor's axis follows the wheels).
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
    for _ in range(iterations):
        world = pose.transform_points(points)
        dist, normal, offset = _nearest_wall(world, walls)
        use = dist <= max_distance_m
        resid = (normal * world).sum(axis=1) - offset
        use &= np.abs(resid) <= max(trim_m, 1e-6)
        matched = int(use.sum())
        if matched < min_matches:
            return None
        n, r = normal[use], resid[use]
        lever = world[use] - np.array([pose.x_m, pose.y_m])
        # d(residual) / d(theta) for a rotation about the scanner: n . (J lever), J = rot90
        jt = -n[:, 0] * lever[:, 1] + n[:, 1] * lever[:, 0]
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
        dx, dy, dth = _step(n, jt, r, lever, damping, degeneracy_ratio, pr)
        # a rotation about the scanner position, then a translation
        pose = Pose2D(pose.x_m + dx, pose.y_m + dy, pose.theta_rad + dth)
        rmse = float(np.sqrt(np.mean(r * r)))
        if math.hypot(dx, dy) < 1e-4 and abs(dth) < 1e-4:
            break
    return WallFit(pose, matched, rmse)
