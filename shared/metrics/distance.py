"""Segment sampling and exact point-to-segment distances, vectorised (the geometry under docs/design.md §5's
metrics).

Segments are ``(L, 4)`` float64 rows ``[x0, y0, x1, y1]`` in metres; points are ``(N, 2)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from shared.metrics.errors import MetricInputError
from shared.types import BoolArray, FloatArray, IntArray

__all__ = [
    "as_segments",
    "closest_points",
    "nearest_segment",
    "paired_distance",
    "sample_segments",
    "segment_lengths",
    "spaced_points",
    "within_distance",
]

_BRUTE_PAIRS = 2_000_000  # point x segment pairs evaluated per brute-force chunk
_CANDIDATES = (4, 32)  # index samples checked per point in each round before falling back to brute force


def as_segments(segments: ArrayLike, *, name: str = "segments", allow_empty: bool = True) -> FloatArray:
    """Validate ``segments`` as a finite ``(L, 4)`` float64 array; raise :class:`MetricInputError` if not."""
    arr = np.asarray(segments, dtype=np.float64)
    if arr.size == 0 and allow_empty:
        return np.zeros((0, 4), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4 or arr.shape[0] == 0:
        need = "(L, 4)" if allow_empty else "(L, 4) with L >= 1"
        raise MetricInputError(f"{name} has shape {arr.shape}: expected {need} rows [x0, y0, x1, y1] in m")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise MetricInputError(f"{name}[{bad}] = {arr[bad].tolist()} is not finite: expected metres")
    return np.ascontiguousarray(arr)


def segment_lengths(segments: FloatArray) -> FloatArray:
    """Euclidean length of each segment (m). O(L)."""
    return np.asarray(np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]))


def sample_segments(segments: FloatArray, spacing_m: float) -> tuple[FloatArray, IntArray, FloatArray]:
    """Cut each segment into ``n = ceil(length / spacing_m)`` equal pieces and return the piece midpoints.

    Returns ``(points (N, 2), owner (N,) segment index, weight_m (N,) piece length)``; the weights of one
    segment sum to its length, so length-weighted statistics over the samples are midpoint-rule integrals
    along the map. Zero-length segments give no samples. O(total length / spacing).
    """
    if not spacing_m > 0.0:
        raise MetricInputError(f"sample spacing = {spacing_m!r} m: expected a positive length")
    length = segment_lengths(segments)
    # the 1e-9 keeps a length that is an exact multiple of the spacing from flipping to one more piece on
    # a rounding error (the same map translated must sample the same way)
    n = np.where(length > 0.0, np.ceil(length / spacing_m - 1e-9), 0).astype(np.intp)
    owner = np.repeat(np.arange(len(segments), dtype=np.intp), n)
    start = np.cumsum(n) - n
    k = np.arange(int(n.sum()), dtype=np.intp) - np.repeat(start, n)
    t = (k + 0.5) / n[owner]
    seg = segments[owner]
    points = seg[:, :2] + t[:, None] * (seg[:, 2:] - seg[:, :2])
    weight = length[owner] / n[owner]
    return points, owner, np.asarray(weight, dtype=np.float64)


def _project(points: FloatArray, a: FloatArray, d: FloatArray) -> FloatArray:
    """Clamped line parameter of ``points`` on segments ``a + t d`` (broadcasting)."""
    dd = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
    num = (points[..., 0] - a[..., 0]) * d[..., 0] + (points[..., 1] - a[..., 1]) * d[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dd > 0.0, num / np.where(dd > 0.0, dd, 1.0), 0.0)
    return np.asarray(np.clip(t, 0.0, 1.0))


def closest_points(points: FloatArray, segments: FloatArray) -> FloatArray:
    """Closest point of segment ``i`` to point ``i`` (paired rows, ``(N, 2)`` and ``(N, 4)``). O(N)."""
    a, d = segments[:, :2], segments[:, 2:] - segments[:, :2]
    t = _project(points, a, d)
    return np.asarray(a + t[:, None] * d)


def paired_distance(points: FloatArray, segments: FloatArray) -> FloatArray:
    """Distance from point ``i`` to segment ``i`` (paired rows). O(N)."""
    q = closest_points(points, segments)
    return np.asarray(np.hypot(points[:, 0] - q[:, 0], points[:, 1] - q[:, 1]))


def _brute(points: FloatArray, segments: FloatArray) -> tuple[FloatArray, IntArray]:
    """Exact nearest segment by chunked broadcasting, O(N L) time, O(chunk) memory."""
    n = len(points)
    dist = np.empty(n, dtype=np.float64)
    index = np.empty(n, dtype=np.intp)
    a = segments[None, :, :2]
    d = segments[None, :, 2:] - segments[None, :, :2]
    step = max(1, _BRUTE_PAIRS // max(1, len(segments)))
    for lo in range(0, n, step):
        p = points[lo : lo + step, None, :]
        t = _project(p, a, d)
        qx = a[..., 0] + t * d[..., 0] - p[..., 0]
        qy = a[..., 1] + t * d[..., 1] - p[..., 1]
        d2 = qx * qx + qy * qy
        best = np.argmin(d2, axis=1)
        index[lo : lo + step] = best
        dist[lo : lo + step] = np.sqrt(d2[np.arange(len(best)), best])
    return dist, index


def spaced_points(segments: FloatArray, spacing_m: float) -> tuple[FloatArray, IntArray]:
    """Points along each segment, end points included, consecutive ones at most ``spacing_m`` apart.

    Returns ``(points (S, 2), owner (S,) segment index)``; every point of a segment lies within
    ``spacing_m / 2`` of one of its points (the search-index sampling). O(total length / spacing).
    """
    length = segment_lengths(segments)
    n = np.maximum(1, np.ceil(length / spacing_m - 1e-9)).astype(np.intp) + 1
    owner = np.repeat(np.arange(len(segments), dtype=np.intp), n)
    start = np.cumsum(n) - n
    k = np.arange(int(n.sum()), dtype=np.intp) - np.repeat(start, n)
    t = k / (n[owner] - 1)
    seg = segments[owner]
    return seg[:, :2] + t[:, None] * (seg[:, 2:] - seg[:, :2]), owner


def nearest_segment(
    points: FloatArray, segments: FloatArray, *, max_distance_m: float | None = None
) -> tuple[FloatArray, IntArray]:
    """Exact distance (m) from each point to its nearest segment, and that segment's index.

    Small problems are brute-forced. Larger ones use a k-d tree on points spaced at most ``h`` along the
    segments: the nearest sample gives an upper bound ``u`` (exact distance to its segment), and every
    segment closer than ``u`` owns a sample within ``u + h/2``; those candidates are checked exactly, and
    points with more than 4, then 32 candidate samples fall back to brute force, so the answer is always
    exact.
    With ``max_distance_m`` set, points farther than that from every segment get ``inf`` and index -1
    (cheaper: they are rejected from the tree alone). Typically O(N log S + S log S), S samples.
    """
    n, n_seg = len(points), len(segments)
    if n_seg == 0:
        return np.full(n, np.inf), np.full(n, -1, dtype=np.intp)
    if n == 0:
        return np.zeros(0), np.zeros(0, dtype=np.intp)
    if n * n_seg <= _BRUTE_PAIRS:
        dist, index = _brute(points, segments)
    else:
        dist, index = _indexed(points, segments, max_distance_m)
    if max_distance_m is not None:
        far = ~(dist <= max_distance_m)
        dist = np.where(far, np.inf, dist)
        index = np.where(far, -1, index)
    return dist, index


def within_distance(points: FloatArray, segments: FloatArray, radius_m: float) -> BoolArray:
    """Whether each point has some segment within ``radius_m`` (exact; cheaper than the distances).

    Same search as :func:`nearest_segment`, but a point stops as soon as one segment is close enough.
    """
    n, n_seg = len(points), len(segments)
    if n_seg == 0 or n == 0:
        return np.zeros(n, dtype=bool)
    if n * n_seg <= _BRUTE_PAIRS:
        dist, _ = _brute(points, segments)
    else:
        dist, _ = _indexed(points, segments, radius_m, settle_below_m=radius_m)
    return np.asarray(dist <= radius_m)


def _indexed(
    points: FloatArray, segments: FloatArray, max_distance_m: float | None, *, settle_below_m: float = -1.0
) -> tuple[FloatArray, IntArray]:
    """k-d tree search; points already closer than ``settle_below_m`` keep their first (bound) answer."""
    length = segment_lengths(segments)
    positive = length[length > 0.0]
    h = float(np.clip(0.5 * np.median(positive), 0.02, 0.1)) if len(positive) else 0.1
    samples, owner = spaced_points(segments, h)
    tree = cKDTree(samples)
    d0, i0 = tree.query(points, k=1)
    index = owner[i0]
    dist = paired_distance(points, segments[index])
    todo = np.ones(len(points), dtype=bool)
    if max_distance_m is not None:
        todo = d0 <= max_distance_m + 0.5 * h + 1e-12
    rows = np.flatnonzero(todo & ~(dist <= settle_below_m))
    for k in _CANDIDATES:
        if len(rows) == 0:
            break
        k = min(k, len(samples))
        bound = dist[rows] + 0.5 * h + 1e-12
        dk, ik = tree.query(points[rows], k=k, distance_upper_bound=float(np.max(bound)))
        dk, ik = dk.reshape(len(rows), k), ik.reshape(len(rows), k)
        valid = (dk <= bound[:, None]) & (ik < len(samples))
        cand = owner[np.where(valid, ik, 0)]
        dc = paired_distance(np.repeat(points[rows], k, axis=0), segments[cand.ravel()]).reshape(len(rows), k)
        dc = np.where(valid, dc, np.inf)
        best = np.argmin(dc, axis=1)
        r = np.arange(len(rows))
        better = dc[r, best] < dist[rows]
        dist[rows[better]] = dc[r, best][better]
        index[rows[better]] = cand[r, best][better]
        # rows whose k-th candidate is still inside the bound may have more: try a larger k
        rows = rows[valid[:, -1]] if k < len(samples) else rows[:0]
    if len(rows):
        dist[rows], index[rows] = _brute(points[rows], segments)
    return dist, index
