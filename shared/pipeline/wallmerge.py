"""The wall map's compiled merge loop: insert segments, find the wall each should join, fuse two walls.

Pure functions over the wall map's state arrays (see :class:`shared.pipeline.wallmap.WallMap` for the
merge rules and the moments they keep); compiled with numba where available. O(W) per inserted segment
for W walls.
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import BoolArray, FloatArray, IntArray

__all__ = ["OBSERVATIONS_CAP", "explained_by", "insert_all"]

#: observation counts saturate here: a wall cut by free space and fused back with its own piece would
#: otherwise double its count each time and wrap around int64 (it then left the shown map)
OBSERVATIONS_CAP = 1 << 40


@njit
def insert_all(
    segs: FloatArray,
    ids: IntArray,
    obs: IntArray,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    n: int,
    next_id: int,
    cos_tol: float,
    offset_tol: float,
    gap_tol: float,
    min_length: float,
    observations: int,
    removed: IntArray,
    by_band: bool,
    sigmas: FloatArray,
    oriented: bool,
    vx: float,
    vy: float,
    k_sigma: float,
    dir_sds: FloatArray,
    info: FloatArray,
    min_info: float,
    may_create: BoolArray,
) -> tuple[int, int, int]:
    """Insert and settle every segment; returns the new wall count, next id and number of removed ids.

    Arrays are the wall map's state (see :class:`shared.pipeline.wallmap.WallMap`), changed in place;
    ``dir_sds`` are the segments' direction standard deviations (rad, 0 unknown), ``info`` the walls'
    accumulated direction information (rad^-2). A segment with ``may_create`` False joins a wall it
    matches but starts no wall of its own."""
    n_removed = 0
    for k in range(segs.shape[0]):
        x0, y0, x1, y1 = segs[k, 0], segs[k, 1], segs[k, 2], segs[k, 3]
        sig = sigmas[k]
        if not (np.isfinite(x0) and np.isfinite(y0) and np.isfinite(x1) and np.isfinite(y1)):
            continue
        if not np.isfinite(sig):
            sig = 0.0
        length = np.hypot(x1 - x0, y1 - y0)
        if length < min_length:
            continue
        i = n
        mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        dx, dy = (x1 - x0) / length, (y1 - y0) / length
        if oriented and dx * (vy - my) - dy * (vx - mx) < 0.0:  # face the scanner: it is on the left
            dx, dy = -dx, -dy
        # a uniform mass along the segment plus its points' scatter across it (covariance
        # L^2 / 12 d d^T + sigma^2 n n^T, n the normal)
        var = length * length / 12.0
        var_n = sig * sig
        ids[i] = next_id
        obs[i] = min(observations, OBSERVATIONS_CAP)
        next_id += 1
        w[i] = length
        s1[i, 0], s1[i, 1] = length * mx, length * my
        s2[i, 0] = length * (var * dx * dx + var_n * dy * dy + mx * mx)
        s2[i, 1] = length * ((var - var_n) * dx * dy + mx * my)
        s2[i, 2] = length * (var * dy * dy + var_n * dx * dx + my * my)
        c[i, 0], c[i, 1] = mx, my
        d[i, 0], d[i, 1] = dx, dy
        lo[i], hi[i] = -0.5 * length, 0.5 * length
        sd = dir_sds[k]
        info[i] = 1.0 / (sd * sd) if np.isfinite(sd) and sd > 0.0 else 0.0
        n += 1
        first = True
        while True:
            j = _match(
                i,
                n,
                w,
                s1,
                s2,
                c,
                d,
                lo,
                hi,
                cos_tol,
                offset_tol,
                gap_tol,
                by_band,
                oriented,
                k_sigma,
                info,
                min_info,
            )
            if j < 0:
                if first and not may_create[k]:  # matched no wall: dropped, not a wall of its own
                    n -= 1
                    next_id -= 1
                break
            first = False
            keep, drop = (i, j) if ids[i] < ids[j] else (j, i)
            removed[n_removed] = ids[drop]
            n_removed += 1
            _fuse(keep, drop, obs, w, s1, s2, c, d, lo, hi)
            info[keep] += info[drop]
            for arr1 in (ids, obs):
                arr1[drop : n - 1] = arr1[drop + 1 : n]
            for arr2 in (w, lo, hi, info):
                arr2[drop : n - 1] = arr2[drop + 1 : n]
            s1[drop : n - 1] = s1[drop + 1 : n]
            s2[drop : n - 1] = s2[drop + 1 : n]
            c[drop : n - 1] = c[drop + 1 : n]
            d[drop : n - 1] = d[drop + 1 : n]
            n -= 1
            i = keep - 1 if drop < keep else keep
    return n, next_id, n_removed


@njit
def _cross_var(k: int, w: FloatArray, s1: FloatArray, s2: FloatArray) -> float:
    """Wall ``k``'s perpendicular scatter (m^2): the minor eigenvalue of its moments' covariance."""
    cx, cy = s1[k, 0] / w[k], s1[k, 1] / w[k]
    sxx = s2[k, 0] / w[k] - cx * cx
    sxy = s2[k, 1] / w[k] - cx * cy
    syy = s2[k, 2] / w[k] - cy * cy
    half = 0.5 * (sxx + syy)
    minor: float = half - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    return max(minor, 0.0)


@njit
def _match(
    i: int,
    n: int,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    cos_tol: float,
    offset_tol: float,
    gap_tol: float,
    by_band: bool,
    oriented: bool,
    k_sigma: float,
    info: FloatArray,
    min_info: float,
) -> int:
    """The first wall wall ``i`` should merge with (collinear, close, overlapping or a small gap), or -1.

    Oriented walls (seen from a known side) merge only with walls facing the same way. With ``k_sigma >
    0`` a wall whose ends lie farther than ``offset_tol`` from the other's line still merges when they lie
    within ``k_sigma`` standard deviations of the two walls' combined perpendicular scatter and the two
    overlap along their length (the same surface drawn twice, e.g. from poses a few cm apart). A wall's
    direction counts as known (so a short tilted piece may join it within its end band) when the wall is
    long enough for the angle test to bound it, or when its accumulated direction information is at least
    ``min_info`` (rad^-2): a short wall seen in many scans is as well determined as a long one."""
    ax, ay = c[i, 0] + d[i, 0] * lo[i], c[i, 1] + d[i, 1] * lo[i]
    bx, by = c[i, 0] + d[i, 0] * hi[i], c[i, 1] + d[i, 1] * hi[i]
    # a short piece's direction is only known to within its ends' band: both ends within offset_tol of a
    # line allow a tilt of up to asin(2 offset_tol / length), so that bounds the angle test from below. Only
    # against a wall whose own direction is known to within the angle test (not itself that short): two
    # short pieces (a person's legs in successive scans) do not vouch for each other's direction.
    length = hi[i] - lo[i]
    cos_i = cos_tol
    if by_band:
        sin_band = min(2.0 * offset_tol / max(length, 1e-12), 1.0)
        cos_i = min(cos_tol, np.sqrt(1.0 - sin_band * sin_band))
    determined_m = 2.0 * offset_tol / max(np.sqrt(max(1.0 - cos_tol * cos_tol, 0.0)), 1e-12)
    var_i = _cross_var(i, w, s1, s2) if k_sigma > 0.0 else 0.0
    for j in range(n):
        if j == i:
            continue
        cos_ij = d[j, 0] * d[i, 0] + d[j, 1] * d[i, 1]
        if not oriented:
            cos_ij = abs(cos_ij)
        if cos_ij < cos_i or (cos_ij < cos_tol and hi[j] - lo[j] < determined_m and info[j] < min_info):
            continue
        nx, ny = -d[j, 1], d[j, 0]
        rax, ray, rbx, rby = ax - c[j, 0], ay - c[j, 1], bx - c[j, 0], by - c[j, 1]
        off = max(abs(rax * nx + ray * ny), abs(rbx * nx + rby * ny))
        ta, tb = rax * d[j, 0] + ray * d[j, 1], rbx * d[j, 0] + rby * d[j, 1]
        gap = max(min(ta, tb) - hi[j], lo[j] - max(ta, tb))
        if off <= offset_tol:
            if gap <= gap_tol:
                return j
            continue
        if (
            k_sigma > 0.0
            and gap < 0.0
            and off * off <= k_sigma * k_sigma * (var_i + _cross_var(j, w, s1, s2))
        ):
            return j
    return -1


@njit
def _fuse(
    keep: int,
    drop: int,
    obs: IntArray,
    w: FloatArray,
    s1: FloatArray,
    s2: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
) -> None:
    """Add wall ``drop``'s moments to wall ``keep`` and refit its line and extent (closed-form 2x2 PCA)."""
    ends = np.empty((4, 2))
    for r, k in enumerate((keep, drop)):
        ends[2 * r, 0], ends[2 * r, 1] = c[k, 0] + d[k, 0] * lo[k], c[k, 1] + d[k, 1] * lo[k]
        ends[2 * r + 1, 0], ends[2 * r + 1, 1] = c[k, 0] + d[k, 0] * hi[k], c[k, 1] + d[k, 1] * hi[k]
    obs[keep] = min(obs[keep] + obs[drop], OBSERVATIONS_CAP)
    w[keep] += w[drop]
    s1[keep, 0] += s1[drop, 0]
    s1[keep, 1] += s1[drop, 1]
    for q in range(3):
        s2[keep, q] += s2[drop, q]
    cx, cy = s1[keep, 0] / w[keep], s1[keep, 1] / w[keep]
    sxx = s2[keep, 0] / w[keep] - cx * cx
    sxy = s2[keep, 1] / w[keep] - cx * cy
    syy = s2[keep, 2] / w[keep] - cy * cy
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis of the 2x2 covariance
    dx, dy = np.cos(phi), np.sin(phi)
    if dx * d[keep, 0] + dy * d[keep, 1] < 0.0:
        dx, dy = -dx, -dy
    t_lo, t_hi = np.inf, -np.inf
    for r in range(4):
        t = (ends[r, 0] - cx) * dx + (ends[r, 1] - cy) * dy
        t_lo, t_hi = min(t_lo, t), max(t_hi, t)
    c[keep, 0], c[keep, 1] = cx, cy
    d[keep, 0], d[keep, 1] = dx, dy
    lo[keep], hi[keep] = t_lo, t_hi


@njit
def explained_by(
    segs: FloatArray,
    sd: FloatArray,
    band: FloatArray,
    c: FloatArray,
    d: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    vx: float,
    vy: float,
    oriented: bool,
    k_sigma: float,
) -> BoolArray:
    """Per segment whether one of the walls ``(c, d, lo, hi)`` explains it (the loop of
    :meth:`shared.pipeline.wallmap.WallMap.explained`, which states the test). O(L x W)."""
    n_seg, n_wall = segs.shape[0], c.shape[0]
    out = np.zeros(n_seg, dtype=np.bool_)
    for i in range(n_seg):
        if not sd[i] > 0.0:
            continue
        ux, uy = segs[i, 2] - segs[i, 0], segs[i, 3] - segs[i, 1]
        norm = max(math.hypot(ux, uy), 1e-12)
        ux, uy = ux / norm, uy / norm
        sign = 1.0
        if oriented:  # face the scanner (on the left) as the stored walls do
            mx, my = 0.5 * (segs[i, 0] + segs[i, 2]), 0.5 * (segs[i, 1] + segs[i, 3])
            sign = 1.0 if ux * (vy - my) - uy * (vx - mx) >= 0.0 else -1.0
        for w in range(n_wall):
            ax, ay = segs[i, 0] - c[w, 0], segs[i, 1] - c[w, 1]
            bx, by = segs[i, 2] - c[w, 0], segs[i, 3] - c[w, 1]
            ta, tb = ax * d[w, 0] + ay * d[w, 1], bx * d[w, 0] + by * d[w, 1]
            if not (max(ta, tb) > lo[w] and min(ta, tb) < hi[w]):
                continue
            off = max(abs(ax * -d[w, 1] + ay * d[w, 0]), abs(bx * -d[w, 1] + by * d[w, 0]))
            if not off <= band[i]:
                continue
            cos = ux * d[w, 0] + uy * d[w, 1]
            cos = sign * cos if oriented else abs(cos)
            if math.acos(min(max(cos, -1.0), 1.0)) <= k_sigma * sd[i]:
                out[i] = True
                break
    return out
