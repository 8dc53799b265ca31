"""The scheduled part of the pipeline: noise removal -> clustering -> straight lines, on chunks of points.

A :class:`Chunk` is what flows between stages: world-frame points with their segment (group) ids and, after
clustering, the centroids with the group each belongs to. Every function here is pure.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from shared.kernels import Lines
from shared.kernels._jit import njit
from shared.kernels.base import takes_spacing
from shared.pipeline.rangenoise import RangeNoise
from shared.types import FloatArray, IntArray

__all__ = [
    "Chunk",
    "centroids_in_order",
    "cluster",
    "concat",
    "extract_lines",
    "extract_lines_grouped",
    "line_sigmas",
    "line_uncertainty",
    "noise_floored_uncertainty",
    "remove_noise",
]


@dataclass(frozen=True, slots=True)
class Chunk:
    """Points ``(N, 2)`` (metres, world frame) with group ids ``(N,)`` (-1: none), optional centroids, the
    number of scan steps the chunk holds (the evidence its walls carry), where the scanner saw them from
    (world frame, metres; the steps' mean for a batch; ``None``: unknown), which tells the wall map which
    face of a wall a segment is, and each point's beam spacing ``(N,)`` (its range times the scanner's
    angular step, metres; ``None``: unknown), which tells noise removal how dense a wall's returns are."""

    points: FloatArray
    groups: IntArray
    centroids: FloatArray
    centroid_groups: IntArray
    steps: int = 1
    viewpoint: tuple[float, float] | None = None
    spacing_m: FloatArray | None = None

    @classmethod
    def of(
        cls,
        points: FloatArray,
        groups: IntArray,
        viewpoint: tuple[float, float] | None = None,
        spacing_m: FloatArray | None = None,
    ) -> Chunk:
        """A chunk of one step's points without centroids, seen from ``viewpoint``."""
        return cls(points, groups, np.zeros((0, 2)), np.zeros(0, dtype=np.intp), 1, viewpoint, spacing_m)


def concat(chunks: list[Chunk]) -> Chunk:
    """One chunk holding all the points and centroids of ``chunks``."""
    if len(chunks) == 1:
        return chunks[0]
    return Chunk(
        np.vstack([c.points for c in chunks]) if chunks else np.zeros((0, 2)),
        np.concatenate([c.groups for c in chunks]) if chunks else np.zeros(0, dtype=np.intp),
        np.vstack([c.centroids for c in chunks]) if chunks else np.zeros((0, 2)),
        np.concatenate([c.centroid_groups for c in chunks]) if chunks else np.zeros(0, dtype=np.intp),
        sum(c.steps for c in chunks),
        _mean_viewpoint(chunks),
        np.concatenate([c.spacing_m for c in chunks])
        if chunks and all(c.spacing_m is not None for c in chunks)
        else None,
    )


def _mean_viewpoint(chunks: list[Chunk]) -> tuple[float, float] | None:
    """The step-weighted mean viewpoint of ``chunks`` (``None`` unless every chunk has one)."""
    if not chunks or any(c.viewpoint is None for c in chunks):
        return None
    w = np.array([max(c.steps, 1) for c in chunks], dtype=np.float64)
    xy = np.array([c.viewpoint for c in chunks], dtype=np.float64)
    mean = (w[:, None] * xy).sum(axis=0) / w.sum()
    return float(mean[0]), float(mean[1])


def remove_noise(kernels: list[Any], chunk: Chunk) -> Chunk:
    """Apply the noise-removal kernels in order (paper §3.2). Points a kernel adds (dilation) take the group
    of the nearest kept point, and its beam spacing. Kernels that take the points' beam spacing
    (:func:`~shared.kernels.base.takes_spacing`) are given the chunk's, when it has one. O(N log N)."""
    points, groups, spacing = chunk.points, chunk.groups, chunk.spacing_m
    for kernel in kernels:
        if len(points) == 0:
            break
        if spacing is not None and takes_spacing(kernel):
            result = kernel.apply(points, spacing_m=spacing)
        else:
            result = kernel.apply(points)
        kept_groups = groups[result.keep]
        kept_spacing = spacing[result.keep] if spacing is not None else None
        if result.n_added:
            kept_pts = points[result.keep]
            added = result.points[len(kept_pts) :]
            if len(kept_pts):
                _, nearest = cKDTree(kept_pts).query(added)
                add_groups = kept_groups[nearest]
                add_spacing = kept_spacing[nearest] if kept_spacing is not None else None
            else:
                add_groups = np.full(len(added), -1, dtype=np.intp)
                add_spacing = np.zeros(len(added)) if kept_spacing is not None else None
            kept_groups = np.concatenate([kept_groups, add_groups])
            if kept_spacing is not None and add_spacing is not None:
                kept_spacing = np.concatenate([kept_spacing, add_spacing])
        points, groups, spacing = np.asarray(result.points), np.asarray(kept_groups), kept_spacing
    return Chunk(
        points, groups, chunk.centroids, chunk.centroid_groups, chunk.steps, chunk.viewpoint, spacing
    )


def cluster(
    kernel: Any,
    chunk: Chunk,
    with_k: Callable[[int], Any] | None = None,
    *,
    min_per_wall: int = 0,
    wall_points: int = 30,
) -> Chunk:
    """Cluster the chunk's points (paper §3.3) segment by segment, so no cluster straddles two walls.

    The kernel's ``n_clusters`` is the batch's total: each segment gets a share proportional to its points
    (at most its point count; a segment too small for even half a cluster gets none, unless no segment
    would get any); ``with_k(k)`` returns the kernel with ``n_clusters = k``. A segment with one cluster
    gets its mean (what k-means and FCM return for k = 1) without a kernel call. Points in no segment are
    not clustered. Kernels without ``n_clusters`` cluster the batch as a whole. ``min_per_wall`` raises the
    share of every segment of at least ``wall_points`` points to that many clusters (2 lets a line through
    the centroids: the total then exceeds ``n_clusters`` when the budget is spread thin).
    """
    if len(chunk.points) == 0:
        return chunk
    total = getattr(kernel.params, "n_clusters", None)
    if total is None or with_k is None:
        return _cluster_whole(kernel, chunk)
    valid = chunk.groups >= 0
    if not valid.any():
        return chunk
    uniq, inverse, counts = np.unique(chunk.groups[valid], return_inverse=True, return_counts=True)
    shares = np.minimum(np.rint(total * counts / counts.sum()).astype(np.intp), counts)
    if min_per_wall > 0:  # every wall-sized segment gets enough clusters for a line through them
        shares = np.where(counts >= wall_points, np.maximum(shares, min(min_per_wall, wall_points)), shares)
    if not shares.any():
        shares = np.ones_like(counts)
    order = np.argsort(inverse, kind="stable")
    pts = chunk.points[valid][order]
    bounds = np.concatenate([[0], np.cumsum(counts)])
    # a segment with one cluster gets its mean: all of them in one pass
    means = np.add.reduceat(pts, bounds[:-1], axis=0) / counts[:, None]
    cents: list[FloatArray] = []
    cgroups: list[IntArray] = []
    for g in np.flatnonzero(shares):
        k = int(shares[g])
        if k == 1:
            cents.append(means[g : g + 1])
        else:
            cents.append(np.asarray(with_k(k).apply(pts[bounds[g] : bounds[g + 1]]).centroids))
        cgroups.append(np.full(len(cents[-1]), uniq[g], dtype=np.intp))
    if not cents:
        return chunk
    return Chunk(
        chunk.points, chunk.groups, np.vstack(cents), np.concatenate(cgroups), chunk.steps, chunk.viewpoint
    )


def _cluster_whole(kernel: Any, chunk: Chunk) -> Chunk:
    """Cluster all points at once; each centroid joins the group most of its points are in."""
    result = kernel.apply(chunk.points)
    k = result.n_clusters
    labels = np.asarray(result.labels)
    cgroups = np.full(k, -1, dtype=np.intp)
    ok = (labels >= 0) & (chunk.groups >= 0)
    if ok.any():
        g = chunk.groups[ok]
        uniq, g_idx = np.unique(g, return_inverse=True)
        counts = np.zeros((k, len(uniq)), dtype=np.int64)
        np.add.at(counts, (labels[ok], g_idx), 1)
        has = counts.sum(axis=1) > 0
        cgroups[has] = uniq[counts[has].argmax(axis=1)]
    return Chunk(
        chunk.points, chunk.groups, np.asarray(result.centroids), cgroups, chunk.steps, chunk.viewpoint
    )


def _order_along_groups(points: FloatArray, groups: IntArray) -> IntArray:
    """Indices sorting ``points`` by group, then by position along the group's principal axis."""
    order = np.argsort(groups, kind="stable")
    g_sorted = groups[order]
    keys = np.zeros(len(points))
    bounds = np.flatnonzero(np.diff(g_sorted)) + 1
    for idx in np.split(order, bounds):
        if len(idx) < 2:
            continue
        pts = points[idx]
        centred = pts - pts.mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        keys[idx] = centred @ vt[0]
    return np.lexsort((keys, groups))


def centroids_in_order(chunk: Chunk) -> tuple[FloatArray, IntArray]:
    """The chunk's centroids that belong to a group ``(C, 2)`` and their groups ``(C,)``, ordered by group
    and along each group's principal axis: what a straight-line kernel consuming centroids is given.
    O(C log C)."""
    keep = chunk.centroid_groups >= 0
    cents, cgroups = chunk.centroids[keep], chunk.centroid_groups[keep]
    order = _order_along_groups(cents, cgroups)
    return cents[order], cgroups[order]


def _respan(lines: Lines, points: FloatArray, groups: IntArray, within_m: float) -> FloatArray:
    """Stretch each line over the points of its group that lie within ``within_m`` of it."""
    segs = np.array(lines.segments, copy=True)
    for i in range(lines.n_lines):
        pts = points[groups == lines.group[i]]
        if len(pts) == 0:
            continue
        th, rho = lines.theta_rad[i], lines.rho_m[i]
        n = np.array([np.cos(th), np.sin(th)])
        d = np.array([-n[1], n[0]])
        near = np.abs(pts @ n - rho) <= within_m
        if not near.any():
            continue
        t = pts[near] @ d
        base = rho * n
        segs[i] = np.concatenate([base + d * t.min(), base + d * t.max()])
    return segs


def _extend_polylines(
    lines: Lines, points: FloatArray, groups: IntArray, within_m: float, max_extension_m: float = 1.0
) -> FloatArray:
    """Stretch the free ends of each group's polyline along their piece over the group's points beyond."""
    segs = np.array(lines.segments, copy=True)
    for g in np.unique(lines.group):
        idx = np.flatnonzero(lines.group == g)
        pts = points[groups == g]
        if len(pts) == 0:
            continue
        ends = segs[idx].reshape(-1, 2)  # 2 end points per piece
        key = np.round(ends, 9)
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        free = counts[inverse.reshape(-1)] == 1
        for e in np.flatnonzero(free):
            piece, side = idx[e // 2], e % 2
            tip, base = segs[piece, 2 * side : 2 * side + 2], segs[piece, 2 - 2 * side : 4 - 2 * side]
            length = float(np.hypot(*(tip - base)))
            if length == 0.0:
                continue
            u = (tip - base) / length
            rel = pts - tip
            along = rel @ u
            off = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
            reach = along[(off <= within_m) & (along > 0.0)]
            if reach.size:
                segs[piece, 2 * side : 2 * side + 2] = tip + u * min(float(reach.max()), max_extension_m)
    return segs


def extract_lines(kernel: Any, chunk: Chunk, respan_within_m: float = 0.05) -> FloatArray:
    """Straight-line segments ``(L, 4)`` from a chunk (paper §3.4, §4); see :func:`extract_lines_grouped`."""
    return extract_lines_grouped(kernel, chunk, respan_within_m)[0]


def extract_lines_grouped(
    kernel: Any, chunk: Chunk, respan_within_m: float = 0.05
) -> tuple[FloatArray, IntArray]:
    """Straight-line segments ``(L, 4)`` from a chunk (paper §3.4, §4) and the group ``(L,)`` each came
    from.

    Kernels consuming centroids get them ordered along their group; their infinite lines are then spanned
    over the group's points (docs/design.md §4: "a map segment is its span over the points it came from");
    centroid joining keeps its polyline but stretches the polyline's two end pieces over the points beyond the
    end centroids, so a wall reaches its corners. Kernels consuming points get the points and groups.
    """
    if getattr(kernel, "consumes", "points") == "centroids":
        cents, cgroups = centroids_in_order(chunk)
        if len(cents) == 0:
            return np.zeros((0, 4)), np.zeros(0, dtype=np.intp)
        lines = kernel.apply(cents, cgroups)
        if kernel.name == "centroid-join":
            return _extend_polylines(lines, chunk.points, chunk.groups, respan_within_m), lines.group
        return _respan(lines, chunk.points, chunk.groups, respan_within_m), lines.group
    if len(chunk.points) == 0:
        return np.zeros((0, 4)), np.zeros(0, dtype=np.intp)
    lines = kernel.apply(chunk.points, chunk.groups)
    return np.asarray(lines.segments), np.asarray(lines.group, dtype=np.intp)


@njit
def _sigmas(
    segs: FloatArray, pts: FloatArray, lo: IntArray, hi: IntArray, out: FloatArray, out_dir: FloatArray
) -> None:
    """Fill ``out[i]`` with the robust scatter of ``pts[lo[i]:hi[i]]`` about segment ``i`` and ``out_dir[i]``
    with its direction's standard deviation (see :func:`line_uncertainty`)."""
    for i in range(segs.shape[0]):
        ax, ay = segs[i, 0], segs[i, 1]
        length = np.hypot(segs[i, 2] - ax, segs[i, 3] - ay)
        if hi[i] - lo[i] < 3 or length <= 0.0:
            continue
        dx, dy = (segs[i, 2] - ax) / length, (segs[i, 3] - ay) / length
        r = np.empty(hi[i] - lo[i])
        ts = np.empty(hi[i] - lo[i])
        m = 0
        for p in range(lo[i], hi[i]):
            rx, ry = pts[p, 0] - ax, pts[p, 1] - ay
            t = rx * dx + ry * dy
            if 0.0 <= t <= length:
                r[m] = abs(rx * dy - ry * dx)
                ts[m] = t
                m += 1
        if m >= 3:
            out[i] = 1.4826 * np.median(r[:m])
            spread = np.sum((ts[:m] - np.mean(ts[:m])) ** 2)
            if spread > 0.0:
                out_dir[i] = out[i] / np.sqrt(spread)


def line_uncertainty(
    segments: FloatArray, segment_groups: IntArray, chunk: Chunk
) -> tuple[FloatArray, FloatArray]:
    """Per segment ``(L,)``: the scatter (metres) of its group's points about the segment's line, and the
    standard deviation (radians) of its direction.

    The scatter is the robust standard deviation ``sigma = 1.4826 median |r|`` of the perpendicular
    distances ``r`` of the group's points that project onto the segment (range noise grows with range: a
    wall at 3 m scatters about 4 cm with the URG-04LX, one at 1 m about 1 cm). The direction's standard
    deviation is that of a least-squares line through those points, ``sigma / sqrt(sum (t - mean t)^2)``
    for their positions ``t`` along it (about ``sigma sqrt(12 / n) / length`` for ``n`` evenly spread
    points), so the wall map can tell a noisy short piece, whose direction is barely known, from a precise
    one. Both are 0 (unknown) for a segment with fewer than 3 such points. O(N log N + N_L) for N points,
    N_L of them in the segments' groups.
    """
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    out = np.zeros(len(segs))
    out_dir = np.zeros(len(segs))
    valid = chunk.groups >= 0
    if len(segs) == 0 or not valid.any():
        return out, out_dir
    order = np.argsort(chunk.groups[valid], kind="stable")
    g_sorted = chunk.groups[valid][order]
    pts = np.ascontiguousarray(chunk.points[valid][order], dtype=np.float64)
    lo = np.searchsorted(g_sorted, segment_groups, side="left").astype(np.intp)
    hi = np.searchsorted(g_sorted, segment_groups, side="right").astype(np.intp)
    _sigmas(np.ascontiguousarray(segs), pts, lo, hi, out, out_dir)
    return out, out_dir


def noise_floored_uncertainty(
    segments: FloatArray,
    chunk: Chunk,
    sigmas_m: FloatArray,
    direction_sds_rad: FloatArray,
    range_noise: RangeNoise,
) -> tuple[FloatArray, FloatArray]:
    """Per segment ``(L,)``: its points' scatter (m) and its direction's standard deviation (rad), from
    :func:`line_uncertainty`, with the scatter taken as at least ``range_noise``'s at the segment's range
    from the chunk's viewpoint (the direction's scaled alike). The scatter of a handful of returns about
    their own fitted line is small by chance: a 0.3 m piece of a wall 4 m away (5 cm noise) came out at
    6 mm, its direction "known" to 1.4 degrees while it was tilted 21. Unknown (0) stays 0; without a
    viewpoint or a noise model the inputs are returned. O(L)."""
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    sig = np.asarray(sigmas_m, dtype=np.float64)
    sds = np.asarray(direction_sds_rad, dtype=np.float64)
    if chunk.viewpoint is None or (range_noise.near_m <= 0.0 and range_noise.ratio <= 0.0) or not len(segs):
        return sig, sds
    mid = 0.5 * (segs[:, :2] + segs[:, 2:])
    rng = np.hypot(mid[:, 0] - chunk.viewpoint[0], mid[:, 1] - chunk.viewpoint[1])
    floor = np.maximum(range_noise.near_m, range_noise.ratio * rng)
    scale = np.ones(len(segs))
    known = (sig > 0.0) & (sds > 0.0)
    scale[known] = np.maximum(sig[known], floor[known]) / sig[known]
    floored: FloatArray = np.where(sig > 0.0, np.maximum(sig, floor), 0.0)
    out: FloatArray = sds * scale
    return floored, out


def line_sigmas(segments: FloatArray, segment_groups: IntArray, chunk: Chunk) -> FloatArray:
    """Per segment ``(L,)``: the scatter (metres) of its group's points about the segment's line (the first
    half of :func:`line_uncertainty`)."""
    return line_uncertainty(segments, segment_groups, chunk)[0]
