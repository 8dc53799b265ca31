"""k-means clustering (paper §3.3, eq. 24): greedy k-means++ seeding, Lloyd iterations, best of restarts.

Eq. 24, the objective minimised, is ``Q = sum_j sum_{i in j} ||p_i - c_j||^2`` (m^2).

Behaviour at the edges (documented contract):

* non-finite rows are ignored and get label ``-1``;
* no finite point: zero centroids, ``objective = 0``, ``n_iter = 0``;
* fewer distinct finite points than ``n_clusters``: as many clusters as distinct points (each centroid is one
  of them, ``objective = 0``);
* a cluster emptied during Lloyd is re-seeded with the point farthest from its centre; in the rare case the
  final assignment still leaves a centroid without points, that centroid is kept.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels.base import ClusteringKernel
from shared.kernels.clustering._lloyd import _kmeans_runs
from shared.kernels.clustering._seeding import finite_points, n_local_trials, seed_draws
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Clusters, freeze

__all__ = ["KMeans", "KMeansParams"]


class KMeansParams(KernelParams):
    """Parameters of :class:`KMeans`."""

    n_clusters: int = param(
        2,
        description="Number of clusters k (the message's cluster-no)",
        ge=1,
        le=1000,
        paper="§3.3, Listing 1",
    )
    max_iterations: int = param(300, description="Maximum Lloyd iterations per restart", ge=1, le=10000)
    tolerance_m: float = param(
        1e-4, description="Stop when no centroid moves farther than this", unit="m", ge=0.0, le=1.0
    )
    n_init: int = param(
        10, description="Most k-means++ restarts; the lowest eq. 24 objective is kept", ge=1, le=100
    )
    seed: int = param(0, description="Seed of numpy.random.default_rng for the k-means++ draws", ge=0)


@register
class KMeans(ClusteringKernel[KMeansParams]):
    """k-means (paper §3.3, eq. 24): greedy k-means++ seeding and Lloyd iterations, best of n_init restarts.

    Time O(n_init N k (ln k + iterations)), memory O(N + k). Deterministic for a given ``seed``.
    """

    name = "kmeans"
    version = "1.0.0"
    Params = KMeansParams

    def apply(self, points: ArrayLike) -> Clusters:
        """Cluster ``points`` ``(N, 2)`` (metres); centroids ``(k', 2)`` with ``k' <= n_clusters``."""
        p = self.params
        pts, finite = finite_points(points)
        n_total = pts.shape[0] if finite is None else finite.shape[0]
        labels = np.full(n_total, -1, dtype=np.intp)
        if pts.shape[0] == 0:
            centroids = np.zeros((0, 2), dtype=np.float64)
            freeze(centroids, labels)
            return Clusters(centroids, labels, 0.0, 0)
        k = min(p.n_clusters, pts.shape[0])
        draws = seed_draws(np.random.default_rng(p.seed), p.n_init, k)
        centres = np.empty((k, 2), dtype=np.float64)
        found = np.empty(pts.shape[0], dtype=np.intp)
        m, objective, n_iter = _kmeans_runs(
            pts, k, n_local_trials(k), draws, p.max_iterations, p.tolerance_m**2, centres, found
        )
        if finite is None:
            labels = found
        else:
            labels[finite] = found
        centroids = np.ascontiguousarray(centres[:m])
        freeze(centroids, labels)
        return Clusters(centroids, labels, float(objective), int(n_iter))
