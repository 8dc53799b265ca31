"""Library equivalents of the kernels, timed in the same run as the kernels (the benchmark's baseline).

These are straightforward compositions of scikit-learn, scikit-fuzzy, scipy and numpy calls, the way one
would glue the paper's pipeline together from off-the-shelf parts. They are references, not kernels.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from shared.types import FloatArray, IntArray, Pose2D

__all__ = [
    "cmeans_skfuzzy",
    "dbscan_sklearn",
    "dilation_ndimage",
    "erosion_ndimage",
    "hough_cluster_numpy",
    "icp_ckdtree",
    "kmeans_sklearn",
    "svd_lines_numpy",
]


def dbscan_sklearn(points: FloatArray, epsilon_m: float, min_points: int) -> IntArray:
    """scikit-learn DBSCAN labels (-1 = noise)."""
    from sklearn.cluster import DBSCAN

    labels: IntArray = DBSCAN(eps=epsilon_m, min_samples=min_points).fit(points).labels_
    return labels


def kmeans_sklearn(
    points: FloatArray, n_clusters: int, seed: int = 0, n_init: int = 10
) -> tuple[FloatArray, float]:
    """scikit-learn KMeans centres and inertia (eq. 24), best of ``n_init`` k-means++ starts."""
    from sklearn.cluster import KMeans

    km = KMeans(n_clusters=n_clusters, n_init=n_init, random_state=seed).fit(points)
    return km.cluster_centers_, float(km.inertia_)


def cmeans_skfuzzy(
    points: FloatArray,
    n_clusters: int,
    m: float = 2.0,
    error: float = 0.005,
    maxiter: int = 1000,
    seed: int = 0,
) -> tuple[FloatArray, float]:
    """scikit-fuzzy c-means centres and the eq. 25 objective computed from its memberships."""
    import skfuzzy

    centres, u, *_ = skfuzzy.cluster.cmeans(points.T, n_clusters, m, error=error, maxiter=maxiter, seed=seed)
    d2 = ((points[None, :, :] - centres[:, None, :]) ** 2).sum(axis=2)
    return np.asarray(centres), float(((u**m) * d2).sum())


def _dense_grid(points: FloatArray, cell_m: float, pad: int) -> Any:
    cells = np.floor(points / cell_m).astype(np.int64)
    lo = cells.min(axis=0) - pad
    shape = cells.max(axis=0) - lo + 1 + pad
    grid = np.zeros(tuple(int(s) for s in shape), dtype=bool)
    grid[cells[:, 0] - lo[0], cells[:, 1] - lo[1]] = True
    return grid


def _plus(psi_h: int, psi_v: int, psi_c: int) -> Any:
    r = max(psi_h, psi_v, psi_c)
    el = np.zeros((2 * r + 1, 2 * r + 1), dtype=bool)
    el[r - psi_h : r + psi_h + 1, r] = True
    el[r, r - psi_v : r + psi_v + 1] = True
    for k in range(-psi_c, psi_c + 1):
        el[r + k, r + k] = el[r + k, r - k] = True
    return el


def erosion_ndimage(points: FloatArray, cell_m: float, psi: tuple[int, int, int]) -> int:
    """scipy.ndimage binary erosion of the dense occupancy grid; returns the surviving cell count."""
    grid = _dense_grid(points, cell_m, pad=max(psi) + 1)
    return int(ndimage.binary_erosion(grid, structure=_plus(*psi)).sum())


def dilation_ndimage(points: FloatArray, cell_m: float, psi: tuple[int, int, int]) -> int:
    """scipy.ndimage binary dilation of the dense occupancy grid; returns the occupied cell count."""
    grid = _dense_grid(points, cell_m, pad=max(psi) + 1)
    return int(ndimage.binary_dilation(grid, structure=_plus(*psi)).sum())


def icp_ckdtree(
    reference: FloatArray,
    current: FloatArray,
    initial: Pose2D,
    max_iterations: int = 30,
    max_correspondence_m: float = 0.3,
    tolerance: float = 1e-4,
) -> Pose2D:
    """Textbook point-to-point ICP with a cKDTree and an SVD (Kabsch) alignment per iteration."""
    tree = cKDTree(reference)
    pose = initial
    for _ in range(max_iterations):
        moved = pose.transform_points(current)
        dist, idx = tree.query(moved, distance_upper_bound=max_correspondence_m)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            break
        src, dst = moved[ok], reference[idx[ok]]
        mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
        u, _, vt = np.linalg.svd((src - mu_s).T @ (dst - mu_d))
        rot = vt.T @ u.T
        if np.linalg.det(rot) < 0:
            vt[-1] *= -1
            rot = vt.T @ u.T
        t = mu_d - rot @ mu_s
        step = Pose2D(float(t[0]), float(t[1]), math.atan2(rot[1, 0], rot[0, 0]))
        pose = step @ pose
        if math.hypot(step.x_m, step.y_m) < tolerance and abs(step.theta_rad) < tolerance:
            break
    return pose


def hough_cluster_numpy(
    points: FloatArray,
    groups: IntArray,
    delta: int = 1,
    theta_step_deg: float = 1.0,
    rho_step_m: float = 0.02,
) -> FloatArray:
    """Algorithm 2 with plain numpy per group: vote, keep cells >= max - delta, average (rho, theta)."""
    thetas = np.deg2rad(np.arange(0.0, 180.0, theta_step_deg))
    cos_t, sin_t = np.cos(thetas), np.sin(thetas)
    out = []
    for g in np.unique(groups[groups >= 0]):
        pts = points[groups == g]
        if len(pts) < 2:
            continue
        rho = pts[:, :1] * cos_t + pts[:, 1:] * sin_t
        lo = rho.min()
        ri = np.rint((rho - lo) / rho_step_m).astype(np.int64)
        acc = np.zeros((int(ri.max()) + 1, len(thetas)), dtype=np.int64)
        np.add.at(acc, (ri, np.broadcast_to(np.arange(len(thetas)), ri.shape)), 1)
        r_i, t_i = np.nonzero(acc >= acc.max() - delta)
        out.append((float((r_i * rho_step_m + lo).mean()), float(thetas[t_i].mean())))
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def svd_lines_numpy(points: FloatArray, groups: IntArray) -> FloatArray:
    """Total-least-squares line per group with numpy.linalg.svd: ``(G, 2)`` of (rho, theta)."""
    out = []
    for g in np.unique(groups[groups >= 0]):
        pts = points[groups == g]
        if len(pts) < 2:
            continue
        mu = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - mu)
        normal = vt[-1]
        theta = math.atan2(normal[1], normal[0])
        out.append((float(mu @ normal), theta))
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)
