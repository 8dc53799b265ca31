"""DBSCAN noise removal (paper §3.2.1): keep core and border points, drop noise points.

A point is a *core* point when at least ``min_points`` points (itself included, like scikit-learn's
``min_samples``) lie within distance ``epsilon_m`` of it (distance <= epsilon, as in scikit-learn); a *border*
point is a non-core point within ``epsilon_m`` of a core point; every other point is *noise*. Core points
within ``epsilon_m`` of each other share a cluster.

The classification and the labels equal ``sklearn.cluster.DBSCAN(eps, min_samples).fit(points).labels_``:
clusters are numbered by their lowest-index core point and a border point takes the lowest-numbered cluster
among its core neighbours, which is what scikit-learn's expansion order produces. Squared distances are
compared with ``epsilon**2`` exactly as scikit-learn's KD/ball trees do; its brute-force path (which
``algorithm="auto"`` picks for tiny inputs) may round a pair lying within an ulp of epsilon the other way.

Algorithm: points are binned into square cells slightly larger than ``epsilon_m`` (a numba hash table, so
memory does not grow with the area covered), each point is compared only with the points of its own and the
8 surrounding cells, neighbour counts give the core points, a union-find joins core points closer than
``epsilon_m`` and a last pass labels the border points. Time O(N + P) for P candidate pairs, memory O(N).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.kernels._jit import njit
from shared.kernels.base import NoiseRemovalKernel
from shared.kernels.noise._cellhash import Int64Array, _build, _find, cell_indices
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import NoiseResult, freeze
from shared.types import BoolArray, FloatArray, IntArray, as_points

__all__ = ["Dbscan", "DbscanParams", "dbscan_core_labels"]

# Cells are this much wider than epsilon so that two points within epsilon never land two cells apart
# through rounding of x / cell; exact while |coordinate| / epsilon < ~1e9 (100 km at 0.1 mm).
_CELL_MARGIN = 1.0 + 1e-6


class DbscanParams(KernelParams):
    """Parameters of :class:`Dbscan` (paper §3.2.1, Listing 1: ``epsilon`` 5 cm)."""

    epsilon_m: float = param(
        0.05,
        description="Neighbourhood radius epsilon (distance <= epsilon counts)",
        unit="m",
        ge=1e-4,
        le=10.0,
        paper="§3.2.1, Listing 1",
    )
    min_points: int = param(
        3,
        description="MinPts: neighbours within epsilon, the point itself included, that make a core point "
        "(scikit-learn's min_samples)",
        ge=1,
        le=1000,
        paper="§3.2.1",
    )
    spacing_factor: float = param(
        1.4,
        description="Where the pipeline tells each point's beam spacing (range x angular step), the "
        "neighbourhood radius of that point is max(epsilon, spacing_factor x spacing): a wall seen at up "
        "to 45 deg incidence (1 / cos 45 deg = 1.41) keeps its neighbouring beams' returns at any range and "
        "on any scanner. 1.4 leaves the paper's 5 cm in force on a URG-04LX (0.35 deg) out to 5.8 m, past "
        "its range; on a 1 deg scanner it takes over beyond 2 m. 0: the paper's fixed epsilon everywhere",
        ge=0.0,
        le=20.0,
    )


@njit
def _find_root(parent: Int64Array, i: int) -> int:
    """Union-find root with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit
def _dbscan(
    x: FloatArray, y: FloatArray, r: FloatArray, ix: Int64Array, iy: Int64Array, min_points: int
) -> tuple[BoolArray, Int64Array]:
    """Core mask and labels (``-1`` = noise) of finite points ``x, y`` with neighbourhood radii ``r`` and
    cells ``ix, iy`` (at least ``max(r)`` wide): two points are neighbours when their distance is at most
    the larger of their radii (squared distances against squared radii, as scikit-learn compares)."""
    n = x.size
    cell, ucx, ucy, table = _build(ix, iy)
    m = ucx.size
    # counting sort of the points by cell: positions start[c]..start[c+1] hold cell c
    start = np.zeros(m + 1, dtype=np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(m):
        start[c + 1] += start[c]
    fill = start[:m].copy()
    order = np.empty(n, dtype=np.int64)
    pos = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cell[i]
        order[fill[c]] = i
        pos[i] = fill[c]
        fill[c] += 1
    xs = x[order]
    ys = y[order]
    r2 = r[order] * r[order]
    # the 3x3 block of cells around each cell; k = (dx + 1) * 3 + (dy + 1), k = 4 is the cell itself and
    # k = 5..8 ((0,1), (1,-1), (1,0), (1,1)) the "forward" half that visits every pair of cells once
    nb = np.empty((m, 9), dtype=np.int64)
    for c in range(m):
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                nb[c, (dx + 1) * 3 + dy + 1] = _find(table, ucx, ucy, ucx[c] + dx, ucy[c] + dy)

    count = np.ones(n, dtype=np.int64)
    for c in range(m):
        a0 = start[c]
        a1 = start[c + 1]
        for p in range(a0, a1):
            for q in range(p + 1, a1):
                dx_ = xs[p] - xs[q]
                dy_ = ys[p] - ys[q]
                if dx_ * dx_ + dy_ * dy_ <= max(r2[p], r2[q]):
                    count[p] += 1
                    count[q] += 1
        for k in range(5, 9):
            c2 = nb[c, k]
            if c2 < 0:
                continue
            b0 = start[c2]
            b1 = start[c2 + 1]
            for p in range(a0, a1):
                for q in range(b0, b1):
                    dx_ = xs[p] - xs[q]
                    dy_ = ys[p] - ys[q]
                    if dx_ * dx_ + dy_ * dy_ <= max(r2[p], r2[q]):
                        count[p] += 1
                        count[q] += 1
    core = count >= min_points

    parent = np.arange(n, dtype=np.int64)
    for c in range(m):
        a0 = start[c]
        a1 = start[c + 1]
        for k in range(4, 9):
            c2 = nb[c, k]
            if c2 < 0:
                continue
            b1 = start[c2 + 1]
            for p in range(a0, a1):
                if not core[p]:
                    continue
                b0 = p + 1 if k == 4 else start[c2]
                for q in range(b0, b1):
                    if not core[q]:
                        continue
                    dx_ = xs[p] - xs[q]
                    dy_ = ys[p] - ys[q]
                    if dx_ * dx_ + dy_ * dy_ <= max(r2[p], r2[q]):
                        rp = _find_root(parent, p)
                        rq = _find_root(parent, q)
                        if rp != rq:
                            parent[max(rp, rq)] = min(rp, rq)

    # clusters numbered by their lowest-index core point (input order), as scikit-learn does
    labels = np.full(n, -1, dtype=np.int64)
    cid = np.full(n, -1, dtype=np.int64)
    n_clusters = 0
    for i in range(n):
        p = pos[i]
        if core[p]:
            root = _find_root(parent, p)
            if cid[root] < 0:
                cid[root] = n_clusters
                n_clusters += 1
            labels[i] = cid[root]
    # border points: the lowest cluster among their core neighbours
    for i in range(n):
        p = pos[i]
        if core[p] or count[p] == 1:
            continue
        best = -1
        c = cell[i]
        for k in range(9):
            c2 = nb[c, k]
            if c2 < 0:
                continue
            for q in range(start[c2], start[c2 + 1]):
                if not core[q]:
                    continue
                dx_ = xs[p] - xs[q]
                dy_ = ys[p] - ys[q]
                if dx_ * dx_ + dy_ * dy_ <= max(r2[p], r2[q]):
                    lab = labels[order[q]]
                    if best < 0 or lab < best:
                        best = lab
        labels[i] = best
    core_in = np.empty(n, dtype=np.bool_)
    for i in range(n):
        core_in[i] = core[pos[i]]
    return core_in, labels


def dbscan_core_labels(
    points: ArrayLike, epsilon_m: float, min_points: int, radius_m: ArrayLike | None = None
) -> tuple[BoolArray, IntArray]:
    """DBSCAN of ``(N, 2)`` points: ``(core (N,) bool, labels (N,))``, labels ``-1`` for noise.

    Identical to ``sklearn.cluster.DBSCAN(eps=epsilon_m, min_samples=min_points)``'s ``labels_`` and core
    samples; non-finite rows are noise and are not counted as anyone's neighbour. ``radius_m`` ``(N,)``
    (metres, each at least ``epsilon_m``) gives each point its own neighbourhood radius instead: two points
    are neighbours when their distance is at most the larger of their two radii, which is scikit-learn's
    DBSCAN with ``eps=1`` on the distances divided by that larger radius. O(N + candidate pairs), the cells
    as wide as the largest radius.
    """
    pts = as_points(points)
    n = pts.shape[0]
    core = np.zeros(n, dtype=np.bool_)
    labels = np.full(n, -1, dtype=np.intp)
    finite = np.isfinite(pts).all(axis=1)
    if radius_m is not None:
        radius = np.asarray(radius_m, dtype=np.float64)
        if radius.shape != (n,):
            raise InvalidInputError(f"radius_m has shape {radius.shape}: expected ({n},), one per point")
        finite &= np.isfinite(radius)
    all_finite = bool(finite.all())
    fp = pts if all_finite else pts[finite]
    if fp.shape[0] == 0:
        return core, labels
    if radius_m is None:
        r = np.full(fp.shape[0], float(epsilon_m))
    else:
        r = np.maximum(radius if all_finite else radius[finite], float(epsilon_m))
    ix, iy = cell_indices(fp, float(r.max()) * _CELL_MARGIN)
    xs = fp[:, 0].copy()  # always a fresh writable array: one numba signature, however the input came
    ys = fp[:, 1].copy()
    core_f, labels_f = _dbscan(xs, ys, r, ix, iy, min_points)
    if all_finite:
        return core_f, labels_f.astype(np.intp, copy=False)
    core[finite] = core_f
    labels[finite] = labels_f
    return core, labels


@register
class Dbscan(NoiseRemovalKernel[DbscanParams]):
    """DBSCAN noise removal (paper §3.2.1): keeps core and border points, drops noise points.

    ``min_points`` counts the point itself (scikit-learn's ``min_samples``). Default 3 with ``epsilon_m``
    5 cm: a wall return then needs one neighbour on each side within 5 cm, which the URG-04LX's 0.35 deg beam
    spacing gives up to ~8 m at normal incidence (3 cm spacing at 5 m), while a lone outlier return has none.
    ``min_points`` 4 would need two neighbours per side, which a single scan only gives within ~4 m; raise it
    for accumulated (offline) batches, where every wall is seen several times.

    Result: ``keep`` marks core and border points; ``points`` are the kept points in input order; ``labels``
    their cluster id ``0..C-1`` (numbered by lowest-index core point, as scikit-learn does). Non-finite rows
    are dropped as noise. Empty input gives an empty result; duplicates count as separate neighbours.
    Time O(N + candidate pairs), memory O(N).
    """

    name = "dbscan"
    version = "1.0.0"
    Params = DbscanParams

    uses_spacing = True

    def apply(self, points: ArrayLike, spacing_m: ArrayLike | None = None) -> NoiseResult:
        """Filter ``points`` ``(N, 2)`` (metres); ``spacing_m`` ``(N,)``: each point's beam spacing (its
        range times the scanner's angular step, metres), which widens its neighbourhood by
        ``spacing_factor``; ``None``: the fixed ``epsilon_m`` of the paper."""
        pts = as_points(points)
        p = self.params
        radius = None
        if spacing_m is not None and p.spacing_factor > 0.0:
            radius = np.maximum(p.spacing_factor * np.asarray(spacing_m, dtype=np.float64), p.epsilon_m)
        _, labels = dbscan_core_labels(pts, p.epsilon_m, p.min_points, radius)
        keep = labels >= 0
        out = pts[keep]
        out_labels = labels[keep].astype(np.intp, copy=True)
        freeze(keep, out, out_labels)
        return NoiseResult(keep=keep, points=out, labels=out_labels)
