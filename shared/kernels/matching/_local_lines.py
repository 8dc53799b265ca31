"""Local lines (normal and offset) of the reference scan's points, for point-to-line ICP; compiled with numba.

The reference points come in beam order, seen from the scanner at the origin. Two consecutive points lie on
the same surface when their gap is within the adaptive breakpoint distance of Borges & Aldon (the paper's
ABD, §3.1 eq. 15): ``D = r sin(dphi) / sin(lambda - dphi) + 3 sigma``, with ``r`` the smaller of the two
ranges and ``dphi`` the angle between their bearings (measured from the points, so thinned scans work too).
A point's *window* holds its connected scan neighbours on each side while they are within ``radius`` of it,
but always the first connected neighbour on each side (so sparse far returns still get a line) and at most
``max_side`` per side.

The line of a point is the total-least-squares (PCA) line of its window: the normal is the eigenvector of
the smallest eigenvalue of the window's 2x2 scatter and the offset ``c = n . mean``. A fit is accepted when
``sqrt(lambda_min / lambda_max) <= max_ratio`` (the RMS distance to the line is at most that share of the
RMS spread along it). The symmetric window is tried first; when it fails (a corner or an edge) the better
of the one-sided windows (the point and its left, or its right, neighbours) is used. A point with fewer
than 3 points in every window, or no acceptable fit, gets no line (``valid`` False): it is isolated.

Complexity: O(M * max_side).
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import BoolArray, FloatArray

__all__: list[str] = []


@njit
def _connected(ref: FloatArray, lambda_rad: float, sigma_m: float) -> BoolArray:
    """``out[i]``: points ``i`` and ``i + 1`` of ``ref`` ``(M, 2)`` lie on one surface (ABD test)."""
    m = ref.shape[0]
    out = np.zeros(max(m - 1, 0), dtype=np.bool_)
    for i in range(m - 1):
        ax = ref[i, 0]
        ay = ref[i, 1]
        bx = ref[i + 1, 0]
        by = ref[i + 1, 1]
        dphi = abs(math.atan2(ax * by - ay * bx, ax * bx + ay * by))
        gap = math.hypot(bx - ax, by - ay)
        if dphi >= lambda_rad:
            out[i] = gap <= 3.0 * sigma_m
            continue
        r = min(math.hypot(ax, ay), math.hypot(bx, by))
        out[i] = gap <= r * math.sin(dphi) / math.sin(lambda_rad - dphi) + 3.0 * sigma_m
    return out


@njit
def _fit(ref: FloatArray, lo: int, hi: int) -> tuple[float, float, float, float]:
    """PCA line of ``ref[lo..hi]`` (inclusive): ``(nx, ny, c, ratio)``; ratio inf when degenerate."""
    n = hi - lo + 1
    mx = 0.0
    my = 0.0
    for k in range(lo, hi + 1):
        mx += ref[k, 0]
        my += ref[k, 1]
    mx /= n
    my /= n
    sxx = 0.0
    syy = 0.0
    sxy = 0.0
    for k in range(lo, hi + 1):
        dx = ref[k, 0] - mx
        dy = ref[k, 1] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    half = 0.5 * (sxx + syy)
    root = math.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    lmax = half + root
    lmin = max(half - root, 0.0)
    if not lmax > 0.0:
        return 0.0, 0.0, 0.0, math.inf
    phi = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # direction of the line
    nx = -math.sin(phi)
    ny = math.cos(phi)
    return nx, ny, nx * mx + ny * my, math.sqrt(lmin / lmax)


@njit
def _local_lines(
    ref: FloatArray, radius_m: float, max_side: int, lambda_rad: float, sigma_m: float, max_ratio: float
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Line of every point of ``ref`` ``(M, 2)`` (finite, beam order): ``(normals (M, 2), offsets (M,),
    valid (M,))``; the line of point ``j`` is ``normals[j] . p = offsets[j]``."""
    m = ref.shape[0]
    normals = np.zeros((m, 2), dtype=np.float64)
    offsets = np.zeros(m, dtype=np.float64)
    valid = np.zeros(m, dtype=np.bool_)
    conn = _connected(ref, lambda_rad, sigma_m)
    r2 = radius_m * radius_m
    for i in range(m):
        lo = i
        while lo > 0 and i - lo < max_side and conn[lo - 1]:
            dx = ref[lo - 1, 0] - ref[i, 0]
            dy = ref[lo - 1, 1] - ref[i, 1]
            if lo < i and dx * dx + dy * dy > r2:
                break
            lo -= 1
        hi = i
        while hi < m - 1 and hi - i < max_side and conn[hi]:
            dx = ref[hi + 1, 0] - ref[i, 0]
            dy = ref[hi + 1, 1] - ref[i, 1]
            if hi > i and dx * dx + dy * dy > r2:
                break
            hi += 1
        best = math.inf
        bnx = 0.0
        bny = 0.0
        bc = 0.0
        if hi - lo >= 2:
            bnx, bny, bc, best = _fit(ref, lo, hi)
        if best > max_ratio:  # a corner or an edge: try the sides
            for a, b in ((lo, i), (i, hi)):
                if b - a >= 2:
                    nx, ny, c, ratio = _fit(ref, a, b)
                    if ratio < best:
                        bnx, bny, bc, best = nx, ny, c, ratio
        if best <= max_ratio:
            normals[i, 0] = bnx
            normals[i, 1] = bny
            offsets[i] = bc
            valid[i] = True
    return normals, offsets, valid
