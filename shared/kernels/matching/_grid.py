"""Exact fixed-radius nearest-neighbour search on a uniform grid, compiled with numba (for ICP's inner loop).

The reference points are bucketed into square cells of side ``h`` (counting sort, O(M + cells)); a query
visits rings of cells around its own cell, nearest ring first, and stops as soon as no unvisited cell can
hold a closer point than the best found or one within the search radius. The answer is the exact nearest
reference point within the radius (ties may pick a different index than a k-d tree). Queries far from the
reference cost O(1); near ones O(points in the few cells visited).

The grid has at most ``_MAX_CELLS_PER_AXIS`` cells per axis; a reference spread wider gets coarser cells
(still exact, only slower). :func:`nearest_within` wraps it for callers and tests; kernels call the
``_grid_*`` functions from their own compiled loops.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.kernels._jit import njit
from shared.types import FloatArray, IntArray, as_points

__all__ = ["nearest_within"]

_MAX_CELLS_PER_AXIS = 256


@njit
def _grid_build(
    ref: FloatArray, cell_m: float, max_cells: int
) -> tuple[FloatArray, IntArray, IntArray, float, float, float, int, int]:
    """Bucket ``ref`` ``(M >= 1, 2)`` (finite) into cells of about ``cell_m``.

    Returns ``(sorted_xy, order, start, x0, y0, h, nx, ny)``: points ``start[c]..start[c+1]-1`` of
    ``sorted_xy`` (original indices in ``order``) lie in cell ``c = cx * ny + cy``.
    """
    m = ref.shape[0]
    x0 = ref[0, 0]
    y0 = ref[0, 1]
    x1 = x0
    y1 = y0
    for i in range(1, m):
        x0 = min(x0, ref[i, 0])
        x1 = max(x1, ref[i, 0])
        y0 = min(y0, ref[i, 1])
        y1 = max(y1, ref[i, 1])
    h = max(cell_m, (x1 - x0) / (max_cells - 1), (y1 - y0) / (max_cells - 1))
    nx = min(int((x1 - x0) / h) + 1, max_cells)
    ny = min(int((y1 - y0) / h) + 1, max_cells)
    cell = np.empty(m, dtype=np.intp)
    start = np.zeros(nx * ny + 1, dtype=np.intp)
    for i in range(m):
        cx = min(int((ref[i, 0] - x0) / h), nx - 1)
        cy = min(int((ref[i, 1] - y0) / h), ny - 1)
        cell[i] = cx * ny + cy
        start[cell[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(m, dtype=np.intp)
    sorted_xy = np.empty((m, 2), dtype=np.float64)
    for i in range(m):
        k = fill[cell[i]]
        fill[cell[i]] += 1
        order[k] = i
        sorted_xy[k, 0] = ref[i, 0]
        sorted_xy[k, 1] = ref[i, 1]
    return sorted_xy, order, start, x0, y0, h, nx, ny


@njit
def _scan_cell(
    sorted_xy: FloatArray, start: IntArray, c: int, qx: float, qy: float, best: float, best_j: int
) -> tuple[float, int]:
    """Improve ``(best squared distance, best position)`` with the points of cell ``c``."""
    for p in range(start[c], start[c + 1]):
        dx = sorted_xy[p, 0] - qx
        dy = sorted_xy[p, 1] - qy
        d2 = dx * dx + dy * dy
        if d2 <= best:
            best = d2
            best_j = p
    return best, best_j


@njit
def _grid_nearest(
    sorted_xy: FloatArray,
    order: IntArray,
    start: IntArray,
    x0: float,
    y0: float,
    h: float,
    nx: int,
    ny: int,
    qx: float,
    qy: float,
    max_d: float,
) -> tuple[int, float]:
    """Nearest reference point to ``(qx, qy)`` within ``max_d``: ``(index, squared distance)``, else
    ``(-1, inf)``. The query must be finite."""
    # distance from the query to the grid's bounding rectangle; nothing within reach beyond it
    gx = max(0.0, x0 - qx, qx - (x0 + nx * h))
    gy = max(0.0, y0 - qy, qy - (y0 + ny * h))
    if gx * gx + gy * gy > max_d * max_d:
        return -1, math.inf
    fx = (qx - x0) / h
    fy = (qy - y0) / h
    cqx = math.floor(fx)
    cqy = math.floor(fy)
    # rings nearer than the grid's edge are empty: start at the first ring that touches the grid
    k = max(0, -cqx, cqx - (nx - 1), -cqy, cqy - (ny - 1))
    # where the query sits inside its own cell (0..h), for the bound on unvisited rings
    inner = min(fx - cqx, cqx + 1 - fx, fy - cqy, cqy + 1 - fy) * h
    best = max_d * max_d
    best_j = -1
    while True:
        lo_x = cqx - k
        hi_x = cqx + k
        lo_y = cqy - k
        hi_y = cqy + k
        for cx in range(max(lo_x, 0), min(hi_x, nx - 1) + 1):
            if cx in (lo_x, hi_x):  # a full column of the ring
                for cy in range(max(lo_y, 0), min(hi_y, ny - 1) + 1):
                    best, best_j = _scan_cell(sorted_xy, start, cx * ny + cy, qx, qy, best, best_j)
            else:  # only the ring's bottom and top cells
                if 0 <= lo_y < ny:
                    best, best_j = _scan_cell(sorted_xy, start, cx * ny + lo_y, qx, qy, best, best_j)
                if 0 <= hi_y < ny:
                    best, best_j = _scan_cell(sorted_xy, start, cx * ny + hi_y, qx, qy, best, best_j)
        # every unvisited cell lies at least this far away
        bound = k * h + inner
        if bound > max_d or best <= bound * bound:
            break
        if lo_x <= 0 and hi_x >= nx - 1 and lo_y <= 0 and hi_y >= ny - 1:
            break
        k += 1
    if best_j < 0:
        return -1, math.inf
    return order[best_j], best


@njit
def _nearest_all(
    ref: FloatArray, queries: FloatArray, max_d: float, cell_m: float, max_cells: int
) -> tuple[IntArray, FloatArray]:
    sorted_xy, order, start, x0, y0, h, nx, ny = _grid_build(ref, cell_m, max_cells)
    n = queries.shape[0]
    idx = np.empty(n, dtype=np.intp)
    dist = np.empty(n, dtype=np.float64)
    for i in range(n):
        j, d2 = _grid_nearest(sorted_xy, order, start, x0, y0, h, nx, ny, queries[i, 0], queries[i, 1], max_d)
        idx[i] = j
        dist[i] = math.sqrt(d2)
    return idx, dist


def nearest_within(
    reference: ArrayLike, queries: ArrayLike, max_distance_m: float, cell_m: float | None = None
) -> tuple[IntArray, FloatArray]:
    """For each query, the index of the nearest finite reference point within ``max_distance_m`` and its
    distance, or ``(-1, inf)`` when there is none. Non-finite queries get ``(-1, inf)``.

    ``cell_m`` (default ``max_distance_m / 4``) only affects speed. O(M + cells) to build, then about
    O(points in the visited cells) per query.
    """
    ref = as_points(reference, name="reference")
    q = as_points(queries, name="queries")
    keep = np.flatnonzero(np.isfinite(ref).all(axis=1))
    idx = np.full(q.shape[0], -1, dtype=np.intp)
    dist = np.full(q.shape[0], np.inf)
    ok = np.isfinite(q).all(axis=1)
    if keep.size == 0 or not ok.any():
        return idx, dist
    cell = max_distance_m / 4.0 if cell_m is None else cell_m
    j, d = _nearest_all(
        np.ascontiguousarray(ref[keep]),
        np.ascontiguousarray(q[ok]),
        float(max_distance_m),
        float(cell),
        _MAX_CELLS_PER_AXIS,
    )
    idx[ok] = np.where(j >= 0, keep[np.maximum(j, 0)], -1)
    dist[ok] = d
    return idx, dist
