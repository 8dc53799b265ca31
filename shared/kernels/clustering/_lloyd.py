"""Compiled Lloyd iterations for k-means (paper §3.3, eq. 24), with restarts from greedy k-means++.

One Lloyd iteration assigns every point to its nearest centre and moves each centre to the mean of its
points, which never increases eq. 24. The assignment uses Hamerly's bounds to skip points whose label
cannot change (same iterates as plain Lloyd, far fewer distance computations once labels settle). A
centre left without points is re-seeded with the point farthest from its own centre (scikit-learn's
rule). Iteration stops when no centre moves more than the tolerance.
"""

from __future__ import annotations

import numpy as np

from shared.kernels._jit import njit
from shared.kernels.clustering._seeding import _kmeanspp
from shared.types import FloatArray, IntArray

__all__: list[str] = []

#: Relative difference below which two restarts count as the same optimum.
_SAME = 1e-9


@njit
def _nearest2(x: float, y: float, centres: FloatArray, m: int) -> tuple[int, float, float]:
    """Nearest of ``centres[:m]`` to ``(x, y)``: (index, its squared distance, the 2nd smallest). O(m)."""
    best = np.inf
    second = np.inf
    lab = 0
    for j in range(m):
        dx = x - centres[j, 0]
        dy = y - centres[j, 1]
        dd = dx * dx + dy * dy
        if dd < best:
            second = best
            best = dd
            lab = j
        elif dd < second:
            second = dd
    return lab, best, second


@njit
def _half_gaps(centres: FloatArray, m: int, gap: FloatArray) -> None:
    """``gap[j]`` = half the distance from centre ``j`` to its nearest other centre (inf if alone). O(m^2)."""
    for j in range(m):
        gap[j] = np.inf
    for j in range(m):
        for q in range(j + 1, m):
            dx = centres[j, 0] - centres[q, 0]
            dy = centres[j, 1] - centres[q, 1]
            h = 0.5 * np.sqrt(dx * dx + dy * dy)
            if h < gap[j]:
                gap[j] = h
            if h < gap[q]:
                gap[q] = h


@njit
def _lloyd(
    pts: FloatArray,
    centres: FloatArray,
    m: int,
    max_iter: int,
    tol2: float,
    labels: IntArray,
    upper: FloatArray,
    lower: FloatArray,
) -> tuple[float, int]:
    """Lloyd iterations on ``centres[:m]`` in place, accelerated with Hamerly's bounds; returns (eq. 24, its).

    Hamerly (2010) keeps per point an upper bound on the distance to its centre and a lower bound on the
    distance to any other centre, and skips the O(m) nearest-centre search when the bounds prove the label
    cannot change; the iterates are exactly Lloyd's. Stops when the largest squared centre move is
    ``<= tol2`` or after ``max_iter`` updates; a last exact assignment makes the labels and the objective
    match the returned centres. O(N m) worst case per iteration, O(N + m^2) typical once the labels settle.
    """
    n = pts.shape[0]
    sums = np.zeros((m, 2))
    counts = np.zeros(m, dtype=np.int64)
    gap = np.empty(m)
    move = np.empty(m)
    for i in range(n):
        lab, best, second = _nearest2(pts[i, 0], pts[i, 1], centres, m)
        labels[i] = lab
        upper[i] = np.sqrt(best)
        lower[i] = np.sqrt(second)
        sums[lab, 0] += pts[i, 0]
        sums[lab, 1] += pts[i, 1]
        counts[lab] += 1
    it = 0
    while True:
        for j in range(m):
            if counts[j] == 0:
                # re-seed an empty cluster with the point farthest from its centre (exact distances)
                far = -1
                far_d = 0.0
                for i in range(n):
                    a = labels[i]
                    dx = pts[i, 0] - centres[a, 0]
                    dy = pts[i, 1] - centres[a, 1]
                    upper[i] = np.sqrt(dx * dx + dy * dy)
                    if upper[i] > far_d and counts[a] > 1:
                        far_d = upper[i]
                        far = i
                if far < 0:
                    continue
                a = labels[far]
                sums[a, 0] -= pts[far, 0]
                sums[a, 1] -= pts[far, 1]
                counts[a] -= 1
                labels[far] = j
                sums[j, 0] = pts[far, 0]
                sums[j, 1] = pts[far, 1]
                counts[j] = 1
                upper[far] = np.inf  # its centre moves onto it below; force a re-check
                lower[far] = 0.0
        top1 = 0.0
        top2 = 0.0
        arg1 = -1
        for j in range(m):
            move[j] = 0.0
            if counts[j] > 0:
                cx = sums[j, 0] / counts[j]
                cy = sums[j, 1] / counts[j]
                dx = cx - centres[j, 0]
                dy = cy - centres[j, 1]
                move[j] = np.sqrt(dx * dx + dy * dy)
                centres[j, 0] = cx
                centres[j, 1] = cy
            if move[j] > top1:
                top2 = top1
                top1 = move[j]
                arg1 = j
            elif move[j] > top2:
                top2 = move[j]
        it += 1
        done = top1 * top1 <= tol2 or it >= max_iter
        _half_gaps(centres, m, gap)
        total = 0.0
        for i in range(n):
            a = labels[i]
            upper[i] += move[a]
            lower[i] -= top2 if a == arg1 else top1
            bound = max(gap[a], lower[i])
            x = pts[i, 0]
            y = pts[i, 1]
            if done:
                # last pass: exact eq. 24 and labels that match the returned centres
                dx = x - centres[a, 0]
                dy = y - centres[a, 1]
                dd = dx * dx + dy * dy
                if dd > bound * bound:
                    lab, best, _second = _nearest2(x, y, centres, m)
                    if best < dd:
                        labels[i] = lab
                        dd = best
                total += dd
                continue
            if upper[i] <= bound:
                continue
            dx = x - centres[a, 0]
            dy = y - centres[a, 1]
            upper[i] = np.sqrt(dx * dx + dy * dy)
            if upper[i] <= bound:
                continue
            lab, best, second = _nearest2(x, y, centres, m)
            upper[i] = np.sqrt(best)
            lower[i] = np.sqrt(second)
            if lab != a:
                sums[a, 0] -= x
                sums[a, 1] -= y
                counts[a] -= 1
                sums[lab, 0] += x
                sums[lab, 1] += y
                counts[lab] += 1
                labels[i] = lab
        if done:
            break
    return total, it


@njit
def _kmeans_runs(
    pts: FloatArray,
    k: int,
    trials: int,
    draws: FloatArray,
    max_iter: int,
    tol2: float,
    best_centres: FloatArray,
    best_labels: IntArray,
) -> tuple[int, float, int]:
    """Seed and run Lloyd once per row of ``draws``; keep the lowest eq. 24. Returns (k found, Q, iterations).

    Restarts stop early once the best objective so far has been reached a second time (relative ``_SAME``):
    the same optimum from two independent seedings means it has a large basin and further restarts rarely
    beat it. This makes small k (the online case, typically one optimum) cost about two runs, while large k
    (every run a different local optimum) uses all of them. ``best_centres`` is ``(k, 2)`` and ``best_labels``
    ``(N,)``; only the first ``k found`` centres are set. O(runs N k (trials + iterations)).
    """
    n = pts.shape[0]
    centres = np.empty((k, 2))
    labels = np.empty(n, dtype=best_labels.dtype)
    upper = np.empty(n)
    lower = np.empty(n)
    best_obj = np.inf
    best_m = 0
    best_it = 0
    hits = 0
    for r in range(draws.shape[0]):
        m = _kmeanspp(pts, k, trials, draws[r], centres)
        obj, it = _lloyd(pts, centres, m, max_iter, tol2, labels, upper, lower)
        if obj < best_obj * (1.0 - _SAME):
            best_obj = obj
            best_m = m
            best_it = it
            best_centres[:m] = centres[:m]
            best_labels[:] = labels
            hits = 1
        elif obj <= best_obj * (1.0 + _SAME):
            hits += 1
        if m == 1 or best_obj <= 0.0 or hits >= 2:
            break  # one centre (the mean), a perfect fit, or a repeated optimum
    return best_m, best_obj, best_it
