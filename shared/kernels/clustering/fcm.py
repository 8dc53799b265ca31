"""Fuzzy c-means clustering (paper §3.3, eq. 25-26), started from greedy k-means++ centres.

Eq. 25, the objective minimised, is ``Q_m = sum_i sum_j u_ij^m ||p_i - c_j||^2`` (m^2); eq. 26 gives the
memberships from the centres and the centres from the memberships; the paper stops when no membership
changes by ``tolerance`` or more between two iterations. The iteration is the eq. 26 update with adaptive
over-relaxation and a monotone safeguard (see :mod:`shared.kernels.clustering._fuzzy`); ``n_iter`` counts
membership passes.

Behaviour at the edges (documented contract):

* non-finite rows are ignored: label ``-1`` and a membership row of zeros;
* no finite point: zero centroids, ``(N, 0)`` memberships, ``objective = 0``, ``n_iter = 0``;
* fewer distinct finite points than ``n_clusters``: as many clusters as distinct points;
* a point on a centre belongs to it with membership 1 (no NaN from the 0/0 in eq. 26).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels.base import ClusteringKernel
from shared.kernels.clustering._fuzzy import _fcm
from shared.kernels.clustering._seeding import _kmeanspp, finite_points, n_local_trials, seed_draws
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Clusters, freeze

__all__ = ["FuzzyCMeans", "FuzzyCMeansParams"]


class FuzzyCMeansParams(KernelParams):
    """Parameters of :class:`FuzzyCMeans`."""

    n_clusters: int = param(
        2,
        description="Number of clusters C (the message's cluster-no)",
        ge=1,
        le=1000,
        paper="§3.3, Listing 1",
    )
    fuzzifier: float = param(
        2.0,
        description="Fuzzifier m of eq. 25-26 (near 1 = hard, larger = fuzzier)",
        gt=1.0,
        le=10.0,
        paper="§3.3 eq. 25",
    )
    tolerance: float = param(
        0.005, description="Stop when no membership changes by this much (nu)", gt=0.0, lt=1.0, paper="§3.3"
    )
    max_iterations: int = param(300, description="Maximum membership/centre updates", ge=1, le=10000)
    seed: int = param(0, description="Seed of numpy.random.default_rng for the k-means++ start", ge=0)


@register
class FuzzyCMeans(ClusteringKernel[FuzzyCMeansParams]):
    """Fuzzy c-means (paper §3.3, eq. 25-26) from a k-means++ start; labels are the highest membership.

    Time O(N C (ln C + passes)), memory O(N C) for the memberships. ``fuzzifier == 2`` (the default) runs a
    pow-free vectorised pass; any other value takes one ``pow`` per point and centre, about 10x slower.
    Deterministic for a given ``seed``.
    """

    name = "fcm"
    version = "1.0.0"
    Params = FuzzyCMeansParams

    def apply(self, points: ArrayLike) -> Clusters:
        """Cluster ``points`` ``(N, 2)`` (metres) into ``C' <= n_clusters`` fuzzy clusters."""
        p = self.params
        pts, finite = finite_points(points)
        n_total = pts.shape[0] if finite is None else finite.shape[0]
        labels = np.full(n_total, -1, dtype=np.intp)
        if pts.shape[0] == 0:
            centroids = np.zeros((0, 2), dtype=np.float64)
            memberships = np.zeros((n_total, 0), dtype=np.float64)
            freeze(centroids, labels, memberships)
            return Clusters(centroids, labels, 0.0, 0, memberships)
        k = min(p.n_clusters, pts.shape[0])
        draws = seed_draws(np.random.default_rng(p.seed), 1, k)[0]
        centres = np.empty((k, 2), dtype=np.float64)
        m = _kmeanspp(pts, k, n_local_trials(k), draws, centres)
        centres = np.ascontiguousarray(centres[:m])
        u = np.empty((pts.shape[0], m), dtype=np.float64)
        objective, n_iter, _converged = _fcm(pts, centres, p.fuzzifier, p.tolerance, p.max_iterations, u)
        found = np.argmax(u, axis=1)
        if finite is None:
            labels = found
            memberships = u
        else:
            labels[finite] = found
            memberships = np.zeros((n_total, m), dtype=np.float64)
            memberships[finite] = u
        freeze(centres, labels, memberships)
        return Clusters(centres, labels, float(objective), int(n_iter), memberships)
