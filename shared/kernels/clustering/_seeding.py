"""Shared pieces of the clustering kernels: finite-row filtering and greedy k-means++ seeding.

k-means++ (Arthur & Vassilvitskii 2007) in its *greedy* form (as scikit-learn uses): each new centre is the
best, by the resulting potential (eq. 24 with the centres so far), of ``2 + floor(ln k)`` candidates drawn
with probability proportional to the squared distance to the nearest centre already chosen. The random
draws come from ``numpy.random.default_rng(seed)`` in Python and are handed to the compiled loop as plain
uniform numbers, so a seed fixes the result.

Seeding stops early when every point coincides with a chosen centre (potential exactly 0): that is how the
kernels return fewer clusters than asked when there are fewer distinct points than ``n_clusters``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.types import BoolArray, FloatArray, as_points

__all__ = ["finite_points", "n_local_trials", "seed_draws"]


def finite_points(points: ArrayLike) -> tuple[FloatArray, BoolArray | None]:
    """The finite rows of ``points`` as a writeable C-contiguous ``(M, 2)`` array, and the finite mask.

    The mask is ``None`` when every row is finite (then no copy is made unless the input is read-only, so
    the compiled loops see one array type). O(N).
    """
    pts = as_points(points)
    ok = np.isfinite(pts)
    if ok.all():  # the flat test is much cheaper than the per-row one
        if not pts.flags.writeable:
            pts = pts.copy()
        return pts, None
    finite: BoolArray = np.asarray(ok.all(axis=1))
    return np.ascontiguousarray(pts[finite]), finite


def n_local_trials(n_clusters: int) -> int:
    """Candidates per new centre in greedy k-means++: ``2 + floor(ln k)`` (scikit-learn's choice)."""
    return 2 + int(math.log(n_clusters)) if n_clusters > 1 else 1


def seed_draws(rng: np.random.Generator, n_runs: int, n_clusters: int) -> FloatArray:
    """Uniform draws in [0, 1) for ``n_runs`` seedings of ``k`` centres: shape ``(n_runs, 1 + (k-1) L)``."""
    width = 1 + (n_clusters - 1) * n_local_trials(n_clusters)
    return rng.random((n_runs, width))


@njit
def _pick(cum: FloatArray, d2: FloatArray, r: float) -> int:
    """First ``i`` with ``cum[i] > r`` (so ``d2[i] > 0``); the last positive one if rounding overshoots."""
    lo = 0
    hi = cum.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if cum[mid] > r:
            hi = mid
        else:
            lo = mid + 1
    if lo >= cum.shape[0]:
        lo = cum.shape[0] - 1
        while lo > 0 and d2[lo] <= 0.0:
            lo -= 1
    return lo


@njit
def _kmeanspp(pts: FloatArray, k: int, trials: int, draws: FloatArray, centres: FloatArray) -> int:
    """Greedy k-means++: fill ``centres[:m]`` and return ``m`` (``m < k`` only if fewer distinct points).

    ``draws`` holds ``1 + (k-1)*trials`` uniforms. O(N k trials) time, O(N) memory. ``pts`` must be non-empty.
    """
    n = pts.shape[0]
    first = min(int(draws[0] * n), n - 1)
    centres[0, 0] = pts[first, 0]
    centres[0, 1] = pts[first, 1]
    d2 = np.empty(n)
    cum = np.empty(n)
    total = 0.0
    for i in range(n):
        dx = pts[i, 0] - centres[0, 0]
        dy = pts[i, 1] - centres[0, 1]
        d2[i] = dx * dx + dy * dy
        total += d2[i]
        cum[i] = total
    m = 1
    while m < k and total > 0.0:
        best_pot = np.inf
        best = 0
        for t in range(trials):
            cand = _pick(cum, d2, draws[1 + (m - 1) * trials + t] * total)
            cx = pts[cand, 0]
            cy = pts[cand, 1]
            pot = 0.0
            for i in range(n):
                dx = pts[i, 0] - cx
                dy = pts[i, 1] - cy
                dd = dx * dx + dy * dy
                pot += dd if dd < d2[i] else d2[i]
            if pot < best_pot:
                best_pot = pot
                best = cand
        cx = pts[best, 0]
        cy = pts[best, 1]
        centres[m, 0] = cx
        centres[m, 1] = cy
        total = 0.0
        for i in range(n):
            dx = pts[i, 0] - cx
            dy = pts[i, 1] - cy
            dd = dx * dx + dy * dy
            if dd < d2[i]:
                d2[i] = dd
            total += d2[i]
            cum[i] = total
        m += 1
    return m
