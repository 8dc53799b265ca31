"""What a scan match tells, per direction: the information matrix of an alignment and its inlier share.

For the pose ``x = (t_x, t_y, theta)`` of a scan ``current`` in the frame of ``reference`` (both ``(N, 2)``
point sets in metres), each current point ``p`` paired with a reference point that has a straight
neighbourhood of normal ``n`` contributes the point-to-line residual ``n . (R p + t) - c`` with Jacobian
``J = [n_x, n_y, n . (R' p)]`` (``R'`` the derivative of the rotation) and variance
``sigma_m^2 + sigma_r(|p|)^2`` (the match's own noise and the scanner's range noise at the return's range,
:mod:`shared.pipeline.rangenoise`); the information is ``sum J^T J / variance`` (the Gauss-Newton Hessian
of point-to-line ICP, Censi 2007 without the correlation term). It is large across walls and near zero
along a featureless corridor, which is what a pose-graph edge must know: a loop closure in a corridor
fixes the pose across it and not along it.

The neighbourhood's normal is the smallest eigenvector of the scatter of the reference points within
``max_distance_m`` (at least ``neighbours`` of them); neighbourhoods whose smaller eigenvalue exceeds
``max_ratio`` of the larger (a corner, a blob) take no part. At most ``max_points`` current points are
used (even stride), so the information of a long-range scan is not that of thousands of returns whose
errors are correlated. Lines fitted to a few noisy returns still carry some information along a
featureless corridor (about 4 cm one sigma for a URG-04LX at 1 m from the walls); :func:`scan_edge` uses
the front end's own local lines and their direction test instead.

Pure; O(N log M) with scipy's cKDTree (the reference tree may be passed in, built once per keyframe).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from shared.pipeline.fusion_solve import fuse_with_odometry
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
from shared.types import FloatArray, IntArray, Pose2D

__all__ = ["MatchInformation", "match_information", "scan_edge"]


@dataclass(frozen=True, slots=True)
class MatchInformation:
    """The information ``(3, 3)`` of an alignment (per m^2, m rad, rad^2), the share of current points
    within the inlier distance of a reference point, and how many pairs gave the information."""

    information: FloatArray
    inlier_share: float
    pairs: int


def _group_moments(
    points: FloatArray, groups: list[list[int]], sizes: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per group of ``points`` ``(M, 2)`` (index lists, ``sizes`` their lengths, each > 0) the second
    central moments ``(sxx, syy, sxy)`` (sums of the products of the deviations from the group's mean),
    for all groups at once (two passes: the means, then the products). O(sum of sizes)."""
    idx = np.fromiter(itertools.chain.from_iterable(groups), dtype=np.intp, count=int(sizes.sum()))
    group = np.repeat(np.arange(len(sizes)), sizes)
    x, y = points[idx, 0], points[idx, 1]
    dx = x - (np.bincount(group, x, len(sizes)) / sizes)[group]
    dy = y - (np.bincount(group, y, len(sizes)) / sizes)[group]
    n = len(sizes)
    sxx: FloatArray = np.bincount(group, dx * dx, n).astype(np.float64)
    syy: FloatArray = np.bincount(group, dy * dy, n).astype(np.float64)
    sxy: FloatArray = np.bincount(group, dx * dy, n).astype(np.float64)
    return sxx, syy, sxy


def match_information(
    reference: FloatArray,
    current: FloatArray,
    pose: Pose2D,
    *,
    inlier_m: float = 0.08,
    sigma_m: float = 0.02,
    range_noise: RangeNoise = NO_RANGE_NOISE,
    max_distance_m: float = 0.15,
    neighbours: int = 5,
    max_ratio: float = 0.1,
    max_points: int = 150,
    tree: cKDTree | None = None,
) -> MatchInformation:
    """Information and inlier share of ``current`` placed at ``pose`` in ``reference``'s frame (module
    docstring). Points farther than ``max_distance_m`` from the reference give no information; the inlier
    share counts every finite current point."""
    ref = reference[np.isfinite(reference).all(axis=1)]
    cur = current[np.isfinite(current).all(axis=1)]
    if len(ref) < neighbours or len(cur) == 0:
        return MatchInformation(np.zeros((3, 3)), 0.0, 0)
    tree = tree if tree is not None else cKDTree(ref)
    moved = pose.transform_points(cur)
    dist, _ = tree.query(moved, k=1)
    share = float(np.mean(dist <= inlier_m))
    if len(cur) > max_points:
        pick = (np.arange(max_points) * len(cur)) // max_points
        cur, moved = cur[pick], moved[pick]
    # each used point's neighbourhood in the reference: the points within ``max_distance_m`` of it (a
    # radius, not a count: a dense submap's few nearest points are all noise)
    hoods = tree.query_ball_point(moved, r=max_distance_m)
    sizes = np.fromiter((len(h) for h in hoods), dtype=np.intp, count=len(hoods))
    full = sizes >= neighbours
    if not full.any():
        return MatchInformation(np.zeros((3, 3)), share, 0)
    cur, moved = cur[full], moved[full]
    sxx, syy, sxy = _group_moments(ref, [h for h, f in zip(hoods, full, strict=True) if f], sizes[full])
    # eigenvalues of [[sxx, sxy], [sxy, syy]] and the normal (eigenvector of the smaller one)
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy**2, 0.0))
    small, large = half_tr - root, half_tr + root
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # direction of the larger eigenvector
    normal = np.stack([-np.sin(angle), np.cos(angle)], axis=1)
    straight = small <= max_ratio * np.maximum(large, 1e-18)
    if not straight.any():
        return MatchInformation(np.zeros((3, 3)), share, 0)
    cur, moved, normal = cur[straight], moved[straight], normal[straight]
    rotated = moved - np.array([pose.x_m, pose.y_m])  # R p
    jac = np.column_stack(
        [normal[:, 0], normal[:, 1], normal[:, 0] * -rotated[:, 1] + normal[:, 1] * rotated[:, 0]]
    )
    ranges = np.hypot(cur[:, 0], cur[:, 1])
    sigma_r = np.maximum(range_noise.near_m, range_noise.ratio * ranges)
    weight = 1.0 / (sigma_m**2 + sigma_r**2)
    info = (jac * weight[:, None]).T @ jac
    return MatchInformation(0.5 * (info + info.T), share, len(cur))


def _robot_to_scanner_jacobian(motion: Pose2D, offset: Pose2D) -> FloatArray:
    """``d(x_s) / d(x_r)`` for the scanner motion ``x_s = O^-1 x_r O`` of the robot motion ``x_r`` in
    ``(x, y, theta)`` coordinates (central differences; exact to about 1e-9). O(1)."""
    inv = offset.inverse()
    jac = np.zeros((3, 3))
    base = np.array(motion.as_tuple())
    for a in range(3):
        step = np.zeros(3)
        step[a] = 1e-6
        hi = (inv @ Pose2D(*(base + step)) @ offset).as_tuple()
        lo = (inv @ Pose2D(*(base - step)) @ offset).as_tuple()
        diff = np.array(hi) - np.array(lo)
        diff[2] = math.remainder(diff[2], math.tau)
        jac[:, a] = diff / 2e-6
    return jac


def scan_edge(
    reference_scan: FloatArray,
    current_scan: FloatArray,
    motion: Pose2D,
    laser_offset: Pose2D,
    *,
    sigma_m: float,
    range_noise: RangeNoise = NO_RANGE_NOISE,
    refine: bool = False,
) -> tuple[Pose2D, FloatArray] | None:
    """A pose-graph edge from two scans (scanner frames, m, beam order): the robot ``motion`` from the
    reference to the current keyframe (robot frames) and its information ``(3, 3)`` in robot
    coordinates, by the front end's own point-to-line model
    (:func:`shared.pipeline.fusion_solve.fuse_with_odometry`
    without odometry: local lines of the reference in beam order, each pair's variance ``sigma_m^2`` plus
    the range noise). ``refine``: first solve the point-to-line match from ``motion`` (a loop closure's
    final step), else take ``motion`` as it is (the front end's chain). ``None`` with too few pairs.
    O(N + M)."""
    offset = laser_offset
    scanner = offset.inverse() @ motion @ offset
    fused = fuse_with_odometry(
        reference_scan,
        current_scan,
        scanner,
        scanner,
        np.eye(3),
        iterations=10 if refine else 1,
        scan_only=True,
        sigma_m=sigma_m,
        range_noise=range_noise,
    )
    if fused is None:
        return None
    pose = offset @ fused.pose @ offset.inverse() if refine else motion
    jac = _robot_to_scanner_jacobian(pose, offset)
    info = jac.T @ fused.information @ jac
    return pose, 0.5 * (info + info.T)
